//! The device brick pool: how the GPU backends hold their volumes.
//!
//! Every channel of a scene (a dense grid, one level of a bricked `.bsv` file, derived
//! bricks, a velocity component) is cut into bricks of [`POOL_BRICK`]^3 voxels. A brick
//! whose voxels are all the same value (empty space, a uniform background) takes no memory
//! on the device: its page-table entry holds the value. Every other brick is copied into a
//! slot of one storage buffer, the pool, with one more voxel per axis (the clamped
//! neighbour that trilinear sampling reads, as the `.bsv` apron holds it), so the eight
//! corners of any sample lie in one slot. The shaders (`shaders/pool.wgsl`) look a sample's
//! brick up in the page table and read its corners from the slot or the constant; the
//! arithmetic after that is the dense sampler's, so a pooled channel samples exactly as the
//! CPU's [`blueshift_volume::Field`] does.
//!
//! The pool is bounded by [`GpuContext::pool_capacity_bytes`]: the device's
//! `max_buffer_size` and `max_storage_buffer_binding_size`, or a smaller cap
//! ([`GpuContext::set_pool_limit`], `--gpu-pool-mb`). A volume larger than the device's
//! buffers therefore renders on the GPU when its non-constant bricks fit. When they do not,
//! the upload is refused with [`Error::LimitExceeded`] naming the pool (`--device auto` then
//! renders on the CPU); the callers' level-of-detail rule picks a coarser level that fits
//! ([`fits`]).
//!
//! Constant bricks of a `.bsv` level are found from its stored macrocells without reading
//! the brick (when the file has no NaN or infinite voxel); all others are read through the
//! field's brick cache, a batch of bricks at a time in parallel, and uploaded batch by batch,
//! so host memory stays at one batch whatever the volume's size.

use blueshift_volume::{Field, VectorField};
use rayon::prelude::*;

use crate::context::GpuContext;
use crate::error::{Error, Result};

/// Own voxels per pool brick edge (the shaders' `POOL_B`).
pub const POOL_BRICK: usize = 32;
/// Stored voxels per pool brick edge: one more for the clamped neighbour (`POOL_S`).
pub const POOL_EDGE: usize = POOL_BRICK + 1;
/// f32 values per pool slot.
pub const SLOT_VALUES: usize = POOL_EDGE * POOL_EDGE * POOL_EDGE;
/// Bytes per pool slot.
pub const SLOT_BYTES: u64 = SLOT_VALUES as u64 * 4;
/// Page-table slot marking a constant brick (the shaders' `POOL_CONSTANT`).
pub const CONSTANT: u32 = u32::MAX;
/// The limit a full pool's [`Error::LimitExceeded`] names.
pub const POOL_LIMIT: &str = "brick pool capacity (max_storage_buffer_binding_size, --gpu-pool-mb)";
/// Bricks read and uploaded together (bounds host memory: 64 slots are 9.2 MB).
const BATCH: usize = 64;

/// The WGSL of the pool's page-table lookup, included by the tracking and Doppler shaders.
pub const POOL_WGSL: &str = include_str!("shaders/pool.wgsl");

