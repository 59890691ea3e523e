//! Bricks and out-of-core access (HDR VolVis section 6.3): a bricked file with all levels of
//! detail, written in one streaming pass, read with positioned reads (an I/O failure is an
//! error, never a crash) through the shared bounded [`BrickCache`], and sampled through the
//! same [`Sampler`] interface as an in-core [`Grid`] (or as a [`crate::Field`]).
//!
//! # File layout (`.bsv`, little-endian, version 4; version 3 files are read too)
//!
//! | bytes | content |
//! |---|---|
//! | 0..8 | magic `BSBRICK1` |
//! | 8..12 | u32 version (4) |
//! | 12..16 | u32 brick edge `B` (even, default 64) |
//! | 16..20 | u32 apron `A` (default 1) |
//! | 20..24 | u32 number of levels |
//! | 24..48 | u64 x 3 level-0 dims |
//! | 48..60 | f32 x 3 level-0 origin |
//! | 60..72 | f32 x 3 level-0 spacing |
//! | 72..76 | u32 level-0 voxel type: 0 = u8, 1 = u16, 2 = f16, 3 = f32 |
//! | 76..80 | u32 channel-name length (at most 255), then the UTF-8 name (80..335) |
//! | 336..340 | u32 macrocell edge `k` of the stored macrocells (0: none) |
//! | 340..348 | u64 offset of the macrocell section |
//! | 348..356 | u64 offset of the brick checksum table |
//! | 356..364 | u64 number of NaN or infinite level-0 voxels |
//! | 364..372 | f32 x 2 range of the finite level-0 values (NaN, NaN if none) |
//! | 372..380 | u64 file length |
//! | 380..384 | f32 smallest positive finite level-0 value (NaN if none) |
//! | 384..392 | u64 checksum of every other header byte (version 4) |
//! | 392.. | u64 checksum of each level's macrocell section (version 4; zeros after) |
//! | 4096.. | level 0 bricks, then level 1, ...; then the macrocells; then the checksums |
//!
//! Level `l` has the geometry of [`crate::Geometry::downsampled`] applied `l` times and
//! `ceil(dims / B)` bricks per axis, stored x fastest. A brick holds `(B + 2A)^3` voxels:
//! its `B^3` own voxels plus an apron of `A` voxels on each side (clamped to the volume's
//! edge), so trilinear sampling never needs a second brick. Levels are added until every
//! dimension fits in one brick. Level 0 keeps the source's in-memory type (u8, u16, f16 or
//! f32; other on-disk types are f32 as in [`crate::io`]), so a u8 CT scan stays one byte per
//! voxel; the down-sampled levels hold means and are f32. Decoded bricks are f32.
//!
//! The macrocell section holds, per level, the min then the max of every macrocell of edge
//! `k` (f32, cells x fastest), exactly what [`Macrocells::build`] computes on that level, so
//! a renderer's majorants cost nothing on re-open. The checksum table holds one u64 per brick
//! (all levels, in file order); a brick that fails it is refused when read.

use std::collections::VecDeque;
use std::fs::File;
use std::io::Read;
use std::os::unix::fs::FileExt;
use std::path::Path;
use std::sync::mpsc::SyncSender;
use std::sync::{Arc, Mutex};

use glam::Vec3;
use rayon::prelude::*;

use crate::cache::{BrickCache, BrickSource, next_uid};
use crate::field::BrickedField;
use crate::grid::{Geometry, Grid, ScalarType, Voxel};
use crate::io::{DiskType, Endian};
use crate::lod::{downsample_row, level_geometries, mean_of_eight};
use crate::macrocell::{DEFAULT_K, Macrocells, layer_min_max};
use crate::{AnyGrid, Error, Limits, MemoryBudget, Result};

/// First bytes of a bricked file.
pub const MAGIC: &[u8] = b"BSBRICK1";
const HEADER_BYTES: u64 = 4096;
const VERSION: u32 = 4;
/// The oldest version read (version 3 has no header and macrocell checksums).
const OLDEST_VERSION: u32 = 3;
/// Where version 4 keeps the checksum of the rest of the header, and from where the
/// checksum of each level's macrocell section (one u64 per level).
const HEADER_SUM_AT: usize = 384;
const MACRO_SUMS_AT: usize = 392;

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
    /// The layout with its brick edge capped at the smallest even edge that covers `dims`'
    /// longest axis (at least 2 and the apron): a larger brick only adds padding (a
    /// `--brick 1024` on a 16^3 volume would write 4 GB of it). [`convert`] and
    /// [`convert_many`] apply it.
    #[must_use]
    pub fn fitted(self, dims: [usize; 3]) -> Self {
        let longest = dims.iter().copied().max().unwrap_or(2);
        let cover = (longest + longest % 2)
            .max(2)
            .max(self.apron + self.apron % 2);
        BrickLayout {
            brick: self.brick.min(cover),
            ..self
        }
    }

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
    /// The whole volume (`dims.x * dims.y * dims.z` values, x fastest), if the source holds
    /// it in memory as f32: an in-core f32 grid, a mapped file of native f32 voxels. The
    /// converter then reads it in place instead of calling `read_slice`. Default: none.
    fn in_place(&self) -> Option<&[f32]> {
        None
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
    fn in_place(&self) -> Option<&[f32]> {
        let grid: &dyn std::any::Any = self.0;
        grid.downcast_ref::<Grid<f32>>().map(Grid::data)
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
/// slice at a time, so memory stays at one slice whatever the volume's size. The file is
/// read with positioned reads, not mapped: a mapped input truncated by another program
/// during a conversion would kill the process with SIGBUS instead of giving an error (a
/// mapping saved about 6% of the conversion's CPU; in-core grids are still read in place).
#[derive(Debug)]
pub struct RawFileSource {
    file: File,
    offset: u64,
    disk: DiskType,
    endian: Endian,
    geometry: Geometry,
    buf: Vec<u8>,
    /// Axes the file stores reversed (a negative spacing in its header).
    flip: [bool; 3],
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
        crate::io::check_regular_file(path)?;
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
            flip: [false; 3],
        })
    }

    /// Replaces origin and spacing (the dims must stay the same).
    pub fn set_geometry(&mut self, geometry: Geometry) -> Result<()> {
        replace_geometry(&mut self.geometry, geometry)
    }

    /// Reads the axes `flip` names reversed, as a header with a negative spacing asks.
    fn flipped(mut self, flip: [bool; 3]) -> Self {
        self.flip = flip;
        self
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
                crate::io::check_regular_file(path)?;
                n.check_len(std::fs::metadata(path)?.len(), path)?;
                Self::new(path, 0, n.disk, n.endian, Geometry::unit(n.dims)).map(Some)
            }
            Format::MetaImage => match crate::io::mhd::raw_payload(path, &Limits::no_limits())? {
                Some((p, off, layout, geom)) if layout.components == 1 => {
                    Self::new(&p, off, layout.disk, layout.endian, geom)
                        .map(|s| Some(s.flipped(layout.flip)))
                }
                _ => Ok(None),
            },
            Format::Nrrd => match crate::io::nrrd::raw_payload(path, &Limits::no_limits())? {
                Some((p, off, layout, geom)) if layout.components == 1 => {
                    Self::new(&p, off, layout.disk, layout.endian, geom)
                        .map(|s| Some(s.flipped(layout.flip)))
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
        level0_type(self.disk)
    }
    fn read_slice(&mut self, z: usize, out: &mut [f32]) -> Result<()> {
        let [nx, ny, _] = self.geometry.dims;
        let bytes = nx * ny * self.disk.size_bytes();
        let zf = if self.flip[2] {
            self.geometry.dims[2] - 1 - z
        } else {
            z
        };
        let at = self.offset + (zf * bytes) as u64;
        let big = self.endian == Endian::Big;
        if self.disk == DiskType::F32 && big == cfg!(target_endian = "big") {
            // Native f32: read straight into the slice.
            self.file
                .read_exact_at(bytemuck::cast_slice_mut(&mut out[..nx * ny]), at)?;
        } else {
            self.buf.resize(bytes, 0);
            self.file.read_exact_at(&mut self.buf, at)?;
            if self.disk == DiskType::F64 {
                crate::io::check_f64_range(&self.buf, big)?;
            }
            values_from_bytes(&self.buf, self.disk, big, out);
        }
        flip_slice(&mut out[..nx * ny], nx, self.flip);
        Ok(())
    }
}

/// Reverses a slice's rows (`flip[1]`) and each row (`flip[0]`): `nx` values a row.
fn flip_slice(slice: &mut [f32], nx: usize, flip: [bool; 3]) {
    if flip[1] {
        let ny = slice.len() / nx;
        for y in 0..ny / 2 {
            let (lo, hi) = slice.split_at_mut((ny - 1 - y) * nx);
            lo[y * nx..(y + 1) * nx].swap_with_slice(&mut hi[..nx]);
        }
    }
    if flip[0] {
        for row in slice.chunks_exact_mut(nx) {
            row.reverse();
        }
    }
}

/// The type a `.bsv` level 0 keeps for voxels stored as `disk`.
fn level0_type(disk: DiskType) -> ScalarType {
    match disk {
        DiskType::U8 => ScalarType::U8,
        DiskType::U16 => ScalarType::U16,
        _ => ScalarType::F32,
    }
}

/// Sets `current` to `new` if `new` is valid and keeps the dims.
fn replace_geometry(current: &mut Geometry, new: Geometry) -> Result<()> {
    new.validate()?;
    if new.dims != current.dims {
        return Err(Error::parameter("new geometry must keep the dims"));
    }
    *current = new;
    Ok(())
}

/// Voxel values of `disk` type (big-endian if `big`) from `bytes` into `out`.
fn values_from_bytes(bytes: &[u8], disk: DiskType, big: bool, out: &mut [f32]) {
    match disk {
        DiskType::U8 => {
            for (o, &b) in out.iter_mut().zip(bytes) {
                *o = f32::from(b);
            }
        }
        disk => {
            for (o, c) in out.iter_mut().zip(bytes.chunks_exact(disk.size_bytes())) {
                *o = crate::io::component(c, disk, big);
            }
        }
    }
}

