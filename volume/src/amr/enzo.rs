//! Enzo output: the text parameter file, the text `.hierarchy` (one entry per grid), and
//! the HDF5 files holding each grid's fields (`/GridNNNNNNNN/<field>`, stored z, y, x
//! without ghost zones; older unpacked output keeps one file per grid with the fields at
//! the root). Units follow yt: cosmological runs take Enzo's comoving units at the
//! snapshot's redshift (proper cgs), others `LengthUnits`, `DensityUnits`, `TimeUnits`.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use glam::DVec3;

use super::{Block, FieldInfo, Hierarchy, Reader, guarded, three};
use crate::{Error, Result};

/// Largest parameter or hierarchy file read, bytes.
const MAX_TEXT_BYTES: u64 = 256 << 20;

/// Where each grid's fields are.
#[derive(Clone, Debug)]
pub(super) struct Files {
    /// Per block: the HDF5 file and the grid's number (its group `GridNNNNNNNN`).
    grids: Vec<(PathBuf, u64)>,
}

/// The `.hierarchy` beside a parameter file.
pub(super) fn hierarchy_path(param: &Path) -> PathBuf {
    let mut s = param.as_os_str().to_owned();
    s.push(".hierarchy");
    PathBuf::from(s)
}

fn read_text(path: &Path) -> Result<String> {
    let meta = std::fs::metadata(path).map_err(|e| io(path, e))?;
    if meta.len() > MAX_TEXT_BYTES {
        return Err(Error::Limits(format!(
            "{}: {} bytes, more than a text file of Enzo's should hold",
            path.display(),
            meta.len()
        )));
    }
    let bytes = std::fs::read(path).map_err(|e| io(path, e))?;
    String::from_utf8(bytes)
        .map_err(|_| Error::invalid(format!("{}: not a text file", path.display())))
}

fn io(path: &Path, e: std::io::Error) -> Error {
    Error::Io(std::io::Error::new(
        e.kind(),
        format!("{}: {e}", path.display()),
    ))
}

/// `key = value` lines (the last of a repeated key wins; comments after `//` or `#`).
fn parse_params(text: &str) -> HashMap<String, String> {
    let mut out = HashMap::new();
    for line in text.lines() {
        let line = line.split("//").next().unwrap_or("");
        let Some((k, v)) = line.split_once('=') else {
            continue;
        };
        let k = k.trim();
        if k.is_empty() || k.starts_with('#') {
            continue;
        }
        out.insert(k.to_owned(), v.trim().to_owned());
    }
    out
}

fn get<'a>(p: &'a HashMap<String, String>, key: &str, path: &Path) -> Result<&'a str> {
    p.get(key)
        .map(String::as_str)
        .ok_or_else(|| Error::invalid(format!("{}: no '{key}'", path.display())))
}

fn num(p: &HashMap<String, String>, key: &str, path: &Path) -> Result<f64> {
    let v = get(p, key, path)?;
    v.split_whitespace()
        .next()
        .and_then(|t| t.parse::<f64>().ok())
        .filter(|x| x.is_finite())
        .ok_or_else(|| Error::invalid(format!("{}: {key} = '{v}' is not a number", path.display())))
}

/// Enzo's comoving units at redshift `z` (yt's `cosmology_get_units`, with the constants
/// Enzo uses): (length cm, density g/cm^3, velocity cm/s).
fn cosmology_units(h: f64, omega_m: f64, box_size: f64, z_init: f64, z: f64) -> (f64, f64, f64) {
    const NEWTON_CGS: f64 = 6.67384e-08;
    const RHO_CRIT_G_CM3_H2: f64 = 1.878_471_083_843_165_4e-29;
    const CM_PER_MPC: f64 = 3.085_677_580_962_325e24;
    let time_scaling = (1.0 / (4.0 * std::f64::consts::PI * NEWTON_CGS * RHO_CRIT_G_CM3_H2)).sqrt();
    let vel_scaling = CM_PER_MPC / time_scaling;
    let length = CM_PER_MPC * box_size / h / (1.0 + z);
    let density = RHO_CRIT_G_CM3_H2 * omega_m * h * h * (1.0 + z).powi(3);
    let velocity = vel_scaling * box_size * omega_m.sqrt() * (1.0 + z_init).sqrt();
    (length, density, velocity)
}

