//! NRRD (<https://teem.sourceforge.net/nrrd/format.html>): attached (`.nrrd`) and detached
//! (`.nhdr` + data file) data, `raw`, `gzip` and `ascii` encodings, both endians, `spacings` or
//! axis-aligned `space directions`, `space origin`, `byte skip`, `line skip`.
//!
//! A 4D file whose first axis has size 3 (`kinds: 3-vector ...`) loads as a [`glam::Vec3`]
//! grid. `space directions` must be axis-aligned: the spacing is the length of each
//! direction. A negative direction or spacing (an axis stored from high to low coordinate,
//! as in LPS medical data) reverses that axis's voxels on reading, with the origin moved to
//! the lowest voxel, so every voxel keeps its world position (the picture is not mirrored).
//! The `space` name is not interpreted: coordinates are taken as given. Rotated directions
//! are refused with [`Error::Unsupported`].

use std::io::{BufRead, BufReader, Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

use glam::Vec3;

use super::{
    DiskType, Encoding, Endian, Layout, ReadOptions, decode, finish, open, parse_dim, parse_f32,
    read_payload,
};
use crate::grid::Geometry;
use crate::volume::{Channel, Volume};
use crate::{Error, Result};

/// Longest header line accepted (bytes).
const MAX_LINE: u64 = 1 << 16;
/// Most header lines accepted.
const MAX_LINES: usize = 4096;

/// Reads one line of at most [`MAX_LINE`] bytes; `None` at end of file. Counts the bytes
/// consumed into `pos`.
pub(crate) fn read_line(r: &mut impl BufRead, pos: &mut u64) -> Result<Option<String>> {
    let mut buf = Vec::new();
    let n = r.by_ref().take(MAX_LINE).read_until(b'\n', &mut buf)?;
    if n == 0 {
        return Ok(None);
    }
    *pos += n as u64;
    if buf.last() != Some(&b'\n') && n as u64 == MAX_LINE {
        return Err(Error::invalid("header line longer than 64 KiB"));
    }
    while matches!(buf.last(), Some(b'\n' | b'\r')) {
        buf.pop();
    }
    String::from_utf8(buf)
        .map(Some)
        .map_err(|_| Error::invalid("header line is not UTF-8 text"))
}

fn nrrd_type(s: &str) -> Result<DiskType> {
    Ok(match s.trim() {
        "signed char" | "int8" | "int8_t" => DiskType::I8,
        "uchar" | "unsigned char" | "uint8" | "uint8_t" => DiskType::U8,
        "short" | "short int" | "signed short" | "signed short int" | "int16" | "int16_t" => {
            DiskType::I16
        }
        "ushort" | "unsigned short" | "unsigned short int" | "uint16" | "uint16_t" => DiskType::U16,
        "int" | "signed int" | "int32" | "int32_t" => DiskType::I32,
        "uint" | "unsigned int" | "uint32" | "uint32_t" => DiskType::U32,
        "float" => DiskType::F32,
        "double" => DiskType::F64,
        other => return Err(Error::unsupported(format!("NRRD type '{other}'"))),
    })
}

fn nrrd_type_name(d: DiskType) -> &'static str {
    match d {
        DiskType::U8 => "uint8",
        DiskType::I8 => "int8",
        DiskType::U16 => "uint16",
        DiskType::I16 => "int16",
        DiskType::U32 => "uint32",
        DiskType::I32 => "int32",
        DiskType::F32 => "float",
        DiskType::F64 => "double",
    }
}

/// Parses a vector such as `(1.5,0,0)`.
fn parse_vector(s: &str, what: &str) -> Result<Vec<f32>> {
    let s = s.trim();
    let inner = s
        .strip_prefix('(')
        .and_then(|t| t.strip_suffix(')'))
        .ok_or_else(|| Error::invalid(format!("NRRD {what}: '{s}' is not a (x,y,z) vector")))?;
    inner
        .split(',')
        .map(|c| parse_f32(c, &format!("NRRD {what}")))
        .collect()
}

