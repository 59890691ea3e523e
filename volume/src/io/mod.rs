//! File formats: raw, NRRD, MetaImage and legacy VTK readers; raw and NRRD writers.
//!
//! # Voxel types on disk and in memory
//!
//! Readers accept u8, i8, u16, i16, u32, i32, f32 and f64 voxels ([`DiskType`]) and map them
//! onto the in-memory types of [`crate::AnyGrid`]:
//!
//! | on disk | in memory | conversion |
//! |---|---|---|
//! | u8 | `u8` | exact |
//! | u16 | `u16` | exact |
//! | i8, i16 | `f32` | exact (CT data keeps its sign, e.g. Hounsfield units) |
//! | u32, i32 | `f32` | rounded to the nearest f32 (exact up to 2^24) |
//! | f32 | `f32` | exact |
//! | f64 | `f32` | rounded to the nearest f32; values beyond f32 range become ±Inf |
//! | 3-component (any type) | `Vec3` (f32) | each component as for f32 above |
//!
//! The on-disk type is kept in [`crate::Channel::stored_as`], so the NRRD writer can
//! write i16 data back as i16 when every value still fits exactly.
//!
//! Every reader checks the header's sizes against [`crate::Limits`] and against the number
//! of bytes actually in the file before it allocates the voxel buffer.

pub mod mhd;
pub mod nrrd;
pub mod raw;
pub mod vtk;

use std::io::Read;
use std::path::Path;

use glam::Vec3;

use crate::grid::{AnyGrid, Geometry, Grid};
use crate::volume::{Channel, Volume};
use crate::{Error, Limits, Result};

/// Voxel types accepted on disk. See the [module docs](self) for the in-memory mapping.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum DiskType {
    /// Unsigned 8-bit.
    U8,
    /// Signed 8-bit.
    I8,
    /// Unsigned 16-bit.
    U16,
    /// Signed 16-bit (typical for CT).
    I16,
    /// Unsigned 32-bit.
    U32,
    /// Signed 32-bit.
    I32,
    /// IEEE single precision.
    F32,
    /// IEEE double precision.
    F64,
}

impl DiskType {
    /// The file type that holds values of the in-memory type `t` as they are: uint8, uint16,
    /// else float32.
    #[must_use]
    pub fn natural(t: crate::ScalarType) -> Self {
        match t {
            crate::ScalarType::U8 => DiskType::U8,
            crate::ScalarType::U16 => DiskType::U16,
            _ => DiskType::F32,
        }
    }

    /// Bytes per component.
    #[must_use]
    pub fn size_bytes(self) -> usize {
        match self {
            DiskType::U8 | DiskType::I8 => 1,
            DiskType::U16 | DiskType::I16 => 2,
            DiskType::U32 | DiskType::I32 | DiskType::F32 => 4,
            DiskType::F64 => 8,
        }
    }

    /// Open SciVis file-name spelling: `uint8`, `int8`, `uint16`, `int16`, `uint32`,
    /// `int32`, `float32`, `float64`.
    #[must_use]
    pub fn scivis_name(self) -> &'static str {
        match self {
            DiskType::U8 => "uint8",
            DiskType::I8 => "int8",
            DiskType::U16 => "uint16",
            DiskType::I16 => "int16",
            DiskType::U32 => "uint32",
            DiskType::I32 => "int32",
            DiskType::F32 => "float32",
            DiskType::F64 => "float64",
        }
    }

    /// Parses the Open SciVis spelling (also accepts `float` and `double`).
    #[must_use]
    pub fn from_scivis_name(s: &str) -> Option<DiskType> {
        Some(match s.to_ascii_lowercase().as_str() {
            "uint8" | "u8" => DiskType::U8,
            "int8" | "i8" => DiskType::I8,
            "uint16" | "u16" => DiskType::U16,
            "int16" | "i16" => DiskType::I16,
            "uint32" | "u32" => DiskType::U32,
            "int32" | "i32" => DiskType::I32,
            "float32" | "float" | "f32" => DiskType::F32,
            "float64" | "double" | "f64" => DiskType::F64,
            _ => return None,
        })
    }

    /// True if `v` converts to this type without loss.
    #[must_use]
    pub fn holds_exactly(self, v: f32) -> bool {
        let int_in = |lo: f64, hi: f64| {
            let d = f64::from(v);
            d.fract() == 0.0 && d >= lo && d <= hi
        };
        match self {
            DiskType::U8 => int_in(0.0, 255.0),
            DiskType::I8 => int_in(-128.0, 127.0),
            DiskType::U16 => int_in(0.0, 65535.0),
            DiskType::I16 => int_in(-32768.0, 32767.0),
            DiskType::U32 => int_in(0.0, 4_294_967_295.0),
            DiskType::I32 => int_in(-2_147_483_648.0, 2_147_483_647.0),
            DiskType::F32 | DiskType::F64 => true,
        }
    }
}

