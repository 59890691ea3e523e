//! `blueshift info FILE [--json]`: dimensions, type, spacing, value range and a histogram
//! summary of any volume file blueshift reads.

use std::path::PathBuf;

use std::fmt::Write as _;

use anyhow::Result;
use blueshift_volume::io::detect_format;
use blueshift_volume::{AnyGrid, Channel};
use serde_json::json;

/// Arguments of `blueshift info`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Volume file: .raw (Open SciVis name_XxYxZ_dtype.raw), .nrrd, .nhdr, .mhd, .mha, .vtk or
    /// .bsv; or a FITS file (.fits, the cubes `doppler --cube` writes): dimensions, WCS, BUNIT.
    pub file: PathBuf,
    /// Print one JSON object instead of text.
    #[arg(long)]
    pub json: bool,
    /// Histogram bins (linear between min and max).
    #[arg(long, default_value_t = 16, value_parser = clap::value_parser!(u32).range(1..=4096))]
    pub bins: u32,
    #[command(flatten)]
    pub input: super::volume_common::InputArgs,
}

/// Statistics of one channel over its finite values (vector channels: all components).
struct Stats {
    count: usize,
    non_finite: usize,
    min: f64,
    max: f64,
    mean: f64,
    percentiles: [(u32, f64); 5],
    counts: Vec<u64>,
}

fn stats(c: &Channel, bins: usize) -> Option<Stats> {
    let mut vals: Vec<f32> = match &c.grid {
        AnyGrid::Vec3(g) => g.data().iter().flat_map(|v| v.to_array()).collect(),
        other => other.to_f32_vec(),
    };
    let total = vals.len();
    vals.retain(|v| v.is_finite());
    if vals.is_empty() {
        return None;
    }
    vals.sort_by(f32::total_cmp);
    let n = vals.len();
    let min = f64::from(vals[0]);
    let max = f64::from(vals[n - 1]);
    let mean = vals.iter().map(|&v| f64::from(v)).sum::<f64>() / n as f64;
    let pct = |p: u32| f64::from(vals[((n - 1) * p as usize) / 100]);
    let mut counts = vec![0u64; bins];
    let width = (max - min) / bins as f64;
    for &v in &vals {
        let b = if width > 0.0 {
            ((f64::from(v) - min) / width) as usize
        } else {
            0
        };
        counts[b.min(bins - 1)] += 1;
    }
    Some(Stats {
        count: n,
        non_finite: total - n,
        min,
        max,
        mean,
        percentiles: [1, 25, 50, 75, 99].map(|p| (p, pct(p))),
        counts,
    })
}

fn type_name(c: &Channel) -> String {
    match c.stored_as {
        Some(d) if c.grid.is_vector() => format!("3 x {}", d.scivis_name()),
        Some(d) => d.scivis_name().to_string(),
        None if c.grid.is_vector() => "3 x float32".to_string(),
        None => match c.grid.scalar_type() {
            blueshift_volume::ScalarType::U8 => "uint8".into(),
            blueshift_volume::ScalarType::U16 => "uint16".into(),
            blueshift_volume::ScalarType::F16 => "float16".into(),
            _ => "float32".into(),
        },
    }
}

/// True for `.fits`, `.fit`, `.fts` names and files that start with the FITS `SIMPLE` card.
fn is_fits(path: &std::path::Path) -> bool {
    let ext = path
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    if ["fits", "fit", "fts"].contains(&ext.as_str()) {
        return true;
    }
    let mut head = [0u8; 9];
    std::fs::File::open(path)
        .and_then(|mut f| std::io::Read::read_exact(&mut f, &mut head))
        .is_ok()
        && &head == b"SIMPLE  ="
}

