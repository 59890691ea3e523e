//! Bricks and out-of-core access (HDR VolVis section 6.3): a bricked file with all levels of
//! detail, written in one streaming pass, read through a memory map with a bounded brick
//! cache, and sampled through the same [`Sampler`] interface as an in-core [`Grid`].
//!
//! # File layout (`.bsv`, little-endian)
//!
//! | bytes | content |
//! |---|---|
//! | 0..8 | magic `BSBRICK1` |
//! | 8..12 | u32 version (1) |
//! | 12..16 | u32 brick edge `B` (even, default 64) |
//! | 16..20 | u32 apron `A` (default 1) |
//! | 20..24 | u32 number of levels |
//! | 24..48 | u64 x 3 level-0 dims |
//! | 48..60 | f32 x 3 level-0 origin |
//! | 60..72 | f32 x 3 level-0 spacing |
//! | 72..76 | u32 level-0 voxel type: 0 = u8, 1 = u16, 2 = f16, 3 = f32 |
//! | 76..80 | u32 channel-name length (at most 255), then the UTF-8 name |
//! | 4096.. | level 0 bricks, then level 1, ... |
//!
//! Level `l` has the geometry of [`crate::Geometry::downsampled`] applied `l` times and
//! `ceil(dims / B)` bricks per axis, stored x fastest. A brick holds `(B + 2A)^3` f32 voxels:
//! its `B^3` own voxels plus an apron of `A` voxels on each side (clamped to the volume's
//! edge), so trilinear sampling never needs a second brick. Levels are added until every
//! dimension fits in one brick. Level 0 keeps the source's in-memory type (u8, u16, f16 or
//! f32; other on-disk types are f32 as in [`crate::io`]), so a u8 CT scan stays one byte per
//! voxel; the down-sampled levels hold means and are f32. Decoded bricks are f32.

use std::fs::File;
use std::io::{BufWriter, Read, Seek, SeekFrom, Write};
use std::path::Path;
use std::sync::{Arc, Mutex};

use glam::Vec3;
use rayon::prelude::*;

use crate::grid::{Geometry, Grid, ScalarType, Voxel};
use crate::io::{DiskType, Endian};
use crate::lod::{downsample_slice, level_geometries};
use crate::{Error, Limits, Result};

/// First bytes of a bricked file.
pub const MAGIC: &[u8] = b"BSBRICK1";
const HEADER_BYTES: u64 = 4096;
const VERSION: u32 = 2;

/// Something that can be sampled like a scalar grid: in-core [`Grid`]s and levels of a
/// [`BrickedFile`].
pub trait Sampler {
    /// The geometry of the sampled grid.
    fn geometry(&self) -> Geometry;
    /// Trilinear sample at continuous index coordinates (clamped to the edge).
    fn sample_index(&self, p: Vec3) -> Result<f32>;
    /// Trilinear sample at a world position.
    fn sample_world(&self, p: Vec3) -> Result<f32> {
        self.sample_index(self.geometry().world_to_index(p))
    }
}

impl<T: Voxel<Value = f32>> Sampler for Grid<T> {
    fn geometry(&self) -> Geometry {
        *Grid::geometry(self)
    }
    fn sample_index(&self, p: Vec3) -> Result<f32> {
        Ok(self.sample_trilinear_index(p))
    }
}

/// Brick edge and apron of a bricked layout.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BrickLayout {
    /// Own voxels per brick edge (even; default 64).
    pub brick: usize,
    /// Extra voxels stored on each side of a brick (default 1, what trilinear sampling needs).
    pub apron: usize,
}

impl Default for BrickLayout {
    fn default() -> Self {
        BrickLayout {
            brick: 64,
            apron: 1,
        }
    }
}

impl BrickLayout {
    fn validate(&self) -> Result<()> {
        if self.brick < 2 || !self.brick.is_multiple_of(2) || self.brick > 1024 {
            return Err(Error::parameter(format!(
                "brick edge {} must be even, 2..=1024",
                self.brick
            )));
        }
        if self.apron < 1 || self.apron > self.brick {
            return Err(Error::parameter(format!(
                "apron {} must be 1..=brick edge",
                self.apron
            )));
        }
        Ok(())
    }
    /// Stored voxels per brick edge, `B + 2A`.
    #[must_use]
    pub fn stored_edge(&self) -> usize {
        self.brick + 2 * self.apron
    }
    /// Bricks per axis for `dims`.
    #[must_use]
    pub fn bricks(&self, dims: [usize; 3]) -> [usize; 3] {
        dims.map(|d| d.div_ceil(self.brick))
    }
}