/// Byte order of multi-byte voxels on disk.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Endian {
    /// Least significant byte first (x86, ARM).
    Little,
    /// Most significant byte first (legacy VTK binary, old SGI/Sun files).
    Big,
}

/// How the voxel bytes are stored after the header.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Encoding {
    /// Uncompressed binary.
    Raw,
    /// gzip (RFC 1952), as in NRRD `encoding: gzip`.
    Gzip,
    /// zlib (RFC 1950), as in MetaImage `CompressedData = True`.
    Zlib,
    /// Whitespace-separated decimal text, as in NRRD `encoding: ascii`.
    Ascii,
}

/// Options shared by all readers (one-liners use the defaults).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ReadOptions {
    /// Size caps checked before allocation.
    pub limits: Limits,
    /// Refuse NaN or ±Inf voxels with [`Error::NonFinite`].
    pub reject_non_finite: bool,
    /// Read the file as headerless raw voxels with this layout, whatever its name says.
    pub raw: Option<RawSpec>,
}

/// The layout of a headerless raw file, given by the caller (see [`ReadOptions::raw`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RawSpec {
    /// Voxels along x, y, z.
    pub dims: [usize; 3],
    /// Voxel type on disk.
    pub disk: DiskType,
    /// Byte order.
    pub endian: Endian,
    /// 1 for scalars, 3 for interleaved vectors.
    pub components: usize,
    /// Bytes to skip before the voxels.
    pub offset: u64,
}

/// A decoded voxel block description: what the header says about the bytes.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Layout {
    pub dims: [usize; 3],
    pub disk: DiskType,
    pub endian: Endian,
    /// 1 for scalars, 3 for interleaved vectors.
    pub components: usize,
    /// Axes the file stores from high to low world coordinate (a negative spacing or
    /// direction): the reader reverses them, so the grid runs along +x, +y, +z as
    /// [`Geometry`] requires and every voxel keeps its world position.
    pub flip: [bool; 3],
}

/// Origin, spacing and reversed axes of a grid whose file gives `dims` voxels from `origin`
/// (voxel 0's position) at `signed` spacing per axis. An axis with a negative spacing runs
/// from high to low world coordinate: its voxels are reversed ([`Layout::flip`]) and the
/// origin becomes its lowest voxel's position, so each voxel keeps its place in the world
/// and the picture is not mirrored.
pub(crate) fn orient(dims: [usize; 3], origin: Vec3, signed: Vec3) -> (Vec3, Vec3, [bool; 3]) {
    let mut o = origin;
    let mut flip = [false; 3];
    for a in 0..3 {
        if signed[a] < 0.0 {
            flip[a] = true;
            o[a] = (f64::from(origin[a]) + (dims[a] as f64 - 1.0) * f64::from(signed[a])) as f32;
        }
    }
    (o, signed.abs(), flip)
}