/// `blueshift info` of a FITS file (the cubes `doppler --cube` writes, or any FITS image):
/// dimensions, the WCS of every axis, BUNIT and the data range.
fn run_fits(args: &Args) -> Result<()> {
    let path = &args.file;
    let bytes =
        std::fs::read(path).map_err(|e| anyhow::anyhow!("cannot read {}: {e}", path.display()))?;
    let h = blueshift_doppler::read_fits(&bytes)
        .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    let dims: Vec<usize> = h.axes.iter().map(|a| a.length).collect();
    let restwav = h.get("RESTWAV").and_then(|v| v.as_f64());
    if args.json {
        let axes: Vec<_> = h
            .axes
            .iter()
            .map(|a| {
                json!({"length": a.length, "ctype": a.ctype, "cunit": a.cunit,
                       "crval": a.crval, "cdelt": a.cdelt, "crpix": a.crpix})
            })
            .collect();
        let out = json!({
            "file": path.display().to_string(),
            "format": "fits",
            "bitpix": h.bitpix,
            "dims": dims,
            "axes": axes,
            "bunit": h.bunit,
            "restwav_m": restwav,
            "min": h.data_range.map(|r| r.0),
            "max": h.data_range.map(|r| r.1),
        });
        outln!("{out}");
        return Ok(());
    }
    let mut t = String::new();
    writeln!(t, "file: {}", path.display())?;
    let kind = match h.bitpix {
        -32 => "IEEE f32",
        -64 => "IEEE f64",
        _ => "integer",
    };
    writeln!(t, "format: FITS (BITPIX {}, {kind})", h.bitpix)?;
    let d: Vec<String> = dims.iter().map(ToString::to_string).collect();
    writeln!(
        t,
        "dims: {} ({} values)",
        d.join(" x "),
        dims.iter().product::<usize>()
    )?;
    for (i, a) in h.axes.iter().enumerate() {
        let unit = if a.cunit.is_empty() {
            String::new()
        } else {
            format!(" {}", a.cunit)
        };
        writeln!(
            t,
            "axis {}: {:<8} {} pixels, CRVAL {:e}{unit} at CRPIX {}, CDELT {:e}{unit}",
            i + 1,
            if a.ctype.is_empty() { "-" } else { &a.ctype },
            a.length,
            a.crval,
            a.crpix,
            a.cdelt
        )?;
    }
    if let Some(r) = restwav {
        writeln!(t, "RESTWAV: {r:e} m")?;
    }
    writeln!(
        t,
        "BUNIT: {}",
        if h.bunit.is_empty() { "-" } else { &h.bunit }
    )?;
    if let Some((lo, hi)) = h.data_range {
        writeln!(t, "data: min {lo:.6e}  max {hi:.6e}")?;
    }
    out!("{t}");
    Ok(())
}