/// A source of z-slices for the streaming converter.
pub trait SlabSource {
    /// Geometry of the whole volume.
    fn geometry(&self) -> Geometry;
    /// Fills `out` (`dims.x * dims.y` values, x fastest) with slice `z`.
    fn read_slice(&mut self, z: usize, out: &mut [f32]) -> Result<()>;
    /// The type level 0 is stored in; every value `read_slice` gives must convert to it
    /// exactly (default f32).
    fn scalar_type(&self) -> ScalarType {
        ScalarType::F32
    }
}

/// Slices of an in-core scalar grid.
#[derive(Debug)]
pub struct GridSource<'a, T>(pub &'a Grid<T>);

impl<T: Voxel<Value = f32>> SlabSource for GridSource<'_, T> {
    fn geometry(&self) -> Geometry {
        *self.0.geometry()
    }
    fn scalar_type(&self) -> ScalarType {
        T::TYPE
    }
    fn read_slice(&mut self, z: usize, out: &mut [f32]) -> Result<()> {
        let [nx, ny, _] = self.0.dims();
        let s = &self.0.data()[z * nx * ny..(z + 1) * nx * ny];
        for (o, v) in out.iter_mut().zip(s) {
            *o = v.value();
        }
        Ok(())
    }
}

/// Slices read straight from uncompressed voxels in a file (raw, raw-encoded NRRD), one
/// slice at a time, so memory stays at one slice whatever the volume's size.
#[derive(Debug)]
pub struct RawFileSource {
    file: File,
    offset: u64,
    disk: DiskType,
    endian: Endian,
    geometry: Geometry,
    buf: Vec<u8>,
}

impl RawFileSource {
    /// Opens `path` holding scalar voxels of `disk` type at byte `offset`; checks that the file
    /// is long enough.
    pub fn new(
        path: &Path,
        offset: u64,
        disk: DiskType,
        endian: Endian,
        geometry: Geometry,
    ) -> Result<Self> {
        geometry.validate()?;
        let file = File::open(path)?;
        let need = (geometry.voxel_count() as u64).saturating_mul(disk.size_bytes() as u64);
        let have = file.metadata()?.len().saturating_sub(offset);
        if need > have {
            return Err(Error::invalid(format!(
                "truncated data: {need} bytes of voxels declared, the file holds {have}: {}",
                path.display()
            )));
        }
        Ok(RawFileSource {
            file,
            offset,
            disk,
            endian,
            geometry,
            buf: Vec::new(),
        })
    }

    /// Replaces origin and spacing (the dims must stay the same).
    pub fn set_geometry(&mut self, geometry: Geometry) -> Result<()> {
        geometry.validate()?;
        if geometry.dims != self.geometry.dims {
            return Err(Error::parameter("new geometry must keep the dims"));
        }
        self.geometry = geometry;
        Ok(())
    }

    /// Opens any file whose voxels can be streamed without decompression: an Open SciVis raw
    /// file, a raw-encoded NRRD or an uncompressed MetaImage. `None` for everything else
    /// (read those in core).
    pub fn probe(path: &Path) -> Result<Option<Self>> {
        use crate::io::{Format, detect_format};
        match detect_format(path)? {
            Format::Raw => {
                let Some(n) = crate::io::raw::parse_scivis_name(path) else {
                    return Ok(None);
                };
                if n.components != 1 {
                    return Ok(None);
                }
                Self::new(path, 0, n.disk, Endian::Little, Geometry::unit(n.dims)).map(Some)
            }
            Format::MetaImage => match crate::io::mhd::raw_payload(path, &Limits::no_limits())? {
                Some((p, off, layout, geom)) if layout.components == 1 => {
                    Self::new(&p, off, layout.disk, layout.endian, geom).map(Some)
                }
                _ => Ok(None),
            },
            Format::Nrrd => match crate::io::nrrd::raw_payload(path, &Limits::no_limits())? {
                Some((p, off, layout, geom)) if layout.components == 1 => {
                    Self::new(&p, off, layout.disk, layout.endian, geom).map(Some)
                }
                _ => Ok(None),
            },
            _ => Ok(None),
        }
    }
}