/// Splits `space directions` into per-axis entries: `(..)` groups or `none`.
fn split_directions(s: &str) -> Result<Vec<Option<Vec<f32>>>> {
    let mut out = Vec::new();
    let mut rest = s.trim();
    while !rest.is_empty() {
        if let Some(r) = rest.strip_prefix("none") {
            out.push(None);
            rest = r.trim_start();
        } else if rest.starts_with('(') {
            let end = rest
                .find(')')
                .ok_or_else(|| Error::invalid("NRRD space directions: missing ')'"))?;
            out.push(Some(parse_vector(&rest[..=end], "space directions")?));
            rest = rest[end + 1..].trim_start();
        } else {
            return Err(Error::invalid(format!(
                "NRRD space directions: unexpected '{rest}'"
            )));
        }
        if out.len() > 16 {
            return Err(Error::invalid("NRRD space directions: too many entries"));
        }
    }
    Ok(out)
}

fn parse_header(path: &Path, limits: &crate::Limits) -> Result<Header> {
    let (f, _) = open(path)?;
    let mut r = BufReader::new(f);
    let mut pos = 0u64;
    let magic = read_line(&mut r, &mut pos)?.ok_or_else(|| Error::invalid("NRRD: empty file"))?;
    if !magic.starts_with("NRRD000") {
        return Err(Error::invalid(format!(
            "NRRD: bad magic '{}'",
            magic.chars().take(16).collect::<String>()
        )));
    }
    let mut disk = None;
    let mut dimension = None;
    let mut sizes: Option<Vec<usize>> = None;
    let mut spacings: Option<Vec<f32>> = None;
    let mut directions = None;
    let mut origin = Vec3::ZERO;
    let mut endian = None;
    let mut encoding = None;
    let mut data_file: Option<String> = None;
    let mut seen = std::collections::HashSet::new();
    let mut kinds: Option<usize> = None;
    let mut data_check = None;
    let mut byte_skip: i64 = 0;
    let mut line_skip: usize = 0;
    let mut ended_by_blank = false;
    for _ in 0..MAX_LINES {
        let Some(line) = read_line(&mut r, &mut pos)? else {
            break;
        };
        if line.is_empty() {
            ended_by_blank = true;
            break;
        }
        if let Some(v) = line.strip_prefix(DATA_CHECK_KEY) {
            data_check = parse_data_check(v);
            continue;
        }
        if line.starts_with('#') || line.contains(":=") {
            continue;
        }
        let (key, value) = line
            .split_once(": ")
            .or_else(|| line.split_once(':'))
            .ok_or_else(|| Error::invalid(format!("NRRD: header line '{line}' has no ': '")))?;
        let value = value.trim();
        // A field given twice is an error in the format (teem refuses it): which one was
        // meant is unknown.
        if !seen.insert(key.trim().replace(' ', "")) {
            return Err(Error::invalid(format!(
                "NRRD: field '{}' given twice",
                key.trim()
            )));
        }
        match key.trim() {
            "type" => disk = Some(nrrd_type(value)?),
            "kinds" => {
                // The component axis of a 4D file is read as a vector: a colour or tensor is
                // not one (on any axis).
                for k in value.split_whitespace() {
                    let k = k.to_ascii_lowercase();
                    if k.contains("color") || k.contains("tensor") || k.contains("matrix") {
                        return Err(Error::unsupported(format!(
                            "NRRD kinds '{k}': colour and tensor volumes are not read \
                             (scalars and 3-vectors are)"
                        )));
                    }
                }
                kinds = Some(value.split_whitespace().count());
            }
            "dimension" => dimension = Some(parse_dim(value, "NRRD dimension")?),
            "sizes" => {
                sizes = Some(
                    value
                        .split_whitespace()
                        .map(|s| parse_dim(s, "NRRD sizes"))
                        .collect::<Result<_>>()?,
                )
            }
            "spacings" => {
                spacings = Some(
                    value
                        .split_whitespace()
                        .map(|s| {
                            if s.eq_ignore_ascii_case("nan") {
                                Ok(f32::NAN)
                            } else {
                                parse_f32(s, "NRRD spacings")
                            }
                        })
                        .collect::<Result<_>>()?,
                );
            }
            "space directions" => directions = Some(split_directions(value)?),
            "space origin" => {
                let v = parse_vector(value, "space origin")?;
                if v.len() != 3 {
                    return Err(Error::invalid("NRRD space origin: needs 3 components"));
                }
                origin = Vec3::new(v[0], v[1], v[2]);
            }
            "endian" => {
                endian = Some(match value {
                    "little" => Endian::Little,
                    "big" => Endian::Big,
                    other => return Err(Error::invalid(format!("NRRD endian '{other}'"))),
                });
            }
            "encoding" => {
                encoding = Some(match value {
                    "raw" => Encoding::Raw,
                    "gzip" | "gz" => Encoding::Gzip,
                    "ascii" | "text" | "txt" => Encoding::Ascii,
                    other => {
                        return Err(Error::unsupported(format!(
                            "NRRD encoding '{other}' (raw, gzip and ascii are read)"
                        )));
                    }
                });
            }
            "data file" | "datafile" => data_file = Some(value.to_string()),
            "byte skip" | "byteskip" => {
                byte_skip = value
                    .parse()
                    .map_err(|_| Error::invalid(format!("NRRD byte skip '{value}'")))?;
                if byte_skip < -1 {
                    return Err(Error::invalid(format!("NRRD byte skip {byte_skip}")));
                }
            }
            "line skip" | "lineskip" => {
                line_skip = value
                    .parse()
                    .map_err(|_| Error::invalid(format!("NRRD line skip '{value}'")))?;
                if line_skip > MAX_LINES {
                    return Err(Error::invalid(format!("NRRD line skip {line_skip}")));
                }
            }
            _ => {}
        }
    }
    let disk = disk.ok_or_else(|| Error::invalid("NRRD: missing 'type'"))?;
    let sizes = sizes.ok_or_else(|| Error::invalid("NRRD: missing 'sizes'"))?;
    let dimension = dimension.ok_or_else(|| Error::invalid("NRRD: missing 'dimension'"))?;
    if sizes.len() != dimension {
        return Err(Error::invalid(format!(
            "NRRD: sizes has {} entries, dimension is {dimension}",
            sizes.len()
        )));
    }
    let encoding = encoding.ok_or_else(|| Error::invalid("NRRD: missing 'encoding'"))?;
    if let Some(k) = kinds.filter(|&k| k != dimension) {
        return Err(Error::invalid(format!(
            "NRRD: kinds has {k} entries, dimension is {dimension}"
        )));
    }
    // Both give the spacing, possibly differently: the format forbids the pair (teem
    // refuses it).
    if spacings.is_some() && directions.is_some() {
        return Err(Error::invalid(
            "NRRD: both 'spacings' and 'space directions' (give one)",
        ));
    }
    if endian.is_none() && disk.size_bytes() > 1 && encoding != Encoding::Ascii {
        return Err(Error::invalid(
            "NRRD: missing 'endian' for a multi-byte type",
        ));
    }
    let endian = endian.unwrap_or(Endian::Little);
    // Axes: optional leading component axis (size 1 or 3), then up to 3 spatial axes.
    let (components, spatial_start) = match dimension {
        2 | 3 => (1, 0),
        4 if sizes[0] == 3 || sizes[0] == 1 => (sizes[0], 1),
        _ => {
            return Err(Error::unsupported(format!(
                "NRRD with dimension {dimension} and sizes {sizes:?} (3D scalars or 3-vectors are read)"
            )));
        }
    };
    let spatial = &sizes[spatial_start..];
    let dims = [spatial[0], spatial[1], spatial.get(2).copied().unwrap_or(1)];
    let mut spacing = Vec3::ONE;
    if let Some(sp) = &spacings {
        if sp.len() != dimension {
            return Err(Error::invalid(format!(
                "NRRD: spacings has {} entries, dimension is {dimension}",
                sp.len()
            )));
        }
        for (a, s) in sp[spatial_start..].iter().enumerate() {
            if !s.is_finite() || *s == 0.0 {
                return Err(Error::invalid(format!(
                    "NRRD: spacing {s} on spatial axis {a}"
                )));
            }
            spacing[a] = *s;
        }
    }
    if let Some(dirs) = &directions {
        if dirs.len() != dimension {
            return Err(Error::invalid(format!(
                "NRRD: space directions has {} entries, dimension is {dimension}",
                dirs.len()
            )));
        }
        for (a, d) in dirs[spatial_start..].iter().enumerate() {
            let d = d
                .as_ref()
                .ok_or_else(|| Error::invalid("NRRD: 'none' direction on a spatial axis"))?;
            if d.len() != 3 {
                return Err(Error::unsupported(
                    "NRRD: space directions with other than 3 components",
                ));
            }
            // In f64: the squares of a direction in centimetres (1e21) overflow f32.
            let len = d
                .iter()
                .map(|&v| f64::from(v) * f64::from(v))
                .sum::<f64>()
                .sqrt() as f32;
            let off = (0..3)
                .filter(|&i| i != a)
                .map(|i| d[i].abs())
                .fold(0.0, f32::max);
            if off > 1e-6 * len {
                return Err(Error::unsupported(format!(
                    "NRRD: rotated space direction {d:?} (only axis-aligned)"
                )));
            }
            spacing[a] = if d[a] < 0.0 { -len } else { len };
        }
    }
    let (origin, spacing, flip) = super::orient(dims, origin, spacing);
    let geometry = Geometry {
        dims,
        origin,
        spacing,
    };
    geometry.validate().map_err(|e| e.context("NRRD"))?;
    let layout = Layout {
        dims,
        disk,
        endian,
        components,
        flip,
    };
    layout.byte_len(limits)?;
    let data_file = match &data_file {
        Some(name) => {
            if name.starts_with("LIST") || name.contains('%') {
                return Err(Error::unsupported(
                    "NRRD: multi-file data ('LIST' or a format pattern)",
                ));
            }
            Some(path.parent().unwrap_or(Path::new(".")).join(name))
        }
        None => {
            if !ended_by_blank {
                return Err(Error::invalid(
                    "NRRD: header does not end with a blank line and names no data file",
                ));
            }
            None
        }
    };
    Ok(Header {
        layout,
        geometry,
        encoding,
        data_file,
        data_check,
        byte_skip,
        line_skip,
        header_end: pos,
    })
}