/// One channel of a pool.
#[derive(Clone, Copy, Debug)]
pub enum PoolChannel<'a> {
    /// A scalar field (vector grids give lengths, as on the CPU).
    Scalar(&'a Field),
    /// Component `.1` (0 x, 1 y, 2 z) of a vector field.
    Component(&'a VectorField, usize),
    /// A channel that is 0 everywhere (no data: one constant page per brick).
    Zero,
}

impl PoolChannel<'_> {
    fn read_block(&self, lo: [usize; 3], out: &mut [f32]) -> Result<()> {
        match self {
            PoolChannel::Scalar(f) => f.read_block(lo, POOL_EDGE, out)?,
            PoolChannel::Component(v, a) => v.read_block(*a, lo, POOL_EDGE, out)?,
            PoolChannel::Zero => out.fill(0.0),
        }
        Ok(())
    }

    fn bricked(&self) -> Option<&blueshift_volume::BrickedField> {
        match self {
            PoolChannel::Scalar(f) => f.as_bricked(),
            PoolChannel::Component(VectorField::Components(c), a) => c[*a].as_bricked(),
            _ => None,
        }
    }

    /// Each brick's value when it is known to be constant without reading it: every brick
    /// of a zero channel; for a `.bsv` level without NaN or infinite voxels, bricks whose
    /// stored macrocells (edge 4, each covering its 5 voxels per axis) all have one value.
    fn constant_hint(&self, dims: [usize; 3]) -> Option<Vec<Option<f32>>> {
        let nb = pool_bricks(dims);
        let n = nb[0] * nb[1] * nb[2];
        if matches!(self, PoolChannel::Zero) {
            return Some(vec![Some(0.0); n]);
        }
        let b = self.bricked()?;
        if b.source().non_finite() != 0 {
            return None;
        }
        let k = 4;
        let m = b.source().stored_macrocells(b.level(), k).ok()??;
        let cd = m.dims();
        let per = POOL_BRICK / k;
        let mut out = Vec::with_capacity(n);
        for i in 0..n {
            let g = [i % nb[0], (i / nb[0]) % nb[1], i / (nb[0] * nb[1])];
            // Cells g*per .. g*per+per cover voxels 32g ..= 32g+32, the slot's.
            let lo = g.map(|c| c * per);
            let hi = [0, 1, 2].map(|a| (lo[a] + per).min(cd[a]));
            let mut value: Option<f32> = None;
            let mut constant = true;
            'cells: for z in lo[2]..hi[2] {
                for y in lo[1]..hi[1] {
                    for x in lo[0]..hi[0] {
                        let (a, b) = m.min_max([x, y, z]);
                        if a != b || value.is_some_and(|v| v != a) {
                            constant = false;
                            break 'cells;
                        }
                        value = Some(a);
                    }
                }
            }
            out.push(if constant { value } else { None });
        }
        Some(out)
    }
}

/// Fields with a level of detail per brick (`BrickedField::per_region`) are the CPU's: the
/// pool holds one level per channel.
pub(crate) fn per_brick_unsupported<'a>(
    fields: impl Iterator<Item = &'a Field>,
) -> std::result::Result<(), crate::Unsupported> {
    for f in fields {
        if f.as_bricked().and_then(|b| b.level_map()).is_some() {
            return Err(crate::Unsupported(
                "per-brick levels of detail (--lod brick) are CPU-only".into(),
            ));
        }
    }
    Ok(())
}

/// Pool bricks per axis for a grid of `dims` voxels.
#[must_use]
pub fn pool_bricks(dims: [usize; 3]) -> [usize; 3] {
    dims.map(|d| d.div_ceil(POOL_BRICK).max(1))
}

/// What a pool holds.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PoolStats {
    /// Channels in the pool.
    pub channels: usize,
    /// Bricks per channel (the page table's length per channel).
    pub bricks_per_channel: usize,
    /// Bricks held in slots (all channels).
    pub resident: usize,
    /// Constant bricks, held as a page-table value only.
    pub constant: usize,
    /// Constant bricks found from stored macrocells, never read.
    pub skipped_reads: usize,
    /// Bytes of the pool buffer.
    pub pool_bytes: u64,
    /// Bytes the channels would take as dense f32 grids (what the backends uploaded before).
    pub dense_bytes: u64,
    /// Bytes the pool may take on this device ([`GpuContext::pool_capacity_bytes`]).
    pub capacity_bytes: u64,
}

impl std::fmt::Display for PoolStats {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "GPU brick pool: {} of {} bricks resident ({:.1} MiB; {} constant, {} never read), \
             {:.1} MiB dense, capacity {:.1} MiB",
            self.resident,
            self.channels * self.bricks_per_channel,
            self.pool_bytes as f64 / 1048576.0,
            self.constant,
            self.skipped_reads,
            self.dense_bytes as f64 / 1048576.0,
            self.capacity_bytes as f64 / 1048576.0,
        )
    }
}

/// A pool and its page table on the device.
#[derive(Debug)]
pub struct DevicePool {
    /// The slots (f32, [`SLOT_VALUES`] each).
    pub pool: wgpu::Buffer,
    /// Per channel, per brick: `(slot, 0)` or `(CONSTANT, value bits)`.
    pub pages: wgpu::Buffer,
    /// What it holds.
    pub stats: PoolStats,
}

