//! `blueshift doppler` and `blueshift demo`: Doppler volume rendering of the synthetic galaxy
//! and hydrogen shell (EXR + PNG, picked spectra as CSV and plots, step-by-step traces).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result, anyhow, bail};
use blueshift_spectrum::{DopplerModel, PiecewiseLinear};
use blueshift_tracking::doppler::{
    ColourMatrix, DisplayOptions, DopplerImage, DopplerScene, DopplerSettings, Exposure, SceneFile,
    SpectralIntegrator, pixel_spectrum, render_doppler, trace_ray,
};
use clap::Parser;
use plotters::style::RGBColor;

use crate::output::{write_bytes_atomic, write_via_temp_path};
use crate::plot::{Series, line_plot};

/// Arguments of `blueshift doppler`.
#[derive(Debug, Parser)]
pub struct Args {
    /// Scene JSON mapping volume files to species, temperature and velocity with units
    /// (format: blueshift_tracking::doppler::scene_file; example: scenes/enzo-moving7.json).
    /// Replaces --synth/--res; --species then selects parts of the scene by name (bb for the
    /// black body) and the factor flags override the file's factors.
    #[arg(long, conflicts_with_all = ["synth", "res"])]
    pub scene: Option<PathBuf>,
    /// Synthetic dataset: galaxy or shell.
    #[arg(long, default_value = "galaxy")]
    pub synth: String,
    /// Voxels per edge of the synthetic dataset.
    #[arg(long, default_value_t = 64)]
    pub res: usize,
    /// Integrator: pwl, banded:N (paper's nearest-band shift) or banded-ec:N (energy-conserving).
    #[arg(long, default_value = "pwl")]
    pub integrator: String,
    /// Doppler model: classical (Eq. 6/7) or relativistic (Eq. 4/5).
    #[arg(long, default_value = "classical")]
    pub doppler: String,
    /// Relativistic radiance transform (I_nu / nu^3 invariant).
    #[arg(long)]
    pub invariant: bool,
    /// Species, comma-separated: bb, H, He, C (default: bb,H for galaxy, H for shell).
    #[arg(long)]
    pub species: Option<String>,
    /// Velocity factor (0: Doppler off); default 1 or the scene file's.
    #[arg(long)]
    pub velocity_factor: Option<f64>,
    /// Temperature factor; default 1 or the scene file's.
    #[arg(long)]
    pub temperature_factor: Option<f64>,
    /// Line emission factor; default 1 or the scene file's.
    #[arg(long)]
    pub emission_factor: Option<f64>,
    /// Line absorption factor (0: emission only); default 0 or the scene file's.
    #[arg(long)]
    pub absorption_factor: Option<f64>,
    /// Black-body factor; default 1 or the scene file's.
    #[arg(long)]
    pub blackbody_factor: Option<f64>,
    /// Subtract the mean velocity.
    #[arg(long)]
    pub subtract_mean_velocity: bool,
    /// Merge tolerance relative to a spectrum's maximum.
    #[arg(long, default_value_t = 1e-4)]
    pub merge_tol: f64,
    /// Per-ray piece budget (coarser merges beyond it).
    #[arg(long, default_value_t = 4096)]
    pub piece_budget: usize,
    /// Ray step, world units (default half a voxel).
    #[arg(long)]
    pub step: Option<f32>,
    /// Line width, nm.
    #[arg(long, default_value_t = 1.0)]
    pub line_width: f64,
    /// Pick a pixel X,Y (repeatable): its spectrum as CSV and PNG next to the output.
    #[arg(long, value_parser = parse_xy)]
    pub pick: Vec<(u32, u32)>,
    /// Trace a pixel's ray X,Y: the spectrum after each step as CSV and a plot.
    #[arg(long, value_parser = parse_xy)]
    pub trace: Option<(u32, u32)>,
    /// Tilt of the orthographic view about the x axis, degrees (0: along +z, the default
    /// axis-aligned view; 90: along +y, a disk seen edge-on).
    #[arg(long, default_value_t = 0.0)]
    pub inclination: f32,
    /// Image width.
    #[arg(long, default_value_t = 256)]
    pub width: u32,
    /// Image height.
    #[arg(long, default_value_t = 256)]
    pub height: u32,
    /// Display colour matrix: srgb or cie (Eq. 10).
    #[arg(long, default_value = "srgb")]
    pub matrix: String,
    /// Display exposure: a number multiplies XYZ; default: the 99th percentile of Y maps to 1.
    #[arg(long)]
    pub exposure: Option<f64>,
    /// Output EXR (XYZ); the PNG goes next to it.
    #[arg(long, default_value = "doppler.exr")]
    pub out: PathBuf,
    /// Spectral cube, line broadening and view direction.
    #[command(flatten)]
    pub cube: super::doppler_cube::CubeArgs,
}

