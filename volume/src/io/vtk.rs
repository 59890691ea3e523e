//! Legacy VTK `DATASET STRUCTURED_POINTS`, `BINARY` (always big-endian) or `ASCII`, with
//! `POINT_DATA` attributes `SCALARS` (one component) and `VECTORS` (three, interleaved).
//! Each attribute becomes a channel named as in the file, so a velocity field comes in with
//! its scalars. `SPACING` and the old `ASPECT_RATIO` both give the spacing; a negative spacing
//! reverses that axis on reading, so every voxel keeps its world position.

use std::io::{BufRead, BufReader, Read};
use std::path::Path;

use glam::Vec3;

use super::{
    DiskType, Encoding, Endian, Layout, ReadOptions, decode, open, parse_dim, parse_f32,
    read_payload,
};
use crate::grid::Geometry;
use crate::volume::{Channel, Volume};
use crate::{Error, Result};

/// The most data arrays (channels) a VTK file may hold.
const MAX_ARRAYS: usize = 4096;

struct Lexer<R> {
    r: R,
    pos: u64,
    len: u64,
}

impl<R: BufRead> Lexer<R> {
    /// Next whitespace-separated token, at most 256 bytes; `None` at end of file.
    fn token(&mut self) -> Result<Option<String>> {
        let mut tok = Vec::new();
        loop {
            let buf = self.r.fill_buf()?;
            if buf.is_empty() {
                break;
            }
            let b = buf[0];
            if b.is_ascii_whitespace() {
                if !tok.is_empty() {
                    break;
                }
                self.r.consume(1);
                self.pos += 1;
                continue;
            }
            tok.push(b);
            self.r.consume(1);
            self.pos += 1;
            if tok.len() > 256 {
                return Err(Error::invalid("VTK: token longer than 256 bytes"));
            }
        }
        if tok.is_empty() {
            return Ok(None);
        }
        String::from_utf8(tok)
            .map(Some)
            .map_err(|_| Error::invalid("VTK: header is not text"))
    }

    fn expect_token(&mut self, what: &str) -> Result<String> {
        self.token()?
            .ok_or_else(|| Error::invalid(format!("VTK: file ends where {what} was expected")))
    }

    /// Rest of the current line (after the last token), consuming the newline.
    fn rest_of_line(&mut self) -> Result<String> {
        super::nrrd::read_line(&mut self.r, &mut self.pos).map(Option::unwrap_or_default)
    }
}

fn vtk_type(s: &str) -> Result<DiskType> {
    Ok(match s.to_ascii_lowercase().as_str() {
        "unsigned_char" => DiskType::U8,
        "char" | "signed_char" => DiskType::I8,
        "unsigned_short" => DiskType::U16,
        "short" => DiskType::I16,
        "unsigned_int" => DiskType::U32,
        "int" => DiskType::I32,
        "float" => DiskType::F32,
        "double" => DiskType::F64,
        other => return Err(Error::unsupported(format!("VTK data type '{other}'"))),
    })
}