impl SlabSource for RawFileSource {
    fn geometry(&self) -> Geometry {
        self.geometry
    }
    fn scalar_type(&self) -> ScalarType {
        match self.disk {
            DiskType::U8 => ScalarType::U8,
            DiskType::U16 => ScalarType::U16,
            _ => ScalarType::F32,
        }
    }
    fn read_slice(&mut self, z: usize, out: &mut [f32]) -> Result<()> {
        let [nx, ny, _] = self.geometry.dims;
        let size = self.disk.size_bytes();
        let bytes = nx * ny * size;
        self.buf.resize(bytes, 0);
        self.file
            .seek(SeekFrom::Start(self.offset + (z * bytes) as u64))?;
        self.file.read_exact(&mut self.buf)?;
        let big = self.endian == Endian::Big;
        for (o, c) in out.iter_mut().zip(self.buf.chunks_exact(size)) {
            *o = crate::io::component(c, self.disk, big);
        }
        Ok(())
    }
}

fn level_offsets(
    geoms: &[Geometry],
    layout: &BrickLayout,
    types: &[ScalarType],
) -> Result<(Vec<u64>, u64)> {
    let mut off = HEADER_BYTES;
    let mut v = Vec::with_capacity(geoms.len());
    for (g, t) in geoms.iter().zip(types) {
        let brick_bytes = (layout.stored_edge() as u64).pow(3) * t.size_bytes() as u64;
        v.push(off);
        let b = layout.bricks(g.dims);
        let n = (b[0] as u64)
            .checked_mul(b[1] as u64)
            .and_then(|n| n.checked_mul(b[2] as u64))
            .and_then(|n| n.checked_mul(brick_bytes))
            .ok_or_else(|| Error::Limits("bricked file size overflows".into()))?;
        off = off
            .checked_add(n)
            .ok_or_else(|| Error::Limits("bricked file size overflows".into()))?;
    }
    Ok((v, off))
}

/// Converts a volume into a bricked file at `out` in one streaming pass per level: level 0
/// reads `B + 2A` slices of the source at a time; each coarser level is down-sampled on the
/// way into a temporary file next to `out`, and bricked from there. `progress(done, total)`
/// reports level-0 slices. Memory stays at `O(dims.x * dims.y * (B + 2A))`.
pub fn convert(
    source: &mut dyn SlabSource,
    out: &Path,
    channel_name: &str,
    layout: BrickLayout,
    progress: &mut dyn FnMut(u64, u64),
) -> Result<()> {
    layout.validate()?;
    let g0 = source.geometry();
    g0.validate()?;
    let geoms = level_geometries(g0, layout.brick);
    let t0 = match source.scalar_type() {
        t @ (ScalarType::U8 | ScalarType::U16 | ScalarType::F16) => t,
        _ => ScalarType::F32,
    };
    let types = level_types(geoms.len(), t0);
    let (offsets, total) = level_offsets(&geoms, &layout, &types)?;
    let name = channel_name.as_bytes();
    if name.len() > 255 {
        return Err(Error::parameter("channel name longer than 255 bytes"));
    }
    let file = std::fs::OpenOptions::new()
        .create(true)
        .write(true)
        .truncate(true)
        .read(true)
        .open(out)?;
    file.set_len(total)?;
    let mut w = BufWriter::new(file);
    let mut h = Vec::with_capacity(HEADER_BYTES as usize);
    h.extend_from_slice(MAGIC);
    h.extend_from_slice(&VERSION.to_le_bytes());
    h.extend_from_slice(&(layout.brick as u32).to_le_bytes());
    h.extend_from_slice(&(layout.apron as u32).to_le_bytes());
    h.extend_from_slice(&(geoms.len() as u32).to_le_bytes());
    for d in g0.dims {
        h.extend_from_slice(&(d as u64).to_le_bytes());
    }
    for v in g0
        .origin
        .to_array()
        .into_iter()
        .chain(g0.spacing.to_array())
    {
        h.extend_from_slice(&v.to_le_bytes());
    }
    h.extend_from_slice(&type_code(t0).to_le_bytes());
    h.extend_from_slice(&(name.len() as u32).to_le_bytes());
    h.extend_from_slice(name);
    w.write_all(&h)?;

    let dir = out
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let mut current: Box<dyn SlabSource> = Box::new(BorrowedSource(source));
    let mut _keep: Option<tempfile::NamedTempFile>;
    for (l, g) in geoms.iter().enumerate() {
        let next = geoms.get(l + 1).copied();
        let mut tmp = match next {
            Some(_) => Some(tempfile::NamedTempFile::new_in(dir)?),
            None => None,
        };
        {
            let mut tmp_w = tmp.as_mut().map(|t| BufWriter::new(t.as_file_mut()));
            let report: &mut dyn FnMut(u64, u64) = if l == 0 { progress } else { &mut |_, _| {} };
            brick_level(
                current.as_mut(),
                *g,
                next,
                &layout,
                types[l],
                offsets[l],
                &mut w,
                tmp_w.as_mut().map(|b| b as &mut dyn Write),
                report,
            )?;
            if let Some(t) = tmp_w.as_mut() {
                t.flush()?;
            }
        }
        if let (Some(t), Some(ng)) = (tmp, next) {
            let src = RawFileSource::new(t.path(), 0, DiskType::F32, Endian::Little, ng)?;
            current = Box::new(src);
            _keep = Some(t);
        }
    }
    w.flush()?;
    w.get_ref().sync_all()?;
    Ok(())
}

