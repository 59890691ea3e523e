//! MetaImage (ITK): `.mha` with the data after the header (`ElementDataFile = LOCAL`) and
//! `.mhd` with a separate data file. Reads `NDims`, `DimSize`, `ElementType`,
//! `ElementSpacing` (or `ElementSize`), `Offset`/`Origin`/`Position`,
//! `ElementByteOrderMSB`/`BinaryDataByteOrderMSB`, `CompressedData` (zlib),
//! `ElementNumberOfChannels` (1, or 3 for a vector field), `HeaderSize` and
//! `ElementDataFile`. A `TransformMatrix` must be axis-aligned; a negative entry (or a
//! negative spacing) reverses that axis as for NRRD, so voxels keep their world positions.
//! Rotations are refused.

use std::io::{BufReader, Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};

use glam::Vec3;

use super::nrrd::read_line;
use super::{
    DiskType, Encoding, Endian, Layout, ReadOptions, decode, finish, open, parse_dim, parse_f32,
    read_payload,
};
use crate::grid::Geometry;
use crate::volume::Volume;
use crate::{Error, Result};

fn met_type(s: &str) -> Result<DiskType> {
    Ok(match s {
        "MET_UCHAR" => DiskType::U8,
        "MET_CHAR" => DiskType::I8,
        "MET_USHORT" => DiskType::U16,
        "MET_SHORT" => DiskType::I16,
        "MET_UINT" | "MET_ULONG" => DiskType::U32,
        "MET_INT" | "MET_LONG" => DiskType::I32,
        "MET_FLOAT" => DiskType::F32,
        "MET_DOUBLE" => DiskType::F64,
        other => {
            return Err(Error::unsupported(format!(
                "MetaImage ElementType '{other}'"
            )));
        }
    })
}

fn bool_value(v: &str, key: &str) -> Result<bool> {
    match v.to_ascii_lowercase().as_str() {
        "true" | "1" => Ok(true),
        "false" | "0" => Ok(false),
        _ => Err(Error::invalid(format!(
            "MetaImage {key}: '{v}' is not True/False"
        ))),
    }
}

fn floats(v: &str, key: &str) -> Result<Vec<f32>> {
    v.split_whitespace()
        .take(64)
        .map(|s| parse_f32(s, &format!("MetaImage {key}")))
        .collect()
}