/// The grid size of the channels (all must agree; zero channels take any).
fn common_dims(what: &str, channels: &[PoolChannel<'_>]) -> Result<[usize; 3]> {
    let mut dims: Option<[usize; 3]> = None;
    for c in channels {
        let d = match c {
            PoolChannel::Scalar(f) => f.geometry().dims,
            PoolChannel::Component(v, _) => v.geometry().dims,
            PoolChannel::Zero => continue,
        };
        if dims.is_some_and(|x| x != d) {
            return Err(Error::InvalidInput(format!(
                "{what}: channels of different sizes ({:?} and {d:?})",
                dims.unwrap_or_default()
            )));
        }
        dims = Some(d);
    }
    let dims = dims.unwrap_or([1, 1, 1]);
    for (a, d) in dims.iter().enumerate() {
        if *d == 0 || u32::try_from(*d).is_err() {
            return Err(Error::LimitExceeded {
                what: format!("{what}: dimension {a}"),
                limit: "u32 voxel coordinate",
                requested: *d as u64,
                max: u64::from(u32::MAX),
            });
        }
    }
    Ok(dims)
}

/// Largest slot count of a pool on `ctx` (also bounded by the shaders' 32-bit indices).
fn capacity_slots(ctx: &GpuContext) -> u64 {
    (ctx.pool_capacity_bytes() / SLOT_BYTES).min(u64::from(u32::MAX) / SLOT_VALUES as u64)
}

/// What is known of a pool before reading any brick ([`estimate`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PoolEstimate {
    /// Bricks not known to be constant: an upper bound on the slots the pool needs.
    pub slots: u64,
    /// Whether `slots` is exact (every channel's constant bricks are known from stored
    /// macrocells, or the channel is zero); otherwise reading may find more constants.
    pub exact: bool,
    /// Slots the device allows ([`GpuContext::pool_capacity_bytes`]).
    pub capacity: u64,
}

impl PoolEstimate {
    /// Whether the pool surely cannot hold the channels (known without reading).
    #[must_use]
    pub fn surely_full(&self) -> bool {
        self.exact && self.slots > self.capacity
    }
}

