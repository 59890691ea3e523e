//! Athena++ `.athdf` output: mesh blocks of one size (`MeshBlockSize`), each at a level
//! (`Levels`, 0 the root) and a logical location in blocks of that level
//! (`LogicalLocations`); variables in datasets of shape (variables, blocks, z, y, x) named
//! by `DatasetNames`, `NumVariables` and `VariableNames`. Athena++ writes no units: values
//! are served in code units.

use std::path::{Path, PathBuf};

use glam::DVec3;
use hdf5_reader::{Hdf5File, SliceInfo, SliceInfoElem};

use super::enzo::{h5, open_h5};
use super::{Block, FieldInfo, Hierarchy, Reader};
use crate::{Error, Result};

/// Where each variable lives.
#[derive(Clone, Debug)]
pub(super) struct Files {
    path: PathBuf,
    /// Per field: the dataset and the variable's index in it.
    vars: Vec<(String, String, u64)>,
}

fn attr_f64s(file: &Hdf5File, name: &str, path: &Path) -> Result<Vec<f64>> {
    let root = file.root_group().map_err(|e| h5(path, e))?;
    let a = root
        .attribute(name)
        .map_err(|e| Error::invalid(format!("{}: no attribute '{name}': {e}", path.display())))?;
    if let Ok(v) = a.read_1d::<f64>() {
        return Ok(v);
    }
    if let Ok(v) = a.read_1d::<i64>() {
        return Ok(v.into_iter().map(|x| x as f64).collect());
    }
    if let Ok(v) = a.read_1d::<i32>() {
        return Ok(v.into_iter().map(f64::from).collect());
    }
    a.read_as_f64()
        .map(|x| vec![x])
        .map_err(|e| Error::invalid(format!("{}: attribute '{name}': {e}", path.display())))
}

fn attr_strings(file: &Hdf5File, name: &str, path: &Path) -> Result<Vec<String>> {
    let root = file.root_group().map_err(|e| h5(path, e))?;
    let a = root
        .attribute(name)
        .map_err(|e| Error::invalid(format!("{}: no attribute '{name}': {e}", path.display())))?;
    a.read_strings()
        .or_else(|_| a.read_string().map(|s| vec![s]))
        .map(|v| {
            v.into_iter()
                .map(|s| s.trim_end_matches('\0').trim().to_owned())
                .collect()
        })
        .map_err(|e| Error::invalid(format!("{}: attribute '{name}': {e}", path.display())))
}

fn usize3(v: &[f64], name: &str, path: &Path) -> Result<[usize; 3]> {
    if v.len() < 3
        || v.iter()
            .take(3)
            .any(|&x| !(1.0..=f64::from(1u32 << 16)).contains(&x))
    {
        return Err(Error::invalid(format!(
            "{}: {name} = {v:?}",
            path.display()
        )));
    }
    Ok([v[0] as usize, v[1] as usize, v[2] as usize])
}

pub(super) fn open(path: &Path) -> Result<Hierarchy> {
    let file = open_h5(path)?;
    let block = usize3(
        &attr_f64s(&file, "MeshBlockSize", path)?,
        "MeshBlockSize",
        path,
    )?;
    let root_dims = usize3(
        &attr_f64s(&file, "RootGridSize", path)?,
        "RootGridSize",
        path,
    )?;
    let mut lo = DVec3::ZERO;
    let mut hi = DVec3::ONE;
    for (a, name) in ["RootGridX1", "RootGridX2", "RootGridX3"]
        .iter()
        .enumerate()
    {
        let v = attr_f64s(&file, name, path)?;
        if v.len() < 3 || !v.iter().all(|x| x.is_finite()) {
            return Err(Error::invalid(format!(
                "{}: {name} = {v:?}",
                path.display()
            )));
        }
        if (v[2] - 1.0).abs() > 1e-12 {
            return Err(Error::unsupported(format!(
                "{}: {name} has a geometric ratio {} (only uniform root grids are read)",
                path.display(),
                v[2]
            )));
        }
        lo[a] = v[0];
        hi[a] = v[1];
    }
    if let Ok(c) = attr_strings(&file, "Coordinates", path)
        && let Some(c) = c.first()
        && c != "cartesian"
    {
        return Err(Error::unsupported(format!(
            "{}: {c} coordinates (only cartesian are read)",
            path.display()
        )));
    }
    let time = attr_f64s(&file, "Time", path)
        .ok()
        .and_then(|v| v.first().copied())
        .unwrap_or(0.0);
    let levels_ds = file.dataset("/Levels").map_err(|e| h5(path, e))?;
    let locs_ds = file.dataset("/LogicalLocations").map_err(|e| h5(path, e))?;
    let n = levels_ds.shape().first().copied().unwrap_or(0) as usize;
    if locs_ds.shape() != [n as u64, 3] {
        return Err(Error::invalid(format!(
            "{}: LogicalLocations has shape {:?} for {n} blocks",
            path.display(),
            locs_ds.shape()
        )));
    }
    if n > super::MAX_BLOCKS {
        return Err(Error::Limits(format!(
            "{}: {n} mesh blocks",
            path.display()
        )));
    }
    let levels: Vec<i64> = read_ints(&levels_ds, n, path)?;
    let locs: Vec<i64> = read_ints(&locs_ds, 3 * n, path)?;
    let mut blocks = Vec::with_capacity(n);
    for i in 0..n {
        let level = levels[i];
        if !(0..=i64::from(super::MAX_LEVELS)).contains(&level) {
            return Err(Error::invalid(format!(
                "{}: block {i} at level {level}",
                path.display()
            )));
        }
        let lo = [0, 1, 2].map(|a| locs[3 * i + a].saturating_mul(block[a] as i64));
        blocks.push(Block {
            level: level as u32,
            lo,
            dims: block,
        });
    }
    // Variables.
    let names = attr_strings(&file, "DatasetNames", path)?;
    let counts = attr_f64s(&file, "NumVariables", path)?;
    let vars = attr_strings(&file, "VariableNames", path)?;
    let whole = |c: &f64| c.is_finite() && *c >= 0.0 && c.fract() == 0.0;
    if names.len() != counts.len()
        || !counts.iter().all(whole)
        || counts.iter().sum::<f64>() != vars.len() as f64
    {
        return Err(Error::invalid(format!(
            "{}: DatasetNames {names:?}, NumVariables {counts:?} and {} VariableNames disagree",
            path.display(),
            vars.len()
        )));
    }
    let mut fields = Vec::new();
    let mut where_ = Vec::new();
    let mut k = 0;
    for (ds, &c) in names.iter().zip(&counts) {
        for j in 0..c as u64 {
            let v = &vars[k];
            k += 1;
            fields.push(FieldInfo {
                name: v.clone(),
                unit: "code".into(),
                to_unit: 1.0,
            });
            where_.push((v.clone(), ds.clone(), j));
        }
    }
    Ok(Hierarchy {
        code: "Athena++",
        path: path.to_path_buf(),
        domain_lo: lo,
        domain_hi: hi,
        root_dims,
        ratio: 2,
        blocks,
        fields,
        time,
        redshift: None,
        length_unit_cm: None,
        reader: Reader::Athena(Files {
            path: path.to_path_buf(),
            vars: where_,
        }),
    })
}

