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
//! Per-brick levels of detail (`--lod brick`, [`BrickedField::per_region`]; HDR VolVis 6.3)
//! are held level by level: the page table has each level's bricks after the finest's, a
//! table of the levels' geometries and each region's level, and a sample in a region of
//! level L looks up level L's brick at the same world point, as the CPU samples it. Only
//! the bricks of a level that some region at that level samples are read and held, so a
//! view whose far regions take coarse levels holds their coarse bricks only. Every channel
//! of a pool shares the regions' levels (the CLI's and the scenes' per-brick rule gives
//! every field the same); channels that differ are refused ([`per_brick_unsupported`]).
//!
//! Constant bricks of a `.bsv` level are found from its stored macrocells without reading
//! the brick (when the file has no NaN or infinite voxel); all others are read through the
//! field's brick cache, a batch of bricks at a time in parallel, and uploaded batch by batch,
//! so host memory stays at one batch whatever the volume's size.

use blueshift_volume::{BrickedField, Field, LevelMap, VectorField};
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
    /// The channel's per-region levels of detail ([`BrickedField::per_region`]), if any.
    fn level_map(&self) -> Option<&LevelMap> {
        self.bricked().and_then(BrickedField::level_map)
    }

    /// Reads the pool brick at voxel `lo` of level `level` (counted from the channel's own;
    /// above 0 only for a channel with per-region levels).
    fn read_block(&self, level: usize, lo: [usize; 3], out: &mut [f32]) -> Result<()> {
        if let Some(m) = self.level_map() {
            let f = m.fields().get(level).ok_or_else(|| {
                Error::InvalidInput(format!("level {level} of a channel's levels of detail"))
            })?;
            f.read_block(lo, POOL_EDGE, out)?;
            return Ok(());
        }
        match self {
            PoolChannel::Scalar(f) => f.read_block(lo, POOL_EDGE, out)?,
            PoolChannel::Component(v, a) => v.read_block(*a, lo, POOL_EDGE, out)?,
            PoolChannel::Zero => out.fill(0.0),
        }
        Ok(())
    }

    fn bricked(&self) -> Option<&BrickedField> {
        match self {
            PoolChannel::Scalar(f) => f.as_bricked(),
            PoolChannel::Component(VectorField::Components(c), a) => c[*a].as_bricked(),
            _ => None,
        }
    }

    /// The bricked level that holds this channel's voxels at `level` (see
    /// [`PoolChannel::read_block`]).
    fn bricked_at(&self, level: usize) -> Option<&BrickedField> {
        match self.level_map() {
            Some(m) => m.fields().get(level),
            None => self.bricked().filter(|_| level == 0),
        }
    }

    /// Each brick's value, at `level` (a grid of `dims` voxels), when it is known to be
    /// constant without reading it: every brick of a zero channel; for a `.bsv` level
    /// without NaN or infinite voxels, bricks whose stored macrocells (edge 4, each
    /// covering its 5 voxels per axis) all have one value.
    fn constant_hint(&self, level: usize, dims: [usize; 3]) -> Option<Vec<Option<f32>>> {
        let nb = pool_bricks(dims);
        let n = nb[0] * nb[1] * nb[2];
        if matches!(self, PoolChannel::Zero) {
            return Some(vec![Some(0.0); n]);
        }
        let b = self.bricked_at(level)?;
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

/// Whether the GPU can hold `fields` in one pool: per-brick levels of detail
/// ([`BrickedField::per_region`], `--lod brick`) are held level by level when every field
/// that has them samples the same level at every point and no field lacks them (the pool's
/// lookup picks one level per sample for all channels).
pub(crate) fn per_brick_unsupported<'a>(
    fields: impl Iterator<Item = &'a Field>,
) -> std::result::Result<(), crate::Unsupported> {
    let maps: Vec<Option<&LevelMap>> = fields
        .map(|f| f.as_bricked().and_then(BrickedField::level_map))
        .collect();
    let first = maps.iter().flatten().next();
    let agree = maps.iter().all(|m| match (m, first) {
        (Some(m), Some(f)) => m.same_regions(f),
        (None, None) => true,
        _ => false,
    });
    if agree {
        Ok(())
    } else {
        Err(crate::Unsupported(
            "channels with different per-brick levels of detail (--lod brick) are CPU-only".into(),
        ))
    }
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
    /// Bricks per channel (the page table's length per channel, every level together).
    pub bricks_per_channel: usize,
    /// Levels of detail the pool holds bricks of (1 unless the channels have per-brick
    /// levels).
    pub levels: usize,
    /// Bricks held in slots (all channels).
    pub resident: usize,
    /// Constant bricks, held as a page-table value only.
    pub constant: usize,
    /// Constant bricks found from stored macrocells, never read.
    pub skipped_reads: usize,
    /// Bricks of a level that no sample reads (per-brick levels of detail: the level's
    /// bricks outside the regions at that level), never read.
    pub unsampled: usize,
    /// Of the resident bricks, those already on the device before the last update
    /// ([`DevicePool::update`]); the rest were uploaded by it.
    pub kept: usize,
    /// Bricks evicted by the last update to make room.
    pub evicted: usize,
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
            "GPU brick pool: {} of {} bricks resident ({:.1} MiB; {} constant, {} never read",
            self.resident,
            self.channels * self.bricks_per_channel,
            self.pool_bytes as f64 / 1048576.0,
            self.constant,
            self.skipped_reads,
        )?;
        if self.kept > 0 || self.evicted > 0 {
            write!(
                f,
                "; {} kept on the device, {} evicted",
                self.kept, self.evicted
            )?;
        }
        if self.levels > 1 {
            write!(
                f,
                "; {} levels per brick, {} bricks no sample reads",
                self.levels, self.unsampled
            )?;
        }
        write!(
            f,
            "), {:.1} MiB dense, capacity {:.1} MiB",
            self.dense_bytes as f64 / 1048576.0,
            self.capacity_bytes as f64 / 1048576.0,
        )
    }
}