/// Runs `blueshift info`.
pub fn run(args: Args) -> Result<()> {
    // A FIFO or device would block the format sniffing below forever (an AMR output may be
    // a folder).
    if !args.file.is_dir() {
        blueshift_volume::io::check_regular_file(&args.file)?;
    }
    if args.input.raw_dims.is_none() && is_fits(&args.file) {
        return run_fits(&args);
    }
    if blueshift_volume::amr::is_amr(&args.file) {
        return run_amr(&args);
    }
    let format = if args.input.raw_dims.is_some() {
        blueshift_volume::io::Format::Raw
    } else {
        detect_format(&args.file).map_err(|e| anyhow::anyhow!("{e}: {}", args.file.display()))?
    };
    let bricked = format == blueshift_volume::io::Format::Bricked;
    let (vol, sampled) = read_volume(&args, bricked)?;
    let bins = args.bins as usize;
    // Bricked files also list their levels of detail.
    let lod = if bricked {
        let f = blueshift_volume::ooc::BrickedFile::open(&args.file, 1)
            .map_err(|e| super::volume_common::with_path(&e, &args.file))?;
        Some(
            (0..f.levels())
                .filter_map(|l| f.level_geometry(l))
                .collect::<Vec<_>>(),
        )
    } else {
        None
    };
    // The file's own geometry (level 0), whichever level the statistics come from.
    let g = lod
        .as_ref()
        .and_then(|l| l.first().copied())
        .unwrap_or(*vol.geometry());
    let sampled_note = sampled.map(|(level, need)| {
        let d = vol.geometry().dims;
        format!(
            "statistics of level {level} ({}x{}x{}), the finest level within --max-memory \
             (level 0 needs {})",
            d[0],
            d[1],
            d[2],
            blueshift_volume::budget::format_bytes(need)
        )
    });
    let per: Vec<_> = vol.channels().iter().map(|c| (c, stats(c, bins))).collect();
    if args.json {
        let chans: Vec<_> = per
            .iter()
            .map(|(c, s)| {
                let mut o = json!({
                    "name": c.name,
                    "type": type_name(c),
                    "memory_type": c.grid.scalar_type().name(),
                    "components": if c.grid.is_vector() { 3 } else { 1 },
                });
                if let Some(s) = s {
                    o["min"] = json!(s.min);
                    o["max"] = json!(s.max);
                    o["mean"] = json!(s.mean);
                    o["finite_count"] = json!(s.count);
                    o["non_finite_count"] = json!(s.non_finite);
                    o["percentiles"] = json!(
                        s.percentiles
                            .iter()
                            .map(|(p, v)| (format!("p{p}"), json!(*v)))
                            .collect::<serde_json::Map<String, serde_json::Value>>()
                    );
                    o["histogram"] =
                        json!({ "bins": bins, "min": s.min, "max": s.max, "counts": s.counts });
                } else {
                    o["min"] = serde_json::Value::Null;
                    o["max"] = serde_json::Value::Null;
                }
                o
            })
            .collect();
        let first = &chans[0];
        let mut out = json!({
            "file": args.file.display().to_string(),
            "format": format!("{format:?}").to_lowercase(),
            "dims": g.dims,
            "spacing": g.spacing.to_array(),
            "origin": g.origin.to_array(),
            "type": first["type"],
            "min": first["min"],
            "max": first["max"],
            "channels": chans,
        });
        if let Some(levels) = &lod {
            out["levels"] = json!(levels.iter().map(|g| g.dims).collect::<Vec<_>>());
        }
        if let Some((level, _)) = sampled {
            out["statistics_level"] = json!(level);
        }
        outln!("{out}");
        return Ok(());
    }
    let mut t = String::new();
    writeln!(t, "file: {}", args.file.display())?;
    writeln!(t, "format: {format:?}")?;
    writeln!(
        t,
        "dims: {} x {} x {} ({} voxels)",
        g.dims[0],
        g.dims[1],
        g.dims[2],
        g.voxel_count()
    )?;
    writeln!(
        t,
        "spacing: {} {} {}",
        g.spacing.x, g.spacing.y, g.spacing.z
    )?;
    writeln!(t, "origin: {} {} {}", g.origin.x, g.origin.y, g.origin.z)?;
    if let Some(levels) = &lod {
        let d: Vec<String> = levels
            .iter()
            .map(|g| format!("{}x{}x{}", g.dims[0], g.dims[1], g.dims[2]))
            .collect();
        writeln!(t, "levels of detail: {}", d.join(", "))?;
    }
    if let Some(note) = &sampled_note {
        writeln!(t, "{note}")?;
    }
    for (c, s) in &per {
        writeln!(
            t,
            "channel '{}': type {} (in memory {})",
            c.name,
            type_name(c),
            c.grid.scalar_type().name()
        )?;
        match s {
            None => writeln!(t, "  no finite values")?,
            Some(s) => {
                writeln!(
                    t,
                    "  min {:.6e}  max {:.6e}  mean {:.6e}",
                    s.min, s.max, s.mean
                )?;
                if s.non_finite > 0 {
                    writeln!(t, "  {} non-finite values (NaN/Inf)", s.non_finite)?;
                }
                let p: Vec<String> = s
                    .percentiles
                    .iter()
                    .map(|(p, v)| format!("p{p} {v:.4e}"))
                    .collect();
                writeln!(t, "  percentiles: {}", p.join("  "))?;
                if s.min > 0.0 {
                    writeln!(t, "  dynamic range: {:.2} decades", (s.max / s.min).log10())?;
                }
                let peak = s.counts.iter().copied().max().unwrap_or(1).max(1);
                writeln!(
                    t,
                    "  histogram ({} bins, {:.4e} .. {:.4e}):",
                    bins, s.min, s.max
                )?;
                for (i, &n) in s.counts.iter().enumerate() {
                    let lo = s.min + (s.max - s.min) * i as f64 / bins as f64;
                    let bar = "#".repeat(((n as f64 / peak as f64) * 40.0).ceil() as usize);
                    writeln!(t, "    {lo:>12.4e} {n:>10} {bar}")?;
                }
            }
        }
    }
    out!("{t}");
    Ok(())
}