fn parse_header(path: &Path) -> Result<Header> {
    let (f, _) = open(path)?;
    let mut r = BufReader::new(f);
    let mut pos = 0u64;
    let mut ndims = None;
    let mut dim_size: Option<Vec<usize>> = None;
    let mut disk = None;
    let mut spacing: Option<Vec<f32>> = None;
    let mut origin: Option<Vec<f32>> = None;
    let mut msb = false;
    let mut compressed = false;
    let mut compressed_size: Option<u64> = None;
    let mut channels = 1usize;
    let mut header_size: i64 = 0;
    let mut data_file = None;
    let mut seen = std::collections::HashSet::new();
    // The direction matrix's diagonal: a negative entry reverses that axis.
    let mut diagonal = [1f32; 3];
    for _ in 0..4096 {
        // Binary data before any `ElementDataFile` line reads as a line that is not text.
        let Some(line) = read_line(&mut r, &mut pos).map_err(|e| match e {
            Error::Invalid(m) if data_file.is_none() => Error::invalid(format!(
                "MetaImage: {m} (the header must end with its ElementDataFile line)"
            )),
            e => e,
        })?
        else {
            break;
        };
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let (key, value) = line
            .split_once('=')
            .ok_or_else(|| Error::invalid(format!("MetaImage: header line '{line}' has no '='")))?;
        let (key, value) = (key.trim(), value.trim());
        // A field given twice (or under two of its names) leaves which was meant unknown.
        let canonical = match key {
            "Origin" | "Position" => "Offset",
            "Rotation" | "Orientation" => "TransformMatrix",
            "BinaryDataByteOrderMSB" => "ElementByteOrderMSB",
            k => k,
        };
        if !seen.insert(canonical.to_string()) {
            return Err(Error::invalid(format!("MetaImage: {key} given twice")));
        }
        match key {
            "NDims" => ndims = Some(parse_dim(value, "MetaImage NDims")?),
            "DimSize" => {
                dim_size = Some(
                    value
                        .split_whitespace()
                        .take(64)
                        .map(|s| parse_dim(s, "MetaImage DimSize"))
                        .collect::<Result<_>>()?,
                );
            }
            "ElementType" => disk = Some(met_type(value)?),
            "ElementSpacing" => spacing = Some(floats(value, key)?),
            "ElementSize" if spacing.is_none() => spacing = Some(floats(value, key)?),
            "Offset" | "Origin" | "Position" => origin = Some(floats(value, key)?),
            "ElementByteOrderMSB" | "BinaryDataByteOrderMSB" => msb = bool_value(value, key)?,
            "CompressedData" => compressed = bool_value(value, key)?,
            "CompressedDataSize" => {
                compressed_size = Some(value.parse().map_err(|_| {
                    Error::invalid(format!("MetaImage: CompressedDataSize '{value}'"))
                })?);
            }
            "ElementNumberOfChannels" => {
                channels = parse_dim(value, "MetaImage ElementNumberOfChannels")?
            }
            "HeaderSize" => {
                header_size = value
                    .parse()
                    .map_err(|_| Error::invalid(format!("MetaImage HeaderSize '{value}'")))?;
                if header_size < -1 {
                    return Err(Error::invalid(format!(
                        "MetaImage HeaderSize {header_size}"
                    )));
                }
            }
            "TransformMatrix" | "Rotation" | "Orientation" => {
                let m = floats(value, key)?;
                let n = match m.len() {
                    4 => 2,
                    9 => 3,
                    k => {
                        return Err(Error::invalid(format!(
                            "MetaImage: {key} has {k} numbers (4 or 9)"
                        )));
                    }
                };
                for (i, v) in m.iter().enumerate() {
                    if i % (n + 1) != 0 && v.abs() > 1e-6 {
                        return Err(Error::unsupported(format!(
                            "MetaImage: rotated {key} (only axis-aligned)"
                        )));
                    }
                }
                for (a, d) in diagonal.iter_mut().enumerate().take(n) {
                    *d = m[a * (n + 1)];
                    if d.abs() < 1e-6 {
                        return Err(Error::invalid(format!(
                            "MetaImage: {key} has a zero on its diagonal"
                        )));
                    }
                }
            }
            "ElementDataFile" => {
                data_file = Some(value.to_string());
                break; // by definition the last header field
            }
            _ => {}
        }
    }
    let ndims = ndims.ok_or_else(|| Error::invalid("MetaImage: missing NDims"))?;
    let dim_size = dim_size.ok_or_else(|| Error::invalid("MetaImage: missing DimSize"))?;
    let disk = disk.ok_or_else(|| Error::invalid("MetaImage: missing ElementType"))?;
    let data_file =
        data_file.ok_or_else(|| Error::invalid("MetaImage: missing ElementDataFile"))?;
    if !(2..=3).contains(&ndims) || dim_size.len() != ndims {
        return Err(Error::invalid(format!(
            "MetaImage: NDims {ndims} with DimSize {dim_size:?} (2D or 3D)"
        )));
    }
    if channels != 1 && channels != 3 {
        return Err(Error::unsupported(format!(
            "MetaImage: {channels} channels per voxel (1 or 3)"
        )));
    }
    let dims = [
        dim_size[0],
        dim_size[1],
        dim_size.get(2).copied().unwrap_or(1),
    ];
    let mut sp = Vec3::ONE;
    if let Some(s) = spacing {
        if s.len() < ndims {
            return Err(Error::invalid(
                "MetaImage: ElementSpacing has too few entries",
            ));
        }
        for a in 0..ndims {
            sp[a] = s[a];
        }
    }
    let mut o = Vec3::ZERO;
    if let Some(v) = origin {
        if v.len() < ndims {
            return Err(Error::invalid("MetaImage: Offset has too few entries"));
        }
        for a in 0..ndims {
            o[a] = v[a];
        }
    }
    for (a, d) in diagonal.iter().enumerate().take(ndims) {
        if *d < 0.0 {
            sp[a] = -sp[a];
        }
    }
    let (o, sp, flip) = super::orient(dims, o, sp);
    let geometry = Geometry {
        dims,
        origin: o,
        spacing: sp,
    };
    geometry.validate().map_err(|e| e.context("MetaImage"))?;
    let layout = Layout {
        dims,
        disk,
        endian: if msb { Endian::Big } else { Endian::Little },
        components: channels,
        flip,
    };
    Ok(Header {
        layout,
        geometry,
        compressed,
        compressed_size,
        header_size,
        data_file,
        header_end: pos,
    })
}

