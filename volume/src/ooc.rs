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
//! | 72..76 | u32 channel-name length (at most 255), then the UTF-8 name |
//! | 4096.. | level 0 bricks, then level 1, ... |
//!
//! Level `l` has the geometry of [`crate::Geometry::downsampled`] applied `l` times and
//! `ceil(dims / B)` bricks per axis, stored x fastest. A brick holds `(B + 2A)^3` f32 voxels:
//! its `B^3` own voxels plus an apron of `A` voxels on each side (clamped to the volume's
//! edge), so trilinear sampling never needs a second brick. Levels are added until every
//! dimension fits in one brick. Voxels are stored as f32 whatever the source type.

use std::collections::HashMap;
use std::fs::File;
use std::io::{BufWriter, Read, Seek, SeekFrom, Write};
use std::path::Path;
use std::sync::{Arc, Mutex};

use glam::Vec3;

use crate::grid::{Geometry, Grid, Voxel};
use crate::io::{DiskType, Endian};
use crate::lod::{downsample_slice, level_geometries};
use crate::{Error, Limits, Result};

/// First bytes of a bricked file.
pub const MAGIC: &[u8] = b"BSBRICK1";
const HEADER_BYTES: u64 = 4096;

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
}

/// Slices of an in-core scalar grid.
#[derive(Debug)]
pub struct GridSource<'a, T>(pub &'a Grid<T>);

impl<T: Voxel<Value = f32>> SlabSource for GridSource<'_, T> {
    fn geometry(&self) -> Geometry {
        *self.0.geometry()
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
    /// file or a raw-encoded NRRD. `None` for everything else (read those in core).
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
            *o = decode_one(c, self.disk, big);
        }
        Ok(())
    }
}

fn decode_one(b: &[u8], disk: DiskType, big: bool) -> f32 {
    macro_rules! num {
        ($t:ty, $n:literal) => {{
            let mut a = [0u8; $n];
            a.copy_from_slice(b);
            if big {
                <$t>::from_be_bytes(a)
            } else {
                <$t>::from_le_bytes(a)
            }
        }};
    }
    match disk {
        DiskType::U8 => f32::from(b[0]),
        DiskType::I8 => f32::from(b[0] as i8),
        DiskType::U16 => f32::from(num!(u16, 2)),
        DiskType::I16 => f32::from(num!(i16, 2)),
        DiskType::U32 => num!(u32, 4) as f32,
        DiskType::I32 => num!(i32, 4) as f32,
        DiskType::F32 => num!(f32, 4),
        DiskType::F64 => num!(f64, 8) as f32,
    }
}