/// Reverses the axes `flip` names in `bytes`: `dims` voxels of `elem` bytes each, x fastest.
pub(crate) fn flip_axes(bytes: &mut [u8], dims: [usize; 3], elem: usize, flip: [bool; 3]) {
    let row = dims[0] * elem;
    let slice = row * dims[1];
    let bytes = &mut bytes[..slice * dims[2]];
    let swap_blocks = |b: &mut [u8], len: usize, count: usize| {
        for i in 0..count / 2 {
            let (lo, hi) = b.split_at_mut((count - 1 - i) * len);
            lo[i * len..(i + 1) * len].swap_with_slice(&mut hi[..len]);
        }
    };
    if flip[2] {
        swap_blocks(bytes, slice, dims[2]);
    }
    if flip[1] {
        for s in bytes.chunks_exact_mut(slice) {
            swap_blocks(s, row, dims[1]);
        }
    }
    if flip[0] {
        for r in bytes.chunks_exact_mut(row) {
            // Reversing the bytes reverses the voxels and each voxel's bytes: put those back.
            r.reverse();
            for v in r.chunks_exact_mut(elem) {
                v.reverse();
            }
        }
    }
}

impl Layout {
    /// Bytes of voxel data the layout needs; checks limits first.
    pub fn byte_len(&self, limits: &Limits) -> Result<usize> {
        let mem = if self.components == 3 {
            12
        } else {
            self.disk.size_bytes().max(4)
        };
        let n = limits.check(self.dims, mem)?;
        let bytes = n
            .checked_mul((self.disk.size_bytes() * self.components) as u64)
            .ok_or_else(|| Error::Limits("voxel byte count overflows".into()))?;
        usize::try_from(bytes).map_err(|_| Error::Limits("voxel byte count overflows".into()))
    }
}

/// Reads exactly `len` voxel bytes from `r` with `encoding`. The raw case needs the caller to
/// have checked `len` against the file size; the compressed cases grow the buffer only as
/// data arrives, so a lying header costs at most what the stream really holds.
pub(crate) fn read_payload(r: impl Read, encoding: Encoding, len: usize) -> Result<Vec<u8>> {
    let mut out = Vec::new();
    let got = match encoding {
        Encoding::Raw => r.take(len as u64).read_to_end(&mut out)?,
        Encoding::Gzip => {
            let mut d = GzMembers::new(std::io::BufReader::new(r));
            let got = d.by_ref().take(len as u64).read_to_end(&mut out)?;
            if got == len {
                check_stream_end(&mut d)?;
            }
            got
        }
        Encoding::Zlib => {
            let mut d = flate2::read::ZlibDecoder::new(r);
            let got = d.by_ref().take(len as u64).read_to_end(&mut out)?;
            if got == len {
                check_stream_end(&mut d)?;
            }
            got
        }
        Encoding::Ascii => {
            return Err(Error::invalid(
                "internal: ASCII data goes through read_ascii",
            ));
        }
    };
    if got < len {
        return Err(Error::invalid(format!(
            "truncated data: the header declares {len} bytes of voxels, the file holds {got}"
        )));
    }
    Ok(out)
}

/// The decompressed bytes of the gzip members of `r`, one after another (as
/// `flate2::read::MultiGzDecoder`), each member's CRC-32 and length checked at its end. The
/// stream ends at the end of the input or where what follows a member is not another member
/// (trailing bytes: padding, a newline), which gzip itself ignores with a warning, rather
/// than failing on them as a gzip header.
pub(crate) struct GzMembers<R: std::io::BufRead> {
    member: Option<flate2::bufread::GzDecoder<R>>,
}

impl<R: std::io::BufRead> GzMembers<R> {
    pub(crate) fn new(r: R) -> Self {
        GzMembers {
            member: Some(flate2::bufread::GzDecoder::new(r)),
        }
    }
}