/// Where a raw-encoded NRRD keeps its voxels: file, byte offset, layout and geometry.
/// `None` for gzip data or headers with `line skip`/`byte skip -1` (read those in core).
pub(crate) fn raw_payload(
    path: &Path,
    limits: &crate::Limits,
) -> Result<Option<(PathBuf, u64, Layout, Geometry)>> {
    let h = parse_header(path, limits)?;
    if h.encoding != Encoding::Raw || h.line_skip != 0 || h.byte_skip < 0 {
        return Ok(None);
    }
    let (p, start) = match &h.data_file {
        Some(d) => (d.clone(), 0),
        None => (path.to_path_buf(), h.header_end),
    };
    Ok(Some((p, start + h.byte_skip as u64, h.layout, h.geometry)))
}

/// Where a gzip-encoded NRRD's compressed voxels start (the file and the byte offset) with
/// their layout and geometry; `None` for other encodings and for line or byte skips (whose
/// bytes are counted before decompression: the in-core reader handles them).
pub(crate) fn gzip_payload(
    path: &Path,
    limits: &crate::Limits,
) -> Result<Option<(PathBuf, u64, Layout, Geometry)>> {
    let h = parse_header(path, limits)?;
    if h.encoding != Encoding::Gzip || h.line_skip != 0 || h.byte_skip != 0 {
        return Ok(None);
    }
    let (p, start) = match &h.data_file {
        Some(d) => (d.clone(), 0),
        None => (path.to_path_buf(), h.header_end),
    };
    Ok(Some((p, start, h.layout, h.geometry)))
}

