//! `blueshift convert IN OUT`: converts between volume formats, and into the bricked
//! out-of-core layout (`.bsv`).
//!
//! The output format comes from OUT's extension: `.nrrd` (attached NRRD), `.nhdr` (detached
//! NRRD header plus `.raw` data beside it), `.raw` (headerless little-endian voxels) or `.bsv`
//! (bricked file with all levels of detail). NRRD and raw output keep the voxel type (e.g.
//! int16 CT stays int16) and the spacing unless `--type` or `--spacing` say otherwise. A
//! multi-channel input (a VTK file with SCALARS and VECTORS) writes its first channel to OUT
//! and every further channel to `OUT-stem_<channel>.ext`; `--channel` picks one. `.bsv`
//! output takes one channel (the first scalar one, or `--channel`); a vector field becomes
//! three files `OUT-stem_x.bsv`, `_y`, `_z`. Raw, uncompressed NRRD / MetaImage and gzip
//! NRRD input streams slice by slice; other input is read in core (within `--max-memory`).

use std::path::PathBuf;

use anyhow::{Context, Result};
use blueshift_volume::io::{DiskType, nrrd};
use blueshift_volume::ooc::{
    self, BrickLayout, GridSource, GzipFileSource, RawFileSource, SlabSource,
};
use blueshift_volume::{AnyGrid, Geometry, ScalarType};
use glam::Vec3;

use super::volume_common::{OutFormat, out_format, parse_disk_type, volume_outputs, write_volume};
use crate::output;

/// Arguments of `blueshift convert`.
#[derive(Clone, Debug, clap::Args)]
pub struct Args {
    /// Input volume (.raw with an Open SciVis name, .nrrd, .nhdr, .mhd, .mha, .vtk, .bsv).
    pub input: PathBuf,
    /// Output file; the extension picks the format (.nrrd, .nhdr, .raw, .bsv).
    pub output: PathBuf,
    /// Convert only this channel.
    #[arg(long)]
    pub channel: Option<String>,
    /// gzip the NRRD data (NRRD output only).
    #[arg(long)]
    pub gzip: bool,
    /// Voxel type to write (uint8, int8, uint16, int16, uint32, int32, float32, float64;
    /// .bsv: uint8, uint16, float32); integers round to nearest and saturate. Default: keep
    /// the input's type. Voxels are held as 32-bit floats in between: an (u)int32 volume with
    /// values beyond 2^24 is written as float32, and float64 values keep float32 precision.
    #[arg(long = "type", value_parser = parse_disk_type)]
    pub disk_type: Option<DiskType>,
    /// Override the spacing, as "sx,sy,sz".
    #[arg(long, value_parser = parse_vec3)]
    pub spacing: Option<Vec3>,
    /// Brick edge for .bsv output (even, 2..=1024).
    #[arg(long, default_value_t = 64)]
    pub brick: usize,
    /// AMR input (an Enzo parameter file, an Athena++ .athdf): the refinement level of the
    /// uniform grid written (0 = the root grid). Required for AMR input.
    #[arg(long)]
    pub level: Option<u32>,
    /// AMR input: how cells are filled. `covering`: yt's covering grid (each cell takes the
    /// value of the finest block of level <= LEVEL over it; coarser cells repeat);
    /// `interpolated`: the continuous reconstruction blueshift renders, sampled at the cell
    /// centres.
    #[arg(long, default_value = "covering", value_parser = ["covering", "interpolated"])]
    pub sampling: String,
    #[command(flatten)]
    pub input_args: super::volume_common::InputArgs,
}

fn parse_vec3(s: &str) -> Result<Vec3, String> {
    let v: Vec<f32> = s
        .split(',')
        .map(|c| {
            c.trim()
                .parse::<f32>()
                .map_err(|_| format!("'{c}' is not a number"))
        })
        .collect::<Result<_, _>>()?;
    match v.as_slice() {
        [x, y, z] if v.iter().all(|c| c.is_finite() && *c > 0.0) => Ok(Vec3::new(*x, *y, *z)),
        _ => Err(format!("'{s}' must be three positive numbers sx,sy,sz")),
    }
}