/// A pool and its page table on the device: a cache of bricks. [`upload`] fills it for one
/// view of the channels; [`DevicePool::update`] re-plans it for another view of the same
/// channels (another level of detail, other regions' levels), keeping the bricks already on
/// the device, uploading the missing ones into free slots, growing the pool up to its
/// capacity and then evicting the bricks the new view does not sample, least recently used
/// first.
#[derive(Debug)]
pub struct DevicePool {
    /// The slots (f32, [`SLOT_VALUES`] each).
    pub pool: wgpu::Buffer,
    /// The header, the level-of-detail table and, per channel, per brick: `(slot, 0)` or
    /// `(CONSTANT, value bits)` (the layout `shaders/pool.wgsl` states).
    pub pages: wgpu::Buffer,
    /// What it holds.
    pub stats: PoolStats,
    cache: SlotCache,
}

/// A brick's identity across views: its channel, source (a bricked level's source and
/// absolute level; 0 for data in memory) and pool brick.
#[derive(Clone, Copy, Debug, Hash, PartialEq, Eq)]
struct BrickKey {
    channel: usize,
    source: u64,
    level: usize,
    brick: usize,
}

/// Which brick each slot holds.
#[derive(Debug, Default)]
struct SlotCache {
    slots: std::collections::HashMap<BrickKey, u32>,
    owner: Vec<Option<BrickKey>>,
    /// The update that last used each slot.
    used: Vec<u64>,
    /// Bricks found constant on reading (no slot; not read again).
    constants: std::collections::HashMap<BrickKey, u32>,
    /// Slots the pool buffer has.
    alloc: u64,
    /// Slots handed out so far (0..next).
    next: u64,
    tick: u64,
    /// Whether the page table on the device matches the slots (false after a failed
    /// update: the pool must be uploaded again).
    valid: bool,
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

/// Margin, in voxels of a level, around the voxels a region's samples read there (covers
/// the f32 rounding of the world-to-level transform).
const NEED_MARGIN: f32 = 1.0;

/// One level of a pool's page table.
struct LevelPages {
    dims: [usize; 3],
    nb: [usize; 3],
    /// The level's first page within a channel's pages.
    offset: usize,
    /// Which pool bricks some sample reads (`None`: all).
    need: Option<Vec<bool>>,
}

/// Where each brick of a pool goes, before any brick is read.
struct Plan {
    /// The page table: header, level-of-detail table, then the pages.
    pages: Vec<[u32; 2]>,
    /// First page.
    t0: usize,
    /// Pages per channel (all levels).
    per: usize,
    levels: Vec<LevelPages>,
    /// Bricks to read: (channel, level, brick of the level).
    todo: Vec<(usize, usize, usize)>,
    /// Whether every channel's constant bricks are known (no brick is read to count slots).
    known: bool,
    /// Constant bricks found from stored macrocells (non-zero channels).
    skipped: usize,
    unsampled: usize,
}

impl Plan {
    fn new(ctx: &GpuContext, what: &str, channels: &[PoolChannel<'_>]) -> Result<Plan> {
        let dims = common_dims(what, channels)?;
        let map = shared_level_map(what, channels)?;
        let levels = match map {
            Some(m) => level_pages(m),
            None => vec![LevelPages {
                dims,
                nb: pool_bricks(dims),
                offset: 0,
                need: None,
            }],
        };
        let per: usize = levels.iter().map(|l| l.nb.iter().product::<usize>()).sum();
        let mut head = vec![[u32::try_from(levels.len()).unwrap_or(u32::MAX), 0], [0, 0]];
        if let Some(m) = map.filter(|_| levels.len() > 1) {
            let r = m.dims();
            let bits = |v: f32| v.to_bits();
            head.push([r[0] as u32, r[1] as u32]);
            head.push([r[2] as u32, m.edge() as u32]);
            for (l, f) in levels.iter().zip(m.fields()) {
                let g = f.geometry();
                head.push([l.dims[0] as u32, l.dims[1] as u32]);
                head.push([l.dims[2] as u32, l.offset as u32]);
                head.push([bits(g.origin.x), bits(g.origin.y)]);
                head.push([bits(g.origin.z), bits(g.spacing.x)]);
                head.push([bits(g.spacing.y), bits(g.spacing.z)]);
            }
            // The regions' levels, four bytes to a u32, eight to an entry.
            for chunk in m.levels().chunks(8) {
                let mut w = [0u32; 2];
                for (i, &l) in chunk.iter().enumerate() {
                    w[i / 4] |= u32::from(l) << (8 * (i % 4));
                }
                head.push(w);
            }
        }
        let t0 = head.len();
        let n_pages =
            (t0 as u64).saturating_add((per as u64).saturating_mul(channels.len().max(1) as u64));
        ctx.check_storage_size("GPU brick pool page table", n_pages.saturating_mul(8))?;
        if u32::try_from(per).is_err() {
            return Err(Error::LimitExceeded {
                what: format!("{what}: page table"),
                limit: "u32 page index",
                requested: per as u64,
                max: u64::from(u32::MAX),
            });
        }
        head[0][1] = per as u32;
        head[1][0] = t0 as u32;
        let mut pages = head;
        pages.resize(n_pages as usize, [CONSTANT, 0]);
        let mut plan = Plan {
            pages,
            t0,
            per,
            levels,
            todo: Vec::new(),
            known: true,
            skipped: 0,
            unsampled: 0,
        };
        for (c, ch) in channels.iter().enumerate() {
            for l in 0..plan.levels.len() {
                let lv = &plan.levels[l];
                let n = lv.nb.iter().product::<usize>();
                let first = t0 + c * per + lv.offset;
                let hint = ch.constant_hint(l, lv.dims);
                plan.known &= hint.is_some();
                for i in 0..n {
                    if lv.need.as_ref().is_some_and(|need| !need[i]) {
                        // No sample reads it: a constant page, never read.
                        plan.unsampled += usize::from(!matches!(ch, PoolChannel::Zero));
                        continue;
                    }
                    match hint.as_ref().and_then(|h| h[i]) {
                        Some(v) => {
                            plan.pages[first + i] = [CONSTANT, v.to_bits()];
                            plan.skipped += usize::from(!matches!(ch, PoolChannel::Zero));
                        }
                        None => plan.todo.push((c, l, i)),
                    }
                }
            }
        }
        Ok(plan)
    }

    fn page(&self, c: usize, l: usize, i: usize) -> usize {
        self.t0 + c * self.per + self.levels[l].offset + i
    }
}

/// The per-region levels of detail every non-zero channel shares, if any (an error when
/// some have them and others differ or lack them).
fn shared_level_map<'a>(what: &str, channels: &[PoolChannel<'a>]) -> Result<Option<&'a LevelMap>> {
    let mut first: Option<&'a LevelMap> = None;
    let mut plain = false;
    for c in channels {
        let m: Option<&'a LevelMap> = match *c {
            PoolChannel::Scalar(f) => f.as_bricked().and_then(BrickedField::level_map),
            PoolChannel::Component(VectorField::Components(v), a) => {
                v[a].as_bricked().and_then(BrickedField::level_map)
            }
            PoolChannel::Component(..) => None,
            PoolChannel::Zero => continue,
        };
        match (m, first) {
            (Some(m), Some(f)) if !m.same_regions(f) => plain = true,
            (Some(m), None) => first = Some(m),
            (None, _) => plain = true,
            _ => {}
        }
    }
    match first {
        Some(_) if plain => Err(Error::Unsupported(format!(
            "{what}: channels with different per-brick levels of detail (--lod brick)"
        ))),
        f => Ok(f),
    }
}