/// What a pool of `channels` on `ctx` needs, from what is known without reading bricks
/// (stored macrocells): see [`PoolEstimate`]. Checks the page table against the device.
pub fn estimate(ctx: &GpuContext, channels: &[PoolChannel<'_>]) -> Result<PoolEstimate> {
    let what = "GPU brick pool";
    let dims = common_dims(what, channels)?;
    let nb = pool_bricks(dims);
    let per = (nb[0] * nb[1] * nb[2]) as u64;
    let pages = per.saturating_mul(channels.len().max(1) as u64);
    ctx.check_storage_size("GPU brick pool page table", pages.saturating_mul(8))?;
    let (mut slots, mut exact) = (0u64, true);
    for c in channels {
        slots += match c.constant_hint(dims) {
            Some(h) => h.iter().filter(|v| v.is_none()).count() as u64,
            None => {
                exact = false;
                per
            }
        };
    }
    Ok(PoolEstimate {
        slots,
        exact,
        capacity: capacity_slots(ctx),
    })
}

/// Whether `err` is a full brick pool (a coarser level of detail may fit).
#[must_use]
pub fn is_pool_full(err: &Error) -> bool {
    matches!(err, Error::LimitExceeded { limit, .. } if *limit == POOL_LIMIT)
}

fn pool_full(ctx: &GpuContext, slots: u64) -> Error {
    Error::LimitExceeded {
        what: format!(
            "GPU brick pool ({slots} non-constant bricks of {POOL_BRICK}^3 at this level of \
             detail; a coarser level, a larger --gpu-pool-mb or the CPU renders it)"
        ),
        limit: POOL_LIMIT,
        requested: slots.saturating_mul(SLOT_BYTES),
        max: capacity_slots(ctx) * SLOT_BYTES,
    }
}

/// Cuts `channels` into pool bricks and uploads the non-constant ones with the page table.
/// Bricks are read through each field (bricked levels through their cache) a batch at a
/// time. Fails with [`Error::LimitExceeded`] when the non-constant bricks exceed
/// [`GpuContext::pool_capacity_bytes`], or with the field's read error.
pub fn upload(ctx: &GpuContext, label: &str, channels: &[PoolChannel<'_>]) -> Result<DevicePool> {
    let dims = common_dims(label, channels)?;
    let nb = pool_bricks(dims);
    let per = nb[0] * nb[1] * nb[2];
    let n_pages = per * channels.len().max(1);
    ctx.check_storage_size("GPU brick pool page table", n_pages as u64 * 8)?;
    let mut pages = vec![[CONSTANT, 0u32]; n_pages];
    let mut todo: Vec<(usize, usize)> = Vec::new();
    let mut skipped = 0usize;
    let mut known = true;
    for (c, ch) in channels.iter().enumerate() {
        match ch.constant_hint(dims) {
            Some(h) => {
                for (i, v) in h.into_iter().enumerate() {
                    match v {
                        Some(v) => {
                            pages[c * per + i] = [CONSTANT, v.to_bits()];
                            skipped += usize::from(!matches!(ch, PoolChannel::Zero));
                        }
                        None => todo.push((c, i)),
                    }
                }
            }
            None => {
                known = false;
                todo.extend((0..per).map(|i| (c, i)));
            }
        }
    }
    let cap = capacity_slots(ctx);
    if known && todo.len() as u64 > cap {
        // Known without reading a brick.
        return Err(pool_full(ctx, todo.len() as u64));
    }
    // The buffer is sized for every brick not known constant (bounded by the capacity):
    // bricks found constant on reading leave slots unused at the end.
    let alloc = (todo.len() as u64).min(cap).max(1);
    let pool = ctx.storage_buffer_zeroed(&format!("{label} pool"), alloc * SLOT_BYTES)?;
    let mut slot = 0u64;
    let mut constant = per * channels.len() - todo.len();
    for (b, batch) in todo.chunks(BATCH).enumerate() {
        let blocks: Vec<Result<Vec<f32>>> = batch
            .par_iter()
            .map(|&(c, i)| {
                let lo = [
                    (i % nb[0]) * POOL_BRICK,
                    ((i / nb[0]) % nb[1]) * POOL_BRICK,
                    (i / (nb[0] * nb[1])) * POOL_BRICK,
                ];
                let mut out = vec![0.0f32; SLOT_VALUES];
                channels[c].read_block(lo, &mut out)?;
                Ok(out)
            })
            .collect();
        let first = slot;
        let mut staging: Vec<f32> = Vec::new();
        for (&(c, i), block) in batch.iter().zip(blocks) {
            let block = block?;
            let bits = block[0].to_bits();
            if block.iter().all(|v| v.to_bits() == bits) {
                pages[c * per + i] = [CONSTANT, bits];
                constant += 1;
                continue;
            }
            if slot >= cap {
                // At least this brick, and at most every brick not read yet, more.
                let unread = todo.len() - (b * BATCH).min(todo.len());
                return Err(pool_full(ctx, slot + unread as u64));
            }
            pages[c * per + i] = [slot as u32, 0];
            staging.extend_from_slice(&block);
            slot += 1;
        }
        if !staging.is_empty() {
            ctx.queue()
                .write_buffer(&pool, first * SLOT_BYTES, bytemuck::cast_slice(&staging));
        }
    }
    // Bricks found constant on reading left slots unused at the end: when that is a
    // quarter of the pool or more, move the pool into a buffer of its own size.
    let (pool, alloc) = if slot.max(1) * 4 <= alloc * 3 {
        let used = slot.max(1) * SLOT_BYTES;
        let fit = ctx.storage_buffer_zeroed(&format!("{label} pool"), used)?;
        ctx.copy_buffer(&pool, &fit, used)?;
        (fit, slot.max(1))
    } else {
        (pool, alloc)
    };
    let pages_buf = ctx.storage_buffer(&format!("{label} page table"), &pages)?;
    let stats = PoolStats {
        channels: channels.len(),
        bricks_per_channel: per,
        resident: slot as usize,
        constant,
        skipped_reads: skipped,
        pool_bytes: alloc * SLOT_BYTES,
        dense_bytes: channels
            .iter()
            .filter(|c| !matches!(c, PoolChannel::Zero))
            .count() as u64
            * dims.iter().product::<usize>() as u64
            * 4,
        capacity_bytes: ctx.pool_capacity_bytes(),
    };
    Ok(DevicePool {
        pool,
        pages: pages_buf,
        stats,
    })
}