/// The unit and factor of an Enzo field, given the code units.
fn field_unit(name: &str, density: f64, velocity: f64) -> (String, f64) {
    match name {
        "Temperature" | "Dust_Temperature" => ("K".into(), 1.0),
        "x-velocity" | "y-velocity" | "z-velocity" => ("cm/s".into(), velocity),
        "TotalEnergy" | "GasEnergy" | "Total_Energy" | "Gas_Energy" | "ThermalEnergy" => {
            ("erg/g".into(), velocity * velocity)
        }
        "Bx" | "By" | "Bz" => (
            "G".into(),
            (4.0 * std::f64::consts::PI * density).sqrt() * velocity,
        ),
        n if n == "Density" || n.ends_with("_Density") => ("g/cm3".into(), density),
        _ => ("code".into(), 1.0),
    }
}

pub(super) fn open(param: &Path) -> Result<Hierarchy> {
    let params = parse_params(&read_text(param)?);
    let hpath = hierarchy_path(param);
    let hier = read_text(&hpath)?;
    let rank = get(&params, "TopGridRank", param)?;
    if rank.trim() != "3" {
        return Err(Error::unsupported(format!(
            "{}: TopGridRank {rank}: only 3-D Enzo output is read",
            param.display()
        )));
    }
    let root_dims: [usize; 3] = three(
        get(&params, "TopGridDimensions", param)?,
        "TopGridDimensions",
    )?;
    let domain_lo = DVec3::from(three::<f64>(
        params.get("DomainLeftEdge").map_or("0 0 0", String::as_str),
        "DomainLeftEdge",
    )?);
    let domain_hi = DVec3::from(three::<f64>(
        params
            .get("DomainRightEdge")
            .map_or("1 1 1", String::as_str),
        "DomainRightEdge",
    )?);
    let ratio = params
        .get("RefineBy")
        .map_or(Ok(2.0), |_| num(&params, "RefineBy", param))?;
    if !(2.0..=16.0).contains(&ratio) || ratio.fract() != 0.0 {
        return Err(Error::invalid(format!(
            "{}: RefineBy = {ratio}",
            param.display()
        )));
    }
    let ratio = ratio as u32;
    let time = params
        .get("InitialTime")
        .map_or(Ok(0.0), |_| num(&params, "InitialTime", param))?;

    // Units.
    let cosmological = params
        .get("ComovingCoordinates")
        .is_some_and(|v| v.trim() == "1");
    let (length_cm, density, velocity, redshift) = if cosmological {
        let h = num(&params, "CosmologyHubbleConstantNow", param)?;
        let om = num(&params, "CosmologyOmegaMatterNow", param)?;
        let bx = num(&params, "CosmologyComovingBoxSize", param)?;
        let zi = num(&params, "CosmologyInitialRedshift", param)?;
        let z = num(&params, "CosmologyCurrentRedshift", param)?;
        let (l, d, v) = cosmology_units(h, om, bx, zi, z);
        (Some(l), d, v, Some(z))
    } else if params.contains_key("LengthUnits") {
        let l = num(&params, "LengthUnits", param)?;
        let d = num(&params, "DensityUnits", param)?;
        let t = num(&params, "TimeUnits", param)?;
        (Some(l), d, l / t, None)
    } else {
        (None, 1.0, 1.0, None)
    };
    if !(density.is_finite() && density > 0.0 && velocity.is_finite() && velocity > 0.0) {
        return Err(Error::invalid(format!(
            "{}: the code units are not positive and finite",
            param.display()
        )));
    }

    // Grids.
    let dir = param.parent().unwrap_or(Path::new("."));
    let root_dx = (domain_hi - domain_lo)
        / DVec3::new(
            root_dims[0] as f64,
            root_dims[1] as f64,
            root_dims[2] as f64,
        );
    let mut blocks = Vec::new();
    let mut grids = Vec::new();
    for entry in hier
        .split("\nGrid = ")
        .skip(usize::from(!hier.starts_with("Grid = ")))
    {
        let entry = entry.strip_prefix("Grid = ").unwrap_or(entry);
        let (num_line, rest) = entry.split_once('\n').unwrap_or((entry, ""));
        let id: u64 = num_line.trim().parse().map_err(|_| {
            Error::invalid(format!(
                "{}: grid number '{}'",
                hpath.display(),
                num_line.trim()
            ))
        })?;
        let p = parse_params(rest);
        let what = |k: &str| format!("grid {id} {k}");
        let start: [i64; 3] = three(get(&p, "GridStartIndex", &hpath)?, &what("GridStartIndex"))?;
        let end: [i64; 3] = three(get(&p, "GridEndIndex", &hpath)?, &what("GridEndIndex"))?;
        let left = DVec3::from(three::<f64>(
            get(&p, "GridLeftEdge", &hpath)?,
            &what("GridLeftEdge"),
        )?);
        let right = DVec3::from(three::<f64>(
            get(&p, "GridRightEdge", &hpath)?,
            &what("GridRightEdge"),
        )?);
        let dims = [0, 1, 2].map(|a| end[a] - start[a] + 1);
        if dims.iter().any(|&d| d <= 0 || d > 1 << 20) {
            return Err(Error::invalid(format!(
                "{}: grid {id} has {dims:?} active cells",
                hpath.display()
            )));
        }
        let dims = dims.map(|d| d as usize);
        let dx = (right - left) / DVec3::new(dims[0] as f64, dims[1] as f64, dims[2] as f64);
        let lv = (root_dx.x / dx.x).log(f64::from(ratio));
        let level = lv.round();
        if !lv.is_finite() || (lv - level).abs() > 1e-6 || !(0.0..=30.0).contains(&level) {
            return Err(Error::invalid(format!(
                "{}: grid {id}'s cell size {} is not the root's {} refined by {ratio}^n",
                hpath.display(),
                dx.x,
                root_dx.x
            )));
        }
        let level = level as u32;
        let cell = dx;
        let lo = [0, 1, 2].map(|a| ((left[a] - domain_lo[a]) / cell[a]).round() as i64);
        let file = p.get("BaryonFileName").map(|f| {
            // The path is the writer's; the file is found beside the parameter file.
            let name = f.rsplit('/').next().unwrap_or(f);
            dir.join(name)
        });
        let Some(file) = file else {
            // A grid without baryon fields holds no data to render.
            continue;
        };
        blocks.push(Block { level, lo, dims });
        grids.push((file, id));
    }
    if blocks.is_empty() {
        return Err(Error::invalid(format!(
            "{}: no grid with baryon fields",
            hpath.display()
        )));
    }
    // Fields: the 3-D datasets of the first grid.
    let (f0, id0) = &grids[0];
    let file = open_h5(f0)?;
    let group = grid_group(&file, *id0, f0)?;
    let mut fields = Vec::new();
    let datasets = group.datasets().map_err(|e| h5(f0, e))?;
    for ds in datasets {
        if ds.ndim() == 3 {
            let name = ds.name().rsplit('/').next().unwrap_or(ds.name()).to_owned();
            let (unit, to_unit) = field_unit(&name, density, velocity);
            fields.push(FieldInfo {
                name,
                unit,
                to_unit,
            });
        }
    }
    fields.sort_by(|a, b| a.name.cmp(&b.name));
    Ok(Hierarchy {
        code: "Enzo",
        path: param.to_path_buf(),
        domain_lo,
        domain_hi,
        root_dims,
        ratio,
        blocks,
        fields,
        time,
        redshift,
        length_unit_cm: length_cm,
        reader: Reader::Enzo(Files { grids }),
    })
}