impl<R: std::io::BufRead> Read for GzMembers<R> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        loop {
            let Some(member) = self.member.as_mut() else {
                return Ok(0);
            };
            let n = member.read(buf)?;
            if n > 0 || buf.is_empty() {
                return Ok(n);
            }
            // This member ended, its trailer checked: another one follows only where gzip's
            // magic byte does.
            let mut rest = self.member.take().expect("a member").into_inner();
            if rest.fill_buf()?.first() == Some(&0x1f) {
                self.member = Some(flate2::bufread::GzDecoder::new(rest));
            }
        }
    }
}

/// Checks that a decompressing reader whose voxels have all been read ends here: its
/// checksum (gzip's CRC-32, zlib's Adler-32), which the decoder verifies at the end of the
/// stream, matches, and it holds no more data than the header's sizes declare. At most one
/// byte more is decompressed, so a stream of any length costs nothing more.
///
/// # Errors
/// [`Error::Invalid`]: a checksum mismatch or other corruption, or data past the voxels.
pub(crate) fn check_stream_end(mut r: impl Read) -> Result<()> {
    let mut one = [0u8; 1];
    loop {
        return match r.read(&mut one) {
            Ok(0) => Ok(()),
            Ok(_) => Err(Error::invalid(
                "the compressed data holds more bytes than the header's sizes declare",
            )),
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            Err(e) => Err(Error::invalid(format!("corrupt compressed data: {e}"))),
        };
    }
}

/// Refuses an input that is not a regular file (a FIFO, device, socket or folder) before it
/// is opened, so reading never blocks on a pipe or reads a device forever. Every reader of
/// this crate opens its inputs through this check; symbolic links are followed.
///
/// # Errors
/// [`Error::Invalid`] naming the kind of file and the path; [`Error::Io`] when the path
/// cannot be inspected (missing, permissions).
pub fn check_regular_file(path: &Path) -> Result<()> {
    let meta = std::fs::metadata(path).map_err(|e| {
        Error::Io(std::io::Error::new(
            e.kind(),
            format!("{e}: {}", path.display()),
        ))
    })?;
    if meta.is_file() {
        return Ok(());
    }
    Err(Error::invalid(format!(
        "not a regular file ({}): {}",
        file_kind(&meta.file_type()),
        path.display()
    )))
}

/// A word for a file type: `FIFO`, `character device`, `socket`, ...
#[must_use]
pub fn file_kind(t: &std::fs::FileType) -> &'static str {
    use std::os::unix::fs::FileTypeExt;
    if t.is_dir() {
        "a folder"
    } else if t.is_fifo() {
        "a FIFO"
    } else if t.is_char_device() {
        "a character device"
    } else if t.is_block_device() {
        "a block device"
    } else if t.is_socket() {
        "a socket"
    } else if t.is_file() {
        "a regular file"
    } else {
        "not a regular file"
    }
}

/// Opens a file and returns it with its length.
pub(crate) fn open(path: &Path) -> Result<(std::fs::File, u64)> {
    check_regular_file(path)?;
    let f = std::fs::File::open(path).map_err(|e| {
        Error::Io(std::io::Error::new(
            e.kind(),
            format!("{e}: {}", path.display()),
        ))
    })?;
    let len = f.metadata()?.len();
    Ok((f, len))
}

/// Converts decoded bytes into a grid following the module's type mapping.
pub(crate) fn decode(bytes: &mut [u8], layout: &Layout, geometry: Geometry) -> Result<AnyGrid> {
    let size = layout.disk.size_bytes();
    let big = layout.endian == Endian::Big;
    let n = geometry.voxel_count() * layout.components;
    if bytes.len() < n * size {
        return Err(Error::invalid("truncated data"));
    }
    if layout.flip.contains(&true) {
        flip_axes(bytes, geometry.dims, size * layout.components, layout.flip);
    }
    let bytes = &*bytes;
    if layout.disk == DiskType::F64 {
        check_f64_range(&bytes[..n * size], big)?;
    }
    let comp = |i: usize| -> f32 { component(&bytes[i * size..i * size + size], layout.disk, big) };
    if layout.components == 3 {
        let data = (0..n / 3)
            .map(|i| Vec3::new(comp(3 * i), comp(3 * i + 1), comp(3 * i + 2)))
            .collect();
        return Ok(Grid::from_vec(geometry, data)?.into());
    }
    if layout.components != 1 {
        return Err(Error::unsupported(format!(
            "{} components per voxel (only 1 or 3 are read)",
            layout.components
        )));
    }
    Ok(match layout.disk {
        DiskType::U8 => Grid::from_vec(geometry, bytes[..n].to_vec())?.into(),
        DiskType::U16 => {
            let data = bytes[..2 * n]
                .chunks_exact(2)
                .map(|c| {
                    if big {
                        u16::from_be_bytes([c[0], c[1]])
                    } else {
                        u16::from_le_bytes([c[0], c[1]])
                    }
                })
                .collect();
            Grid::from_vec(geometry, data)?.into()
        }
        _ => Grid::from_vec(geometry, (0..n).map(comp).collect())?.into(),
    })
}