/// The scalar voxels of a gzip-encoded NRRD (attached or detached), decompressed slice by
/// slice in order as [`convert`] asks for them: a compressed volume converts holding one
/// slice of it, at the speed of decompression.
pub struct GzipFileSource {
    reader: crate::io::GzMembers<std::io::BufReader<File>>,
    disk: DiskType,
    endian: Endian,
    geometry: Geometry,
    /// The next slice the stream holds.
    next: usize,
    buf: Vec<u8>,
    path: std::path::PathBuf,
    /// Reversed x and y axes (a negative spacing in the header).
    flip: [bool; 3],
}

impl std::fmt::Debug for GzipFileSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GzipFileSource")
            .field("path", &self.path)
            .field("geometry", &self.geometry)
            .field("next", &self.next)
            .finish_non_exhaustive()
    }
}

impl GzipFileSource {
    /// Whether `path` is a gzip-encoded NRRD whose z axis is stored reversed (a negative
    /// spacing): [`Self::probe`] does not stream it, as a gzip stream cannot be read
    /// backwards, so it is read whole.
    #[must_use]
    pub fn reverses_z(path: &Path) -> bool {
        use crate::io::{Format, detect_format};
        matches!(detect_format(path), Ok(Format::Nrrd))
            && matches!(
                crate::io::nrrd::gzip_payload(path, &Limits::no_limits()),
                Ok(Some((_, _, layout, _))) if layout.flip[2]
            )
    }

    /// Opens a gzip-encoded NRRD of scalars without skips; `None` for any other file (read
    /// those in core, or stream them with [`RawFileSource::probe`]).
    pub fn probe(path: &Path) -> Result<Option<Self>> {
        use crate::io::{Format, detect_format};
        if detect_format(path)? != Format::Nrrd {
            return Ok(None);
        }
        let Some((data, start, layout, geometry)) =
            crate::io::nrrd::gzip_payload(path, &Limits::no_limits())?
        else {
            return Ok(None);
        };
        // A reversed z axis would need the stream's slices last to first.
        if layout.components != 1 || layout.flip[2] {
            return Ok(None);
        }
        geometry.validate()?;
        crate::io::check_regular_file(&data)?;
        let mut file = File::open(&data)?;
        std::io::Seek::seek(&mut file, std::io::SeekFrom::Start(start))?;
        Ok(Some(Self {
            reader: crate::io::GzMembers::new(std::io::BufReader::new(file)),
            disk: layout.disk,
            endian: layout.endian,
            geometry,
            next: 0,
            buf: Vec::new(),
            path: data,
            flip: layout.flip,
        }))
    }
}

impl GzipFileSource {
    /// Replaces origin and spacing (the dims must stay the same).
    pub fn set_geometry(&mut self, geometry: Geometry) -> Result<()> {
        replace_geometry(&mut self.geometry, geometry)
    }
}

impl SlabSource for GzipFileSource {
    fn geometry(&self) -> Geometry {
        self.geometry
    }
    fn scalar_type(&self) -> ScalarType {
        level0_type(self.disk)
    }
    fn read_slice(&mut self, z: usize, out: &mut [f32]) -> Result<()> {
        if z != self.next {
            return Err(Error::parameter(format!(
                "a gzip stream reads its slices in order: slice {z} asked, {} next",
                self.next
            )));
        }
        let [nx, ny, nz] = self.geometry.dims;
        self.buf.resize(nx * ny * self.disk.size_bytes(), 0);
        self.reader.read_exact(&mut self.buf).map_err(|e| {
            if e.kind() == std::io::ErrorKind::UnexpectedEof {
                Error::invalid(format!(
                    "truncated data: the gzip stream ends in slice {z} of {nz}: {}",
                    self.path.display()
                ))
            } else {
                Error::invalid(format!("{e}: {}", self.path.display()))
            }
        })?;
        self.next += 1;
        if self.next == nz {
            crate::io::check_stream_end(&mut self.reader).map_err(|e| match e {
                Error::Invalid(m) => Error::invalid(format!("{m}: {}", self.path.display())),
                other => other,
            })?;
        }
        if self.disk == DiskType::F64 {
            crate::io::check_f64_range(&self.buf, self.endian == Endian::Big)?;
        }
        values_from_bytes(&self.buf, self.disk, self.endian == Endian::Big, out);
        flip_slice(&mut out[..nx * ny], nx, self.flip);
        Ok(())
    }
}

/// Where everything of a bricked file lives.
#[derive(Clone, Debug)]
struct Plan {
    geoms: Vec<Geometry>,
    types: Vec<ScalarType>,
    /// Byte offset of each level's first brick.
    offsets: Vec<u64>,
    /// Index of each level's first brick in the checksum table.
    first_brick: Vec<usize>,
    /// Macrocell edge (0: none stored).
    k: usize,
    /// Byte offset of each level's macrocell mins (the maxs follow).
    macro_offsets: Vec<u64>,
    checksum_offset: u64,
    total: u64,
}

fn overflow() -> Error {
    Error::Limits("bricked file size overflows".into())
}

fn macro_dims(g: &Geometry, k: usize) -> [usize; 3] {
    g.dims.map(|d| d.saturating_sub(1).div_ceil(k).max(1))
}

impl Plan {
    fn new(g0: Geometry, layout: &BrickLayout, t0: ScalarType, k: usize) -> Result<Plan> {
        let geoms = level_geometries(g0, layout.brick);
        if geoms.len() > crate::cache::MAX_LEVELS {
            return Err(overflow());
        }
        let types = level_types(geoms.len(), t0);
        let mut off = HEADER_BYTES;
        let mut offsets = Vec::with_capacity(geoms.len());
        let mut first_brick = Vec::with_capacity(geoms.len());
        let mut bricks = 0usize;
        for (g, t) in geoms.iter().zip(&types) {
            let brick_bytes = (layout.stored_edge() as u64).pow(3) * t.size_bytes() as u64;
            offsets.push(off);
            first_brick.push(bricks);
            let b = layout.bricks(g.dims);
            let n = b[0]
                .checked_mul(b[1])
                .and_then(|n| n.checked_mul(b[2]))
                .ok_or_else(overflow)?;
            bricks = bricks.checked_add(n).ok_or_else(overflow)?;
            off = (n as u64)
                .checked_mul(brick_bytes)
                .and_then(|n| off.checked_add(n))
                .ok_or_else(overflow)?;
        }
        let mut macro_offsets = Vec::with_capacity(geoms.len());
        if k > 0 {
            for g in &geoms {
                macro_offsets.push(off);
                let c = macro_dims(g, k);
                let cells = (c[0] as u64) * (c[1] as u64) * (c[2] as u64);
                off = cells
                    .checked_mul(8)
                    .and_then(|n| off.checked_add(n))
                    .ok_or_else(overflow)?;
            }
        }
        let checksum_offset = off;
        let total = (bricks as u64)
            .checked_mul(8)
            .and_then(|n| off.checked_add(n))
            .ok_or_else(overflow)?;
        Ok(Plan {
            geoms,
            types,
            offsets,
            first_brick,
            k,
            macro_offsets,
            checksum_offset,
            total,
        })
    }
}

/// The macrocell edge a layout stores: [`DEFAULT_K`] when it divides the brick edge (each
/// macrocell then lies in one brick's stored voxels), else none.
fn stored_k(layout: &BrickLayout) -> usize {
    if layout.brick.is_multiple_of(DEFAULT_K) {
        DEFAULT_K
    } else {
        0
    }
}

const CHECKSUM_M: u64 = 0x9E37_79B9_7F4A_7C15;
const CHECKSUM_START: [u64; 4] = [1, 2, 3, 4];

/// A 64-bit checksum of a brick's bytes (four multiply-rotate lanes over u64 words).
fn checksum(bytes: &[u8]) -> u64 {
    let mut h = CHECKSUM_START;
    let whole = bytes.len() / 32 * 32;
    checksum_chunks(&mut h, &bytes[..whole]);
    checksum_finish(h, &bytes[whole..], bytes.len())
}

/// Adds whole 32-byte chunks to a [`checksum`]'s lanes (a brick is summed as it is filled,
/// while its bytes are in the cache).
fn checksum_chunks(h: &mut [u64; 4], bytes: &[u8]) {
    const M: u64 = CHECKSUM_M;
    debug_assert!(bytes.len().is_multiple_of(32));
    for c in bytes.as_chunks::<32>().0 {
        for (i, lane) in h.iter_mut().enumerate() {
            let w = u64::from_le_bytes(c[8 * i..8 * i + 8].try_into().expect("8 bytes"));
            *lane = (*lane ^ w).wrapping_mul(M).rotate_left(29);
        }
    }
}

/// A [`checksum`] from its lanes after the whole chunks, the last `tail` bytes (fewer than
/// 32) and the length summed.
fn checksum_finish(mut h: [u64; 4], tail_bytes: &[u8], len: usize) -> u64 {
    const M: u64 = CHECKSUM_M;
    let mut tail = 0u64;
    for (i, &b) in tail_bytes.iter().enumerate() {
        tail ^= u64::from(b) << ((i % 8) * 8);
        if i % 8 == 7 {
            h[0] = (h[0] ^ tail).wrapping_mul(M).rotate_left(29);
            tail = 0;
        }
    }
    h[1] = (h[1] ^ tail ^ len as u64).wrapping_mul(M);
    h.iter()
        .fold(0u64, |a, &x| (a ^ x).wrapping_mul(M).rotate_left(23))
}

fn encode(vals: &[f32], t: ScalarType, out: &mut [u8]) {
    match t {
        ScalarType::U8 => {
            for (o, &v) in out.iter_mut().zip(vals) {
                *o = v as u8;
            }
        }
        ScalarType::U16 => {
            for (o, &v) in out.chunks_exact_mut(2).zip(vals) {
                o.copy_from_slice(&(v as u16).to_le_bytes());
            }
        }
        ScalarType::F16 => {
            for (o, &v) in out.chunks_exact_mut(2).zip(vals) {
                o.copy_from_slice(&half::f16::from_f32(v).to_le_bytes());
            }
        }
        _ => {
            if cfg!(target_endian = "little") {
                out.copy_from_slice(bytemuck::cast_slice(vals));
            } else {
                for (o, &v) in out.chunks_exact_mut(4).zip(vals) {
                    o.copy_from_slice(&v.to_le_bytes());
                }
            }
        }
    }
}