fn parse_xy(s: &str) -> std::result::Result<(u32, u32), String> {
    let (a, b) = s.split_once(',').ok_or("expected X,Y")?;
    Ok((
        a.trim().parse().map_err(|_| format!("bad X in '{s}'"))?,
        b.trim().parse().map_err(|_| format!("bad Y in '{s}'"))?,
    ))
}

fn build(args: &Args) -> Result<(DopplerScene, DopplerSettings)> {
    let mut scene = if let Some(path) = &args.scene {
        let file = SceneFile::read(path)?;
        let tokens: Option<Vec<&str>> = args
            .species
            .as_deref()
            .map(|sp| sp.split(',').filter(|t| !t.trim().is_empty()).collect());
        file.load_selected(tokens.as_deref())?
    } else {
        if !(2..=512).contains(&args.res) {
            bail!("--res {} must be 2..=512", args.res);
        }
        let (vol, default_species) = match args.synth.as_str() {
            "galaxy" => (blueshift_volume::synth::galaxy(args.res, 1)?, "bb,H"),
            "shell" | "hydrogen-shell" => {
                (blueshift_volume::synth::hydrogen_shell(args.res, 1)?, "H")
            }
            other => bail!("unknown --synth '{other}' (galaxy, shell)"),
        };
        let sp = args
            .species
            .clone()
            .unwrap_or_else(|| default_species.to_owned());
        let tokens: Vec<&str> = sp.split(',').filter(|t| !t.trim().is_empty()).collect();
        DopplerScene::from_volume(&vol, &tokens)?
    };
    for (flag, v, slot) in [
        (
            "--velocity-factor",
            args.velocity_factor,
            &mut scene.factors.velocity,
        ),
        (
            "--temperature-factor",
            args.temperature_factor,
            &mut scene.factors.temperature,
        ),
        (
            "--emission-factor",
            args.emission_factor,
            &mut scene.factors.emission,
        ),
        (
            "--absorption-factor",
            args.absorption_factor,
            &mut scene.factors.absorption,
        ),
        (
            "--blackbody-factor",
            args.blackbody_factor,
            &mut scene.factors.blackbody,
        ),
    ] {
        if let Some(v) = v {
            if !(v.is_finite() && v >= 0.0) {
                bail!("{flag} {v} must be finite and >= 0");
            }
            *slot = v;
        }
    }
    if args.subtract_mean_velocity {
        scene.subtract_mean_velocity();
    }
    let mut st = DopplerSettings::default_for(&scene, args.width, args.height);
    st.integrator = args.integrator.parse::<SpectralIntegrator>()?;
    st.model = match args.doppler.as_str() {
        "classical" => DopplerModel::Classical,
        "relativistic" => DopplerModel::Relativistic,
        other => bail!("unknown --doppler '{other}' (classical, relativistic)"),
    };
    st.invariant = args.invariant;
    if args.inclination != 0.0 {
        if !(args.inclination.is_finite() && args.inclination.abs() <= 90.0) {
            bail!("--inclination {} must lie in [-90, 90]", args.inclination);
        }
        let (lo, hi) = scene.geometry().world_bounds();
        let (centre, radius) = (0.5 * (lo + hi), 0.5 * (hi - lo).length());
        let (si, ci) = args.inclination.to_radians().sin_cos();
        let dir = glam::Vec3::new(0.0, si, ci);
        st.camera.target = centre;
        st.camera.eye = centre - dir * (radius + 1.0);
        st.camera.up = glam::Vec3::new(0.0, ci, -si);
        st.camera.projection = blueshift_tracking::Projection::Orthographic {
            height: (hi - lo).x.max((hi - lo).y),
        };
    }
    st.merge_tolerance = args.merge_tol;
    st.piece_budget = args.piece_budget;
    st.step = args.step;
    st.line_width_nm = args.line_width;
    Ok((scene, st))
}