struct BorrowedSource<'a>(&'a mut dyn SlabSource);
impl SlabSource for BorrowedSource<'_> {
    fn geometry(&self) -> Geometry {
        self.0.geometry()
    }
    fn read_slice(&mut self, z: usize, out: &mut [f32]) -> Result<()> {
        self.0.read_slice(z, out)
    }
    fn scalar_type(&self) -> ScalarType {
        self.0.scalar_type()
    }
}

fn type_code(t: ScalarType) -> u32 {
    match t {
        ScalarType::U8 => 0,
        ScalarType::U16 => 1,
        ScalarType::F16 => 2,
        _ => 3,
    }
}

fn type_from_code(c: u32) -> Option<ScalarType> {
    Some(match c {
        0 => ScalarType::U8,
        1 => ScalarType::U16,
        2 => ScalarType::F16,
        3 => ScalarType::F32,
        _ => return None,
    })
}

/// Storage type of each level: level 0 as given, the means of coarser levels as f32.
fn level_types(levels: usize, t0: ScalarType) -> Vec<ScalarType> {
    (0..levels)
        .map(|l| if l == 0 { t0 } else { ScalarType::F32 })
        .collect()
}

fn put_value(out: &mut Vec<u8>, t: ScalarType, v: f32) {
    match t {
        ScalarType::U8 => out.push(v as u8),
        ScalarType::U16 => out.extend_from_slice(&(v as u16).to_le_bytes()),
        ScalarType::F16 => out.extend_from_slice(&half::f16::from_f32(v).to_le_bytes()),
        _ => out.extend_from_slice(&v.to_le_bytes()),
    }
}

fn decode_values(bytes: &[u8], t: ScalarType) -> Vec<f32> {
    match t {
        ScalarType::U8 => bytes.iter().map(|&b| f32::from(b)).collect(),
        ScalarType::U16 => bytes
            .chunks_exact(2)
            .map(|b| f32::from(u16::from_le_bytes([b[0], b[1]])))
            .collect(),
        ScalarType::F16 => bytes
            .chunks_exact(2)
            .map(|b| half::f16::from_le_bytes([b[0], b[1]]).to_f32())
            .collect(),
        _ => bytes
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect(),
    }
}