/// Refuses float64 voxels beyond the range of the f32 values blueshift holds voxels in, which
/// would otherwise become infinities (and be reported as non-finite data the file does not
/// hold). Values too small for f32 become 0 or subnormal, as rounding does.
///
/// # Errors
/// [`Error::Invalid`] naming the first such value.
pub(crate) fn check_f64_range(bytes: &[u8], big: bool) -> Result<()> {
    for c in bytes.chunks_exact(8) {
        let a: [u8; 8] = c.try_into().expect("8 bytes");
        let v = if big {
            f64::from_be_bytes(a)
        } else {
            f64::from_le_bytes(a)
        };
        if v.is_finite() && v.abs() > f64::from(f32::MAX) {
            return Err(Error::invalid(format!(
                "float64 value {v:e} is beyond the range of the 32-bit floats voxels are held \
                 in (about ±3.4e38): rescale the data"
            )));
        }
    }
    Ok(())
}

/// One on-disk component as f32 (the module's conversion table).
#[inline]
pub(crate) fn component(b: &[u8], disk: DiskType, big: bool) -> f32 {
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

/// Wraps a decoded grid as a one-channel volume, applying the options.
pub(crate) fn finish(
    name: &str,
    grid: AnyGrid,
    disk: DiskType,
    opts: &ReadOptions,
) -> Result<Volume> {
    if opts.reject_non_finite {
        grid.reject_non_finite()?;
    }
    let mut v = Volume::new(*grid.geometry())?;
    v.push_channel(Channel {
        name: name.to_string(),
        grid,
        stored_as: Some(disk),
    })?;
    Ok(v)
}

/// Parses a finite float from header text.
pub(crate) fn parse_f32(s: &str, what: &str) -> Result<f32> {
    let v: f32 = s
        .trim()
        .parse()
        .map_err(|_| Error::invalid(format!("{what}: '{s}' is not a number")))?;
    if !v.is_finite() {
        return Err(Error::invalid(format!("{what}: '{s}' is not finite")));
    }
    Ok(v)
}

/// Parses a positive dimension from header text.
pub(crate) fn parse_dim(s: &str, what: &str) -> Result<usize> {
    let v: usize = s
        .trim()
        .parse()
        .map_err(|_| Error::invalid(format!("{what}: '{s}' is not a positive integer")))?;
    if v == 0 {
        return Err(Error::invalid(format!("{what}: a size of 0")));
    }
    Ok(v)
}

/// The file formats [`read`] recognises.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    /// Headerless voxels, size and type from the Open SciVis file name.
    Raw,
    /// NRRD, attached (`.nrrd`) or detached (`.nhdr`).
    Nrrd,
    /// MetaImage, `.mha` (attached) or `.mhd` (detached).
    MetaImage,
    /// Legacy VTK `STRUCTURED_POINTS`.
    Vtk,
    /// The bricked out-of-core layout of [`crate::ooc`] (`.bsv`); `read` loads level 0.
    Bricked,
}