struct Header {
    layout: Layout,
    geometry: Geometry,
    compressed: bool,
    /// `CompressedDataSize`: the zlib stream's length in bytes, if given.
    compressed_size: Option<u64>,
    header_size: i64,
    data_file: String,
    header_end: u64,
}

/// Where an uncompressed MetaImage keeps its voxels: file, byte offset, layout and geometry;
/// `None` for compressed data (read those in core).
pub(crate) fn raw_payload(
    path: &Path,
    limits: &crate::Limits,
) -> Result<Option<(PathBuf, u64, Layout, Geometry)>> {
    let h = parse_header(path)?;
    let len = h.layout.byte_len(limits)? as u64;
    if h.compressed || h.data_file.starts_with("LIST") || h.data_file.contains('%') {
        return Ok(None);
    }
    let (p, start) = if h.data_file == "LOCAL" {
        (path.to_path_buf(), h.header_end)
    } else {
        (
            path.parent().unwrap_or(Path::new(".")).join(&h.data_file),
            0,
        )
    };
    super::check_regular_file(&p)?;
    let file_len = std::fs::metadata(&p)?.len();
    let off = if h.header_size == -1 {
        file_len.saturating_sub(len)
    } else {
        start + h.header_size as u64
    };
    Ok(Some((p, off, h.layout, h.geometry)))
}

/// Reads a MetaImage file.
pub fn read(path: &Path, opts: &ReadOptions) -> Result<Volume> {
    let Header {
        layout,
        geometry,
        compressed,
        compressed_size,
        header_size,
        data_file,
        header_end,
    } = parse_header(path)?;
    let (disk, channels) = (layout.disk, layout.components);
    let (f, file_len) = open(path)?;
    let mut r = BufReader::new(f);
    r.seek(SeekFrom::Start(header_end))?;
    let pos = header_end;
    let len = layout.byte_len(&opts.limits)?;
    let encoding = if compressed {
        Encoding::Zlib
    } else {
        Encoding::Raw
    };

    let (mut src, avail): (Box<dyn Read>, u64) = if data_file == "LOCAL" {
        (Box::new(r), file_len.saturating_sub(pos))
    } else if data_file.starts_with("LIST") || data_file.contains('%') {
        return Err(Error::unsupported(
            "MetaImage: multi-file data (LIST or a pattern)",
        ));
    } else {
        let dpath = path.parent().unwrap_or(Path::new(".")).join(&data_file);
        let (df, dlen) = open(&dpath)?;
        (Box::new(BufReader::new(df)), dlen)
    };
    let avail = if header_size == -1 {
        if compressed {
            return Err(Error::invalid(
                "MetaImage: HeaderSize -1 with compressed data",
            ));
        }
        if (len as u64) > avail {
            return Err(Error::invalid(format!(
                "MetaImage: truncated data: {len} bytes declared, {avail} in the file"
            )));
        }
        let skip = avail - len as u64;
        std::io::copy(&mut src.by_ref().take(skip), &mut std::io::sink())?;
        len as u64
    } else {
        let skip = header_size as u64;
        let got = std::io::copy(&mut src.by_ref().take(skip), &mut std::io::sink())?;
        if got < skip {
            return Err(Error::invalid(
                "MetaImage: HeaderSize runs past the end of the data file",
            ));
        }
        avail - skip
    };
    if !compressed && (len as u64) > avail {
        return Err(Error::invalid(format!(
            "MetaImage: truncated data: the header declares {len} bytes of voxels, the file holds {avail}: {}",
            path.display()
        )));
    }
    // A compressed stream reads no further than its declared size (as ITK reads it), and a
    // declared size past the file's end is refused here, not as a damaged stream.
    if let (true, Some(size)) = (compressed, compressed_size) {
        if size > avail {
            return Err(Error::invalid(format!(
                "MetaImage: CompressedDataSize {size} bytes, the file holds {avail} after the header"
            )));
        }
        src = Box::new(src.take(size));
    }
    let mut bytes = read_payload(src, encoding, len)?;
    let grid = decode(&mut bytes, &layout, geometry)?;
    let name = if channels == 3 { "vectors" } else { "scalars" };
    finish(name, grid, disk, opts)
}