struct Header {
    layout: Layout,
    geometry: Geometry,
    encoding: Encoding,
    data_file: Option<PathBuf>,
    /// The data file's size and FNV-1a 64 checksum, from a `blueshift data:=` line.
    data_check: Option<(u64, u64)>,
    byte_skip: i64,
    line_skip: usize,
    header_end: u64,
}

/// Reads an NRRD file (attached or detached).
pub fn read(path: &Path, opts: &ReadOptions) -> Result<Volume> {
    let h = parse_header(path, &opts.limits)?;
    let (layout, geometry, encoding, byte_skip, line_skip) =
        (h.layout, h.geometry, h.encoding, h.byte_skip, h.line_skip);
    let (components, disk) = (layout.components, layout.disk);
    let len = layout.byte_len(&opts.limits)?;
    let (mut src, src_len, start): (Box<dyn Read>, u64, u64) = match &h.data_file {
        Some(dpath) => {
            let (mut df, dlen) = open(dpath)?;
            if let Some(check) = h.data_check {
                verify_data_file(&mut df, dlen, check, dpath)?;
            }
            (Box::new(BufReader::new(df)), dlen, 0)
        }
        None => {
            let (mut f, file_len) = open(path)?;
            f.seek(SeekFrom::Start(h.header_end))?;
            (Box::new(BufReader::new(f)), file_len, h.header_end)
        }
    };
    let mut consumed = start;
    for _ in 0..line_skip {
        // Line skip counts lines of the data; `src` is buffered, so byte reads are cheap.
        let mut b = [0u8; 1];
        loop {
            if src.read(&mut b)? == 0 {
                return Err(Error::invalid(
                    "NRRD: line skip runs past the end of the data",
                ));
            }
            consumed += 1;
            if b[0] == b'\n' {
                break;
            }
        }
    }
    let remaining = src_len.saturating_sub(consumed);
    if byte_skip == -1 {
        if encoding != Encoding::Raw {
            return Err(Error::invalid(
                "NRRD: byte skip -1 is only valid with raw encoding",
            ));
        }
        if (len as u64) > remaining {
            return Err(truncated(len, remaining, path));
        }
        // Data is at the end of the data file.
        let skip = remaining - len as u64;
        std::io::copy(&mut src.by_ref().take(skip), &mut std::io::sink())?;
    } else if byte_skip > 0 {
        let got = std::io::copy(
            &mut src.by_ref().take(byte_skip as u64),
            &mut std::io::sink(),
        )?;
        if got < byte_skip as u64 {
            return Err(Error::invalid(
                "NRRD: byte skip runs past the end of the data",
            ));
        }
        if encoding == Encoding::Raw && (len as u64) > remaining - got {
            return Err(truncated(len, remaining - got, path));
        }
    } else if encoding == Encoding::Raw && (len as u64) > remaining {
        return Err(truncated(len, remaining, path));
    }
    let (mut bytes, layout) = if encoding == Encoding::Ascii {
        let b = super::read_ascii(src, layout.disk, geometry.voxel_count() * components)?;
        (
            b,
            Layout {
                endian: Endian::Little,
                ..layout
            },
        )
    } else {
        (read_payload(src, encoding, len)?, layout)
    };
    let grid = decode(&mut bytes, &layout, geometry)?;
    let name = if components == 3 {
        "vectors"
    } else {
        "scalars"
    };
    finish(name, grid, disk, opts)
}