#[allow(clippy::too_many_arguments)]
fn brick_level(
    src: &mut dyn SlabSource,
    g: Geometry,
    next: Option<Geometry>,
    layout: &BrickLayout,
    ty: ScalarType,
    level_offset: u64,
    w: &mut BufWriter<File>,
    mut coarse_out: Option<&mut dyn Write>,
    progress: &mut dyn FnMut(u64, u64),
) -> Result<()> {
    let [nx, ny, nz] = g.dims;
    let (b, a, s) = (layout.brick, layout.apron, layout.stored_edge());
    let nb = layout.bricks(g.dims);
    let slice = nx * ny;
    let mut slab = vec![0f32; slice * s];
    let brick_bytes = (s * s * s * ty.size_bytes()) as u64;
    let mut coarse = next.map(|c| vec![0f32; c.dims[0] * c.dims[1]]);
    for bz in 0..nb[2] {
        // Slab: slices bz*B - A .. bz*B + B + A, clamped to the volume.
        for (i, chunk) in slab.chunks_exact_mut(slice).enumerate() {
            let z = (bz * b + i) as i64 - a as i64;
            src.read_slice(z.clamp(0, nz as i64 - 1) as usize, chunk)?;
        }
        progress(((bz + 1) * b).min(nz) as u64, nz as u64);
        for by in 0..nb[1] {
            // The bricks of one row along x are independent: fill them in parallel (each
            // brick's bytes depend only on the slab), then write them in order.
            let slab_ref = &slab;
            let row: Vec<Vec<u8>> = (0..nb[0])
                .into_par_iter()
                .map(|bx| {
                    let mut brick = Vec::with_capacity(s * s * s * ty.size_bytes());
                    for lz in 0..s {
                        for ly in 0..s {
                            let y =
                                ((by * b + ly) as i64 - a as i64).clamp(0, ny as i64 - 1) as usize;
                            let base = lz * slice + y * nx;
                            for lx in 0..s {
                                let x = ((bx * b + lx) as i64 - a as i64).clamp(0, nx as i64 - 1)
                                    as usize;
                                put_value(&mut brick, ty, slab_ref[base + x]);
                            }
                        }
                    }
                    brick
                })
                .collect();
            let idx = (nb[0] * (by + nb[1] * bz)) as u64;
            w.seek(SeekFrom::Start(level_offset + idx * brick_bytes))?;
            for brick in &row {
                w.write_all(brick)?;
            }
        }
        if let (Some(c), Some(cg), Some(out)) = (coarse.as_mut(), next, coarse_out.as_mut()) {
            // Coarse slices j with 2j in this brick row's own slices.
            let j0 = bz * b / 2;
            let j1 = (((bz + 1) * b) / 2).min(cg.dims[2]);
            for j in j0..j1 {
                let fine =
                    |x: usize, y: usize, z: usize| slab[(z + a - bz * b) * slice + y * nx + x];
                downsample_slice(fine, g.dims, j, c, [cg.dims[0], cg.dims[1]]);
                for v in c.iter() {
                    out.write_all(&v.to_le_bytes())?;
                }
            }
        }
    }
    Ok(())
}

type BrickKey = (u32, u64);
/// A decoded brick and the tick of its last use.
type Slot = Option<(Arc<[f32]>, u64)>;

/// Decoded bricks: one slot per brick of every level (indexing instead of hashing keeps warm
/// lookups cheap), plus the list of occupied slots for least-recently-used eviction.
#[derive(Debug, Default)]
struct Cache {
    slots: Vec<Vec<Slot>>,
    resident: Vec<BrickKey>,
    tick: u64,
}

/// A bricked file opened through a memory map, with a bounded cache of decoded bricks.
///
/// Sampling is `&self` and thread-safe (the cache sits behind a mutex).
#[derive(Debug)]
pub struct BrickedFile {
    map: memmap2::Mmap,
    layout: BrickLayout,
    geoms: Vec<Geometry>,
    types: Vec<ScalarType>,
    offsets: Vec<u64>,
    name: String,
    capacity: usize,
    cache: Mutex<Cache>,
}