fn display(args: &Args) -> Result<DisplayOptions> {
    Ok(DisplayOptions {
        matrix: match args.matrix.as_str() {
            "srgb" => ColourMatrix::Srgb,
            "cie" => ColourMatrix::CieRgbEq10,
            other => bail!("unknown --matrix '{other}' (srgb, cie)"),
        },
        exposure: match args.exposure {
            Some(k) if k.is_finite() && k > 0.0 => Exposure::Fixed(k),
            Some(k) => bail!("--exposure {k} must be finite and > 0"),
            None => Exposure::Percentile(99.0),
        },
    })
}

fn render(scene: &DopplerScene, st: &DopplerSettings) -> Result<DopplerImage> {
    let bar = indicatif::ProgressBar::new(u64::from(st.height));
    bar.set_style(
        indicatif::ProgressStyle::with_template("{bar:30} {pos}/{len} rows [{elapsed}]")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    let img = render_doppler(scene, st, &|| bar.inc(1))?;
    bar.finish_and_clear();
    Ok(img)
}

fn write_exr(path: &Path, img: &DopplerImage) -> Result<()> {
    let buf = image::Rgba32FImage::from_fn(img.width, img.height, |x, y| {
        let p = img.xyz[(y * img.width + x) as usize];
        image::Rgba([p[0] as f32, p[1] as f32, p[2] as f32, 1.0])
    });
    write_via_temp_path(path, |p| {
        buf.save_with_format(p, image::ImageFormat::OpenExr)
            .with_context(|| format!("cannot write {}", path.display()))
    })
}

fn write_png(path: &Path, w: u32, h: u32, rgb: Vec<u8>) -> Result<()> {
    let img = image::RgbImage::from_raw(w, h, rgb).ok_or_else(|| anyhow!("image size"))?;
    write_via_temp_path(path, |p| {
        img.save_with_format(p, image::ImageFormat::Png)
            .with_context(|| format!("cannot write {}", path.display()))
    })
}

/// The spectrum as points whose linear interpolation is exact: every piece's end points
/// (a jump appears as two points at one wavelength; gaps between pieces drop to zero) plus
/// a uniform grid of 801 points over `range` for the zero baseline. Narrow lines are never
/// lost between grid points.
fn samples(s: &PiecewiseLinear, range: (f64, f64)) -> Vec<(f64, f64)> {
    let mut pts: Vec<(f64, f64)> = Vec::with_capacity(2 * s.piece_count() + 801);
    let mut prev_end: Option<f64> = None;
    for p in s.pieces() {
        if prev_end != Some(p.start_nm) {
            if let Some(e) = prev_end {
                pts.push((e, 0.0));
            }
            pts.push((p.start_nm, 0.0));
        }
        pts.push((p.start_nm, p.value_start));
        pts.push((p.end_nm, p.value_end));
        prev_end = Some(p.end_nm);
    }
    if let Some(e) = prev_end {
        pts.push((e, 0.0));
    }
    // Break points are already sorted (pieces are ordered and disjoint).
    let breaks: Vec<f64> = pts.iter().map(|p| p.0).collect();
    for i in 0..=800 {
        let l = range.0 + (range.1 - range.0) * f64::from(i) / 800.0;
        // Grid points strictly inside a piece or a gap add nothing but the baseline; skip
        // those that coincide with a break point so jumps keep their order.
        if breaks.binary_search_by(|b| b.total_cmp(&l)).is_err() {
            pts.push((l, s.eval(l)));
        }
    }
    pts.sort_by(|a, b| a.0.total_cmp(&b.0));
    pts
}

fn spectrum_csv(s: &PiecewiseLinear, range: (f64, f64)) -> String {
    let mut out = String::from("wavelength_nm,value\n");
    for (l, v) in samples(s, range) {
        let _ = writeln!(out, "{l},{v:e}");
    }
    out
}

fn sibling(out: &Path, suffix: &str) -> PathBuf {
    let stem = out
        .file_stem()
        .and_then(|s| s.to_str())
        .unwrap_or("doppler");
    out.with_file_name(format!("{stem}{suffix}"))
}

const COLOURS: [RGBColor; 6] = [
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
    RGBColor(148, 103, 189),
    RGBColor(255, 127, 14),
    RGBColor(23, 190, 207),
];

/// Runs `blueshift doppler`.
pub fn run(args: Args) -> Result<()> {
    let (scene, mut st) = build(&args)?;
    super::doppler_cube::apply_view(&args.cube, &scene, &mut st)?;
    st.broadening = super::doppler_cube::broadening(&args.cube)?;
    if args.cube.cube.is_some() {
        return super::doppler_cube::run_cube(&args.cube, &scene, &st);
    }
    let disp = display(&args)?;
    for &(x, y) in args.pick.iter().chain(args.trace.iter()) {
        if x >= st.width || y >= st.height {
            bail!(
                "pixel {x},{y} is outside the {}x{} image",
                st.width,
                st.height
            );
        }
    }
    let start = Instant::now();
    let img = render(&scene, &st)?;
    let secs = start.elapsed().as_secs_f64();
    write_exr(&args.out, &img)?;
    let png = args.out.with_extension("png");
    write_png(&png, img.width, img.height, disp.to_rgb8(&img))?;
    let mut series = Vec::new();
    for (i, &(x, y)) in args.pick.iter().enumerate() {
        let s = pixel_spectrum(&scene, &st, x, y)?;
        write_bytes_atomic(
            &sibling(&args.out, &format!("_pick_{x}_{y}.csv")),
            spectrum_csv(&s, st.range_nm).as_bytes(),
        )?;
        series.push(Series {
            label: format!("pixel {x},{y}"),
            points: samples(&s, st.range_nm),
            colour: COLOURS[i % COLOURS.len()],
        });
    }
    if !series.is_empty() {
        line_plot(
            &sibling(&args.out, "_picks.png"),
            "picked spectra",
            "wavelength (nm)",
            "spectral radiance",
            &series,
            (900, 500),
        )?;
    }
    if let Some((x, y)) = args.trace {
        let steps = trace_ray(&scene, &st, x, y)?;
        let mut csv = String::from("step,t,radial_velocity_m_per_s,wavelength_nm,value\n");
        for (i, s) in steps.iter().enumerate() {
            for (l, v) in samples(&s.spectrum, st.range_nm).into_iter().step_by(4) {
                let _ = writeln!(csv, "{i},{},{:e},{l},{v:e}", s.t, s.radial_velocity_m_per_s);
            }
        }
        write_bytes_atomic(
            &sibling(&args.out, &format!("_trace_{x}_{y}.csv")),
            csv.as_bytes(),
        )?;
        // Small multiples as overlaid curves: 6 evenly spaced steps.
        let n = steps.len();
        if n > 0 {
            let series: Vec<Series> = (0..6)
                .map(|k| (k * (n - 1)) / 5)
                .enumerate()
                .map(|(c, i)| Series {
                    label: format!("step {i}"),
                    points: samples(&steps[i].spectrum, st.range_nm),
                    colour: COLOURS[c % COLOURS.len()],
                })
                .collect();
            line_plot(
                &sibling(&args.out, &format!("_trace_{x}_{y}.png")),
                "step-by-step accumulation",
                "wavelength (nm)",
                "spectral radiance",
                &series,
                (900, 500),
            )?;
        }
    }
    println!(
        "wrote {} and {} ({}x{}, {:.2} s, pieces per ray mean {:.1} max {}, budget fallbacks {})",
        args.out.display(),
        png.display(),
        img.width,
        img.height,
        secs,
        img.pieces.mean,
        img.pieces.max,
        img.pieces.fallback_rays
    );
    Ok(())
}

/// Arguments of `blueshift demo`.
#[derive(Debug, Parser)]
pub struct DemoArgs {
    /// Output folder.
    pub outdir: PathBuf,
    /// Image size (square).
    #[arg(long, default_value_t = 192)]
    pub size: u32,
    /// Galaxy voxels per edge.
    #[arg(long, default_value_t = 64)]
    pub res: usize,
}

/// Runs `blueshift demo`: the galaxy with Doppler on and off side by side, plus picked spectra.
pub fn run_demo(args: DemoArgs) -> Result<()> {
    std::fs::create_dir_all(&args.outdir)
        .with_context(|| format!("cannot create {}", args.outdir.display()))?;
    let size = args.size;
    let picks = [(size / 4, size / 2), (3 * size / 4, size / 2)];
    let mut base = Args::parse_from(["doppler"]);
    base.res = args.res;
    base.width = size;
    base.height = size;
    base.species = Some("bb,H".into());
    base.blackbody_factor = Some(0.1);
    base.inclination = 60.0;
    let start = Instant::now();
    let mut images = Vec::new();
    let mut series = Vec::new();
    for (label, vf) in [("doppler_on", 30.0), ("doppler_off", 0.0)] {
        base.velocity_factor = Some(vf);
        let (scene, st) = build(&base)?;
        let img = render(&scene, &st)?;
        write_exr(&args.outdir.join(format!("{label}.exr")), &img)?;
        for (i, &(x, y)) in picks.iter().enumerate() {
            let s = pixel_spectrum(&scene, &st, x, y)?;
            write_bytes_atomic(
                &args.outdir.join(format!("{label}_pick_{x}_{y}.csv")),
                spectrum_csv(&s, st.range_nm).as_bytes(),
            )?;
            series.push(Series {
                label: format!("{label} {x},{y}"),
                points: samples(&s, st.range_nm),
                colour: COLOURS[(images.len() * 2 + i) % COLOURS.len()],
            });
        }
        images.push(img);
    }
    // One exposure for both halves so they compare.
    let scale = DisplayOptions::default().scale_for(&images[1]);
    let disp = DisplayOptions {
        matrix: ColourMatrix::Srgb,
        exposure: Exposure::Fixed(scale),
    };
    let (a, b) = (disp.to_rgb8(&images[0]), disp.to_rgb8(&images[1]));
    let mut rgb = Vec::with_capacity(a.len() * 2);
    let row = size as usize * 3;
    for y in 0..size as usize {
        rgb.extend_from_slice(&a[y * row..(y + 1) * row]);
        rgb.extend_from_slice(&b[y * row..(y + 1) * row]);
    }
    write_png(&args.outdir.join("side_by_side.png"), 2 * size, size, rgb)?;
    line_plot(
        &args.outdir.join("spectra.png"),
        "galaxy: picked spectra, inclined 60 deg, Doppler on (velocity x30) and off",
        "wavelength (nm)",
        "spectral radiance",
        &series,
        (1000, 500),
    )?;
    println!(
        "wrote {}/side_by_side.png (left: Doppler on, right: off), spectra.png, EXRs and CSVs in {:.1} s",
        args.outdir.display(),
        start.elapsed().as_secs_f64()
    );
    Ok(())
}