/// The key of the header line recording a detached data file's size and checksum,
/// `blueshift data:=BYTES FNV1A64HEX`: a header and data file written together match, so a
/// header left beside another run's data file (a writer killed between its renames) is
/// refused instead of read as the wrong voxels.
const DATA_CHECK_KEY: &str = "blueshift data:=";

fn parse_data_check(v: &str) -> Option<(u64, u64)> {
    let (len, sum) = v.trim().split_once(' ')?;
    Some((len.parse().ok()?, u64::from_str_radix(sum.trim(), 16).ok()?))
}

/// FNV-1a, 64 bits, continued from `h` (start with [`FNV_OFFSET`]).
fn fnv1a64(mut h: u64, bytes: &[u8]) -> u64 {
    for &b in bytes {
        h ^= u64::from(b);
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    h
}

const FNV_OFFSET: u64 = 0xcbf2_9ce4_8422_2325;

/// Checks a detached data file against its header's `blueshift data:=` line, then rewinds.
fn verify_data_file(
    f: &mut std::fs::File,
    len: u64,
    (want_len, want): (u64, u64),
    path: &Path,
) -> Result<()> {
    let mismatch = || {
        Error::invalid(format!(
            "NRRD: the data file does not match its header (written by another run; rewrite both): {}",
            path.display()
        ))
    };
    if len != want_len {
        return Err(mismatch());
    }
    let mut h = FNV_OFFSET;
    let mut buf = vec![0u8; 1 << 16];
    loop {
        let n = f.read(&mut buf)?;
        if n == 0 {
            break;
        }
        h = fnv1a64(h, &buf[..n]);
    }
    if h != want {
        return Err(mismatch());
    }
    f.seek(SeekFrom::Start(0))?;
    Ok(())
}

fn truncated(len: usize, avail: u64, path: &Path) -> Error {
    Error::invalid(format!(
        "NRRD: truncated data: the header declares {len} bytes of voxels, the file holds {avail}: {}",
        path.display()
    ))
}

/// Options for [`write()`] and [`write_detached`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct WriteOptions {
    /// gzip the voxel data (`encoding: gzip`) instead of `raw`.
    pub gzip: bool,
    /// Voxel type to write; `None` keeps the channel's type ([`super::output_type`]).
    /// Integer targets round to nearest and saturate.
    pub disk: Option<DiskType>,
}