fn progress_bar(total: u64) -> crate::progress::Progress {
    crate::progress::Progress::new(
        total,
        "bricking [{bar:40}] {pos}/{len} slices ({eta})",
        "bricking",
        "slices",
    )
}

/// Runs `blueshift convert`.
pub fn run(args: Args) -> Result<()> {
    output::check_outputs(&[args.output.as_path()], &[args.input.as_path()])?;
    let fmt = out_format(&args.output)?;
    if args.gzip && fmt == OutFormat::Raw {
        anyhow::bail!("--gzip: only NRRD output is compressed; a .raw file is stored raw");
    }
    if blueshift_volume::amr::is_amr(&args.input) {
        return run_amr(&args, fmt);
    }
    if args.level.is_some() {
        anyhow::bail!("--level: only AMR input (an Enzo parameter file, an .athdf) has levels");
    }
    let ctx = || format!("cannot convert {}", args.input.display());
    let read = |p: &std::path::Path| args.input_args.read(p);
    let opts = args.input_args.read_options()?;
    if fmt == OutFormat::Bricked {
        bricked_type(&args)?;
        let layout = BrickLayout {
            brick: args.brick,
            ..BrickLayout::default()
        };
        // Stream straight from the file when its voxels are stored uncompressed, or
        // decompress a gzip NRRD slice by slice.
        let streamed: Option<Box<dyn SlabSource + Send>> = match opts.raw {
            Some(r) if r.components == 1 => Some(Box::new(
                RawFileSource::new(
                    &args.input,
                    r.offset,
                    r.disk,
                    r.endian,
                    Geometry::unit(r.dims),
                )
                .with_context(ctx)?,
            )),
            Some(_) => None,
            None => match RawFileSource::probe(&args.input).with_context(ctx)? {
                Some(s) => Some(Box::new(s)),
                None => GzipFileSource::probe(&args.input)
                    .with_context(ctx)?
                    .map(|s| Box::new(s) as Box<dyn SlabSource + Send>),
            },
        };
        if args.channel.is_none()
            && !opts.reject_non_finite
            && let Some(mut src) = streamed
        {
            return match args.spacing {
                Some(spacing) => brick(
                    &mut Spaced {
                        inner: &mut *src,
                        spacing,
                    },
                    &args,
                    "scalars",
                    layout,
                ),
                None => brick(&mut *src, &args, "scalars", layout),
            };
        }
        let mut vol = read(&args.input).map_err(|e| {
            if GzipFileSource::reverses_z(&args.input) {
                e.context(
                    "a gzip NRRD with a reversed z axis (a negative spacing) is read whole, \
                     as a gzip stream cannot be read backwards: store it raw to stream it",
                )
            } else {
                e
            }
        })?;
        if let Some(s) = args.spacing {
            vol.set_geometry(Geometry {
                spacing: s,
                ..*vol.geometry()
            })
            .with_context(ctx)?;
        }
        let ch = match &args.channel {
            Some(name) => vol.channel(name).ok_or_else(|| {
                anyhow::anyhow!("no channel '{name}' in {}", args.input.display())
            })?,
            None => vol
                .channels()
                .iter()
                .find(|c| !c.grid.is_vector())
                .or_else(|| vol.channels().first())
                .ok_or_else(|| anyhow::anyhow!("{} has no channel", args.input.display()))?,
        };
        let name = ch.name.clone();
        if args.channel.is_none() && vol.channels().len() > 1 {
            let all: Vec<&str> = vol.channels().iter().map(|c| c.name.as_str()).collect();
            errln!(
                "note: {} has {} channels ({}); a .bsv file holds one: converting '{name}' \
                 (--channel NAME converts another)",
                args.input.display(),
                all.len(),
                all.join(", ")
            );
        }
        return match &ch.grid {
            AnyGrid::U8(g) => brick(&mut GridSource(g), &args, &name, layout),
            AnyGrid::U16(g) => brick(&mut GridSource(g), &args, &name, layout),
            AnyGrid::F16(g) => brick(&mut GridSource(g), &args, &name, layout),
            AnyGrid::F32(g) => brick(&mut GridSource(g), &args, &name, layout),
            AnyGrid::Vec3(g) => brick_vector(g, &args, &name, layout),
        };
    }
    let mut vol = read(&args.input)?;
    if let Some(s) = args.spacing {
        vol.set_geometry(Geometry {
            spacing: s,
            ..*vol.geometry()
        })
        .with_context(ctx)?;
    }
    let opts = nrrd::WriteOptions {
        gzip: args.gzip,
        disk: args.disk_type,
    };
    // Every file written (further channels, a detached data file) against the input and
    // the files it names.
    let all = volume_outputs(&args.output, &vol, args.channel.as_deref(), &opts)?;
    let refs: Vec<&std::path::Path> = all.iter().map(PathBuf::as_path).collect();
    output::check_outputs(&refs, &[args.input.as_path()])?;
    let written = write_volume(&args.output, &vol, args.channel.as_deref(), &opts)?;
    for p in written {
        output::wrote(&p);
    }
    Ok(())
}