/// Encodes the stored voxels `x0..x0 + out.len() / size` of `row` into `out`, clamping x to
/// the row (the apron beyond the volume's edge repeats the edge voxel): the part inside the
/// row in one [`encode`], then the clamped voxels one at a time.
fn encode_run(row: &[f32], x0: i64, t: ScalarType, out: &mut [u8]) {
    let ts = t.size_bytes();
    let n = out.len() / ts;
    let nx = row.len() as i64;
    // Any stored run overlaps the row: x0 < nx (a brick starts inside the volume) and
    // x0 + n > 0 (the apron is at most one brick edge).
    let lo = x0.clamp(0, nx) as usize;
    let hi = (x0 + n as i64).clamp(0, nx) as usize;
    let left = (lo as i64 - x0) as usize;
    let inside = hi.saturating_sub(lo);
    debug_assert!(inside > 0, "stored run {x0}+{n} outside a row of {nx}");
    let (head, tail) = out.split_at_mut(left * ts);
    let (mid, tail) = tail.split_at_mut(inside * ts);
    encode(&row[lo..lo + inside], t, mid);
    for o in head.chunks_exact_mut(ts) {
        encode(&row[..1], t, o);
    }
    for o in tail.chunks_exact_mut(ts) {
        encode(&row[row.len() - 1..], t, o);
    }
}

/// [`downsample_row`] for a row whose fine rows are given, `[(y0, z0), (y1, z0), (y0, z1),
/// (y1, z1)]`: the same sums in the same order, written over pairs so that they vectorise
/// (the same bits, up to which NaN a sum of NaNs gives).
fn downsample_rows(rows: [&[f32]; 4], out: &mut [f32]) {
    let nx = rows[0].len();
    let pairs = (nx / 2).min(out.len());
    let p = rows.map(|r| &r.as_chunks::<2>().0[..pairs]);
    for (x, o) in out[..pairs].iter_mut().enumerate() {
        let s = ((p[0][x][0] + p[0][x][1]) + (p[1][x][0] + p[1][x][1]))
            + ((p[2][x][0] + p[2][x][1]) + (p[3][x][0] + p[3][x][1]));
        *o = if s.is_nan() {
            let v = [p[0][x], p[1][x], p[2][x], p[3][x]];
            mean_of_eight(s, *v.as_flattened().as_array().expect("eight voxels"))
        } else {
            s * 0.125
        };
    }
    // An odd row's last coarse voxel has one fine voxel per row, counted twice.
    for (x, o) in out.iter_mut().enumerate().skip(pairs) {
        let v: [f32; 8] = std::array::from_fn(|i| rows[i / 2][(2 * x + i % 2).min(nx - 1)]);
        let s = ((v[0] + v[1]) + (v[2] + v[3])) + ((v[4] + v[5]) + (v[6] + v[7]));
        *o = mean_of_eight(s, v);
    }
}

fn decode(bytes: &[u8], t: ScalarType) -> Vec<f32> {
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

/// A z-slice in a level's window: computed or copied (owned, recycled once spent), or read in
/// place from the source's memory (a mapped input file), which outlives the conversion.
enum Slice<'a> {
    Owned(Vec<f32>),
    InPlace(&'a [f32]),
}

impl std::ops::Deref for Slice<'_> {
    type Target = [f32];
    fn deref(&self) -> &[f32] {
        match self {
            Slice::Owned(v) => v,
            Slice::InPlace(s) => s,
        }
    }
}

impl Slice<'_> {
    fn into_owned(self) -> Option<Vec<f32>> {
        match self {
            Slice::Owned(v) => Some(v),
            Slice::InPlace(_) => None,
        }
    }
}

/// Coarse slices with at least this many values are down-sampled in parallel.
const PARALLEL_VALUES: usize = 1 << 18;

/// One level being written: a window of the z-slices its next brick slab needs.
struct LevelWriter<'a> {
    g: Geometry,
    ty: ScalarType,
    offset: u64,
    nb: [usize; 3],
    first_brick: usize,
    macro_off: Option<u64>,
    /// `(z, slice)`, consecutive z.
    window: VecDeque<(usize, Slice<'a>)>,
    next_slab: usize,
    free: Vec<Vec<f32>>,
    /// Macrocell layers computed (as soon as their last slice came, while their slices are
    /// in the cache) and not yet written: `(cz, mins, maxs)`, consecutive cz.
    layers: VecDeque<(usize, Vec<f32>, Vec<f32>)>,
    next_layer: usize,
}

impl<'a> LevelWriter<'a> {
    /// Slice `z` clamped to the level (it must be in the window).
    fn slice(&self, z: i64) -> &[f32] {
        let zc = z.clamp(0, self.g.dims[2] as i64 - 1) as usize;
        let base = self.window.front().map_or(0, |w| w.0);
        &self.window[zc - base].1
    }

    /// Min and max of the macrocells of edge `k` in layer `cz` (its slices in the window).
    fn layer(&self, k: usize, cz: usize) -> (usize, Vec<f32>, Vec<f32>) {
        let n = self.g.dims;
        let c = macro_dims(&self.g, k);
        let mut mn = vec![f32::INFINITY; c[0] * c[1]];
        let mut mx = vec![f32::NEG_INFINITY; c[0] * c[1]];
        let row = |y: usize, z: usize| &self.slice(z as i64)[y * n[0]..(y + 1) * n[0]];
        layer_min_max(n, k, cz, row, |v: f32| v, &mut mn, &mut mx);
        (cz, mn, mx)
    }

    /// The macrocell layers of edge `k` whose slices are all in once slice `z` is: from
    /// `next_layer` on.
    fn layers_due(&self, k: usize, z: usize) -> std::ops::Range<usize> {
        if k == 0 || self.macro_off.is_none() {
            return 0..0;
        }
        let cz = macro_dims(&self.g, k)[2];
        let last = self.g.dims[2] - 1;
        let mut end = self.next_layer;
        while end < cz && ((end + 1) * k).min(last) <= z {
            end += 1;
        }
        self.next_layer..end
    }

    /// The last slice slab `bz` needs.
    fn slab_top(&self, layout: &BrickLayout, bz: usize) -> usize {
        ((bz + 1) * layout.brick + layout.apron - 1).min(self.g.dims[2] - 1)
    }

    fn take_buffer(&mut self) -> Vec<f32> {
        let n = self.g.dims[0] * self.g.dims[1];
        let mut v = self.free.pop().unwrap_or_default();
        v.resize(n, 0.0);
        v
    }
}

struct Writer<'a> {
    file: &'a File,
    layout: BrickLayout,
    plan: &'a Plan,
    levels: Vec<LevelWriter<'a>>,
    checksums: Vec<u64>,
    /// Which output this is.
    id: usize,
    /// Bricks and macrocell sections on their way to the writer thread.
    sink: Option<SyncSender<Block>>,
    /// Buffers the writer thread is done with.
    pool: &'a Mutex<Vec<Vec<u8>>>,
}

impl<'a> Writer<'a> {
    fn new(
        id: usize,
        file: &'a File,
        layout: BrickLayout,
        plan: &'a Plan,
        pool: &'a Mutex<Vec<Vec<u8>>>,
    ) -> Self {
        let levels = plan
            .geoms
            .iter()
            .enumerate()
            .map(|(l, g)| LevelWriter {
                g: *g,
                ty: plan.types[l],
                offset: plan.offsets[l],
                nb: layout.bricks(g.dims),
                first_brick: plan.first_brick[l],
                macro_off: plan.macro_offsets.get(l).copied(),
                window: VecDeque::new(),
                next_slab: 0,
                free: Vec::new(),
                layers: VecDeque::new(),
                next_layer: 0,
            })
            .collect();
        let last = plan.geoms.len() - 1;
        let b = layout.bricks(plan.geoms[last].dims);
        let total_bricks = plan.first_brick[last] + b[0] * b[1] * b[2];
        Writer {
            file,
            layout,
            plan,
            levels,
            checksums: vec![0; total_bricks],
            id,
            sink: None,
            pool,
        }
    }