/// The levels of a per-region map: each level's bricks that some region at that level
/// samples (with the corners its trilinear samples read, and [`NEED_MARGIN`]).
fn level_pages(m: &LevelMap) -> Vec<LevelPages> {
    let fields = m.fields();
    let base = *fields[0].geometry();
    let r = m.dims();
    let edge = m.edge();
    let mut offset = 0;
    let mut out: Vec<LevelPages> = fields
        .iter()
        .map(|f| {
            let dims = f.geometry().dims;
            let nb = pool_bricks(dims);
            let lp = LevelPages {
                dims,
                nb,
                offset,
                need: Some(vec![false; nb.iter().product()]),
            };
            offset += nb.iter().product::<usize>();
            lp
        })
        .collect();
    for (ri, &l) in m.levels().iter().enumerate() {
        let l = usize::from(l);
        let g = fields[l].geometry();
        let lv = &mut out[l];
        let reg = [ri % r[0], (ri / r[0]) % r[1], ri / (r[0] * r[1])];
        // Base-level index coordinates of the region: [r edge, (r + 1) edge], and beyond
        // the grid for the boundary regions (samples outside clamp to the same voxels).
        let lo = glam::Vec3::from(reg.map(|c| (c * edge) as f32));
        let hi = glam::Vec3::from(reg.map(|c| ((c + 1) * edge) as f32));
        let (a, b) = (
            g.world_to_index(base.index_to_world(lo)),
            g.world_to_index(base.index_to_world(hi)),
        );
        let (qa, qb) = (a.min(b), a.max(b));
        let span: [[usize; 2]; 3] = std::array::from_fn(|x| {
            let top = (lv.dims[x] - 1) as f32;
            // Boundary regions also take the samples outside the grid (and NaN, region
            // 0), which clamp to the level's first or last voxel wherever its grid ends.
            let v0 = if reg[x] == 0 {
                0
            } else {
                (qa[x] - NEED_MARGIN).clamp(0.0, top).floor() as usize
            };
            let v1 = if reg[x] + 1 == r[x] {
                lv.dims[x] - 1
            } else {
                (qb[x] + NEED_MARGIN).clamp(0.0, top).floor() as usize
            };
            [v0 / POOL_BRICK, v1 / POOL_BRICK]
        });
        let need = lv.need.as_mut().expect("set above");
        for z in span[2][0]..=span[2][1] {
            for y in span[1][0]..=span[1][1] {
                for x in span[0][0]..=span[0][1] {
                    need[x + lv.nb[0] * (y + lv.nb[1] * z)] = true;
                }
            }
        }
    }
    out
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
    let plan = Plan::new(ctx, "GPU brick pool", channels)?;
    Ok(PoolEstimate {
        slots: plan.todo.len() as u64,
        exact: plan.known,
        capacity: capacity_slots(ctx),
    })
}