/// The NRRD header text (up to and excluding the blank line) for `channel`, written as
/// `disk`. `data_file` names a detached data file.
fn header(channel: &Channel, disk: DiskType, gzip: bool, data_file: Option<&str>) -> String {
    let g = channel.grid.geometry();
    let [nx, ny, nz] = g.dims;
    let (o, s) = (g.origin, g.spacing);
    let mut h = String::from("NRRD0004\n# written by blueshift-volume\n");
    h += &format!("type: {}\n", nrrd_type_name(disk));
    if channel.grid.is_vector() {
        h += &format!(
            "dimension: 4\nsizes: 3 {nx} {ny} {nz}\nkinds: 3-vector domain domain domain\n"
        );
        h += &format!(
            "space: 3D-right-handed\nspace directions: none ({},0,0) (0,{},0) (0,0,{})\n",
            s.x, s.y, s.z
        );
    } else {
        h += &format!("dimension: 3\nsizes: {nx} {ny} {nz}\n");
        h += &format!(
            "space: 3D-right-handed\nspace directions: ({},0,0) (0,{},0) (0,0,{})\n",
            s.x, s.y, s.z
        );
    }
    h += &format!("space origin: ({},{},{})\n", o.x, o.y, o.z);
    h += &format!("content: {}\n", channel.name.replace(['\n', '\r'], " "));
    if disk.size_bytes() > 1 {
        h += "endian: little\n";
    }
    h += if gzip {
        "encoding: gzip\n"
    } else {
        "encoding: raw\n"
    };
    if let Some(d) = data_file {
        h += &format!("data file: {d}\n");
    }
    h
}

fn payload(channel: &Channel, disk: DiskType, gzip: bool) -> Result<Vec<u8>> {
    let raw = super::encode(&channel.grid, disk);
    if !gzip {
        return Ok(raw);
    }
    let mut enc = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::default());
    enc.write_all(&raw)?;
    Ok(enc.finish()?)
}

/// Writes an attached NRRD (header, blank line, data). The voxel type is the channel's
/// original on-disk type when that is lossless ([`super::output_type`]), the spacing and
/// origin are kept, and the channel name goes into `content`. Returns the type written.
pub fn write(w: &mut dyn Write, channel: &Channel, opts: &WriteOptions) -> Result<DiskType> {
    let disk = opts.disk.unwrap_or_else(|| super::output_type(channel));
    w.write_all(header(channel, disk, opts.gzip, None).as_bytes())?;
    w.write_all(b"\n")?;
    w.write_all(&payload(channel, disk, opts.gzip)?)?;
    Ok(disk)
}

/// Writes a detached NRRD: the header to `header_out` (naming `data_file_name`, relative to
/// the header's folder) and the voxels to `data_out`.
pub fn write_detached(
    header_out: &mut dyn Write,
    data_out: &mut dyn Write,
    data_file_name: &str,
    channel: &Channel,
    opts: &WriteOptions,
) -> Result<DiskType> {
    let disk = opts.disk.unwrap_or_else(|| super::output_type(channel));
    let data = payload(channel, disk, opts.gzip)?;
    let mut h = header(channel, disk, opts.gzip, Some(data_file_name));
    h += &format!(
        "{DATA_CHECK_KEY}{} {:016x}\n",
        data.len(),
        fnv1a64(FNV_OFFSET, &data)
    );
    header_out.write_all(h.as_bytes())?;
    data_out.write_all(&data)?;
    Ok(disk)
}

/// Writes an attached NRRD file at `path` (not atomic; the CLI wraps it).
pub fn write_file(path: &Path, channel: &Channel, opts: &WriteOptions) -> Result<DiskType> {
    let mut f = std::io::BufWriter::new(std::fs::File::create(path)?);
    let d = write(&mut f, channel, opts)?;
    f.flush()?;
    Ok(d)
}