fn level_offsets(geoms: &[Geometry], layout: &BrickLayout) -> Result<(Vec<u64>, u64)> {
    let brick_bytes = (layout.stored_edge() as u64).pow(3) * 4;
    let mut off = HEADER_BYTES;
    let mut v = Vec::with_capacity(geoms.len());
    for g in geoms {
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
    let (offsets, total) = level_offsets(&geoms, &layout)?;
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
    h.extend_from_slice(&1u32.to_le_bytes());
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
}

#[allow(clippy::too_many_arguments)]
fn brick_level(
    src: &mut dyn SlabSource,
    g: Geometry,
    next: Option<Geometry>,
    layout: &BrickLayout,
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
    let brick_bytes = (s * s * s * 4) as u64;
    let mut brick = vec![0u8; s * s * s * 4];
    let mut coarse = next.map(|c| vec![0f32; c.dims[0] * c.dims[1]]);
    for bz in 0..nb[2] {
        // Slab: slices bz*B - A .. bz*B + B + A, clamped to the volume.
        for (i, chunk) in slab.chunks_exact_mut(slice).enumerate() {
            let z = (bz * b + i) as i64 - a as i64;
            src.read_slice(z.clamp(0, nz as i64 - 1) as usize, chunk)?;
        }
        progress(((bz + 1) * b).min(nz) as u64, nz as u64);
        for by in 0..nb[1] {
            for bx in 0..nb[0] {
                let mut k = 0;
                for lz in 0..s {
                    for ly in 0..s {
                        let y = ((by * b + ly) as i64 - a as i64).clamp(0, ny as i64 - 1) as usize;
                        for lx in 0..s {
                            let x =
                                ((bx * b + lx) as i64 - a as i64).clamp(0, nx as i64 - 1) as usize;
                            brick[k..k + 4]
                                .copy_from_slice(&slab[lz * slice + y * nx + x].to_le_bytes());
                            k += 4;
                        }
                    }
                }
                let idx = (bx + nb[0] * (by + nb[1] * bz)) as u64;
                w.seek(SeekFrom::Start(level_offset + idx * brick_bytes))?;
                w.write_all(&brick)?;
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

#[derive(Debug, Default)]
struct Cache {
    map: HashMap<BrickKey, (Arc<[f32]>, u64)>,
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
        if h.len() < 76 || !h.starts_with(MAGIC) {
            return Err(Error::invalid(format!(
                "not a bricked volume file: {}",
                path.display()
            )));
        }
        let u32_at = |o: usize| u32::from_le_bytes([h[o], h[o + 1], h[o + 2], h[o + 3]]);
        let u64_at = |o: usize| u64::from_le_bytes(h[o..o + 8].try_into().expect("8 bytes"));
        let f32_at = |o: usize| f32::from_le_bytes(h[o..o + 4].try_into().expect("4 bytes"));
        if u32_at(8) != 1 {
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
        let name_len = u32_at(72) as usize;
        if name_len > 255 {
            return Err(Error::invalid("bricked file: channel name too long"));
        }
        let name = String::from_utf8(h[76..76 + name_len].to_vec())
            .map_err(|_| Error::invalid("bricked file: name is not UTF-8"))?;
        let geoms = level_geometries(g0, layout.brick);
        if geoms.len() != u32_at(20) as usize {
            return Err(Error::invalid(
                "bricked file: level count does not match the dimensions",
            ));
        }
        let (offsets, total) = level_offsets(&geoms, &layout)?;
        if (h.len() as u64) < total {
            return Err(Error::invalid(format!(
                "truncated bricked file: {} bytes, {total} expected: {}",
                h.len(),
                path.display()
            )));
        }
        Ok(BrickedFile {
            map,
            layout,
            geoms,
            offsets,
            name,
            capacity: cache_bricks.max(1),
            cache: Mutex::new(Cache::default()),
        })
    }

    /// Name of the stored channel.
    #[must_use]
    pub fn channel_name(&self) -> &str {
        &self.name
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
        Ok(LevelSampler { file: self, level })
    }

    /// Number of decoded bricks held now.
    #[must_use]
    pub fn resident_bricks(&self) -> usize {
        self.cache.lock().map(|c| c.map.len()).unwrap_or(0)
    }

    /// Drops every cached brick (a cold cache).
    pub fn clear_cache(&self) {
        if let Ok(mut c) = self.cache.lock() {
            c.map.clear();
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
            cache.map.contains_key(&(l as u32, self.brick_of(l, v)))
        })
    }

    fn brick(&self, level: usize, idx: u64) -> Result<Arc<[f32]>> {
        let key = (level as u32, idx);
        let mut c = self
            .cache
            .lock()
            .map_err(|_| Error::invalid("brick cache poisoned"))?;
        c.tick += 1;
        let tick = c.tick;
        if let Some(e) = c.map.get_mut(&key) {
            e.1 = tick;
            return Ok(e.0.clone());
        }
        let s = self.layout.stored_edge();
        let n = s * s * s;
        let start = (self.offsets[level] + idx * (n as u64 * 4)) as usize;
        let bytes = self
            .map
            .get(start..start + 4 * n)
            .ok_or_else(|| Error::invalid("bricked file: brick outside the file"))?;
        let data: Arc<[f32]> = bytes
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect();
        if c.map.len() >= self.capacity
            && let Some(old) = c.map.iter().min_by_key(|(_, v)| v.1).map(|(k, _)| *k)
        {
            c.map.remove(&old);
        }
        c.map.insert(key, (data.clone(), tick));
        Ok(data)
    }

    /// Loads a whole level into memory as an f32 grid (checked against `limits`).
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
        Ok(out.into())
    }

    fn read_brick_uncached(&self, level: usize, idx: u64) -> Result<Vec<f32>> {
        let s = self.layout.stored_edge();
        let n = s * s * s;
        let start = (self.offsets[level] + idx * (n as u64 * 4)) as usize;
        let bytes = self
            .map
            .get(start..start + 4 * n)
            .ok_or_else(|| Error::invalid("bricked file: brick outside the file"))?;
        Ok(bytes
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect())
    }
}

/// One level of a [`BrickedFile`] as a [`Sampler`]; gives the same values as trilinear
/// sampling of the in-core grid, voxel for voxel.
#[derive(Debug, Clone, Copy)]
pub struct LevelSampler<'a> {
    file: &'a BrickedFile,
    level: usize,
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
        let brick = self.file.brick(self.level, idx)?;
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