/// AMR input: one field resampled to the uniform grid of `--level`.
fn run_amr(args: &Args, fmt: OutFormat) -> Result<()> {
    use blueshift_volume::amr::Hierarchy;
    let ctx = || format!("cannot convert {}", args.input.display());
    let h = Hierarchy::open(&args.input).with_context(ctx)?;
    let Some(level) = args.level else {
        let levels: Vec<String> = (0..=h.max_level())
            .map(|l| {
                let n = h.level_dims(l);
                format!("{l} ({}x{}x{})", n[0], n[1], n[2])
            })
            .collect();
        anyhow::bail!(
            "--level: AMR input needs the level of the grid to write: {}",
            levels.join(", ")
        );
    };
    if level > h.max_level() {
        anyhow::bail!(
            "--level {level}: the hierarchy's finest level is {}",
            h.max_level()
        );
    }
    let name = match &args.channel {
        Some(n) => n.clone(),
        None => h.default_field().with_context(ctx)?.to_owned(),
    };
    let n = h.level_dims(level);
    crate::limits::check(
        format_args!("a {}x{}x{} grid of f32 (--level {level})", n[0], n[1], n[2]),
        blueshift_volume::budget::grid_bytes(n, 4, 1),
    )?;
    let limits = blueshift_volume::Limits::no_limits();
    let field = h.field(&name, &limits).with_context(ctx)?;
    let grid = if args.sampling == "covering" {
        field.covering_grid(level, &limits)
    } else {
        field.resample(level, &limits)
    }
    .with_context(ctx)?;
    let mut grid = grid;
    if let Some(s) = args.spacing {
        grid = blueshift_volume::Grid::from_vec(
            Geometry {
                spacing: s,
                ..*grid.geometry()
            },
            grid.into_vec(),
        )
        .with_context(ctx)?;
    }
    let unit = h
        .field_info(&name)
        .map(|f| f.unit.clone())
        .unwrap_or_default();
    errln!(
        "{}: {} AMR field {name} [{unit}] at level {level} ({}x{}x{}, {})",
        args.input.display(),
        h.code,
        n[0],
        n[1],
        n[2],
        args.sampling
    );
    if fmt == OutFormat::Bricked {
        bricked_type(args)?;
        let layout = BrickLayout {
            brick: args.brick,
            ..BrickLayout::default()
        };
        return brick(&mut GridSource(&grid), args, &name, layout);
    }
    let mut vol = blueshift_volume::Volume::new(*grid.geometry()).with_context(ctx)?;
    vol.push(&name, AnyGrid::F32(grid)).with_context(ctx)?;
    let opts = nrrd::WriteOptions {
        gzip: args.gzip,
        disk: args.disk_type,
    };
    let all = volume_outputs(&args.output, &vol, None, &opts)?;
    let refs: Vec<&std::path::Path> = all.iter().map(PathBuf::as_path).collect();
    output::check_outputs(&refs, &[args.input.as_path()])?;
    for p in write_volume(&args.output, &vol, None, &opts)? {
        output::wrote(&p);
    }
    Ok(())
}