pub(super) fn h5(path: &Path, e: hdf5_reader::error::Error) -> Error {
    Error::invalid(format!("{}: HDF5: {e}", path.display()))
}

pub(super) fn open_h5(path: &Path) -> Result<hdf5_reader::Hdf5File> {
    if !path.is_file() {
        return Err(Error::Io(std::io::Error::new(
            std::io::ErrorKind::NotFound,
            format!("{}: no such file", path.display()),
        )));
    }
    let len = std::fs::metadata(path).map_err(|e| io(path, e))?.len();
    let head = {
        use std::io::Read as _;
        let mut b = [0u8; 16];
        let mut f = std::fs::File::open(path).map_err(|e| io(path, e))?;
        let n = f.read(&mut b).map_err(|e| io(path, e))?;
        b[..n].to_vec()
    };
    // Files with a version 0/1 superblock (HDF5 1.4-1.8) may hold version-2 layout
    // messages, which hdf5-reader misparses; they are read into memory and mended first.
    if len <= MAX_LEGACY_BYTES && head.len() == 16 && head[..8] == HDF5_SIGNATURE && head[8] <= 1 {
        let mut bytes = std::fs::read(path).map_err(|e| io(path, e))?;
        mend_legacy_layouts(&mut bytes);
        return hdf5_reader::Hdf5File::from_vec(bytes).map_err(|e| h5(path, e));
    }
    hdf5_reader::Hdf5File::open(path).map_err(|e| h5(path, e))
}