/// Guesses the format from the extension, then from the first bytes of the file.
pub fn detect_format(path: &Path) -> Result<Format> {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    let by_ext = if name.ends_with(".nrrd") || name.ends_with(".nhdr") {
        Some(Format::Nrrd)
    } else if name.ends_with(".mhd") || name.ends_with(".mha") {
        Some(Format::MetaImage)
    } else if name.ends_with(".vtk") {
        Some(Format::Vtk)
    } else if name.ends_with(".bsv") {
        Some(Format::Bricked)
    } else {
        None
    };
    if let Some(f) = by_ext {
        return Ok(f);
    }
    let (mut f, _) = open(path)?;
    let mut head = [0u8; 64];
    let mut n = 0;
    while n < head.len() {
        let k = f.read(&mut head[n..])?;
        if k == 0 {
            break;
        }
        n += k;
    }
    let head = &head[..n];
    if head.starts_with(b"NRRD000") {
        Ok(Format::Nrrd)
    } else if head.starts_with(b"# vtk DataFile") {
        Ok(Format::Vtk)
    } else if head.starts_with(crate::ooc::MAGIC) {
        Ok(Format::Bricked)
    } else if head.starts_with(b"ObjectType") || head.starts_with(b"NDims") {
        Ok(Format::MetaImage)
    } else if raw::parse_scivis_name(path).is_some() {
        Ok(Format::Raw)
    } else if path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("raw"))
    {
        Err(Error::invalid(
            "a raw file's name gives its volume: name_XxYxZ_type.raw with sizes of at least 1 \
             and a type such as uint8, int16, uint16, float32 or float64 (or give --raw-dims \
             and --raw-type)",
        ))
    } else {
        Err(Error::unsupported(
            "cannot tell the file format (expected .raw with an Open SciVis name such as \
             skull_256x256x256_uint8.raw, or .nrrd, .nhdr, .mhd, .mha, .vtk, .bsv)",
        ))
    }
}

/// Reads any supported file into a [`Volume`] with default [`ReadOptions`].
///
/// ```no_run
/// let vol = blueshift_volume::read("skull_256x256x256_uint8.raw")?;
/// println!("{:?}", vol.geometry().dims);
/// # Ok::<(), blueshift_volume::Error>(())
/// ```
pub fn read(path: impl AsRef<Path>) -> Result<Volume> {
    read_with(path, &ReadOptions::default())
}

/// Reads any supported file into a [`Volume`].
pub fn read_with(path: impl AsRef<Path>, opts: &ReadOptions) -> Result<Volume> {
    let path = path.as_ref();
    if let Some(r) = &opts.raw {
        return raw::read_raw(path, r.dims, r.disk, r.endian, r.components, r.offset, opts);
    }
    match detect_format(path)? {
        Format::Raw => raw::read_scivis(path, opts),
        Format::Nrrd => nrrd::read(path, opts),
        Format::MetaImage => mhd::read(path, opts),
        Format::Vtk => vtk::read(path, opts),
        Format::Bricked => {
            let f = crate::ooc::BrickedFile::open(path, 64)?;
            let grid = f.load_level(0, &opts.limits)?;
            let v = Volume::single(f.channel_name().to_string(), grid)?;
            if opts.reject_non_finite {
                v.reject_non_finite()?;
            }
            Ok(v)
        }
    }
}

/// Chooses the on-disk type a writer uses for `channel`: its original type when every value
/// converts exactly, else the natural type of the in-memory grid.
#[must_use]
pub fn output_type(channel: &Channel) -> DiskType {
    let natural = DiskType::natural(channel.grid.scalar_type());
    match channel.stored_as {
        Some(d) if d != natural && !channel.grid.is_vector() => {
            let n = channel.grid.geometry().voxel_count();
            if (0..n).all(|i| d.holds_exactly(channel.grid.scalar_at(i))) {
                d
            } else {
                natural
            }
        }
        Some(DiskType::F64) => DiskType::F64,
        _ => natural,
    }
}