impl BrickedFile {
    /// Opens a bricked file; at most `cache_bricks` (at least 1) decoded bricks are kept.
    pub fn open(path: &Path, cache_bricks: usize) -> Result<Self> {
        let file = File::open(path)?;
        // SAFETY: the map is read-only and this crate never writes to the file while it is
        // mapped; as with any memory map, another process truncating the file underneath
        // is outside what safe code can guard against.
        #[allow(unsafe_code)]
        let map = unsafe { memmap2::Mmap::map(&file)? };
        let h = &map[..];
        if h.len() < 80 || !h.starts_with(MAGIC) {
            return Err(Error::invalid(format!(
                "not a bricked volume file: {}",
                path.display()
            )));
        }
        let u32_at = |o: usize| u32::from_le_bytes([h[o], h[o + 1], h[o + 2], h[o + 3]]);
        let u64_at = |o: usize| u64::from_le_bytes(h[o..o + 8].try_into().expect("8 bytes"));
        let f32_at = |o: usize| f32::from_le_bytes(h[o..o + 4].try_into().expect("4 bytes"));
        if u32_at(8) != VERSION {
            return Err(Error::unsupported(format!(
                "bricked file version {}",
                u32_at(8)
            )));
        }
        let layout = BrickLayout {
            brick: u32_at(12) as usize,
            apron: u32_at(16) as usize,
        };
        layout
            .validate()
            .map_err(|e| Error::invalid(format!("bricked file: {e}")))?;
        let mut dims = [0usize; 3];
        for (a, d) in dims.iter_mut().enumerate() {
            *d = usize::try_from(u64_at(24 + 8 * a))
                .map_err(|_| Error::invalid("bricked file: dims overflow"))?;
        }
        let origin = Vec3::new(f32_at(48), f32_at(52), f32_at(56));
        let spacing = Vec3::new(f32_at(60), f32_at(64), f32_at(68));
        let g0 = Geometry {
            dims,
            origin,
            spacing,
        };
        g0.validate()
            .map_err(|e| Error::invalid(format!("bricked file: {e}")))?;
        Limits::no_limits().check(dims, 4)?;
        let t0 = type_from_code(u32_at(72))
            .ok_or_else(|| Error::invalid("bricked file: unknown voxel type"))?;
        let name_len = u32_at(76) as usize;
        if name_len > 255 {
            return Err(Error::invalid("bricked file: channel name too long"));
        }
        let name = String::from_utf8(
            h.get(80..80 + name_len)
                .ok_or_else(|| Error::invalid("truncated bricked file header"))?
                .to_vec(),
        )
        .map_err(|_| Error::invalid("bricked file: name is not UTF-8"))?;
        let geoms = level_geometries(g0, layout.brick);
        if geoms.len() != u32_at(20) as usize {
            return Err(Error::invalid(
                "bricked file: level count does not match the dimensions",
            ));
        }
        let types = level_types(geoms.len(), t0);
        let (offsets, total) = level_offsets(&geoms, &layout, &types)?;
        if (h.len() as u64) < total {
            return Err(Error::invalid(format!(
                "truncated bricked file: {} bytes, {total} expected: {}",
                h.len(),
                path.display()
            )));
        }
        // The file holds every brick (checked above), so these slots are bounded by its size.
        let slots = geoms
            .iter()
            .map(|g| {
                let b = layout.bricks(g.dims);
                vec![None; b[0] * b[1] * b[2]]
            })
            .collect();
        let cache = Mutex::new(Cache {
            slots,
            resident: Vec::new(),
            tick: 0,
        });
        Ok(BrickedFile {
            map,
            layout,
            geoms,
            types,
            offsets,
            name,
            capacity: cache_bricks.max(1),
            cache,
        })
    }

    /// Name of the stored channel.
    #[must_use]
    pub fn channel_name(&self) -> &str {
        &self.name
    }

    /// Storage type of level 0 (coarser levels are f32).
    #[must_use]
    pub fn level0_type(&self) -> ScalarType {
        self.types[0]
    }

    /// Brick edge and apron.
    #[must_use]
    pub fn layout(&self) -> BrickLayout {
        self.layout
    }

    /// Number of levels of detail (level 0 is the finest).
    #[must_use]
    pub fn levels(&self) -> usize {
        self.geoms.len()
    }