/// A vector field as three scalar `.bsv` files, `OUT-stem_x.bsv`, `_y`, `_z` (as `synth`
/// writes velocities, and as Doppler scenes list them): all three or none.
fn brick_vector(
    g: &blueshift_volume::Grid<Vec3>,
    args: &Args,
    name: &str,
    layout: BrickLayout,
) -> Result<()> {
    let stem = args.output.with_extension("");
    let paths: Vec<PathBuf> = ["x", "y", "z"]
        .iter()
        .map(|a| PathBuf::from(format!("{}_{a}.bsv", stem.display())))
        .collect();
    let refs: Vec<&std::path::Path> = paths.iter().map(PathBuf::as_path).collect();
    output::check_outputs(&refs, &[args.input.as_path()])?;
    crate::limits::check(
        format_args!("one component of the vector field '{name}'"),
        blueshift_volume::budget::grid_bytes(g.geometry().dims, 4, 1),
    )?;
    let mut written: Vec<&PathBuf> = Vec::new();
    for (c, (path, axis)) in paths.iter().zip(["x", "y", "z"]).enumerate() {
        let component = g.data().iter().map(|v| v[c]).collect();
        let done = blueshift_volume::Grid::from_vec(*g.geometry(), component)
            .map_err(anyhow::Error::from)
            .and_then(|grid| {
                let one = Args {
                    output: path.clone(),
                    ..args.clone()
                };
                brick(
                    &mut GridSource(&grid),
                    &one,
                    &format!("{name}_{axis}"),
                    layout,
                )
            });
        if let Err(e) = done {
            for p in written {
                let _ = std::fs::remove_file(p);
            }
            return Err(e);
        }
        written.push(path);
    }
    Ok(())
}

/// `--gzip` does not apply to `.bsv` output, and `--type` only for the types a `.bsv` level
/// holds: refused rather than ignored. Returns the type to store, if `--type` gives one.
fn bricked_type(args: &Args) -> Result<Option<ScalarType>> {
    if args.gzip {
        anyhow::bail!("--gzip: only NRRD output is compressed; .bsv bricks are stored raw");
    }
    Ok(match args.disk_type {
        None => None,
        Some(DiskType::U8) => Some(ScalarType::U8),
        Some(DiskType::U16) => Some(ScalarType::U16),
        Some(DiskType::F32) => Some(ScalarType::F32),
        Some(t) => anyhow::bail!(
            "--type {}: a .bsv file stores uint8, uint16 or float32 voxels",
            t.scivis_name()
        ),
    })
}

/// A source with `--spacing` in place of its own.
struct Spaced<'a> {
    inner: &'a mut (dyn SlabSource + Send),
    spacing: Vec3,
}

impl SlabSource for Spaced<'_> {
    fn geometry(&self) -> Geometry {
        Geometry {
            spacing: self.spacing,
            ..self.inner.geometry()
        }
    }
    fn scalar_type(&self) -> ScalarType {
        self.inner.scalar_type()
    }
    fn read_slice(&mut self, z: usize, out: &mut [f32]) -> blueshift_volume::Result<()> {
        self.inner.read_slice(z, out)
    }
    fn in_place(&self) -> Option<&[f32]> {
        self.inner.in_place()
    }
}

/// A source's slices converted to `ty` as NRRD output converts them (integers round to
/// nearest and saturate, NaN becomes 0).
struct AsType<'a> {
    inner: &'a mut (dyn SlabSource + Send),
    ty: ScalarType,
}