/// Encodes a channel's voxels little-endian as `disk` (vectors: 3 interleaved components).
/// Conversion to an integer type rounds to nearest and saturates at the type's range.
pub(crate) fn encode(grid: &AnyGrid, disk: DiskType) -> Vec<u8> {
    let n = grid.geometry().voxel_count();
    let mut out = Vec::with_capacity(n * disk.size_bytes() * if grid.is_vector() { 3 } else { 1 });
    // Integer targets round to nearest and saturate at the type's range (NaN becomes 0).
    let mut put = |v: f32| match disk {
        DiskType::U8 => out.push(v.round() as u8),
        DiskType::I8 => out.push(v.round() as i8 as u8),
        DiskType::U16 => out.extend_from_slice(&(v.round() as u16).to_le_bytes()),
        DiskType::I16 => out.extend_from_slice(&(v.round() as i16).to_le_bytes()),
        DiskType::U32 => out.extend_from_slice(&(f64::from(v).round() as u32).to_le_bytes()),
        DiskType::I32 => out.extend_from_slice(&(f64::from(v).round() as i32).to_le_bytes()),
        DiskType::F32 => out.extend_from_slice(&v.to_le_bytes()),
        DiskType::F64 => out.extend_from_slice(&f64::from(v).to_le_bytes()),
    };
    match grid {
        AnyGrid::U8(g) if disk == DiskType::U8 => return g.data().to_vec(),
        AnyGrid::Vec3(g) => {
            for v in g.data() {
                put(v.x);
                put(v.y);
                put(v.z);
            }
        }
        _ => {
            for i in 0..n {
                put(grid.scalar_at(i));
            }
        }
    }
    out
}

/// Reads `count` whitespace-separated numbers and returns them as little-endian `disk`
/// values (integers round to nearest and saturate). Memory grows only with the numbers read.
pub(crate) fn read_ascii(r: impl Read, disk: DiskType, count: usize) -> Result<Vec<u8>> {
    use std::io::BufRead;
    let mut r = std::io::BufReader::new(r);
    let mut out = Vec::new();
    let mut tok = Vec::with_capacity(32);
    let mut n = 0;
    while n < count {
        tok.clear();
        loop {
            let buf = r.fill_buf()?;
            if buf.is_empty() {
                break;
            }
            let b = buf[0];
            r.consume(1);
            if b.is_ascii_whitespace() || b == b',' {
                if tok.is_empty() {
                    continue;
                }
                break;
            }
            tok.push(b);
            if tok.len() > 64 {
                return Err(Error::invalid(
                    "ASCII data: a number longer than 64 characters",
                ));
            }
        }
        if tok.is_empty() {
            return Err(Error::invalid(format!(
                "truncated ASCII data: {n} of {count} values"
            )));
        }
        let t = std::str::from_utf8(&tok).map_err(|_| Error::invalid("ASCII data is not text"))?;
        let v: f64 = t
            .parse()
            .map_err(|_| Error::invalid(format!("ASCII data: '{t}' is not a number")))?;
        check_ascii_value(v, t, disk).map_err(Error::Invalid)?;
        put_le(&mut out, disk, v);
        n += 1;
    }
    Ok(out)
}

/// Refuses an ASCII value its declared type cannot hold, which would otherwise be rounded or
/// clamped without a word (`300` in a `uchar` file): an integer type takes whole numbers in
/// its range, `float` finite values in f32's range (NaN and infinities as written).
pub(crate) fn check_ascii_value(
    v: f64,
    text: &str,
    disk: DiskType,
) -> std::result::Result<(), String> {
    let range = match disk {
        DiskType::U8 => Some((0.0, f64::from(u8::MAX))),
        DiskType::I8 => Some((f64::from(i8::MIN), f64::from(i8::MAX))),
        DiskType::U16 => Some((0.0, f64::from(u16::MAX))),
        DiskType::I16 => Some((f64::from(i16::MIN), f64::from(i16::MAX))),
        DiskType::U32 => Some((0.0, f64::from(u32::MAX))),
        DiskType::I32 => Some((f64::from(i32::MIN), f64::from(i32::MAX))),
        DiskType::F32 | DiskType::F64 => None,
    };
    let fits = match range {
        Some((lo, hi)) => v.fract() == 0.0 && (lo..=hi).contains(&v),
        None if disk == DiskType::F32 => !v.is_finite() || v.abs() <= f64::from(f32::MAX),
        None => true,
    };
    if fits {
        Ok(())
    } else {
        Err(format!(
            "ASCII data: '{text}' is not a {} value",
            disk.scivis_name()
        ))
    }
}