    /// Geometry of `level`.
    #[must_use]
    pub fn level_geometry(&self, level: usize) -> Option<Geometry> {
        self.geoms.get(level).copied()
    }

    /// A [`Sampler`] over one level.
    pub fn level(&self, level: usize) -> Result<LevelSampler<'_>> {
        if level >= self.geoms.len() {
            return Err(Error::parameter(format!(
                "level {level} of {}",
                self.geoms.len()
            )));
        }
        Ok(LevelSampler {
            file: self,
            level,
            last: std::cell::RefCell::new(None),
        })
    }

    /// Number of decoded bricks held now.
    #[must_use]
    pub fn resident_bricks(&self) -> usize {
        self.cache.lock().map(|c| c.resident.len()).unwrap_or(0)
    }

    /// Drops every cached brick (a cold cache).
    pub fn clear_cache(&self) {
        if let Ok(mut c) = self.cache.lock() {
            let c = &mut *c;
            for (l, i) in c.resident.drain(..) {
                c.slots[l as usize][i as usize] = None;
            }
        }
    }

    fn brick_of(&self, level: usize, v: [usize; 3]) -> u64 {
        let nb = self.layout.bricks(self.geoms[level].dims);
        let b = v.map(|c| c / self.layout.brick);
        (b[0] + nb[0] * (b[1] + nb[1] * b[2])) as u64
    }

    /// The finest level whose brick around world position `p` is already in the cache, for
    /// progressive refinement; `None` if no level is resident there.
    #[must_use]
    pub fn finest_resident_level(&self, p: Vec3) -> Option<usize> {
        let cache = self.cache.lock().ok()?;
        (0..self.geoms.len()).find(|&l| {
            let g = self.geoms[l];
            let q = g.world_to_index(p);
            let v = [0, 1, 2].map(|a| {
                if q[a].is_nan() {
                    0
                } else {
                    (q[a].max(0.0) as usize).min(g.dims[a] - 1)
                }
            });
            cache.slots[l][self.brick_of(l, v) as usize].is_some()
        })
    }

    fn brick(&self, level: usize, idx: u64) -> Result<Arc<[f32]>> {
        let mut guard = self
            .cache
            .lock()
            .map_err(|_| Error::invalid("brick cache poisoned"))?;
        let c = &mut *guard;
        c.tick += 1;
        let tick = c.tick;
        if let Some(e) = &mut c.slots[level][idx as usize] {
            e.1 = tick;
            return Ok(e.0.clone());
        }
        let data: Arc<[f32]> = self.read_brick_uncached(level, idx)?.into();
        if c.resident.len() >= self.capacity {
            // Evict the least recently used brick.
            let slots = &c.slots;
            if let Some(pos) = (0..c.resident.len()).min_by_key(|&i| {
                let (l, b) = c.resident[i];
                slots[l as usize][b as usize].as_ref().map_or(0, |e| e.1)
            }) {
                let (l, b) = c.resident.swap_remove(pos);
                c.slots[l as usize][b as usize] = None;
            }
        }
        c.slots[level][idx as usize] = Some((data.clone(), tick));
        c.resident.push((level as u32, idx));
        Ok(data)
    }

    /// Loads a whole level into memory (checked against `limits`), in its storage type.
    pub fn load_level(&self, level: usize, limits: &Limits) -> Result<crate::AnyGrid> {
        let g = self
            .level_geometry(level)
            .ok_or_else(|| Error::parameter(format!("level {level}")))?;
        let mut out = Grid::<f32>::zeros(g, limits)?;
        let [nx, ny, nz] = g.dims;
        let (b, a, s) = (
            self.layout.brick,
            self.layout.apron,
            self.layout.stored_edge(),
        );
        let nb = self.layout.bricks(g.dims);
        let data = out.data_mut();
        for bz in 0..nb[2] {
            for by in 0..nb[1] {
                for bx in 0..nb[0] {
                    let brick =
                        self.read_brick_uncached(level, (bx + nb[0] * (by + nb[1] * bz)) as u64)?;
                    for z in bz * b..((bz + 1) * b).min(nz) {
                        for y in by * b..((by + 1) * b).min(ny) {
                            for x in bx * b..((bx + 1) * b).min(nx) {
                                let l = (x - bx * b + a)
                                    + s * ((y - by * b + a) + s * (z - bz * b + a));
                                data[x + nx * (y + ny * z)] = brick[l];
                            }
                        }
                    }
                }
            }
        }
        let f = out.into_vec();
        Ok(match self.types[level] {
            ScalarType::U8 => Grid::from_vec(g, f.into_iter().map(|v| v as u8).collect())?.into(),
            ScalarType::U16 => Grid::from_vec(g, f.into_iter().map(|v| v as u16).collect())?.into(),
            ScalarType::F16 => {
                Grid::from_vec(g, f.into_iter().map(half::f16::from_f32).collect())?.into()
            }
            _ => Grid::from_vec(g, f)?.into(),
        })
    }

    fn read_brick_uncached(&self, level: usize, idx: u64) -> Result<Vec<f32>> {
        let s = self.layout.stored_edge();
        let t = self.types[level];
        let bytes_per = (s * s * s * t.size_bytes()) as u64;
        let start = usize::try_from(self.offsets[level] + idx * bytes_per)
            .map_err(|_| Error::invalid("bricked file: brick offset overflows"))?;
        let bytes = self
            .map
            .get(start..start + bytes_per as usize)
            .ok_or_else(|| Error::invalid("bricked file: brick outside the file"))?;
        Ok(decode_values(bytes, t))
    }
}