const HDF5_SIGNATURE: [u8; 8] = [0x89, b'H', b'D', b'F', b'\r', b'\n', 0x1a, b'\n'];

/// Largest legacy HDF5 file read into memory to mend its layout messages.
const MAX_LEGACY_BYTES: u64 = 4 << 30;

/// Rewrites the version byte of every version-2 data layout message of the file's object
/// headers to 1, returning how many it changed.
///
/// The HDF5 specification gives versions 1 and 2 of the data layout message the same
/// fields (five reserved bytes after the layout class), but hdf5-reader 0.12 skips only
/// three for version 2, so it reads a wrong data address and dimensions (the original Enzo
/// snapshot in shared/data, written by HDF5 1.6, has them). Object headers are found
/// through the symbol-table nodes (`SNOD`) of version 0/1 files; a message is changed only
/// inside a well-formed version-1 object header, so stray bytes are left alone.
pub(super) fn mend_legacy_layouts(bytes: &mut [u8]) -> usize {
    if bytes.len() < 16 || bytes[..8] != HDF5_SIGNATURE || bytes[8] > 1 {
        return 0;
    }
    let (off, len) = (usize::from(bytes[13]), usize::from(bytes[14]));
    if !matches!(off, 2 | 4 | 8) || !matches!(len, 2 | 4 | 8) {
        return 0;
    }
    let read = |b: &[u8], at: usize, n: usize| -> Option<u64> {
        let s = b.get(at..at.checked_add(n)?)?;
        Some(
            s.iter()
                .rev()
                .fold(0u64, |acc, &x| (acc << 8) | u64::from(x)),
        )
    };
    let mut headers = std::collections::BTreeSet::new();
    let entry = 2 * off + 24;
    let mut i = 0;
    while let Some(p) = bytes[i..].windows(4).position(|w| w == b"SNOD") {
        let at = i + p;
        i = at + 4;
        if bytes.get(at + 4) != Some(&1) {
            continue;
        }
        let Some(n) = read(bytes, at + 6, 2) else {
            continue;
        };
        for e in 0..n as usize {
            if let Some(a) = read(bytes, at + 8 + e * entry + off, off) {
                headers.insert(a as usize);
            }
        }
    }
    let mut changed = 0;
    for h in headers {
        // A version-1 object header: version 1, a reserved zero, the message count, then
        // its first chunk at h + 16.
        if bytes.get(h) != Some(&1) || bytes.get(h + 1) != Some(&0) {
            continue;
        }
        let Some(size) = read(bytes, h + 8, 4) else {
            continue;
        };
        let mut chunks = vec![(h + 16, size as usize)];
        let mut guard = 0;
        while let Some((start, size)) = chunks.pop() {
            guard += 1;
            if guard > 64 {
                break;
            }
            let end = start.saturating_add(size).min(bytes.len());
            let mut p = start;
            while p + 8 <= end {
                let (Some(kind), Some(n)) = (read(bytes, p, 2), read(bytes, p + 2, 2)) else {
                    break;
                };
                let data = p + 8;
                let n = n as usize;
                if data + n > end {
                    break;
                }
                if kind == 0x0008 && n >= 8 && bytes[data] == 2 && bytes[data + 2] <= 2 {
                    bytes[data] = 1;
                    changed += 1;
                }
                if kind == 0x0010
                    && let (Some(a), Some(l)) =
                        (read(bytes, data, off), read(bytes, data + off, len))
                {
                    chunks.push((a as usize, l as usize));
                }
                p = data + n;
            }
        }
    }
    changed
}