/// Appends `v` as a little-endian `disk` value (integers round to nearest and saturate).
pub(crate) fn put_le(b: &mut Vec<u8>, disk: DiskType, v: f64) {
    match disk {
        DiskType::U8 => b.push(v.round() as u8),
        DiskType::I8 => b.push(v.round() as i8 as u8),
        DiskType::U16 => b.extend_from_slice(&(v.round() as u16).to_le_bytes()),
        DiskType::I16 => b.extend_from_slice(&(v.round() as i16).to_le_bytes()),
        DiskType::U32 => b.extend_from_slice(&(v.round() as u32).to_le_bytes()),
        DiskType::I32 => b.extend_from_slice(&(v.round() as i32).to_le_bytes()),
        DiskType::F32 => b.extend_from_slice(&(v as f32).to_le_bytes()),
        DiskType::F64 => b.extend_from_slice(&v.to_le_bytes()),
    }
}

/// A staged reader for the full case (CONVENTIONS C8, like exrs's `read()...`):
///
/// ```no_run
/// use blueshift_volume::{Limits, io::reader};
/// let vol = reader("carotid.vtk")
///     .channels(["vectors"])
///     .limits(Limits { max_voxels: 1 << 24, ..Limits::default() })
///     .reject_non_finite()
///     .load()?;
/// # Ok::<(), blueshift_volume::Error>(())
/// ```
#[must_use]
pub fn reader(path: impl AsRef<Path>) -> Reader {
    Reader {
        path: path.as_ref().to_path_buf(),
        opts: ReadOptions::default(),
        channels: None,
    }
}

/// Built by [`reader`]; finish with [`Reader::load`].
#[derive(Clone, Debug)]
pub struct Reader {
    path: std::path::PathBuf,
    opts: ReadOptions,
    channels: Option<Vec<String>>,
}

impl Reader {
    /// Keep only these channels (in this order); an unknown name is [`Error::Parameter`].
    #[must_use]
    pub fn channels<S: Into<String>>(mut self, names: impl IntoIterator<Item = S>) -> Self {
        self.channels = Some(names.into_iter().map(Into::into).collect());
        self
    }
    /// Size caps checked before allocation.
    #[must_use]
    pub fn limits(mut self, limits: Limits) -> Self {
        self.opts.limits = limits;
        self
    }
    /// Refuse NaN or ±Inf voxels.
    #[must_use]
    pub fn reject_non_finite(mut self) -> Self {
        self.opts.reject_non_finite = true;
        self
    }
    /// Read the file as headerless raw voxels with this layout.
    #[must_use]
    pub fn raw(mut self, spec: RawSpec) -> Self {
        self.opts.raw = Some(spec);
        self
    }
    /// Reads the file.
    pub fn load(self) -> Result<Volume> {
        let vol = read_with(&self.path, &self.opts)?;
        let Some(names) = self.channels else {
            return Ok(vol);
        };
        let mut out = Volume::new(*vol.geometry())?;
        let mut all = vol.into_channels();
        for n in names {
            let i = all.iter().position(|c| c.name == n).ok_or_else(|| {
                let have: Vec<&str> = all.iter().map(|c| c.name.as_str()).collect();
                Error::parameter(format!("no channel '{n}' (channels: {})", have.join(", ")))
            })?;
            out.push_channel(all.swap_remove(i))?;
        }
        Ok(out)
    }
}