/// One level of a [`BrickedFile`] as a [`Sampler`]; gives the same values as trilinear
/// sampling of the in-core grid, voxel for voxel.
///
/// It remembers the last brick it used, so coherent samples (along a ray) skip the shared
/// cache; make one sampler per thread (it is `Send`, not `Sync`). The remembered brick may
/// outlive its eviction from the cache by one brick per sampler.
#[derive(Debug)]
pub struct LevelSampler<'a> {
    file: &'a BrickedFile,
    level: usize,
    last: std::cell::RefCell<Option<(u64, Arc<[f32]>)>>,
}

impl Sampler for LevelSampler<'_> {
    fn geometry(&self) -> Geometry {
        self.file.geoms[self.level]
    }

    fn sample_index(&self, p: Vec3) -> Result<f32> {
        let g = self.file.geoms[self.level];
        let [nx, ny, nz] = g.dims;
        let max = Vec3::new((nx - 1) as f32, (ny - 1) as f32, (nz - 1) as f32);
        let p = p.max(Vec3::ZERO).min(max);
        let p = Vec3::new(
            if p.x.is_nan() { 0.0 } else { p.x },
            if p.y.is_nan() { 0.0 } else { p.y },
            if p.z.is_nan() { 0.0 } else { p.z },
        );
        let f = p.floor();
        let t = p - f;
        let v0 = [f.x as usize, f.y as usize, f.z as usize];
        let idx = self.file.brick_of(self.level, v0);
        let mut last = self.last.borrow_mut();
        let brick = match &*last {
            Some((i, b)) if *i == idx => b.clone(),
            _ => {
                let b = self.file.brick(self.level, idx)?;
                *last = Some((idx, b.clone()));
                b
            }
        };
        drop(last);
        let (b, a, s) = (
            self.file.layout.brick,
            self.file.layout.apron,
            self.file.layout.stored_edge(),
        );
        // Local coordinates of v0; v0 + 1 lies in the apron, which repeats the edge voxel
        // exactly where the in-core sampler clamps.
        let l = v0.map(|c| c % b + a);
        let v = |dx: usize, dy: usize, dz: usize| {
            brick[(l[0] + dx) + s * ((l[1] + dy) + s * (l[2] + dz))]
        };
        let lerp = |a: f32, b: f32, t: f32| a * (1.0 - t) + b * t;
        let c00 = lerp(v(0, 0, 0), v(1, 0, 0), t.x);
        let c10 = lerp(v(0, 1, 0), v(1, 1, 0), t.x);
        let c01 = lerp(v(0, 0, 1), v(1, 0, 1), t.x);
        let c11 = lerp(v(0, 1, 1), v(1, 1, 1), t.x);
        Ok(lerp(lerp(c00, c10, t.y), lerp(c01, c11, t.y), t.z))
    }
}