/// The group of grid `id`: `/GridNNNNNNNN` (packed output), else the root (one file per
/// grid).
fn grid_group(
    file: &hdf5_reader::Hdf5File,
    id: u64,
    path: &Path,
) -> Result<hdf5_reader::group::Group> {
    let name = format!("/Grid{id:08}");
    match file.group(&name) {
        Ok(g) => Ok(g),
        Err(_) => file.root_group().map_err(|e| h5(path, e)),
    }
}

/// Reads field `name` of the `needed` blocks (the others' values are left empty), each
/// grid file opened once per run of consecutive needed grids it holds; a file holding no
/// needed grid is never opened. A failure names the grid's file.
pub(super) fn read_field(
    files: &Files,
    h: &Hierarchy,
    name: &str,
    needed: &[bool],
) -> Result<Vec<Vec<f32>>> {
    let mut out = Vec::with_capacity(h.blocks.len());
    let mut open: Option<(PathBuf, hdf5_reader::Hdf5File)> = None;
    for ((b, (path, id)), &need) in h.blocks.iter().zip(&files.grids).zip(needed) {
        if !need {
            out.push(Vec::new());
            continue;
        }
        if open.as_ref().is_none_or(|(p, _)| p != path) {
            drop(open.take());
            open = Some((path.clone(), guarded(path, || open_h5(path))?));
        }
        let file = &open.as_ref().expect("opened above").1;
        out.push(guarded(path, || read_block(file, path, *id, b, name))?);
    }
    Ok(out)
}

/// Field `name` of grid `id` (block `b`) in the open `file` at `path`.
fn read_block(
    file: &hdf5_reader::Hdf5File,
    path: &Path,
    id: u64,
    b: &Block,
    name: &str,
) -> Result<Vec<f32>> {
    let group = grid_group(file, id, path)?;
    let ds = group.dataset(name).map_err(|e| {
        Error::invalid(format!(
            "{}: grid {id} has no field '{name}': {e}",
            path.display()
        ))
    })?;
    let want = [b.dims[2] as u64, b.dims[1] as u64, b.dims[0] as u64];
    if ds.shape() != want {
        return Err(Error::invalid(format!(
            "{}: grid {id} field '{name}' has shape {:?}, the hierarchy says {want:?} (z, y, x)",
            path.display(),
            ds.shape()
        )));
    }
    let mut v = vec![0.0f32; b.cells()];
    if ds.read_into(&mut v).is_err() {
        // Double-precision output.
        let a = ds.read_array::<f64>().map_err(|e| h5(path, e))?;
        if a.len() != v.len() {
            return Err(Error::invalid(format!(
                "{}: grid {id} field '{name}' read {} values, {} expected",
                path.display(),
                a.len(),
                v.len()
            )));
        }
        v = a.iter().map(|&x| x as f32).collect();
    }
    Ok(v)
}