    /// Adds slice `z` of level `l`, writes every slab it completes and passes the down-sampled
    /// slices on to the coarser levels. Returns spent buffers of level `l`.
    fn push(&mut self, l: usize, z: usize, slice: Slice<'a>) -> Result<Vec<Slice<'a>>> {
        self.levels[l].window.push_back((z, slice));
        let nz = self.levels[l].g.dims[2];
        let k = self.plan.k;
        let due = self.levels[l].layers_due(k, z);
        let j = z / 2;
        let mut coarse = (l + 1 < self.levels.len() && (z % 2 == 1 || z == nz - 1))
            .then(|| self.levels[l + 1].take_buffer());
        let c = self.levels.get(l + 1).map_or([0; 3], |lw| lw.g.dims);
        let lw = &self.levels[l];
        let [nx, ny, _] = lw.g.dims;
        // The fine slices (when down-sampling is due, else any slice in the window).
        let (s0, s1) = if coarse.is_some() {
            (lw.slice(2 * j as i64), lw.slice((2 * j + 1) as i64))
        } else {
            (lw.slice(z as i64), lw.slice(z as i64))
        };
        let down_row = |(y, row): (usize, &mut [f32])| {
            let (y0, y1) = (2 * y, (2 * y + 1).min(ny - 1));
            let r = |y: usize| y * nx..(y + 1) * nx;
            let rows = [&s0[r(y0)], &s0[r(y1)], &s1[r(y0)], &s1[r(y1)]];
            downsample_rows(rows, row);
            // Which NaN a sum of NaNs (or of opposite infinities) gives depends on the order
            // of the additions, which vectorising changed: rows with a NaN are summed again
            // by the scalar code, so files keep the same bytes.
            if row.iter().fold(false, |n, v| n | v.is_nan()) {
                let fine = |x: usize, yy: usize, zz: usize| {
                    if zz == 2 * j {
                        s0[x + nx * yy]
                    } else {
                        s1[x + nx * yy]
                    }
                };
                downsample_row(fine, [nx, ny, nz], j, y, row);
            }
        };
        let compute_layers = || due.clone().map(|cz| lw.layer(k, cz)).collect::<Vec<_>>();
        // A slice's down-sampling and macrocell layers take tens of microseconds for a
        // 256^2 slice, about what handing them to the thread pool and waiting costs: only
        // large slices are split.
        let layers = match coarse.as_mut() {
            Some(coarse) if coarse.len() >= PARALLEL_VALUES => {
                rayon::join(
                    || coarse.par_chunks_mut(c[0]).enumerate().for_each(down_row),
                    compute_layers,
                )
                .1
            }
            Some(coarse) => {
                coarse.chunks_mut(c[0]).enumerate().for_each(down_row);
                compute_layers()
            }
            None => compute_layers(),
        };
        self.levels[l].layers.extend(layers);
        self.levels[l].next_layer = due.end;
        if let Some(coarse) = coarse {
            let spent = self.push(l + 1, j, Slice::Owned(coarse))?;
            self.levels[l + 1]
                .free
                .extend(spent.into_iter().filter_map(Slice::into_owned));
        }
        let mut spent = Vec::new();
        while self.levels[l].next_slab < self.levels[l].nb[2]
            && z >= self.levels[l].slab_top(&self.layout, self.levels[l].next_slab)
        {
            let bz = self.levels[l].next_slab;
            self.write_slab(l, bz)?;
            self.levels[l].next_slab += 1;
            // Keep what the next slab needs: slices from (bz + 1) B - A on.
            let keep = ((bz + 1) * self.layout.brick).saturating_sub(self.layout.apron);
            while self.levels[l].window.front().is_some_and(|w| w.0 < keep) {
                if let Some((_, v)) = self.levels[l].window.pop_front() {
                    spent.push(v);
                }
            }
        }
        Ok(spent)
    }

    fn write_slab(&mut self, l: usize, bz: usize) -> Result<()> {
        let lw = &self.levels[l];
        let layout = self.layout;
        let (b, a, s) = (layout.brick, layout.apron, layout.stored_edge());
        let [nx, ny, _] = lw.g.dims;
        let nb = lw.nb;
        let ts = lw.ty.size_bytes();
        let brick_bytes = s * s * s * ts;
        let (pool, sink, id) = (self.pool, self.sink.as_ref(), self.id);
        let sums: Vec<Result<Vec<u64>>> = (0..nb[1])
            .into_par_iter()
            .map(|by| {
                let first = ((by + nb[1] * bz) * nb[0]) as u64;
                let at = lw.offset + first * brick_bytes as u64;
                let sink = sink.ok_or_else(writer_gone)?;
                let mut bufs: Vec<Vec<u8>> = (0..nb[0])
                    .map(|_| take_exact(pool, brick_bytes))
                    .collect::<Result<_>>()?;
                // Plane by plane, row by row, every brick of the row in turn: the source is
                // read in order (a brick at a time, its short runs missed the cache), and
                // each plane is checksummed while it is in the cache.
                let plane = s * s * ts;
                let mut sums = vec![CHECKSUM_START; nb[0]];
                let mut summed = 0;
                for lz in 0..s {
                    let sl = lw.slice((bz * b + lz) as i64 - a as i64);
                    for ly in 0..s {
                        let y = ((by * b + ly) as i64 - a as i64).clamp(0, ny as i64 - 1) as usize;
                        let row = &sl[y * nx..(y + 1) * nx];
                        let at = (lz * s + ly) * s * ts;
                        for (bx, out) in bufs.iter_mut().enumerate() {
                            let x0 = (bx * b) as i64 - a as i64;
                            encode_run(row, x0, lw.ty, &mut out[at..at + s * ts]);
                        }
                    }
                    let upto = (lz + 1) * plane / 32 * 32;
                    for (sum, out) in sums.iter_mut().zip(&bufs) {
                        checksum_chunks(sum, &out[summed..upto]);
                    }
                    summed = upto;
                }
                let sums: Vec<u64> = sums
                    .into_iter()
                    .zip(&bufs)
                    .map(|(sum, out)| checksum_finish(sum, &out[summed..], out.len()))
                    .collect();
                // Brick by brick (adjacent in the file): the writer's queue then holds a few
                // bricks rather than a few rows of them (a row of 64^3 bricks across 2048^2
                // slices is 37 MB).
                for (bx, buf) in bufs.into_iter().enumerate() {
                    sink.send(Block {
                        output: id,
                        at: at + (bx * brick_bytes) as u64,
                        bytes: buf,
                        recycle: true,
                    })
                    .map_err(|_| writer_gone())?;
                }
                Ok(sums)
            })
            .collect();
        for (by, r) in sums.into_iter().enumerate() {
            let base = lw.first_brick + (by + nb[1] * bz) * nb[0];
            self.checksums[base..base + nb[0]].copy_from_slice(&r?);
        }
        if let Some(off) = self.levels[l].macro_off {
            self.write_macrocells(l, bz, off)?;
        }
        Ok(())
    }

    /// Min/max of the macrocells whose z lies in slab `bz` (each lies in the window).
    fn write_macrocells(&mut self, l: usize, bz: usize, off: u64) -> Result<()> {
        let k = self.plan.k;
        let lw = &mut self.levels[l];
        let c = macro_dims(&lw.g, k);
        let layer = c[0] * c[1];
        let cells = layer * c[2];
        let cz0 = bz * self.layout.brick / k;
        let cz1 = ((bz + 1) * self.layout.brick / k).min(c[2]);
        if cz0 >= cz1 {
            return Ok(());
        }
        let mut mins = Vec::with_capacity((cz1 - cz0) * layer);
        let mut maxs = Vec::with_capacity((cz1 - cz0) * layer);
        for cz in cz0..cz1 {
            // Computed in `push` (any layer still missing is computed here).
            while lw.layers.front().is_some_and(|f| f.0 < cz) {
                lw.layers.pop_front();
            }
            let (_, a, b) = match lw.layers.front() {
                Some(f) if f.0 == cz => lw.layers.pop_front().unwrap_or_else(|| lw.layer(k, cz)),
                _ => lw.layer(k, cz),
            };
            mins.extend(a);
            maxs.extend(b);
        }
        // Through the writer thread: a write from here would wait on the file's inode lock
        // while the writer holds it (spinning, on Linux), taking a core from the bricks.
        let at = (cz0 * layer * 4) as u64;
        let sink = self.sink.as_ref().ok_or_else(writer_gone)?;
        for (vals, at) in [(mins, off + at), (maxs, off + (cells * 4) as u64 + at)] {
            sink.send(Block {
                output: self.id,
                at,
                bytes: f32_bytes(&vals),
                recycle: false,
            })
            .map_err(|_| writer_gone())?;
        }
        Ok(())
    }
}

/// Sets the length of the temporary output `file` to `len`, reserving all its blocks where
/// the file system can (Linux `fallocate`). Reserved blocks make the writes cheaper and the
/// end of the conversion immediate: ext4 need not allocate blocks as it caches each page,
/// nor flush the whole file when it is renamed over an existing one (its `auto_da_alloc`,
/// which made the rename wait for the file's write-back). A full disk is this call's error,
/// before any work. Where `fallocate` is unsupported, only the length is set.
fn reserve(file: &File, len: u64) -> Result<()> {
    #[cfg(target_os = "linux")]
    {
        use rustix::io::Errno;
        loop {
            match rustix::fs::fallocate(file, rustix::fs::FallocateFlags::empty(), 0, len) {
                Ok(()) => return Ok(()),
                Err(Errno::INTR) => {}
                Err(e) if e == Errno::OPNOTSUPP || e == Errno::NOSYS => break,
                Err(e) => return Err(Error::Io(e.into())),
            }
        }
    }
    file.set_len(len)?;
    Ok(())
}

/// Bytes for the writer thread to write at `at` in output `output`; bricks (`recycle`) come
/// back to the buffer pool afterwards.
struct Block {
    output: usize,
    at: u64,
    bytes: Vec<u8>,
    recycle: bool,
}

/// A pooled buffer of exactly `len` bytes, or a new one: a level-0 brick of uint8 or uint16
/// is shorter than the f32 bricks of the coarser levels, and growing a buffer of the other
/// length would copy and zero it.
fn take_exact(pool: &Mutex<Vec<Vec<u8>>>, len: usize) -> Result<Vec<u8>> {
    let mut p = lock(pool);
    match p.iter().rposition(|b| b.len() == len) {
        Some(i) => Ok(p.swap_remove(i)),
        None => {
            drop(p);
            zeroed_bytes(len).ok_or_else(|| {
                Error::Budget(crate::budget::BudgetError::refused(
                    "a brick of the conversion",
                    len as u64,
                ))
            })
        }
    }
}

/// `len` zero bytes, or `None` where the allocator refuses them (an error then, not an
/// abort). Zeroed by the allocator (`calloc`): fresh pages from the system are not written
/// twice, as `try_reserve_exact` and a fill would write them.
fn zeroed_bytes(len: usize) -> Option<Vec<u8>> {
    if len == 0 {
        return Some(Vec::new());
    }
    let layout = std::alloc::Layout::array::<u8>(len).ok()?;
    // SAFETY: `layout` has a non-zero size. A non-null pointer from `alloc_zeroed` is `len`
    // initialised (zero) bytes allocated by the global allocator with the layout of a
    // `Vec<u8>` of capacity `len` (alignment 1), which is what `from_raw_parts` requires.
    #[allow(unsafe_code)]
    unsafe {
        let ptr = std::alloc::alloc_zeroed(layout);
        (!ptr.is_null()).then(|| Vec::from_raw_parts(ptr, len, len))
    }
}

fn writer_gone() -> Error {
    Error::invalid("the bricked-file writer thread stopped")
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

fn f32_bytes(v: &[f32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

/// Statistics of the level-0 values, gathered while reading.
#[derive(Clone, Copy, Debug)]
struct ValueStats {
    non_finite: u64,
    lo: f32,
    hi: f32,
    pos_lo: f32,
}

impl ValueStats {
    fn new() -> Self {
        ValueStats {
            non_finite: 0,
            lo: f32::INFINITY,
            hi: f32::NEG_INFINITY,
            pos_lo: f32::INFINITY,
        }
    }

    /// Adds `vals`, eight lanes at a time: value `8 i + j` goes to lane `j`, where it moves
    /// the lane's minimum only if strictly smaller (the maximum if strictly larger), so the
    /// result is exact and the same on every platform; the lanes are combined at the end.
    fn add(&mut self, vals: &[f32]) {
        const L: usize = 8;
        let mut lanes = Lanes {
            lo: [f32::INFINITY; L],
            hi: [f32::NEG_INFINITY; L],
            pos: [f32::INFINITY; L],
            bad: [0; L],
        };
        let (chunks, rest) = vals.as_chunks::<L>();
        // Lane counters are u32: flush them before they could wrap.
        for block in chunks.chunks(1 << 20) {
            lanes.add(block);
            self.non_finite += lanes.bad.iter().map(|&b| u64::from(b)).sum::<u64>();
            lanes.bad = [0; L];
        }
        let Lanes {
            mut lo,
            mut hi,
            mut pos,
            ..
        } = lanes;
        for &v in rest {
            if v.is_finite() {
                lo[0] = lo[0].min(v);
                hi[0] = hi[0].max(v);
                if v > 0.0 {
                    pos[0] = pos[0].min(v);
                }
            } else {
                self.non_finite += 1;
            }
        }
        for i in 0..L {
            self.lo = self.lo.min(lo[i]);
            self.hi = self.hi.max(hi[i]);
            self.pos_lo = self.pos_lo.min(pos[i]);
        }
    }
}

/// Per-lane minimum, maximum, smallest positive value (all of finite values) and count of
/// non-finite values, for [`ValueStats::add`].
struct Lanes {
    lo: [f32; 8],
    hi: [f32; 8],
    pos: [f32; 8],
    bad: [u32; 8],
}

impl Lanes {
    /// Adds `block` lane by lane (at most 2^32 - 1 blocks, so the counts cannot wrap).
    #[cfg(target_arch = "x86_64")]
    fn add(&mut self, block: &[[f32; 8]]) {
        // SAFETY: SSE2 is part of the x86_64 baseline, so every x86_64 CPU runs `add_sse2`.
        #[allow(unsafe_code)]
        unsafe {
            self.add_sse2(block);
        }
    }

    /// SSE2 version of [`Lanes::add_scalar`], with the same result in every lane: written
    /// portably, LLVM keeps the selects scalar and the statistics cost as much as the
    /// kernel's read of the file. A non-finite value is turned into a NaN (all bits set),
    /// which `minps` and `maxps` pass over (they return their second operand, the lane's
    /// value so far, when either is NaN, and also when both are equal, as the scalar
    /// version keeps the first of equal values).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "sse2")]
    fn add_sse2(&mut self, block: &[[f32; 8]]) {
        use std::arch::x86_64::{
            __m128, __m128i, _mm_and_ps, _mm_castps_si128, _mm_castsi128_ps, _mm_cmple_ps,
            _mm_cmpnlt_ps, _mm_max_ps, _mm_min_ps, _mm_or_ps, _mm_set1_epi32, _mm_set1_ps,
            _mm_setzero_ps, _mm_sub_epi32,
        };
        let inf = _mm_set1_ps(f32::INFINITY);
        let abs = _mm_castsi128_ps(_mm_set1_epi32(0x7fff_ffff));
        let zero = _mm_setzero_ps();
        let mut lo: [__m128; 2] = bytemuck::cast(self.lo);
        let mut hi: [__m128; 2] = bytemuck::cast(self.hi);
        let mut pos: [__m128; 2] = bytemuck::cast(self.pos);
        let mut bad: [__m128i; 2] = bytemuck::cast(self.bad);
        for c in block {
            let v: [__m128; 2] = bytemuck::cast(*c);
            for h in 0..2 {
                // All ones where |v| is not below infinity: infinite or NaN.
                let nf = _mm_cmpnlt_ps(_mm_and_ps(v[h], abs), inf);
                let x = _mm_or_ps(v[h], nf);
                lo[h] = _mm_min_ps(x, lo[h]);
                hi[h] = _mm_max_ps(x, hi[h]);
                // NaN unless positive.
                let p = _mm_or_ps(x, _mm_cmple_ps(x, zero));
                pos[h] = _mm_min_ps(p, pos[h]);
                // nf is -1 where not finite.
                bad[h] = _mm_sub_epi32(bad[h], _mm_castps_si128(nf));
            }
        }
        self.lo = bytemuck::cast(lo);
        self.hi = bytemuck::cast(hi);
        self.pos = bytemuck::cast(pos);
        self.bad = bytemuck::cast(bad);
    }

    #[cfg(not(target_arch = "x86_64"))]
    fn add(&mut self, block: &[[f32; 8]]) {
        self.add_scalar(block);
    }

    /// The portable version: what [`Lanes::add`] computes on every platform.
    #[cfg(any(test, not(target_arch = "x86_64")))]
    fn add_scalar(&mut self, block: &[[f32; 8]]) {
        for c in block {
            for i in 0..8 {
                let v = c[i];
                let fin = v.abs() < f32::INFINITY;
                let a = if fin { v } else { f32::INFINITY };
                let b = if fin { v } else { f32::NEG_INFINITY };
                let p = if fin && v > 0.0 { v } else { f32::INFINITY };
                self.lo[i] = if a < self.lo[i] { a } else { self.lo[i] };
                self.hi[i] = if b > self.hi[i] { b } else { self.hi[i] };
                self.pos[i] = if p < self.pos[i] { p } else { self.pos[i] };
                self.bad[i] += u32::from(!fin);
            }
        }
    }
}

/// Converts a volume into a bricked file at `out` in one streaming pass: the source's
/// z-slices are read on a second thread (which also gathers the value statistics), and
/// every level (each the 2x down-sampling of the one before) is bricked, checksummed and
/// handed to a writer thread as soon as its brick slab is complete, with the macrocells of
/// every level. Memory stays at about `dims.x * dims.y * (B + 2A) * 4 / 3` f32 values (the
/// slab windows of all levels; `dims.x * dims.y * (B + 2A) / 3` when the source is read
/// in place, [`SlabSource::in_place`]) plus two rows of bricks being filled and a few
/// bricks queued for the writer. The file is written under a temporary name beside `out`
/// and renamed over it only when complete, so an interrupted conversion leaves no half file.
/// `progress(done, total)` reports level-0 slices.
pub fn convert(
    source: &mut (dyn SlabSource + Send),
    out: &Path,
    channel_name: &str,
    layout: BrickLayout,
    progress: &mut dyn FnMut(u64, u64),
) -> Result<()> {
    convert_within(
        source,
        out,
        channel_name,
        layout,
        &MemoryBudget::machine_default(),
        progress,
    )
}

/// [`convert`] within `budget`: [`conversion_bytes`] of the volume is checked against it
/// before anything is allocated or created.
///
/// # Errors
/// As [`convert`]; [`Error::Budget`] when the conversion's memory does not fit `budget`.
pub fn convert_within(
    source: &mut (dyn SlabSource + Send),
    out: &Path,
    channel_name: &str,
    layout: BrickLayout,
    budget: &MemoryBudget,
    progress: &mut dyn FnMut(u64, u64),
) -> Result<()> {
    convert_many_within(
        &mut OneChannel(source),
        &[(out, channel_name)],
        layout,
        budget,
        progress,
    )
}

/// The bytes of the `.bsv` file [`convert`] writes for a volume of `dims` whose values are
/// of type `t`, with `layout` (fitted to `dims` first): every level's bricks with their
/// aprons, the macrocells, the checksums and the header.
///
/// # Errors
/// An invalid layout or dims; a size that overflows.
pub fn bricked_file_bytes(dims: [usize; 3], layout: BrickLayout, t: ScalarType) -> Result<u64> {
    layout.validate()?;
    let g = Geometry::unit(dims);
    g.validate()?;
    let layout = layout.fitted(dims);
    Ok(Plan::new(g, &layout, stored_level0(t), stored_k(&layout))?.total)
}

/// The type a `.bsv` level 0 stores a source's values of type `t` in.
fn stored_level0(t: ScalarType) -> ScalarType {
    match t {
        t @ (ScalarType::U8 | ScalarType::U16 | ScalarType::F16) => t,
        _ => ScalarType::F32,
    }
}

/// The bytes [`convert_many`] holds at most while converting a volume of `dims` whose
/// channels' level 0 are stored as `types` (one per channel) with `layout` (fitted to
/// `dims` first, as the converter does), on this thread pool:
/// - every level's window of slices (f32): the stored edge plus four slices of the level
///   (at most the level's slices plus two), and four level-0 slices per channel on their
///   way from the reader;
/// - the bricks in flight, per brick size: a row of bricks per pool thread at work (at most
///   the level's rows, for the level and channel that need most) while the writer's queue
///   of eight and the brick it writes may still hold bricks of a finer or coarser level, at
///   most every brick of that size;
/// - the checksum of every brick.
///
/// A long thin volume with a large brick edge needs whole bricks for few voxels: 1000 x 2 x
/// 2 in bricks of 1000 holds a 4 GB brick.
#[must_use]
pub fn conversion_bytes(dims: [usize; 3], layout: BrickLayout, types: &[ScalarType]) -> u64 {
    let layout = layout.fitted(dims);
    let threads = rayon::current_num_threads().max(1) as u64;
    let s = layout.stored_edge() as u64;
    let mut total = 0u64;
    // Per brick size in bytes: the most bricks one slab's rows hold, and all bricks.
    let mut sizes: Vec<(u64, u64, u64)> = Vec::new();
    let geoms = level_geometries(Geometry::unit(dims), layout.brick);
    for &t in types {
        let t0 = stored_level0(t);
        let slice0 = (dims[0] as u64).saturating_mul(dims[1] as u64);
        total = total.saturating_add(slice0.saturating_mul(16));
        for (g, ty) in geoms.iter().zip(level_types(geoms.len(), t0)) {
            let slice = (g.dims[0] as u64).saturating_mul(g.dims[1] as u64);
            let window = (s + 4).min(g.dims[2] as u64 + 2);
            total = total.saturating_add(slice.saturating_mul(4).saturating_mul(window));
            let nb = layout.bricks(g.dims).map(|n| n as u64);
            let bricks = nb[0].saturating_mul(nb[1]).saturating_mul(nb[2]);
            total = total.saturating_add(bricks.saturating_mul(8));
            let rows = threads.min(nb[1]).saturating_mul(nb[0]);
            let bytes = s.saturating_pow(3).saturating_mul(ty.size_bytes() as u64);
            match sizes.iter_mut().find(|(b, _, _)| *b == bytes) {
                Some((_, r, n)) => {
                    *r = (*r).max(rows);
                    *n = n.saturating_add(bricks);
                }
                None => sizes.push((bytes, rows, bricks)),
            }
        }
    }
    sizes.iter().fold(total, |t, &(bytes, rows, bricks)| {
        t.saturating_add(bytes.saturating_mul(rows.saturating_add(9).min(bricks)))
    })
}

/// A source of z-slices of several scalar channels at once, such as a synthetic dataset
/// computed slice by slice ([`crate::synth::Stream`]).
pub trait MultiSlabSource {
    /// Geometry of every channel.
    fn geometry(&self) -> Geometry;
    /// Number of channels.
    fn channels(&self) -> usize;
    /// The type channel `c`'s level 0 is stored in (default f32).
    fn scalar_type(&self, _c: usize) -> ScalarType {
        ScalarType::F32
    }
    /// Fills `out[c]` (resized to `dims.x * dims.y`, x fastest) with slice `z` of channel `c`.
    fn read_slices(&mut self, z: usize, out: &mut [Vec<f32>]) -> Result<()>;
    /// Every channel's whole volume (as [`SlabSource::in_place`]), if the source holds them
    /// in memory as f32; then [`MultiSlabSource::read_slices`] is not called. Default: none.
    fn in_place(&self) -> Option<Vec<&[f32]>> {
        None
    }
}

struct OneChannel<'a>(&'a mut (dyn SlabSource + Send));

/// Where the converter's slices come from.
enum Input<'a> {
    /// Every channel's whole volume, in memory.
    InPlace(Vec<&'a [f32]>),
    Read(&'a mut (dyn MultiSlabSource + Send)),
}

impl MultiSlabSource for OneChannel<'_> {
    fn geometry(&self) -> Geometry {
        self.0.geometry()
    }
    fn channels(&self) -> usize {
        1
    }
    fn scalar_type(&self, _c: usize) -> ScalarType {
        self.0.scalar_type()
    }
    fn in_place(&self) -> Option<Vec<&[f32]>> {
        self.0.in_place().map(|v| vec![v])
    }
    fn read_slices(&mut self, z: usize, out: &mut [Vec<f32>]) -> Result<()> {
        let n = self.0.geometry().dims[0] * self.0.geometry().dims[1];
        out[0].resize(n, 0.0);
        self.0.read_slice(z, &mut out[0])
    }
}

/// [`convert`] for several channels read together: channel `c` goes to `outs[c]` (a path
/// and the channel name stored in it), all in the one pass over the source. Every file is
/// written under a temporary name and renamed only when all are complete.
pub fn convert_many(
    source: &mut (dyn MultiSlabSource + Send),
    outs: &[(&Path, &str)],
    layout: BrickLayout,
    progress: &mut dyn FnMut(u64, u64),
) -> Result<()> {
    convert_many_within(
        source,
        outs,
        layout,
        &MemoryBudget::machine_default(),
        progress,
    )
}

/// [`convert_many`] within `budget` ([`convert_within`]).
///
/// # Errors
/// As [`convert_many`]; [`Error::Budget`] when the conversion's memory does not fit
/// `budget`.
pub fn convert_many_within(
    source: &mut (dyn MultiSlabSource + Send),
    outs: &[(&Path, &str)],
    layout: BrickLayout,
    budget: &MemoryBudget,
    progress: &mut dyn FnMut(u64, u64),
) -> Result<()> {
    layout.validate()?;
    let g0 = source.geometry();
    g0.validate()?;
    if outs.len() != source.channels() || outs.is_empty() {
        return Err(Error::parameter(format!(
            "{} outputs for {} channels",
            outs.len(),
            source.channels()
        )));
    }
    let types: Vec<ScalarType> = (0..outs.len()).map(|c| source.scalar_type(c)).collect();
    let [nx, ny, nz] = g0.dims;
    let fitted = layout.fitted(g0.dims);
    budget.check(
        format_args!(
            "converting this {nx}x{ny}x{nz} volume into bricks of edge {} (a smaller brick \
             edge needs less)",
            fitted.brick
        ),
        conversion_bytes(g0.dims, layout, &types),
    )?;
    let layout = fitted;
    let mut plans = Vec::with_capacity(outs.len());
    let mut tmps = Vec::with_capacity(outs.len());
    for (c, (out, name)) in outs.iter().enumerate() {
        let t0 = stored_level0(source.scalar_type(c));
        plans.push(Plan::new(g0, &layout, t0, stored_k(&layout))?);
        if name.len() > 255 {
            return Err(Error::parameter("channel name longer than 255 bytes"));
        }
        let dir = out
            .parent()
            .filter(|p| !p.as_os_str().is_empty())
            .unwrap_or(Path::new("."));
        let mut b = tempfile::Builder::new();
        // `.blueshift-<pid>-<random>.bsv.partial`, as the CLI names its temporaries, so
        // `blueshift clean` can tell a killed run's file from a running one's.
        let prefix = format!(".blueshift-{}-", std::process::id());
        b.prefix(&prefix).suffix(".bsv.partial");
        // Mode 0666 less the umask, as `File::create` gives (tempfile's default is 0600).
        b.permissions(std::os::unix::fs::PermissionsExt::from_mode(0o666));
        let tmp = b.tempfile_in(dir)?;
        reserve(tmp.as_file(), plans[c].total)?;
        tmps.push(tmp);
    }
    let pool = Mutex::new(Vec::new());
    let mut writers: Vec<Writer> = plans
        .iter()
        .zip(&tmps)
        .enumerate()
        .map(|(id, (plan, tmp))| Writer::new(id, tmp.as_file(), layout, plan, &pool))
        .collect();
    let nz = g0.dims[2];
    let nc = outs.len();
    let slice_len = g0.dims[0] * g0.dims[1];
    // Volumes held in memory are read in place: no slice is copied, and the bricks of f32
    // go from there to the file in one copy, the kernel's.
    let input = match source.in_place() {
        Some(v) if v.len() == nc && v.iter().all(|c| c.len() == slice_len * nz) => {
            let source: &(dyn MultiSlabSource + Send) = source;
            Input::InPlace(source.in_place().unwrap_or_default())
        }
        _ => Input::Read(source),
    };
    let stats = std::thread::scope(|scope| -> Result<Vec<ValueStats>> {
        // Slices read in place cost no memory: let the reader (which then only gathers the
        // statistics, touching the pages first) run further ahead.
        let depth = if matches!(input, Input::InPlace(_)) {
            8
        } else {
            2
        };
        let (tx, rx) = std::sync::mpsc::sync_channel::<Result<(usize, Vec<Slice>)>>(depth);
        let (back_tx, back_rx) = std::sync::mpsc::channel::<Vec<f32>>();
        let reader = scope.spawn(move || {
            let mut input = input;
            let mut st = vec![ValueStats::new(); nc];
            for z in 0..nz {
                let r = match &mut input {
                    Input::InPlace(volumes) => Ok(volumes
                        .iter()
                        .map(|v| Slice::InPlace(&v[z * slice_len..(z + 1) * slice_len]))
                        .collect::<Vec<_>>()),
                    Input::Read(source) => {
                        let mut bufs: Vec<Vec<f32>> = (0..nc)
                            .map(|_| back_rx.try_recv().unwrap_or_default())
                            .collect();
                        source
                            .read_slices(z, &mut bufs)
                            .map(|()| bufs.into_iter().map(Slice::Owned).collect())
                    }
                };
                let r = r.map(|slices| {
                    for (s, b) in st.iter_mut().zip(&slices) {
                        s.add(b);
                    }
                    (z, slices)
                });
                let failed = r.is_err();
                if tx.send(r).is_err() || failed {
                    break;
                }
            }
            st
        });
        // One thread writes, in slab order: buffered writes to one file serialise on its
        // inode lock anyway, and the bricks are computed meanwhile. The writer is the slower
        // side, so a longer queue only holds more bricks: each is memory the process touches
        // for the first time, which costs more than the copy into it (on this VM, 8 queued
        // bricks took a 256^3 conversion from 80 to 100 ms).
        let (sink, rows) = std::sync::mpsc::sync_channel::<Block>(2);
        for w in &mut writers {
            w.sink = Some(sink.clone());
        }
        drop(sink);
        let pool = &pool;
        let files: Vec<&File> = tmps.iter().map(tempfile::NamedTempFile::as_file).collect();
        let writer = scope.spawn(move || -> Result<()> {
            for b in rows {
                files[b.output].write_all_at(&b.bytes, b.at)?;
                if b.recycle {
                    lock(pool).push(b.bytes);
                }
            }
            Ok(())
        });
        let mut run = || -> Result<()> {
            for r in &rx {
                let (z, slices) = r?;
                progress(z as u64 + 1, nz as u64);
                for (w, slice) in writers.iter_mut().zip(slices) {
                    for b in w.push(0, z, slice)? {
                        if let Some(b) = b.into_owned() {
                            let _ = back_tx.send(b);
                        }
                    }
                }
            }
            Ok(())
        };
        let done = run();
        drop(rx);
        for w in &mut writers {
            w.sink = None;
        }
        let written = writer
            .join()
            .map_err(|_| Error::invalid("the bricked-file writer thread panicked"))?;
        written?;
        done?;
        reader
            .join()
            .map_err(|_| Error::invalid("the volume reader thread panicked"))
    })?;
    for (((w, plan), (_, name)), st) in writers.iter().zip(&plans).zip(outs).zip(&stats) {
        if w.levels.iter().any(|l| l.next_slab != l.nb[2]) {
            return Err(Error::invalid(
                "the source ended before every slice was read",
            ));
        }
        w.file
            .write_all_at(&u64_bytes(&w.checksums), plan.checksum_offset)?;
        let macro_sums = macrocell_checksums(w.file, plan)?;
        w.file.write_all_at(
            &header(plan, &layout, g0, name.as_bytes(), st, &macro_sums),
            0,
        )?;
    }
    drop(writers);
    for (tmp, (out, _)) in tmps.into_iter().zip(outs) {
        tmp.persist(out).map_err(|e| Error::Io(e.error))?;
    }
    Ok(())
}

/// The bytes of level `level`'s macrocell section (mins then maxs).
fn macrocell_bytes(plan: &Plan, level: usize) -> u64 {
    let c = macro_dims(&plan.geoms[level], plan.k);
    (c[0] * c[1] * c[2]) as u64 * 8
}

/// The checksum of each level's macrocell section as written (read back a MiB at a time;
/// none without macrocells).
fn macrocell_checksums(file: &File, plan: &Plan) -> Result<Vec<u64>> {
    if plan.k == 0 {
        return Ok(Vec::new());
    }
    let mut buf = vec![0u8; 1 << 20];
    (0..plan.geoms.len())
        .map(|l| {
            let (start, len) = (plan.macro_offsets[l], macrocell_bytes(plan, l));
            let mut h = CHECKSUM_START;
            let mut done = 0u64;
            loop {
                let n =
                    usize::try_from((len - done).min(buf.len() as u64)).map_err(|_| overflow())?;
                file.read_exact_at(&mut buf[..n], start + done)?;
                done += n as u64;
                if done == len {
                    let whole = n / 32 * 32;
                    checksum_chunks(&mut h, &buf[..whole]);
                    return Ok(checksum_finish(h, &buf[whole..n], len as usize));
                }
                checksum_chunks(&mut h, &buf[..n]);
            }
        })
        .collect()
}

/// The checksum version 4 keeps at [`HEADER_SUM_AT`]: of every other header byte.
fn header_checksum(h: &[u8]) -> u64 {
    let mut rest = h[..HEADER_SUM_AT].to_vec();
    rest.extend_from_slice(&h[HEADER_SUM_AT + 8..]);
    checksum(&rest)
}

fn u64_bytes(v: &[u64]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

fn header(
    plan: &Plan,
    layout: &BrickLayout,
    g0: Geometry,
    name: &[u8],
    stats: &ValueStats,
    macro_sums: &[u64],
) -> Vec<u8> {
    let mut h = vec![0u8; HEADER_BYTES as usize];
    let mut put = |at: usize, b: &[u8]| h[at..at + b.len()].copy_from_slice(b);
    put(0, MAGIC);
    put(8, &VERSION.to_le_bytes());
    put(12, &(layout.brick as u32).to_le_bytes());
    put(16, &(layout.apron as u32).to_le_bytes());
    put(20, &(plan.geoms.len() as u32).to_le_bytes());
    for (a, d) in g0.dims.iter().enumerate() {
        put(24 + 8 * a, &(*d as u64).to_le_bytes());
    }
    for a in 0..3 {
        put(48 + 4 * a, &g0.origin[a].to_le_bytes());
        put(60 + 4 * a, &g0.spacing[a].to_le_bytes());
    }
    put(72, &type_code(plan.types[0]).to_le_bytes());
    put(76, &(name.len() as u32).to_le_bytes());
    put(80, name);
    put(336, &(plan.k as u32).to_le_bytes());
    put(
        340,
        &plan
            .macro_offsets
            .first()
            .copied()
            .unwrap_or(0)
            .to_le_bytes(),
    );
    put(348, &plan.checksum_offset.to_le_bytes());
    put(356, &stats.non_finite.to_le_bytes());
    let finite = stats.lo <= stats.hi;
    let or_nan = |v: f32, ok: bool| if ok { v } else { f32::NAN };
    put(364, &or_nan(stats.lo, finite).to_le_bytes());
    put(368, &or_nan(stats.hi, finite).to_le_bytes());
    put(372, &plan.total.to_le_bytes());
    put(
        380,
        &or_nan(stats.pos_lo, stats.pos_lo.is_finite()).to_le_bytes(),
    );
    for (l, sum) in macro_sums.iter().enumerate() {
        put(MACRO_SUMS_AT + 8 * l, &sum.to_le_bytes());
    }
    let sum = header_checksum(&h);
    h[HEADER_SUM_AT..HEADER_SUM_AT + 8].copy_from_slice(&sum.to_le_bytes());
    h
}

/// The bricks of an opened `.bsv` file: what [`BrickCache`]s read.
#[derive(Debug)]
pub struct FileBricks {
    uid: u64,
    file: File,
    layout: BrickLayout,
    plan: Plan,
    name: String,
    checksums: Vec<u64>,
    non_finite: u64,
    range: Option<(f32, f32)>,
    positive_min: Option<f32>,
    /// Each level's macrocell checksum (version 4; none in version 3 files).
    macro_sums: Option<Vec<u64>>,
    path: std::path::PathBuf,
}

impl BrickSource for FileBricks {
    fn uid(&self) -> u64 {
        self.uid
    }
    fn layout(&self) -> BrickLayout {
        self.layout
    }
    fn geometries(&self) -> &[Geometry] {
        &self.plan.geoms
    }
    fn read_brick(&self, level: usize, idx: u64) -> Result<Vec<f32>> {
        let s = self.layout.stored_edge();
        let mut v = vec![0f32; s * s * s];
        self.read_brick_into(level, idx, &mut v)?;
        Ok(v)
    }
    fn read_brick_into(&self, level: usize, idx: u64, out: &mut [f32]) -> Result<()> {
        let s = self.layout.stored_edge();
        let t = self.plan.types[level];
        let bytes_per = s * s * s * t.size_bytes();
        if out.len() != s * s * s {
            return Err(Error::invalid("brick buffer of the wrong size"));
        }
        let at = self.plan.offsets[level] + idx * bytes_per as u64;
        let want = self.checksums[self.plan.first_brick[level] + idx as usize];
        let bad = || {
            Error::invalid(format!(
                "bricked file '{}': brick {idx} of level {level} is corrupt (checksum \
                 mismatch): {}",
                self.name,
                self.path.display()
            ))
        };
        // A read that fails (a file truncated or gone bad under an open scene) names the
        // file and the brick: a scene may sample several files.
        let read = |buf: &mut [u8]| {
            self.file.read_exact_at(buf, at).map_err(|e| {
                let what = format!("bricked file '{}': brick {idx} of level {level}", self.name);
                match Error::from(e) {
                    Error::Io(e) => Error::Io(std::io::Error::new(
                        e.kind(),
                        format!("{what}: {e}: {}", self.path.display()),
                    )),
                    Error::Invalid(m) => {
                        Error::invalid(format!("{what}: {m}: {}", self.path.display()))
                    }
                    e => Error::invalid(format!("{what}: {e}: {}", self.path.display())),
                }
            })
        };
        if t == ScalarType::F32 && cfg!(target_endian = "little") {
            read(bytemuck::cast_slice_mut(out))?;
            if checksum(bytemuck::cast_slice(out)) != want {
                return Err(bad());
            }
            return Ok(());
        }
        let mut buf = vec![0u8; bytes_per];
        read(&mut buf)?;
        if checksum(&buf) != want {
            return Err(bad());
        }
        for (o, v) in out.iter_mut().zip(decode(&buf, t)) {
            *o = v;
        }
        Ok(())
    }
    fn stored_macrocells(&self, level: usize, k: usize) -> Result<Option<Macrocells>> {
        if k != self.plan.k || k == 0 || level >= self.plan.geoms.len() {
            return Ok(None);
        }
        let g = self.plan.geoms[level];
        let c = macro_dims(&g, k);
        let cells = c[0] * c[1] * c[2];
        let mut buf = vec![0f32; 2 * cells];
        self.file.read_exact_at(
            bytemuck::cast_slice_mut(&mut buf),
            self.plan.macro_offsets[level],
        )?;
        if let Some(sums) = &self.macro_sums
            && sums.get(level) != Some(&checksum(bytemuck::cast_slice(&buf)))
        {
            return Err(Error::invalid(format!(
                "bricked file '{}': the macrocells of level {level} are corrupt (checksum \
                 mismatch): {}",
                self.name,
                self.path.display()
            )));
        }
        if cfg!(target_endian = "big") {
            for v in &mut buf {
                *v = f32::from_le_bytes(v.to_ne_bytes());
            }
        }
        let max = buf.split_off(cells);
        Macrocells::from_parts(g, k, buf, max)
            .map(Some)
            .map_err(|e| {
                Error::invalid(format!(
                    "bricked file '{}': {e}: {}",
                    self.name,
                    self.path.display()
                ))
            })
    }
    fn finite_range(&self) -> Option<(f32, f32)> {
        self.range
    }
    fn non_finite(&self) -> u64 {
        self.non_finite
    }
    fn positive_min(&self) -> Option<f32> {
        self.positive_min
    }
}

impl FileBricks {
    fn open(path: &Path) -> Result<Self> {
        crate::io::check_regular_file(path)?;
        let mut file = File::open(path)?;
        if !file.metadata()?.is_file() {
            return Err(Error::invalid(format!(
                "not a regular file: {}",
                path.display()
            )));
        }
        let len = file.metadata()?.len();
        let mut h = vec![0u8; HEADER_BYTES as usize];
        let n = file.read(&mut h)?;
        h.truncate(n);
        if h.len() < 80 || !h.starts_with(MAGIC) {
            return Err(Error::invalid(format!(
                "not a bricked volume file: {}",
                path.display()
            )));
        }
        let u32_at = |o: usize| u32::from_le_bytes([h[o], h[o + 1], h[o + 2], h[o + 3]]);
        let version = u32_at(8);
        if !(OLDEST_VERSION..=VERSION).contains(&version) {
            return Err(Error::unsupported(format!(
                "bricked file version {} (this build reads versions {OLDEST_VERSION} to \
                 {VERSION}; convert the source again): {}",
                u32_at(8),
                path.display()
            )));
        }
        if h.len() < HEADER_BYTES as usize {
            return Err(Error::invalid(format!(
                "truncated bricked file header: {}",
                path.display()
            )));
        }
        let u64_at = |o: usize| u64::from_le_bytes(h[o..o + 8].try_into().expect("8 bytes"));
        if version >= 4 && u64_at(HEADER_SUM_AT) != header_checksum(&h) {
            return Err(Error::invalid(format!(
                "bricked file header is corrupt (checksum mismatch): {}",
                path.display()
            )));
        }
        let f32_at = |o: usize| f32::from_le_bytes(h[o..o + 4].try_into().expect("4 bytes"));
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
        let g0 = Geometry {
            dims,
            origin: Vec3::new(f32_at(48), f32_at(52), f32_at(56)),
            spacing: Vec3::new(f32_at(60), f32_at(64), f32_at(68)),
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
        let name = String::from_utf8(h[80..80 + name_len].to_vec())
            .map_err(|_| Error::invalid("bricked file: name is not UTF-8"))?;
        let k = u32_at(336) as usize;
        if k != 0 && k != stored_k(&layout) {
            return Err(Error::invalid("bricked file: bad macrocell edge"));
        }
        let plan = Plan::new(g0, &layout, t0, k)?;
        if plan.geoms.len() != u32_at(20) as usize {
            return Err(Error::invalid(
                "bricked file: level count does not match the dimensions",
            ));
        }
        if u64_at(340) != plan.macro_offsets.first().copied().unwrap_or(0)
            || u64_at(348) != plan.checksum_offset
            || u64_at(372) != plan.total
        {
            return Err(Error::invalid(
                "bricked file: section offsets do not match the dimensions",
            ));
        }
        if len < plan.total {
            return Err(Error::invalid(format!(
                "truncated bricked file: {len} bytes, {} expected: {}",
                plan.total,
                path.display()
            )));
        }
        if len > plan.total {
            // The header records the file's length: more bytes are another file's data
            // appended, or a header that does not belong to these bricks.
            return Err(Error::invalid(format!(
                "bricked file has {} bytes after its end ({len} bytes, its header records {}): {}",
                len - plan.total,
                plan.total,
                path.display()
            )));
        }
        let n_bricks =
            usize::try_from((plan.total - plan.checksum_offset) / 8).map_err(|_| overflow())?;
        let mut sums = vec![0u8; n_bricks * 8];
        file.read_exact_at(&mut sums, plan.checksum_offset)?;
        let checksums = sums
            .chunks_exact(8)
            .map(|c| u64::from_le_bytes(c.try_into().expect("8 bytes")))
            .collect();
        let (lo, hi) = (f32_at(364), f32_at(368));
        let levels = plan.geoms.len();
        let macro_sums = (version >= 4 && plan.k != 0)
            .then(|| (0..levels).map(|l| u64_at(MACRO_SUMS_AT + 8 * l)).collect());
        Ok(FileBricks {
            uid: next_uid(),
            file,
            layout,
            plan,
            name,
            checksums,
            non_finite: u64_at(356),
            range: (lo <= hi).then_some((lo, hi)),
            positive_min: Some(f32_at(380)).filter(|v| *v > 0.0 && v.is_finite()),
            macro_sums,
            path: path.to_path_buf(),
        })
    }
}

/// A bricked file opened for sampling through a [`BrickCache`].
#[derive(Clone, Debug)]
pub struct BrickedFile {
    bricks: Arc<FileBricks>,
    cache: Arc<BrickCache>,
}

impl BrickedFile {
    /// Opens a bricked file with a cache of its own holding at most `cache_bricks` (at least
    /// 1) decoded bricks.
    pub fn open(path: &Path, cache_bricks: usize) -> Result<Self> {
        let bricks = FileBricks::open(path)?;
        let s = bricks.layout.stored_edge();
        let cache = BrickCache::new(cache_bricks.max(1).saturating_mul(s * s * s * 4));
        Ok(BrickedFile {
            bricks: Arc::new(bricks),
            cache,
        })
    }

    /// Opens a bricked file that samples through `cache` (shared with other channels).
    /// Opening reads the header and the checksum table only.
    pub fn open_with_cache(path: &Path, cache: Arc<BrickCache>) -> Result<Self> {
        Ok(BrickedFile {
            bricks: Arc::new(FileBricks::open(path)?),
            cache,
        })
    }

    /// Name of the stored channel.
    #[must_use]
    pub fn channel_name(&self) -> &str {
        &self.bricks.name
    }

    /// Storage type of level 0 (coarser levels are f32).
    #[must_use]
    pub fn level0_type(&self) -> ScalarType {
        self.bricks.plan.types[0]
    }

    /// Brick edge and apron.
    #[must_use]
    pub fn layout(&self) -> BrickLayout {
        self.bricks.layout
    }

    /// Number of levels of detail (level 0 is the finest).
    #[must_use]
    pub fn levels(&self) -> usize {
        self.bricks.plan.geoms.len()
    }

    /// Geometry of `level`.
    #[must_use]
    pub fn level_geometry(&self, level: usize) -> Option<Geometry> {
        self.bricks.plan.geoms.get(level).copied()
    }

    /// Geometries of every level, finest first.
    #[must_use]
    pub fn geometries(&self) -> &[Geometry] {
        &self.bricks.plan.geoms
    }

    /// The cache this file samples through.
    #[must_use]
    pub fn cache(&self) -> &Arc<BrickCache> {
        &self.cache
    }

    /// The brick source (for [`crate::field::CombinedSource`] and custom caches).
    #[must_use]
    pub fn source(&self) -> Arc<dyn BrickSource> {
        self.bricks.clone()
    }

    /// Level `level` as a [`crate::Field`]-ready sampler through this file's cache.
    pub fn field(&self, level: usize) -> Result<BrickedField> {
        BrickedField::new(self.source(), self.cache.clone(), level)
    }

    /// A [`Sampler`] over one level (errors are returned per sample).
    pub fn level(&self, level: usize) -> Result<LevelSampler> {
        Ok(LevelSampler {
            field: self.field(level)?,
        })
    }

    /// Number of decoded bricks held now by the cache.
    #[must_use]
    pub fn resident_bricks(&self) -> usize {
        self.cache.stats().resident_bricks
    }

    /// Drops every cached brick (a cold cache).
    pub fn clear_cache(&self) {
        self.cache.clear();
    }

    /// The finest level whose brick around world position `p` is already in the cache, for
    /// progressive refinement; `None` if no level is resident there.
    #[must_use]
    pub fn finest_resident_level(&self, p: Vec3) -> Option<usize> {
        let layout = self.bricks.layout;
        (0..self.levels()).find(|&l| {
            let g = self.bricks.plan.geoms[l];
            let q = g.world_to_index(p);
            let v = [0, 1, 2].map(|a| {
                if q[a].is_nan() {
                    0
                } else {
                    (q[a].max(0.0) as usize).min(g.dims[a] - 1) / layout.brick
                }
            });
            let nb = layout.bricks(g.dims);
            let idx = (v[0] + nb[0] * (v[1] + nb[1] * v[2])) as u64;
            self.cache.contains(self.bricks.as_ref(), l, idx)
        })
    }

    /// Loads a whole level into memory (checked against `limits`), in its storage type.
    pub fn load_level(&self, level: usize, limits: &Limits) -> Result<AnyGrid> {
        let f = self.field(level)?.load(limits)?;
        let g = *f.geometry();
        let f = f.into_vec();
        Ok(match self.bricks.plan.types[level] {
            ScalarType::U8 => Grid::from_vec(g, f.into_iter().map(|v| v as u8).collect())?.into(),
            ScalarType::U16 => Grid::from_vec(g, f.into_iter().map(|v| v as u16).collect())?.into(),
            ScalarType::F16 => {
                Grid::from_vec(g, f.into_iter().map(half::f16::from_f32).collect())?.into()
            }
            _ => Grid::from_vec(g, f)?.into(),
        })
    }
}

/// One level of a [`BrickedFile`] as a [`Sampler`]; gives the same values as trilinear
/// sampling of the in-core grid, voxel for voxel, and returns read failures per sample.
#[derive(Clone, Debug)]
pub struct LevelSampler {
    field: BrickedField,
}

impl Sampler for LevelSampler {
    fn geometry(&self) -> Geometry {
        *self.field.geometry()
    }

    fn sample_index(&self, p: Vec3) -> Result<f32> {
        self.field.try_sample_index(p)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A reserved output has its planned length and, where `fallocate` works (any Linux
    /// temporary directory: ext4, xfs, btrfs, tmpfs), a block behind every byte already.
    #[test]
    fn a_reserved_output_has_its_length_and_its_blocks() {
        let tmp = tempfile::NamedTempFile::new().unwrap();
        let len = 3 * 1024 * 1024 + 12_345;
        reserve(tmp.as_file(), len).unwrap();
        let meta = tmp.as_file().metadata().unwrap();
        assert_eq!(meta.len(), len);
        #[cfg(target_os = "linux")]
        {
            use std::os::unix::fs::MetadataExt;
            assert!(meta.blocks() * 512 >= len, "{} blocks", meta.blocks());
        }
    }

    /// The SSE2 lane statistics give the portable version's bits (NaNs of either sign,
    /// infinities, signed zeros, subnormals and ordinary values mixed).
    #[test]
    fn lane_statistics_match_the_portable_version() {
        let mut state = 0x853c_49e6_748f_ea9bu64;
        let mut next = || {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            (state >> 32) as u32
        };
        let special = [
            f32::NAN,
            -f32::NAN,
            f32::from_bits(0xffff_ffff),
            f32::INFINITY,
            f32::NEG_INFINITY,
            0.0,
            -0.0,
            f32::from_bits(1),
            f32::from_bits(0x8000_0001),
            f32::MAX,
            f32::MIN,
        ];
        for round in 0..50 {
            let block: Vec<[f32; 8]> = (0..64)
                .map(|_| {
                    std::array::from_fn(|_| {
                        let u = next();
                        match u % 8 {
                            0 => special[(u >> 8) as usize % special.len()],
                            1 => f32::from_bits(next()),
                            // Only zeros in some rounds, to test ties of +0 and -0.
                            _ if round % 5 == 0 => special[5 + (u >> 8) as usize % 2],
                            _ => (u >> 8) as f32 * 1e-3 - 8000.0,
                        }
                    })
                })
                .collect();
            let fresh = || Lanes {
                lo: [f32::INFINITY; 8],
                hi: [f32::NEG_INFINITY; 8],
                pos: [f32::INFINITY; 8],
                bad: [0; 8],
            };
            let (mut fast, mut slow) = (fresh(), fresh());
            fast.add(&block);
            slow.add_scalar(&block);
            let bits = |v: [f32; 8]| v.map(f32::to_bits);
            assert_eq!(bits(fast.lo), bits(slow.lo), "round {round}");
            assert_eq!(bits(fast.hi), bits(slow.hi), "round {round}");
            assert_eq!(bits(fast.pos), bits(slow.pos), "round {round}");
            assert_eq!(fast.bad, slow.bad, "round {round}");
        }
    }
}