fn read_ints(ds: &hdf5_reader::Dataset, n: usize, path: &Path) -> Result<Vec<i64>> {
    let arr = ds
        .read_array::<i64>()
        .map(|a| a.iter().copied().collect::<Vec<_>>())
        .or_else(|_| {
            ds.read_array::<i32>()
                .map(|a| a.iter().map(|&x| i64::from(x)).collect())
        })
        .map_err(|e| h5(path, e))?;
    if arr.len() != n {
        return Err(Error::invalid(format!(
            "{}: {} has {} values, {n} expected",
            path.display(),
            ds.name(),
            arr.len()
        )));
    }
    Ok(arr)
}

/// Reads variable `name` of the `needed` blocks (the others' values are left empty), one
/// hyperslab `(var, run, z, y, x)` per run of consecutive needed blocks.
pub(super) fn read_field(
    files: &Files,
    h: &Hierarchy,
    name: &str,
    needed: &[bool],
) -> Result<Vec<Vec<f32>>> {
    let path = &files.path;
    let (_, ds_name, j) = files
        .vars
        .iter()
        .find(|(v, _, _)| v == name)
        .ok_or_else(|| Error::parameter(format!("{}: no variable '{name}'", path.display())))?;
    if !needed.contains(&true) {
        return Ok(vec![Vec::new(); h.blocks.len()]);
    }
    let file = open_h5(path)?;
    let ds = file
        .dataset(&format!("/{ds_name}"))
        .map_err(|e| h5(path, e))?;
    let n = h.blocks.len() as u64;
    let d = h.blocks[0].dims;
    let want = [n, d[2] as u64, d[1] as u64, d[0] as u64];
    if ds.shape().len() != 5 || ds.shape()[1..] != want || ds.shape()[0] <= *j {
        return Err(Error::invalid(format!(
            "{}: dataset {ds_name} has shape {:?}, expected (variables, {n}, {}, {}, {})",
            path.display(),
            ds.shape(),
            d[2],
            d[1],
            d[0]
        )));
    }
    let all = SliceInfoElem::Slice {
        start: 0,
        end: u64::MAX,
        step: 1,
    };
    let per = d[0] * d[1] * d[2];
    let mut out = vec![Vec::new(); n as usize];
    let mut i = 0;
    while i < needed.len() {
        if !needed[i] {
            i += 1;
            continue;
        }
        let end = (i..needed.len())
            .find(|&k| !needed[k])
            .unwrap_or(needed.len());
        let sel = SliceInfo {
            selections: vec![
                SliceInfoElem::Index(*j),
                SliceInfoElem::Slice {
                    start: i as u64,
                    end: end as u64,
                    step: 1,
                },
                all.clone(),
                all.clone(),
                all.clone(),
            ],
        };
        let arr = ds
            .read_slice::<f32>(&sel)
            .or_else(|_| ds.read_slice::<f64>(&sel).map(|a| a.mapv(|x| x as f32)))
            .map_err(|e| h5(path, e))?;
        let flat: Vec<f32> = arr.iter().copied().collect();
        if flat.len() != per * (end - i) {
            return Err(Error::invalid(format!(
                "{}: {ds_name}[{j}] blocks {i}..{end} read {} values, {} expected",
                path.display(),
                flat.len(),
                per * (end - i)
            )));
        }
        for (k, chunk) in flat.chunks_exact(per).enumerate() {
            out[i + k] = chunk.to_vec();
        }
        i = end;
    }
    Ok(out)
}