/// Reads a legacy VTK structured-points file; one channel per `SCALARS`/`VECTORS` block.
pub fn read(path: &Path, opts: &ReadOptions) -> Result<Volume> {
    let (f, file_len) = open(path)?;
    let mut lx = Lexer {
        r: BufReader::new(f),
        pos: 0,
        len: file_len,
    };
    let magic = lx.rest_of_line()?;
    if !magic.starts_with("# vtk DataFile") {
        return Err(Error::invalid(
            "VTK: first line is not '# vtk DataFile Version ...'",
        ));
    }
    let _title = lx.rest_of_line()?;
    let binary = match lx
        .expect_token("ASCII or BINARY")?
        .to_ascii_uppercase()
        .as_str()
    {
        "BINARY" => true,
        "ASCII" => false,
        other => {
            return Err(Error::invalid(format!(
                "VTK: '{other}' where ASCII or BINARY was expected"
            )));
        }
    };
    if !lx.expect_token("DATASET")?.eq_ignore_ascii_case("DATASET") {
        return Err(Error::invalid("VTK: missing DATASET"));
    }
    let ds = lx.expect_token("dataset type")?;
    if !ds.eq_ignore_ascii_case("STRUCTURED_POINTS") {
        return Err(Error::unsupported(format!(
            "VTK dataset '{ds}' (STRUCTURED_POINTS only)"
        )));
    }
    let mut dims = None;
    let mut spacing = Vec3::ONE;
    let mut origin = Vec3::ZERO;
    let mut npoints: Option<usize> = None;
    let mut volume: Option<Volume> = None;
    let mut suffixes: std::collections::HashMap<String, usize> = std::collections::HashMap::new();
    let vec3 = |lx: &mut Lexer<_>, what: &str| -> Result<Vec3> {
        let mut v = [0f32; 3];
        for c in &mut v {
            *c = parse_f32(&lx.expect_token(what)?, &format!("VTK {what}"))?;
        }
        Ok(Vec3::from_array(v))
    };
    while let Some(tok) = lx.token()? {
        match tok.to_ascii_uppercase().as_str() {
            "DIMENSIONS" => {
                let mut d = [0usize; 3];
                for v in &mut d {
                    *v = parse_dim(&lx.expect_token("DIMENSIONS")?, "VTK DIMENSIONS")?;
                }
                dims = Some(d);
            }
            "SPACING" | "ASPECT_RATIO" => spacing = vec3(&mut lx, "SPACING")?,
            "ORIGIN" => origin = vec3(&mut lx, "ORIGIN")?,
            "POINT_DATA" => {
                npoints = Some(parse_dim(
                    &lx.expect_token("POINT_DATA")?,
                    "VTK POINT_DATA",
                )?)
            }
            kw @ ("SCALARS" | "VECTORS") => {
                let dims =
                    dims.ok_or_else(|| Error::invalid("VTK: attribute data before DIMENSIONS"))?;
                let n = npoints
                    .ok_or_else(|| Error::invalid("VTK: attribute data before POINT_DATA"))?;
                let (origin, spacing, flip) = super::orient(dims, origin, spacing);
                let geometry = Geometry {
                    dims,
                    origin,
                    spacing,
                };
                geometry.validate().map_err(|e| e.context("VTK"))?;
                if Some(n)
                    != dims[0]
                        .checked_mul(dims[1])
                        .and_then(|v| v.checked_mul(dims[2]))
                {
                    return Err(Error::invalid(format!(
                        "VTK: POINT_DATA {n} does not match DIMENSIONS {dims:?}"
                    )));
                }
                let name = lx.expect_token("attribute name")?;
                let disk = vtk_type(&lx.expect_token("data type")?)?;
                let mut components = if kw == "VECTORS" { 3 } else { 1 };
                let rest = lx.rest_of_line()?;
                if kw == "SCALARS" {
                    if let Some(c) = rest.split_whitespace().next() {
                        components = parse_dim(c, "VTK SCALARS numComp")?;
                    }
                    if components != 1 && components != 3 {
                        return Err(Error::unsupported(format!(
                            "VTK SCALARS with {components} components"
                        )));
                    }
                    // The format requires a `LOOKUP_TABLE name` line after SCALARS.
                    let lt = lx.expect_token("LOOKUP_TABLE")?;
                    if !lt.eq_ignore_ascii_case("LOOKUP_TABLE") {
                        return Err(Error::invalid(format!(
                            "VTK: '{lt}' where LOOKUP_TABLE was expected"
                        )));
                    }
                    lx.expect_token("lookup table name")?;
                    lx.rest_of_line()?;
                }
                let layout = Layout {
                    dims,
                    disk,
                    endian: Endian::Big,
                    components,
                    flip,
                };
                let len = layout.byte_len(&opts.limits)?;
                let mut bytes = if binary {
                    let avail = lx.len.saturating_sub(lx.pos);
                    if len as u64 > avail {
                        return Err(Error::invalid(format!(
                            "VTK: truncated data: {kw} {name} needs {len} bytes, the file holds {avail}: {}",
                            path.display()
                        )));
                    }
                    let b = read_payload((&mut lx.r).take(len as u64), Encoding::Raw, len)?;
                    lx.pos += len as u64;
                    b
                } else {
                    let count = n * components;
                    if count as u64 > lx.len.saturating_sub(lx.pos) {
                        return Err(Error::invalid(format!(
                            "VTK: truncated ASCII data for {kw} {name}"
                        )));
                    }
                    let mut b = Vec::with_capacity(len);
                    for _ in 0..count {
                        let t = lx.expect_token("ASCII voxel values")?;
                        let v: f64 = t
                            .parse()
                            .map_err(|_| Error::invalid(format!("VTK: '{t}' is not a number")))?;
                        super::check_ascii_value(v, &t, disk)
                            .map_err(|m| Error::invalid(format!("VTK: {m}")))?;
                        put_be(&mut b, disk, v);
                    }
                    b
                };
                let grid = decode(&mut bytes, &layout, geometry)?;
                if opts.reject_non_finite {
                    grid.reject_non_finite()?;
                }
                let v = match &mut volume {
                    Some(v) => v,
                    None => volume.insert(Volume::new(geometry)?),
                };
                if v.channels().len() >= MAX_ARRAYS {
                    return Err(Error::Limits(format!(
                        "VTK: more than {MAX_ARRAYS} data arrays"
                    )));
                }
                // A repeated name gets the next free suffix (`name_2`, `name_3`, ...),
                // found from the last one given to that name, not by trying from 2.
                let mut cname = name.clone();
                let k = suffixes.entry(name.clone()).or_insert(2);
                while v.channel(&cname).is_some() {
                    cname = format!("{name}_{k}");
                    *k += 1;
                }
                v.push_channel(Channel {
                    name: cname,
                    grid,
                    stored_as: Some(disk),
                })?;
            }
            "CELL_DATA"
            | "FIELD"
            | "NORMALS"
            | "TENSORS"
            | "TEXTURE_COORDINATES"
            | "COLOR_SCALARS"
            | "LOOKUP_TABLE" => {
                // Attributes this reader does not load: stop here, keeping what was read.
                if volume.is_some() {
                    break;
                }
                return Err(Error::unsupported(format!(
                    "VTK attribute '{tok}' (SCALARS and VECTORS are read)"
                )));
            }
            other => return Err(Error::invalid(format!("VTK: unexpected keyword '{other}'"))),
        }
    }
    volume.ok_or_else(|| Error::invalid("VTK: no SCALARS or VECTORS data"))
}

/// Appends `v` as a big-endian `disk` value (used to feed ASCII data through [`decode`]).
fn put_be(b: &mut Vec<u8>, disk: DiskType, v: f64) {
    match disk {
        DiskType::U8 => b.push(v as u8),
        DiskType::I8 => b.push(v as i8 as u8),
        DiskType::U16 => b.extend_from_slice(&(v as u16).to_be_bytes()),
        DiskType::I16 => b.extend_from_slice(&(v as i16).to_be_bytes()),
        DiskType::U32 => b.extend_from_slice(&(v as u32).to_be_bytes()),
        DiskType::I32 => b.extend_from_slice(&(v as i32).to_be_bytes()),
        DiskType::F32 => b.extend_from_slice(&(v as f32).to_be_bytes()),
        DiskType::F64 => b.extend_from_slice(&v.to_be_bytes()),
    }
}