/// The volume whose statistics `info` gives: the file read whole within `--max-memory`;
/// for a `.bsv` file whose level 0 does not fit, the finest coarser level that does (with
/// the copy the statistics sort), and that level with the bytes level 0 needs.
fn read_volume(
    args: &Args,
    bricked: bool,
) -> Result<(blueshift_volume::Volume, Option<(usize, u64)>)> {
    use blueshift_volume::budget::grid_bytes;
    let opts = args.input.read_options()?;
    let err = match blueshift_volume::read_with(&args.file, &opts) {
        Ok(v) => return Ok((v, None)),
        Err(e) => e,
    };
    if bricked && matches!(err, blueshift_volume::Error::Limits(_)) {
        let with_path =
            |e: &blueshift_volume::Error| super::volume_common::with_path(e, &args.file);
        let f =
            blueshift_volume::ooc::BrickedFile::open(&args.file, 1).map_err(|e| with_path(&e))?;
        let budget = crate::limits::budget().bytes();
        for level in 1..f.levels() {
            let Some(g) = f.level_geometry(level) else {
                break;
            };
            if grid_bytes(g.dims, 4, 2) > budget {
                continue;
            }
            let grid = f
                .load_level(level, &opts.limits)
                .map_err(|e| with_path(&e))?;
            let stored_as = blueshift_volume::DiskType::natural(f.level0_type());
            let mut v = blueshift_volume::Volume::new(g).map_err(|e| with_path(&e))?;
            v.push_channel(Channel {
                name: f.channel_name().to_owned(),
                grid,
                stored_as: Some(stored_as),
            })
            .map_err(|e| with_path(&e))?;
            let need = grid_bytes(f.geometries()[0].dims, 4, 2);
            return Ok((v, Some((level, need))));
        }
    }
    Err(super::volume_common::read_error(&err, &args.file))
}

/// AMR output (an Enzo parameter file, an Athena++ `.athdf`): levels, blocks, fields, units.
fn run_amr(args: &Args) -> Result<()> {
    let h = blueshift_volume::amr::Hierarchy::open(&args.file)
        .map_err(|e| super::volume_common::with_path(&e, &args.file))?;
    if !args.json {
        out!("{}", blueshift_volume::amr::describe(&h));
        return Ok(());
    }
    let levels: Vec<_> = (0..=h.max_level())
        .map(|l| {
            let blocks: Vec<_> = h.blocks.iter().filter(|b| b.level == l).collect();
            json!({
                "level": l,
                "blocks": blocks.len(),
                "cells": blocks.iter().map(|b| b.cells()).sum::<usize>(),
                "cell_size": h.cell_size(l).x,
                "uniform_dims": h.level_dims(l),
            })
        })
        .collect();
    let fields: Vec<_> = h
        .fields
        .iter()
        .map(|f| json!({ "name": f.name, "unit": f.unit, "code_to_unit": f.to_unit }))
        .collect();
    let out = json!({
        "file": args.file.display().to_string(),
        "format": "amr",
        "code": h.code,
        "blocks": h.blocks.len(),
        "levels": levels,
        "refinement_ratio": h.ratio,
        "root_dims": h.root_dims,
        "domain": [h.domain_lo.to_array(), h.domain_hi.to_array()],
        "time": h.time,
        "redshift": h.redshift,
        "length_unit_cm": h.length_unit_cm,
        "fields": fields,
    });
    outln!("{}", serde_json::to_string_pretty(&out)?);
    Ok(())
}