/// Whether `err` is a full brick pool (a coarser level of detail may fit).
#[must_use]
pub fn is_pool_full(err: &Error) -> bool {
    matches!(err, Error::LimitExceeded { limit, .. } if *limit == POOL_LIMIT)
}

/// The pool's [`Error::LimitExceeded`] for `slots` non-constant bricks.
pub(crate) fn pool_full(ctx: &GpuContext, slots: u64) -> Error {
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
/// Channels with per-brick levels of detail (all alike) are held level by level: each
/// level's bricks that some region at that level samples. Bricks are read through each
/// field (bricked levels through their cache) a batch at a time. Fails with
/// [`Error::LimitExceeded`] when the non-constant bricks exceed
/// [`GpuContext::pool_capacity_bytes`], or with the field's read error.
pub fn upload(ctx: &GpuContext, label: &str, channels: &[PoolChannel<'_>]) -> Result<DevicePool> {
    let mut pool = DevicePool {
        pool: ctx.storage_buffer_zeroed(&format!("{label} pool"), SLOT_BYTES)?,
        pages: ctx.storage_buffer_zeroed(&format!("{label} page table"), 8)?,
        stats: PoolStats::default(),
        cache: SlotCache::default(),
    };
    pool.update(ctx, label, channels)?;
    Ok(pool)
}

impl DevicePool {
    /// Whether the page table matches the slots: false after a failed
    /// [`DevicePool::update`] (the pool must then be uploaded again).
    #[must_use]
    pub fn is_valid(&self) -> bool {
        self.cache.valid
    }

    /// Marks the pool unusable until the next successful [`DevicePool::update`] (a caller
    /// whose own tables failed to follow the pool).
    pub fn invalidate(&mut self) {
        self.cache.valid = false;
    }

    /// Re-plans the pool for `channels`, another view of the channels it holds (the same
    /// sources, perhaps another level or other per-region levels): bricks already on the
    /// device are kept, missing ones read (a batch at a time, in parallel) and uploaded into
    /// free slots; the pool grows up to [`GpuContext::pool_capacity_bytes`], then evicts
    /// the bricks this view does not sample, least recently used first. Fails with the
    /// pool's [`Error::LimitExceeded`] when this view's own bricks exceed the capacity, or
    /// with a read error; after a failure [`DevicePool::is_valid`] is false.
    ///
    /// # Errors
    /// As above; channels of different sizes; page tables beyond the device's limits.
    pub fn update(
        &mut self,
        ctx: &GpuContext,
        label: &str,
        channels: &[PoolChannel<'_>],
    ) -> Result<()> {
        // Data in memory has no source identity to key its bricks by: never reused.
        let keyed = channels
            .iter()
            .all(|c| matches!(c, PoolChannel::Zero) || c.bricked().is_some());
        if (!self.cache.valid || !keyed) && self.cache.alloc > 0 {
            // A failed update may have recorded slots it never wrote, and in-memory data
            // cannot be matched: forget every slot (the buffer stays, its contents are
            // rewritten as bricks are placed).
            let c = &mut self.cache;
            c.slots.clear();
            c.constants.clear();
            c.owner.iter_mut().for_each(|o| *o = None);
            c.next = 0;
        }
        self.cache.valid = false;
        let dims = common_dims(label, channels)?;
        let mut plan = Plan::new(ctx, label, channels)?;
        let cap = capacity_slots(ctx);
        let key = |c: usize, l: usize, i: usize| {
            let b = channels[c].bricked_at(l);
            BrickKey {
                channel: c,
                source: b.map_or(0, |b| b.source().uid()),
                level: b.map_or(l, BrickedField::level),
                brick: i,
            }
        };
        let cache = &mut self.cache;
        let first = cache.alloc == 0;
        cache.tick += 1;
        let tick = cache.tick;
        let todo = std::mem::take(&mut plan.todo);
        let mut missing: Vec<(usize, usize, usize, BrickKey)> = Vec::new();
        let mut kept = 0usize;
        for &(c, l, i) in &todo {
            let k = key(c, l, i);
            let page = plan.page(c, l, i);
            if let Some(&s) = cache.slots.get(&k) {
                plan.pages[page] = [s, 0];
                cache.used[s as usize] = tick;
                kept += 1;
            } else if let Some(&bits) = cache.constants.get(&k) {
                plan.pages[page] = [CONSTANT, bits];
            } else {
                missing.push((c, l, i, k));
            }
        }
        let needed = (kept + missing.len()) as u64;
        if plan.known && needed > cap {
            // Known without reading a brick.
            return Err(pool_full(ctx, needed));
        }
        if first {
            // Sized for every brick not known constant (bounded by the capacity): bricks
            // found constant on reading leave slots unused at the end.
            let alloc = needed.min(cap).max(1);
            self.pool = ctx.storage_buffer_zeroed(&format!("{label} pool"), alloc * SLOT_BYTES)?;
            cache.alloc = alloc;
            cache.owner = vec![None; alloc as usize];
            cache.used = vec![0; alloc as usize];
        }
        // Slots this view does not sample, least recently used first.
        let mut evictable: std::collections::VecDeque<u32> = {
            let mut v: Vec<u32> = (0..cache.next as u32)
                .filter(|&s| cache.owner[s as usize].is_some() && cache.used[s as usize] < tick)
                .collect();
            v.sort_by_key(|&s| (cache.used[s as usize], s));
            v.into()
        };
        let mut loaded = 0usize;
        let mut evicted = 0usize;
        for (b, batch) in missing.chunks(BATCH).enumerate() {
            let blocks: Vec<Result<Vec<f32>>> = batch
                .par_iter()
                .map(|&(c, l, i, _)| {
                    let nb = plan.levels[l].nb;
                    let lo = [
                        (i % nb[0]) * POOL_BRICK,
                        ((i / nb[0]) % nb[1]) * POOL_BRICK,
                        (i / (nb[0] * nb[1])) * POOL_BRICK,
                    ];
                    let mut out = vec![0.0f32; SLOT_VALUES];
                    channels[c].read_block(l, lo, &mut out)?;
                    Ok(out)
                })
                .collect();
            // Runs of consecutive slots are written together.
            let mut run: Option<(u64, Vec<f32>)> = None;
            for (&(c, l, i, k), block) in batch.iter().zip(blocks) {
                let block = block?;
                let page = plan.page(c, l, i);
                let bits = block[0].to_bits();
                if block.iter().all(|v| v.to_bits() == bits) {
                    plan.pages[page] = [CONSTANT, bits];
                    cache.constants.insert(k, bits);
                    continue;
                }
                let slot = if cache.next < cache.alloc {
                    cache.next += 1;
                    cache.next - 1
                } else if cache.alloc < cap {
                    // Grow: room for every brick not read yet, at least doubling.
                    let unread = (missing.len() - (b * BATCH).min(missing.len())) as u64;
                    let alloc = (cache.alloc * 2).max(cache.next + unread).min(cap);
                    let grown =
                        ctx.storage_buffer_zeroed(&format!("{label} pool"), alloc * SLOT_BYTES)?;
                    if let Some((at, data)) = run.take() {
                        ctx.queue().write_buffer(
                            &self.pool,
                            at * SLOT_BYTES,
                            bytemuck::cast_slice(&data),
                        );
                    }
                    ctx.copy_buffer(&self.pool, &grown, cache.next * SLOT_BYTES)?;
                    self.pool = grown;
                    cache.alloc = alloc;
                    cache.owner.resize(alloc as usize, None);
                    cache.used.resize(alloc as usize, 0);
                    cache.next += 1;
                    cache.next - 1
                } else if let Some(s) = evictable.pop_front() {
                    if let Some(old) = cache.owner[s as usize].take() {
                        cache.slots.remove(&old);
                    }
                    evicted += 1;
                    u64::from(s)
                } else {
                    // This view's bricks: the kept ones, those placed, and every one not
                    // read yet.
                    let unread = missing.len() - (b * BATCH).min(missing.len());
                    return Err(pool_full(ctx, (kept + loaded + unread) as u64));
                };
                cache.owner[slot as usize] = Some(k);
                cache.used[slot as usize] = tick;
                cache.slots.insert(k, slot as u32);
                plan.pages[page] = [slot as u32, 0];
                loaded += 1;
                match &mut run {
                    Some((at, data)) if *at + (data.len() / SLOT_VALUES) as u64 == slot => {
                        data.extend_from_slice(&block);
                    }
                    _ => {
                        if let Some((at, data)) = run.replace((slot, block)) {
                            ctx.queue().write_buffer(
                                &self.pool,
                                at * SLOT_BYTES,
                                bytemuck::cast_slice(&data),
                            );
                        }
                    }
                }
            }
            if let Some((at, data)) = run.take() {
                ctx.queue()
                    .write_buffer(&self.pool, at * SLOT_BYTES, bytemuck::cast_slice(&data));
            }
        }
        // A first upload whose bricks were partly constant on reading left slots unused at
        // the end: when that is a quarter of the pool or more, move the pool into a buffer
        // of its own size.
        if first && cache.next.max(1) * 4 <= cache.alloc * 3 {
            let used = cache.next.max(1);
            let fit = ctx.storage_buffer_zeroed(&format!("{label} pool"), used * SLOT_BYTES)?;
            ctx.copy_buffer(&self.pool, &fit, used * SLOT_BYTES)?;
            self.pool = fit;
            cache.alloc = used;
            cache.owner.truncate(used as usize);
            cache.used.truncate(used as usize);
        }
        let bytes = plan.pages.len() as u64 * 8;
        if self.pages.size() == bytes.max(4).div_ceil(4) * 4 && !first {
            ctx.queue()
                .write_buffer(&self.pages, 0, bytemuck::cast_slice(&plan.pages));
        } else {
            self.pages = ctx.storage_buffer(&format!("{label} page table"), &plan.pages)?;
        }
        let resident = kept + loaded;
        let total = plan.per * channels.len();
        self.stats = PoolStats {
            channels: channels.len(),
            bricks_per_channel: plan.per,
            levels: plan.levels.len(),
            resident,
            constant: total - resident - plan.unsampled,
            skipped_reads: plan.skipped,
            unsampled: plan.unsampled,
            kept,
            evicted,
            pool_bytes: cache.alloc * SLOT_BYTES,
            dense_bytes: channels
                .iter()
                .filter(|c| !matches!(c, PoolChannel::Zero))
                .count() as u64
                * dims.iter().product::<usize>() as u64
                * 4,
            capacity_bytes: ctx.pool_capacity_bytes(),
        };
        cache.valid = true;
        Ok(())
    }
}