impl SlabSource for AsType<'_> {
    fn geometry(&self) -> Geometry {
        self.inner.geometry()
    }
    fn scalar_type(&self) -> ScalarType {
        self.ty
    }
    fn read_slice(&mut self, z: usize, out: &mut [f32]) -> blueshift_volume::Result<()> {
        self.inner.read_slice(z, out)?;
        match self.ty {
            ScalarType::U8 => out.iter_mut().for_each(|v| *v = f32::from(v.round() as u8)),
            ScalarType::U16 => out
                .iter_mut()
                .for_each(|v| *v = f32::from(v.round() as u16)),
            _ => {}
        }
        Ok(())
    }
}

/// A note on stderr, after a conversion, when the bricked file is more than eight times the
/// volume's voxels: cubic bricks padding a thin volume (4096 x 4096 x 1 in bricks of 64 is
/// 2.8 GB for 17 MB) or tiny bricks' aprons (edge 2 stores 4^3 values for 8 voxels). Names
/// the cause and the brick edge that writes the smallest file.
fn padding_note(dims: [usize; 3], layout: BrickLayout, t: blueshift_volume::ScalarType) {
    let size = |brick| {
        ooc::bricked_file_bytes(dims, BrickLayout { brick, ..layout }, t).unwrap_or(u64::MAX)
    };
    let voxels = (dims[0] as u64) * (dims[1] as u64) * (dims[2] as u64);
    let data = voxels.saturating_mul(t.size_bytes() as u64);
    let bytes = size(layout.brick);
    if bytes / 8 <= data.max(1 << 20) {
        return;
    }
    let best = [8, 16, 32, 64, 128]
        .into_iter()
        .filter(|&b| b != layout.brick)
        .map(|b| (b, size(b)))
        .min_by_key(|&(_, s)| s);
    let fmt = blueshift_volume::budget::format_bytes;
    let [x, y, z] = dims;
    // The two causes: whole cubic bricks padding thin axes, and each brick's apron.
    let b = layout.brick;
    let padded = dims
        .iter()
        .map(|&d| (d.div_ceil(b) * b) as f64)
        .product::<f64>();
    let pad = padded / voxels.max(1) as f64;
    let stored = b + 2 * layout.apron;
    let apron = (stored as f64 / b as f64).powi(3);
    let cause = if pad >= apron {
        format!("bricks are cubes, and whole bricks hold {pad:.1} times its voxels")
    } else {
        format!(
            "each brick stores a {}-voxel apron around its {b}^3 voxels, {stored}^3 values \
             ({apron:.1} times)",
            layout.apron
        )
    };
    let mut note = format!(
        "note: bricks of edge {b} made this {x}x{y}x{z} volume {}, {} times its {} of \
         voxels: {cause}",
        fmt(bytes),
        bytes / data.max(1),
        fmt(data)
    );
    if let Some((b, s)) = best.filter(|&(_, s)| s < bytes) {
        note.push_str(&format!("; --brick {b} writes {}", fmt(s)));
    }
    errln!("{note}");
}

fn brick(
    src: &mut (dyn SlabSource + Send),
    args: &Args,
    name: &str,
    layout: BrickLayout,
) -> Result<()> {
    if let Some(ty) = bricked_type(args)?
        && ty != src.scalar_type()
    {
        return brick(
            &mut AsType { inner: src, ty },
            &Args {
                disk_type: None,
                ..args.clone()
            },
            name,
            layout,
        );
    }
    let (dims, ty) = (src.geometry().dims, src.scalar_type());
    let pb = progress_bar(src.geometry().dims[2] as u64);
    output::write_via_temp_path(&args.output, |tmp| {
        ooc::convert_within(
            src,
            tmp,
            name,
            layout,
            crate::limits::budget(),
            &mut |done, total| {
                pb.set_length(total);
                pb.set_position(done);
            },
        )
        .with_context(|| format!("cannot convert {}", args.input.display()))
    })?;
    pb.finish();
    output::wrote(&args.output);
    padding_note(dims, layout, ty);
    Ok(())
}
