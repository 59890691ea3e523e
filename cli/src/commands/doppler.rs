//! `blueshift doppler` and `blueshift demo`: Doppler volume rendering of the synthetic galaxy
//! and hydrogen shell (EXR + PNG, picked spectra as CSV and plots, step-by-step traces).

use crate::plot::PALETTE as COLOURS;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result, anyhow, bail};
use blueshift_camera::OnProgress;
use blueshift_doppler::{
    ColourMatrix, DisplayOptions, DopplerImage, DopplerScene, DopplerSession, DopplerSettings,
    Exposure, SceneFile, SpectralIntegrator,
};
use blueshift_spectrum::{DopplerModel, PiecewiseLinear};
use clap::Parser;
use plotters::prelude::*;

use crate::output::{OutputSet, write_bytes_atomic, write_via_temp_path};
use crate::plot::{FONT, Series, line_plot, register_font};

/// Arguments of `blueshift doppler`.
#[derive(Clone, Debug, Parser)]
pub struct Args {
    /// Scene JSON mapping volume files to species, temperature and velocity with units
    /// (format: blueshift_doppler::scene_file; example: scenes/enzo-moving7.json).
    /// Replaces --synth/--res; --species then selects parts of the scene by name (bb for the
    /// black body) and the factor flags override the file's factors.
    #[arg(long, conflicts_with_all = ["synth", "res"])]
    pub scene: Option<PathBuf>,
    /// A time series of snapshots, one frame each (frame k written as STEM_kkkk.EXT for
    /// every output): scene files, each the frame's --scene. `--distributed frames` spreads
    /// the frames over the ranks.
    #[arg(
        long,
        num_args = 1..,
        value_name = "SCENE",
        conflicts_with_all = ["scene", "synth", "res"]
    )]
    pub series: Vec<PathBuf>,
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
    /// Relativistic radiance transform (I_nu / nu^3 invariant): with a moving observer
    /// (--observer-velocity, --beta, --ramp) the searchlight effect.
    #[arg(long, visible_alias = "searchlight")]
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
    /// Error budget per ray: with absorption the image's XYZ stays within this fraction of
    /// the unattenuated emission's (per channel); an absorbing cube's channels within about
    /// half this fraction of their unattenuated values (beside the line profiles' own
    /// error); picked spectra within this fraction of their maximum. Larger is faster
    /// (1e-2 ... 5e-2 are typically still more accurate than banded:4000).
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
    /// Trace a pixel's ray X,Y: the spectrum after each step as CSV, small multiples (PNG) and
    /// an animation (GIF).
    #[arg(long, value_parser = parse_xy)]
    pub trace: Option<(u32, u32)>,
    /// Tilt of the orthographic view about the x axis, degrees (0: the observer at +z, the
    /// default view, x right and y up; 90: the observer at +y, a disk seen edge-on).
    #[arg(long, default_value_t = 0.0)]
    pub inclination: f32,
    /// Vertical field of view, degrees: a perspective camera framing the view (default:
    /// orthographic; spectral cubes need orthographic).
    #[arg(long, allow_hyphen_values = true)]
    pub fov: Option<f32>,
    /// View preset, eye, target, up and zoom.
    #[command(flatten)]
    pub view: super::view_args::ViewArgs,
    /// A moving observer: relativistic aberration and Doppler shift (with --searchlight,
    /// brightness too) of an observer flying through the volume.
    #[command(flatten)]
    pub observer: super::observer_args::ObserverArgs,
    /// Image width.
    #[arg(long, default_value_t = 256)]
    pub width: u32,
    /// Image height.
    #[arg(long, default_value_t = 256)]
    pub height: u32,
    /// Display colour matrix: srgb or cie (Eq. 10).
    #[arg(long, default_value = "srgb")]
    pub matrix: String,
    /// Colour space of the output EXR: xyz (CIE 1931 XYZ in R, G, B with the XYZ
    /// `chromaticities` attribute) or linear-srgb (converted with the sRGB matrix).
    #[arg(long, value_enum, default_value = "xyz")]
    pub exr_space: crate::output::ExrSpace,
    /// Display luminance scaling (paper Fig. 4): a number multiplies XYZ (one reference for
    /// all pixels), `pNN` maps the NN-th percentile of Y to 1 (default p99), `per-pixel`
    /// divides each pixel by its own Y (chromaticity only).
    #[arg(long, value_name = "K|pNN|per-pixel")]
    pub exposure_scale: Option<String>,
    /// Exposure in stops after the luminance scaling, as in every command: each stop doubles
    /// the display values (not with --exposure-scale per-pixel).
    #[arg(long, value_name = "STOPS", allow_hyphen_values = true)]
    pub exposure: Option<String>,
    /// Tone mapping of the display PNG after the scaling and the colour matrix: `none`
    /// (clamp to [0, 1]) or a blueshift-tonemap operator with its paper's default
    /// parameters: linear, drago, reinhard, reinhard-local, durand, fattal.
    #[arg(long, default_value = "none")]
    pub tonemap: String,
    /// Draw an orientation triad (world x red, y green, z blue, as the camera sees them) in
    /// the PNG's bottom-right corner.
    #[arg(long)]
    pub triad: bool,
    /// Also write a figure (PNG): the true-colour image with a scale bar and the Doppler
    /// colour key, the velocity-coded panel (H-alpha moment 1, km/s, masked below 1 % of the
    /// emission) with its colour bar, and the picked spectra (--pick; default three pixels
    /// across the middle row).
    #[arg(long)]
    pub figure: Option<PathBuf>,
    /// Output EXR (XYZ); the PNG goes next to it.
    #[arg(long, default_value = "doppler.exr")]
    pub out: PathBuf,
    /// Spectral cube, line broadening and view direction.
    #[command(flatten)]
    pub cube: super::doppler_cube::CubeArgs,
    /// Where to render the image: cpu (default, the f64 reference), gpu (a wgpu adapter or an
    /// error) or auto (a hardware GPU when present, else the CPU). The GPU runs the
    /// piecewise-linear and banded integrators, with or without absorption and line
    /// broadening; spectral cubes are CPU-only (gpu refuses them, auto uses the CPU), as are
    /// picked spectra and traces.
    #[arg(long, default_value = "cpu")]
    pub device: blueshift_gpu::DeviceChoice,
    /// Spread the render over the ranks of an MPI job (run under `mpirun -np N`; needs a
    /// build with the `mpi` feature): `data` (each rank renders its piece of a k-d split of
    /// the volume; without absorption the XYZ images add, with absorption the optical depth
    /// in front of each piece is summed first, so the spectra are composited exactly; a
    /// `--cube` adds its channels the same way, each piece's spectrum attenuated by the depth
    /// in front of it), `tiles` (each rank renders a band of image rows: the single-process
    /// image or cube bit for bit, any integrator, absorbing cubes included) or `frames` (the
    /// frames of `--series`, `--orbit` or `--ramp`, round robin; each rank writes its own).
    /// Rank 0 writes the outputs.
    #[arg(long, value_name = "MODE")]
    pub distributed: Option<String>,
    /// Compositing schedule of `--distributed data`: auto (binary swap for a power-of-two
    /// rank count, radix-k otherwise), direct-send, binary-swap, or radix-k factors `K1,K2,..`
    /// (bottom round first; their product is the rank count).
    #[arg(long, value_name = "SCHEDULE", default_value = "auto")]
    pub compositing: String,
    /// Out-of-core (.bsv) fields of --scene: budget of the brick cache they share, MiB
    /// [default: a quarter of physical memory, at most half of --max-memory]; more than
    /// --max-memory is refused. The image does not depend on it.
    #[arg(long, value_name = "MIB")]
    pub cache_mb: Option<u64>,
    /// Level of detail of .bsv and AMR fields: exact (the finest: the in-core image; the
    /// default for .bsv), auto (the coarsest level whose voxels are no larger than a pixel
    /// of the default view where the volume is nearest; the default for AMR output, whose
    /// regions are each sampled at their own data's level below it), brick (that rule per
    /// brick of the finest level, where the brick is nearest: far bricks are read coarse;
    /// CPU) or a level number (0 = finest).
    #[arg(long)]
    pub lod: Option<String>,
    /// Progressive levels of detail (scenes whose fields are all .bsv files; CPU). `levels`
    /// (the default): render the coarsest level first, then each finer one down to the --lod
    /// level (exact by default) while its bricks load ahead. `bricks` (HDR VolVis 6.3): the
    /// coarsest level, then images in which each brick's region samples the finest level
    /// loaded there so far while the --lod level loads, then the --lod level. Each pass's
    /// level and time go to stderr and the last image is written
    #[arg(long, num_args = 0..=1, default_missing_value = "levels", value_name = "levels|bricks")]
    pub progressive: Option<String>,
    /// Working precision of the GPU kernels: auto (f64 where the adapter has SHADER_F64, as
    /// the CPU; else f32), f64 (agrees with the CPU to rounding; an error without SHADER_F64)
    /// or f32 (faster on GPUs with slow f64; within 2e-3 of the CPU per pixel, see
    /// blueshift-gpu's doppler module). The CPU ignores it.
    #[arg(long, default_value = "auto")]
    pub gpu_precision: blueshift_gpu::doppler::DopplerPrecision,
    /// GPU: cap of the device brick pool, MiB [default: the adapter's largest storage
    /// buffer]. The pool holds only bricks that are not constant; when a level's do not fit,
    /// --lod auto renders the finest coarser level that does, other levels fail on gpu (auto
    /// renders them on the CPU).
    #[arg(long, value_name = "MIB")]
    pub gpu_pool_mb: Option<u64>,
}

fn parse_xy(s: &str) -> std::result::Result<(u32, u32), String> {
    let (a, b) = s.split_once(',').ok_or("expected X,Y")?;
    Ok((
        a.trim().parse().map_err(|_| format!("bad X in '{s}'"))?,
        b.trim().parse().map_err(|_| format!("bad Y in '{s}'"))?,
    ))
}

pub(crate) fn build(args: &Args) -> Result<(DopplerScene, DopplerSettings)> {
    let (scene, st, _, _) = build_levels(args)?;
    Ok((scene, st))
}

/// The level-0 scene of a bricked scene and the level it was moved to.
type Level0 = (DopplerScene, usize);

/// [`build`], also giving the level-0 scene and the level the scene was moved to when its
/// fields are bricked and a level was picked (or `--progressive` asked).
/// The brick cache of a scene file's `.bsv` fields.
type Bricks = Option<std::sync::Arc<blueshift_volume::BrickCache>>;

/// Also gives the brick cache a scene file's `.bsv` fields sample through.
fn build_levels(args: &Args) -> Result<(DopplerScene, DopplerSettings, Option<Level0>, Bricks)> {
    let mut level0 = None;
    let mut bricks = None;
    let mut scene = if let Some(path) = &args.scene {
        let file = SceneFile::read(path)?;
        let tokens: Option<Vec<&str>> = args
            .species
            .as_deref()
            .map(|sp| sp.split(',').filter(|t| !t.trim().is_empty()).collect());
        let cache = super::render::brick_cache(args.cache_mb)?;
        bricks = Some(cache.clone());
        let load = || {
            Ok(file.load_within(
                tokens.as_deref(),
                &blueshift_doppler::MemoryVolumes::new(),
                Some(cache),
                crate::limits::budget(),
            )?)
        };
        // `--distributed data`: each rank reads only its piece's AMR blocks, except the
        // velocity's when its mean is subtracted (a pass over the whole field); velocities
        // not named as AMR channels are then read whole with the rest.
        let mean =
            args.subtract_mean_velocity || file.velocity.as_ref().is_some_and(|v| v.subtract_mean);
        let whole: Option<Vec<String>> = if mean {
            file.velocity
                .as_ref()
                .and_then(|v| v.channels.clone())
                .map(|c| c.to_vec())
        } else {
            Some(Vec::new())
        };
        let data =
            crate::dist::mode(args.distributed.as_deref())? == Some(blueshift_dist::Mode::Data);
        if data && whole.is_none() && file.has_amr() {
            errln!(
                "note: the mean velocity is subtracted from a velocity that is not named by \
                 AMR channels: every rank reads the whole AMR fields"
            );
        }
        let scene = if let (true, Some(whole)) = (data, &whole) {
            crate::dist::load_scoped(&args.compositing, whole, load)?
        } else {
            load()?
        };
        super::render::check_brick_sizes(scene.fields())?;
        // AMR scenes default to the level the view needs (their finest level, 2048^3 for
        // the Enzo snapshot, is finer than any image); other scenes to the finest level.
        let default_lod = if file.has_amr() { "auto" } else { "exact" };
        let lod: blueshift_volume::Lod = args.lod.as_deref().unwrap_or(default_lod).parse()?;
        match scene.levels() {
            Some(levels) if lod == blueshift_volume::Lod::Brick => {
                if args.progressive.is_some() {
                    bail!("--lod brick: --progressive renders whole levels");
                }
                // Each brick its own level: the footprint of the default view where the
                // brick is nearest to the eye.
                let st = DopplerSettings::default_for(&scene, args.width, args.height);
                scene.per_brick(|lo, hi| {
                    blueshift_volume::lod_level(
                        &levels,
                        st.camera.pixel_footprint(lo, hi, args.height),
                    )
                })?
            }
            Some(levels) if lod != blueshift_volume::Lod::Exact || args.progressive.is_some() => {
                let st = DopplerSettings::default_for(&scene, args.width, args.height);
                let (lo, hi) = scene.geometry().world_bounds();
                let level = lod.pick(&levels, st.camera.pixel_footprint(lo, hi, args.height));
                let at = scene.at_level(level)?;
                level0 = Some((scene, level));
                at
            }
            None if !matches!(
                lod,
                blueshift_volume::Lod::Exact | blueshift_volume::Lod::Level(0)
            ) =>
            {
                bail!("--lod {lod}: levels of detail need every field of the scene in .bsv files")
            }
            _ => scene,
        }
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
    if let Some((s0, _)) = &mut level0 {
        s0.factors = scene.factors;
    }
    if args.subtract_mean_velocity {
        // Levels of detail share the finest level's mean (as a scene file's
        // "subtract_mean" gives them).
        match &mut level0 {
            Some((s0, level)) => {
                s0.subtract_mean_velocity()?;
                scene = s0.at_level(*level)?;
            }
            None => scene.subtract_mean_velocity()?,
        }
    }
    let mut st = DopplerSettings::default_for(&scene, args.width, args.height);
    st.integrator = args.integrator.parse::<SpectralIntegrator>()?;
    st.model = args.doppler.parse::<DopplerModel>().map_err(|_| {
        anyhow!(
            "unknown --doppler '{}' ({})",
            args.doppler,
            DopplerModel::NAMES.join(", ")
        )
    })?;
    st.invariant = args.invariant;
    if args.inclination != 0.0 {
        st.incline(&scene, args.inclination)
            .map_err(|e| anyhow::anyhow!("--inclination: {e}"))?;
    }
    st.merge_tolerance = args.merge_tol;
    st.piece_budget = args.piece_budget;
    st.step = args.step;
    st.line_width_nm = args.line_width;
    Ok((scene, st, level0, bricks))
}

/// `st` with the camera the flags give for `scene` (another level of detail), as `--lod` of
/// that level would render it (every level frames the finest level's box).
fn reframe(args: &Args, scene: &DopplerScene, st: &DopplerSettings) -> Result<DopplerSettings> {
    let mut t = st.clone();
    t.camera = DopplerSettings::default_for(scene, st.width, st.height).camera;
    if args.inclination != 0.0 {
        t.incline(scene, args.inclination)
            .map_err(|e| anyhow::anyhow!("--inclination: {e}"))?;
    }
    apply_camera(args, scene, &mut t)?;
    Ok(t)
}

/// `--view`, `--fov`, `--eye`, `--target`, `--up` and `--zoom` over the view `build` and the
/// cube flags chose (`--view` is `--normal` of its axis; one view flag at a time).
pub(crate) fn apply_camera(
    args: &Args,
    scene: &DopplerScene,
    st: &mut DopplerSettings,
) -> Result<()> {
    let aspect = st.width as f32 / st.height.max(1) as f32;
    if let Some(view) = args.view.preset()? {
        if args.cube.axis.is_some() || args.cube.normal.is_some() || args.inclination != 0.0 {
            bail!("give one of --view, --axis, --normal and --inclination");
        }
        st.camera = blueshift_doppler::los_camera(scene, view.normal(), aspect, st.cell_domain)?;
    }
    if let Some(fov) = args.fov {
        let (lo, hi) = scene.frame_bounds(false);
        let back = st.camera.eye - st.camera.target;
        st.camera =
            blueshift_camera::Camera::framing(lo, hi, back, st.camera.up, aspect, false, fov)
                .map_err(|e| anyhow!("--fov: {e}"))?;
    }
    st.camera = args.view.apply_over(st.camera)?;
    Ok(())
}

pub(crate) fn display(args: &Args) -> Result<DisplayOptions> {
    let matrix = args.matrix.parse::<ColourMatrix>().map_err(|_| {
        anyhow!(
            "unknown --matrix '{}' ({})",
            args.matrix,
            ColourMatrix::NAMES.join(", ")
        )
    })?;
    let exposure = match &args.exposure_scale {
        None => Exposure::Percentile(99.0),
        // The library says `exposure E: why`; the flag is `--exposure-scale`.
        Some(e) => e.parse::<Exposure>().map_err(|err| match err {
            blueshift_doppler::Error::Parameter(m) => {
                anyhow!("--{}", m.replacen("exposure", "exposure-scale", 1))
            }
            other => other.into(),
        })?,
    };
    if exposure == Exposure::PerPixel && exposure_stops(args)? != 0.0 {
        bail!("--exposure: per-pixel scaling maps every pixel to Y = 1; stops do not apply");
    }
    Ok(DisplayOptions { matrix, exposure })
}

/// `--exposure` in stops (0 without the flag). The multiplier and percentile it took before
/// are `--exposure-scale` now; those spellings are refused with a pointer there.
pub(crate) fn exposure_stops(args: &Args) -> Result<f64> {
    let Some(e) = args.exposure.as_deref().map(str::trim) else {
        return Ok(0.0);
    };
    match e.parse::<f64>() {
        Ok(s) if s.is_finite() => Ok(s),
        _ if e == "per-pixel" || e.starts_with('p') => bail!(
            "--exposure {e}: --exposure is in stops; the percentile and per-pixel scalings are --exposure-scale {e}"
        ),
        _ => bail!("--exposure {e}: expected a finite number of stops"),
    }
}

/// The names `--tonemap` accepts.
const TONEMAPS: &str = "none, linear, drago, reinhard, reinhard-local, durand, fattal";

/// The tone-mapping operator named by `--tonemap` (`None` for `none`).
fn tonemap_op(name: &str) -> Result<Option<blueshift_tonemap::Operator>> {
    use blueshift_tonemap::{
        DragoParams, DurandParams, FattalParams, LinearParams, Operator, ReinhardLocalParams,
        ReinhardParams,
    };
    Ok(match name {
        "none" | "clamp" => None,
        "linear" => Some(Operator::Linear(LinearParams::default())),
        "drago" => Some(Operator::Drago(DragoParams::default())),
        "reinhard" => Some(Operator::Reinhard(ReinhardParams::default())),
        "reinhard-local" => Some(Operator::ReinhardLocal(ReinhardLocalParams::default())),
        "durand" => Some(Operator::Durand(DurandParams::default())),
        "fattal" => Some(Operator::Fattal(FattalParams::default())),
        other => bail!("--tonemap {other:?}: expected one of {TONEMAPS}"),
    })
}

/// The display image: Fig. 4 scaling and colour matrix, then the tone-mapping operator (or
/// a clamp), sRGB-encoded to 8 bits.
fn display_rgb8(
    disp: &DisplayOptions,
    op: Option<&blueshift_tonemap::Operator>,
    img: &DopplerImage,
) -> Result<Vec<u8>> {
    let Some(op) = op else {
        return Ok(disp.to_rgb8(img));
    };
    let lin = disp.to_linear_rgb(img);
    let rgb = image::Rgb32FImage::from_fn(img.width, img.height, |x, y| {
        let p = lin[(y * img.width + x) as usize];
        image::Rgb([p[0] as f32, p[1] as f32, p[2] as f32])
    });
    let out = op.apply(&rgb).context("--tonemap")?;
    Ok(out
        .into_raw()
        .into_iter()
        .map(blueshift_tonemap::io::srgb8)
        .collect())
}

fn render(session: &DopplerSession) -> Result<DopplerImage> {
    let bar = crate::progress::Progress::new(
        u64::from(session.settings().height),
        "{bar:30} {pos}/{len} rows [{elapsed}]",
        "doppler",
        "rows",
    );
    let img = session.render(&OnProgress::new(|_| bar.inc(1)))?;
    bar.finish();
    Ok(img)
}

/// `--progressive`: every level from the coarsest to `target`, one stderr line per pass.
/// `run(observer, on_step, bricks)` renders the passes (the CPU's loops, or the GPU's
/// through one device pool).
fn render_progressive<E>(
    scene0: &DopplerScene,
    mode: Option<&str>,
    run: impl FnOnce(
        &dyn blueshift_camera::Observer<DopplerImage>,
        &mut dyn FnMut(u32, usize, usize),
        bool,
    ) -> std::result::Result<DopplerImage, E>,
) -> std::result::Result<DopplerImage, E> {
    struct Passes {
        start: Instant,
        level: std::sync::Mutex<(usize, Instant)>,
        dims: Vec<[usize; 3]>,
        /// `--progressive bricks`: the share of bricks at the final level of the next image.
        note: std::sync::Mutex<String>,
    }
    impl blueshift_camera::Observer<DopplerImage> for Passes {
        fn level(&self, _pass: u32, level: usize) {
            *self
                .level
                .lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner) = (level, Instant::now());
        }
        fn pass(&self, pass: u32, _image: &DopplerImage, _noise: Option<f64>) {
            let (level, began) = *self
                .level
                .lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner);
            let note = std::mem::take(
                &mut *self
                    .note
                    .lock()
                    .unwrap_or_else(std::sync::PoisonError::into_inner),
            );
            let what = if note.is_empty() {
                String::new()
            } else {
                format!(" and finer where loaded{note}")
            };
            super::render::progressive_line(pass, level, &self.dims, &what, began, self.start);
        }
    }
    let dims = scene0
        .levels()
        .unwrap_or_default()
        .iter()
        .map(|g| g.dims)
        .collect();
    let obs = Passes {
        start: Instant::now(),
        level: std::sync::Mutex::new((0, Instant::now())),
        dims,
        note: std::sync::Mutex::new(String::new()),
    };
    let mut on_step = |_, at: usize, regions: usize| {
        *obs.note
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner) =
            format!(", {at} of {regions} bricks at the final level");
    };
    run(&obs, &mut on_step, mode == Some("bricks"))
}

/// The one wording of a device failure: `--device gpu: <why>; use --device cpu or auto` for
/// what the GPU does not support, the error with its context otherwise.
pub(crate) fn device_error(e: anyhow::Error) -> anyhow::Error {
    match e.downcast_ref::<blueshift_gpu::Error>() {
        Some(blueshift_gpu::Error::Unsupported(what)) if what.contains("--device") => {
            anyhow!("--device gpu: {what}")
        }
        Some(blueshift_gpu::Error::Unsupported(what)) => {
            anyhow!("--device gpu: {what}; use --device cpu or auto")
        }
        Some(_) => e.context("--device"),
        None => e,
    }
}

fn write_exr(path: &Path, img: &DopplerImage, space: crate::output::ExrSpace) -> Result<()> {
    let mut set = OutputSet::new();
    stage_exr(&mut set, path, img, space)?;
    set.commit()
}

/// Stages the Doppler image's EXR in `set`.
fn stage_exr(
    set: &mut OutputSet,
    path: &Path,
    img: &DopplerImage,
    space: crate::output::ExrSpace,
) -> Result<()> {
    // Block after block (the same bytes every run), via a temporary file.
    let m = blueshift_spectrum::xyz_to_linear_srgb_matrix();
    let data: Vec<f32> = img
        .xyz
        .iter()
        .flat_map(|p| {
            let c = match space {
                crate::output::ExrSpace::Xyz => *p,
                crate::output::ExrSpace::LinearSrgb => {
                    std::array::from_fn(|i| m[i][0] * p[0] + m[i][1] * p[1] + m[i][2] * p[2])
                }
            };
            [c[0] as f32, c[1] as f32, c[2] as f32, 1.0]
        })
        .collect();
    set.via_path(path, |p| {
        crate::output::exr_file(p, (img.width, img.height), 4, &data, space)
            .with_context(|| format!("cannot write {}", path.display()))
    })
}

fn write_png(path: &Path, w: u32, h: u32, rgb: Vec<u8>) -> Result<()> {
    let mut set = OutputSet::new();
    stage_png(&mut set, path, w, h, rgb)?;
    set.commit()
}

/// Stages an 8-bit RGB PNG in `set`.
fn stage_png(set: &mut OutputSet, path: &Path, w: u32, h: u32, rgb: Vec<u8>) -> Result<()> {
    let img = image::RgbImage::from_raw(w, h, rgb).ok_or_else(|| anyhow!("image size"))?;
    set.via_path(path, |p| {
        blueshift_tonemap::io::save_rgb8_png(p, &img)
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

/// Runs `blueshift doppler`: one frame, or with `--ramp` one frame per speed (each output
/// `STEM_kkkk.EXT`).
pub fn run(args: Args) -> Result<()> {
    let mode = crate::dist::mode(args.distributed.as_deref())?;
    use blueshift_dist::Mode;
    // Doppler integrators are deterministic: no sample-parallel mode.
    crate::dist::check_mode(mode, &[Mode::Data, Mode::Tiles, Mode::Frames], "doppler")?;
    use super::observer_args::{Series, frame_path, run_frames};
    let outputs = |a: &mut Args, k: usize| {
        a.out = frame_path(&a.out, k);
        a.figure = a.figure.as_deref().map(|p| frame_path(p, k));
        a.cube.cube = a.cube.cube.as_deref().map(|p| frame_path(p, k));
    };
    // Each rank renders whole frames on its own.
    let frame = |mut a: Args| {
        if mode == Some(Mode::Frames) {
            a.distributed = None;
        }
        run_frame(a)
    };
    let keep = |k| crate::dist::keeps_frame(mode, k);
    let input = |a: &mut Args, p: &Path| -> Result<()> {
        a.scene = Some(p.to_path_buf());
        Ok(())
    };
    let series = Series {
        paths: &args.series,
        input: &input,
    };
    if run_frames(
        &args,
        &series,
        |a| &mut a.view,
        |a| &mut a.observer,
        outputs,
        check_frame_outputs,
        frame,
        keep,
    )? {
        return Ok(());
    }
    if mode == Some(Mode::Frames) {
        bail!("--distributed frames: spreads the frames of --series, --orbit or --ramp; give one");
    }
    run_frame(args)
}

/// The observer of `args` for the view of `st` (the default direction of `--beta`), else the
/// scene file's `observer_velocity`.
fn observer_for(
    args: &Args,
    st: &DopplerSettings,
) -> Result<Option<blueshift_relativity::MovingObserver>> {
    let view = (st.camera.target - st.camera.eye).normalize_or_zero();
    if let Some(o) = args.observer.observer(view, None, args.invariant)? {
        return Ok(Some(o));
    }
    match &args.scene {
        Some(p) => Ok(SceneFile::read(p)?.observer(args.invariant)?),
        None => Ok(None),
    }
}

/// Checks the outputs of frames (each one's image or cube and every file beside it) against
/// all their scene files and `more` inputs, in one pass.
fn check_frame_outputs(frames: &[&Args], more: &[&Path]) -> Result<()> {
    let mut all: Vec<PathBuf> = Vec::new();
    let mut inputs: Vec<&Path> = more.to_vec();
    for args in frames {
        inputs.extend(args.scene.as_deref());
        match &args.cube.cube {
            Some(cube) => all.extend(super::doppler_cube::cube_outputs(&args.cube, cube)),
            None => {
                // The image, its PNG, the figure and every pick and trace file.
                all.push(args.out.clone());
                all.push(args.out.with_extension("png"));
                all.extend(args.figure.clone());
                for &(x, y) in &args.pick {
                    all.push(sibling(&args.out, &format!("_pick_{x}_{y}.csv")));
                }
                if !args.pick.is_empty() {
                    all.push(sibling(&args.out, "_picks.png"));
                }
                if let Some((x, y)) = args.trace {
                    for ext in ["csv", "png", "gif"] {
                        all.push(sibling(&args.out, &format!("_trace_{x}_{y}.{ext}")));
                    }
                }
            }
        }
    }
    let outs: Vec<&Path> = all.iter().map(PathBuf::as_path).collect();
    crate::output::check_outputs(&outs, &inputs)
}

/// Bytes per pixel a Doppler image holds: its XYZ (f64), the display RGB (f32), the EXR
/// written (f32) and the 8-bit PNG, rounded up.
const DOPPLER_BYTES_PER_PIXEL: u64 = 64;
/// Bytes per value of a spectral cube: the cube (f32), its FITS bytes and the NRRD beside
/// it.
const CUBE_BYTES_PER_VALUE: u64 = 12;

/// Checks the image's (or the cube's) memory against the budget (`--max-memory`) before
/// the scene is loaded.
fn check_memory(args: &Args) -> Result<()> {
    let (w, h) = (u64::from(args.width), u64::from(args.height));
    let image = blueshift_volume::budget::image_bytes(w, h, DOPPLER_BYTES_PER_PIXEL);
    if args.cube.cube.is_none() {
        return crate::limits::check(
            format_args!("this image ({w}x{h}, {DOPPLER_BYTES_PER_PIXEL} bytes per pixel)"),
            image,
        );
    }
    let n = super::doppler_cube::cube_spec(&args.cube)?.channels as u64;
    let cube = blueshift_volume::budget::image_bytes(w, h, n.saturating_mul(CUBE_BYTES_PER_VALUE));
    crate::limits::check(
        format_args!("this cube ({w}x{h}x{n} channels, {CUBE_BYTES_PER_VALUE} bytes per value)"),
        cube.saturating_add(image),
    )
}

fn run_frame(args: Args) -> Result<()> {
    // Refuse an output that cannot be written, or a result beyond the memory budget, before
    // loading or rendering anything.
    check_frame_outputs(&[&args], &[])?;
    check_memory(&args)?;
    let (scene, mut st, level0, bricks) = build_levels(&args)?;
    if let Some(mode) = args.progressive.as_deref()
        && mode != "levels"
        && mode != "bricks"
    {
        bail!("--progressive {mode}: levels or bricks");
    }
    if args.progressive.is_some() {
        if level0.is_none() {
            bail!("--progressive: levels of detail need every field of the scene in .bsv files");
        }
        if args.cube.cube.is_some() {
            bail!("--progressive renders images (not cubes)");
        }
    }
    super::doppler_cube::apply_view(&args.cube, &scene, &mut st)?;
    apply_camera(&args, &scene, &mut st)?;
    st.observer = observer_for(&args, &st)?;
    st.broadening = super::doppler_cube::broadening(&args.cube)?;
    if args.cube.cube.is_some() {
        if args.device == blueshift_gpu::DeviceChoice::Gpu {
            bail!("--device gpu: spectral cubes are CPU-only; use --device cpu or auto");
        }
        let units = match &args.scene {
            Some(p) => SceneFile::read(p)?.cube,
            None => None,
        };
        let mode = crate::dist::mode(args.distributed.as_deref())?;
        return super::doppler_cube::run_cube(
            &args.cube,
            &scene,
            &st,
            units.as_ref(),
            mode.map(|m| (m, args.compositing.as_str())),
        );
    }
    let disp = display(&args)?;
    let stops = exposure_stops(&args)?;
    let op = tonemap_op(args.tonemap.trim())?;
    for &(x, y) in args.pick.iter().chain(args.trace.iter()) {
        if x >= st.width || y >= st.height {
            bail!(
                "pixel {x},{y} is outside the {}x{} image",
                st.width,
                st.height
            );
        }
    }
    // One session: the image, the picks and the trace share its prepared tables.
    let absorbs = scene.absorbs();
    let mut session = DopplerSession::new(scene, st)?;
    // One render: nothing to keep for a factor edit.
    session.set_keep_samples(false);
    let session = session;
    let (scene, st) = (session.scene(), session.settings());
    // A precision the adapter lacks is the user's error on gpu and auto alike (not a reason
    // to fall back), named by its flag.
    if let Some(ctx) = args.device.context().context("--device")?
        && blueshift_gpu::doppler::supports(scene, st).is_ok()
    {
        args.gpu_precision
            .is_double_on(ctx)
            .context("--gpu-precision")?;
    }
    let start = Instant::now();
    let mut on = "cpu";
    let device = args.device;
    let distributed = if let Some(mode) = crate::dist::mode(args.distributed.as_deref())? {
        if args.progressive.is_some() {
            bail!("--distributed: not with --progressive");
        }
        match crate::dist::doppler(mode, scene, st, &args.compositing)? {
            // Not rank 0: rank 0 writes the outputs.
            None => return Ok(()),
            Some(img) => Some(blueshift_gpu::Ran {
                value: img,
                device: blueshift_camera::DeviceKind::Cpu,
                fallback: None,
            }),
        }
    } else {
        None
    };
    let ran = if let Some(ran) = distributed {
        ran
    } else {
        blueshift_gpu::run_with_fallback(
            device,
            || blueshift_gpu::doppler::supports(scene, st),
            |ctx| {
                let double = args.gpu_precision.is_double_on(ctx)?;
                on = if double { "gpu (f64)" } else { "gpu (f32)" };
                super::render::set_gpu_pool(ctx, args.gpu_pool_mb)?;
                let asked = level0.as_ref().map(|(_, l)| *l);
                let bricked = scene.levels().is_some()
                    || scene
                        .species()
                        .iter()
                        .any(|s| s.density.as_bricked().is_some());
                let auto = args.lod.as_deref().map(str::trim) == Some("auto");
                if let (Some((s0, target)), Some(mode)) = (&level0, args.progressive.as_deref()) {
                    // Every pass a view of one device pool.
                    return render_progressive(s0, Some(mode), |obs, on_step, bricks| {
                        let (img, stats) = blueshift_gpu::doppler::render_doppler_gpu_progressive(
                            ctx,
                            s0,
                            st,
                            *target,
                            bricks,
                            obs,
                            on_step,
                            args.gpu_precision,
                        )?;
                        super::render::report_pool(&stats, true, asked, asked);
                        Ok(img)
                    });
                }
                let mut level = asked;
                let mut coarser: Option<(DopplerScene, DopplerSettings)> = None;
                let per_brick = args.lod.as_deref().map(str::trim) == Some("brick");
                let mut regions_coarser = 0;
                let mut first_full: Option<blueshift_gpu::Error> = None;
                loop {
                    let (s, t) = coarser.as_ref().map_or((scene, st), |(s, t)| (s, t));
                    match blueshift_gpu::doppler::render_doppler_gpu_pooled(
                        ctx,
                        s,
                        t,
                        args.gpu_precision,
                    ) {
                        Ok((img, stats)) => {
                            super::render::report_pool(&stats, bricked, asked, level);
                            if regions_coarser > 0 {
                                errln!(
                                    "--lod brick: every brick {regions_coarser} level(s) coarser \
                                     than the rule asks, to fit the GPU brick pool"
                                );
                            }
                            return Ok(img);
                        }
                        // --lod brick: a pool too small for the per-brick view renders every
                        // region one level coarser, until it fits.
                        Err(e) if per_brick && blueshift_gpu::pool::is_pool_full(&e) => {
                            let bad = |e: String| blueshift_gpu::Error::InvalidInput(e);
                            let (s, moved) = scene
                                .coarser_regions(regions_coarser + 1)
                                .map_err(|e| bad(e.to_string()))?;
                            // The view asked for says by how much it overflows.
                            first_full.get_or_insert(e);
                            if !moved {
                                return Err(first_full.take().unwrap_or_else(|| {
                                    bad("no per-brick view fits the pool".into())
                                }));
                            }
                            regions_coarser += 1;
                            coarser = Some((s, st.clone()));
                        }
                        // --lod auto: the finest coarser level whose bricks fit the pool.
                        Err(e) if auto && blueshift_gpu::pool::is_pool_full(&e) => {
                            let (Some((s0, _)), Some(l)) = (&level0, level) else {
                                return Err(e);
                            };
                            if l + 1 >= s0.levels().map_or(1, |g| g.len()) {
                                return Err(e);
                            }
                            // As `--lod` of that level would render it (its own framing).
                            let bad = |e: String| blueshift_gpu::Error::InvalidInput(e);
                            let s = s0.at_level(l + 1).map_err(|e| bad(e.to_string()))?;
                            let t = reframe(&args, &s, st).map_err(|e| bad(format!("{e:#}")))?;
                            coarser = Some((s, t));
                            level = Some(l + 1);
                        }
                        Err(e) => return Err(e),
                    }
                }
            },
            || match &level0 {
                Some((s0, target)) if args.progressive.is_some() => {
                    render_progressive(s0, args.progressive.as_deref(), |obs, on_step, bricks| {
                        Ok(if bricks {
                            blueshift_doppler::render_doppler_bricks(s0, st, *target, obs, on_step)?
                        } else {
                            blueshift_doppler::render_doppler_lod(s0, st, *target, obs)?
                        })
                    })
                }
                _ => render(&session),
            },
        )
        .map_err(device_error)?
    };
    if let Some(why) = &ran.fallback {
        errln!("--device auto: {why}; rendering on the CPU");
    }
    if ran.device == blueshift_camera::DeviceKind::Cpu {
        on = "cpu";
    }
    let img = ran.value;
    let secs = start.elapsed().as_secs_f64();
    // The out-of-core reads, as `render` reports them (nothing for in-core scenes); a
    // per-brick level of detail mixes levels (the reads say which).
    if let Some(cache) = &bricks {
        let level = match &level0 {
            Some((_, l)) => Some(*l),
            None => (args.lod.as_deref() != Some("brick")).then_some(0),
        };
        super::render::report_cache(cache, level);
    }
    // The EXR and its PNG are one set: both staged, then renamed (the PNG first).
    let png = args.out.with_extension("png");
    let disp = disp.with_stops(stops, &img);
    let mut shown = display_rgb8(&disp, op.as_ref(), &img)?;
    if args.triad {
        let o = crate::figure::triad_overlay(img.width, img.height, &st.camera)?;
        crate::figure::apply_overlay(&mut shown, &o);
    }
    let mut set = OutputSet::new();
    stage_png(&mut set, &png, img.width, img.height, shown)?;
    stage_exr(&mut set, &args.out, &img, args.exr_space)?;
    set.commit()?;
    crate::output::wrote_with(
        &args.out,
        &format!(
            "{}x{}, {:.2} s on the {on}, {}",
            img.width,
            img.height,
            secs,
            if img.pieces.max == 0 && !absorbs {
                "emission only: the rays sum XYZ and keep no spectrum pieces".to_owned()
            } else if img.pieces.max == 0 {
                "no optical-depth pieces kept (the banded integrator, or every absorption line \
                 within the tolerance's first-order share)"
                    .to_owned()
            } else {
                format!(
                    "pieces per ray mean {:.1} max {}, budget fallbacks {}",
                    img.pieces.mean, img.pieces.max, img.pieces.fallback_rays
                )
            }
        ),
    );
    crate::output::wrote(&png);
    let mut series = Vec::new();
    for (i, &(x, y)) in args.pick.iter().enumerate() {
        let s = session.pixel_spectrum(x, y)?;
        let csv = sibling(&args.out, &format!("_pick_{x}_{y}.csv"));
        write_bytes_atomic(&csv, spectrum_csv(&s, st.range_nm).as_bytes())?;
        crate::output::wrote(&csv);
        series.push(Series {
            label: format!("pixel {x},{y}"),
            points: samples(&s, st.range_nm),
            colour: COLOURS[i % COLOURS.len()],
        });
    }
    if !series.is_empty() {
        let plot = sibling(&args.out, "_picks.png");
        line_plot(
            &plot,
            "picked spectra",
            "wavelength (nm)",
            "spectral radiance",
            &series,
            (900, 500),
        )?;
        crate::output::wrote(&plot);
    }
    if let Some(fig) = &args.figure {
        let (w, h) = (st.width, st.height);
        let mut phys = scene.clone();
        phys.factors.velocity = 1.0;
        let vmax = crate::figure::los_speed_kms(&phys, st);
        let vmap = crate::figure::velocity_map(&phys, st, vmax, 0.01)?;
        let picks: Vec<(u32, u32)> = if args.pick.is_empty() {
            auto_picks(&img, vmap.as_deref())
        } else {
            args.pick.clone()
        };
        let mut fpicks = Vec::new();
        for &(x, y) in &picks {
            let s = session.pixel_spectrum(x, y)?;
            fpicks.push(crate::figure::Pick {
                xy: (x, y),
                on: samples(&s, st.range_nm),
                off: Vec::new(),
            });
        }
        let mut panels = vec![crate::figure::Panel {
            title: if (scene.factors.velocity - 1.0).abs() > 1e-12 {
                format!("true colour (velocity x{})", scene.factors.velocity)
            } else {
                "true colour".into()
            },
            rgb: display_rgb8(&disp, op.as_ref(), &img)?,
        }];
        let mut strips = vec![Some(crate::figure::colour_key(scene, st, vmax)?)];
        if let Some(map) = &vmap {
            let (rgb, bar) = crate::figure::velocity_panel(map, vmax);
            panels.push(crate::figure::Panel {
                title: "line-of-sight velocity".into(),
                rgb,
            });
            strips.push(Some(bar));
        }
        let unit = match &args.cube.world_unit {
            Some(u) => {
                let (name, k) = u
                    .split_once(':')
                    .and_then(|(n, k)| Some((n.trim().to_owned(), k.trim().parse::<f64>().ok()?)))
                    .filter(|(_, k)| k.is_finite() && *k > 0.0)
                    .ok_or_else(|| anyhow!("--world-unit '{u}': expected UNIT:SCALE"))?;
                readable_length(name, k)
            }
            None if args.scene.is_none() && args.synth == "galaxy" => ("kpc".into(), 1.0),
            None => ("world units".into(), 1.0),
        };
        crate::figure::write_figure(
            fig,
            &crate::figure::Figure {
                size: (w, h),
                panels,
                strips,
                ringed: 1,
                scale: (pixel_world(st) > 0.0).then(|| (pixel_world(st), unit.0, unit.1)),
                picks: fpicks,
                spectra_title: "picked spectra".into(),
            },
        )?;
        crate::output::wrote(fig);
    }
    if let Some((x, y)) = args.trace {
        let steps = session.trace(x, y)?;
        let mut csv = String::from("step,t,radial_velocity_m_per_s,wavelength_nm,value\n");
        for (i, s) in steps.iter().enumerate() {
            for (l, v) in samples(&s.spectrum, st.range_nm).into_iter().step_by(4) {
                let _ = writeln!(csv, "{i},{},{:e},{l},{v:e}", s.t, s.radial_velocity_m_per_s);
            }
        }
        let csv_path = sibling(&args.out, &format!("_trace_{x}_{y}.csv"));
        write_bytes_atomic(&csv_path, csv.as_bytes())?;
        crate::output::wrote(&csv_path);
        if !steps.is_empty() {
            let panels = sibling(&args.out, &format!("_trace_{x}_{y}.png"));
            trace_panels(
                &panels,
                &format!("pixel {x},{y}: spectrum after each step (back to front)"),
                &steps,
                st.range_nm,
            )?;
            crate::output::wrote(&panels);
            let gif = sibling(&args.out, &format!("_trace_{x}_{y}.gif"));
            trace_animation(&gif, &format!("pixel {x},{y}"), &steps, st.range_nm)?;
            crate::output::wrote(&gif);
        }
    }
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

/// The figure's default picks: the brightest pixel, then the most approaching and the most
/// receding pixel of the velocity map among those with at least a tenth of the brightest
/// luminance (distinct pixels only).
fn auto_picks(img: &DopplerImage, vmap: Option<&[Option<f32>]>) -> Vec<(u32, u32)> {
    let w = img.width as usize;
    let y: Vec<f64> = img
        .xyz
        .iter()
        .map(|p| if p[1].is_finite() { p[1] } else { 0.0 })
        .collect();
    let Some((best, &ymax)) = y.iter().enumerate().max_by(|a, b| a.1.total_cmp(b.1)) else {
        return Vec::new();
    };
    let mut out = vec![best];
    if let Some(v) = vmap {
        let lit = |i: usize| y[i] >= 0.1 * ymax;
        let cands: Vec<(usize, f32)> = v
            .iter()
            .enumerate()
            .filter_map(|(i, v)| v.filter(|_| lit(i)).map(|v| (i, v)))
            .collect();
        for pick in [
            cands.iter().min_by(|a, b| a.1.total_cmp(&b.1)),
            cands.iter().max_by(|a, b| a.1.total_cmp(&b.1)),
        ]
        .into_iter()
        .flatten()
        {
            if !out.contains(&pick.0) {
                out.push(pick.0);
            }
        }
    }
    out.into_iter()
        .map(|i| ((i % w) as u32, (i / w) as u32))
        .collect()
}

/// A length unit a reader knows: cm or m scales become pc, kpc or Mpc (value = world x
/// scale); other units stay as given.
fn readable_length(unit: String, scale: f64) -> (String, f64) {
    const PC_CM: f64 = 3.085_677_581e18;
    let per_cm = match unit.as_str() {
        "cm" => 1.0,
        "m" => 100.0,
        _ => return (unit, scale),
    };
    let pc = scale * per_cm / PC_CM;
    if pc >= 1e5 {
        ("Mpc".into(), pc / 1e6)
    } else if pc >= 100.0 {
        ("kpc".into(), pc / 1e3)
    } else {
        ("pc".into(), pc)
    }
}

/// World length of one pixel of an orthographic camera (vertically); 0 for perspective.
fn pixel_world(st: &DopplerSettings) -> f64 {
    match st.camera.projection {
        blueshift_camera::Projection::Orthographic { height } => {
            f64::from(height) / f64::from(st.height.max(1))
        }
        blueshift_camera::Projection::Perspective { .. } => 0.0,
    }
}

/// Runs `blueshift demo`: the galaxy with Doppler on and off side by side, plus picked spectra.
pub fn run_demo(args: DemoArgs) -> Result<()> {
    std::fs::create_dir_all(&args.outdir)
        .with_context(|| format!("cannot create {}", args.outdir.display()))?;
    crate::output::check_output(&args.outdir.join("demo.png"))?;
    let size = args.size;
    if !(8..=2048).contains(&size) {
        bail!("--size {size} must be 8..=2048");
    }
    let picks = [
        (size / 4, size / 2),
        (size / 2, size / 2),
        (3 * size / 4, size / 2),
    ];
    let mut demo_picks: Vec<DemoPick> = picks
        .iter()
        .map(|&xy| DemoPick {
            xy,
            on: Vec::new(),
            off: Vec::new(),
        })
        .collect();
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
    // One session; Doppler off is a factor edit (nothing but the factors is rebuilt).
    base.velocity_factor = Some(30.0);
    let (scene, st) = build(&base)?;
    let mut session = DopplerSession::new(scene, st)?;
    for (label, vf) in [("doppler_on", 30.0), ("doppler_off", 0.0)] {
        let mut factors = session.scene().factors;
        factors.velocity = vf;
        session.set_factors(factors)?;
        let st = session.settings();
        let img = render(&session)?;
        let exr = args.outdir.join(format!("{label}.exr"));
        write_exr(&exr, &img, crate::output::ExrSpace::Xyz)?;
        crate::output::wrote(&exr);
        for (i, &(x, y)) in picks.iter().enumerate() {
            let s = session.pixel_spectrum(x, y)?;
            let csv = args.outdir.join(format!("{label}_pick_{x}_{y}.csv"));
            write_bytes_atomic(&csv, spectrum_csv(&s, st.range_nm).as_bytes())?;
            crate::output::wrote(&csv);
            let pts = samples(&s, st.range_nm);
            if vf > 0.0 {
                demo_picks[i].on = pts.clone();
            } else {
                demo_picks[i].off = pts.clone();
            }
            series.push(Series {
                label: format!("{label} {x},{y}"),
                points: pts,
                colour: COLOURS[(images.len() * picks.len() + i) % COLOURS.len()],
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
    let side = args.outdir.join("side_by_side.png");
    write_png(&side, 2 * size, size, rgb)?;
    crate::output::wrote(&side);
    let st = session.settings().clone();
    let mut phys = session.scene().clone();
    phys.factors.velocity = 1.0;
    let vmax = crate::figure::los_speed_kms(&phys, &st);
    let mut shown = session.scene().clone();
    shown.factors.velocity = 30.0;
    let key = crate::figure::colour_key(&shown, &st, vmax)?;
    let mut panels = vec![
        crate::figure::Panel {
            title: "true colour, Doppler on (velocity x30)".into(),
            rgb: a,
        },
        crate::figure::Panel {
            title: "true colour, Doppler off".into(),
            rgb: b,
        },
    ];
    let mut strips = vec![Some(key), None];
    if let Some(map) = crate::figure::velocity_map(&phys, &st, vmax, 0.01)? {
        let (rgb, bar) = crate::figure::velocity_panel(&map, vmax);
        panels.push(crate::figure::Panel {
            title: "line-of-sight velocity".into(),
            rgb,
        });
        strips.push(Some(bar));
    }
    crate::figure::write_figure(
        &args.outdir.join("demo.png"),
        &crate::figure::Figure {
            size: (size, size),
            panels,
            strips,
            ringed: 2,
            scale: Some((pixel_world(&st), "kpc".into(), 1.0)),
            picks: demo_picks
                .into_iter()
                .map(|p| crate::figure::Pick {
                    xy: p.xy,
                    on: p.on,
                    off: p.off,
                })
                .collect(),
            spectra_title:
                "galaxy inclined 60 deg: picked spectra (solid: Doppler on x30, thin: off)".into(),
        },
    )?;
    crate::output::wrote_with(
        &args.outdir.join("demo.png"),
        "Doppler on and off with the picked spectra under them",
    );
    line_plot(
        &args.outdir.join("spectra.png"),
        "galaxy: picked spectra, inclined 60 deg, Doppler on (velocity x30) and off",
        "wavelength (nm)",
        "spectral radiance",
        &series,
        (1000, 500),
    )?;
    crate::output::wrote_with(
        &args.outdir.join("spectra.png"),
        &format!("demo done in {:.1} s", start.elapsed().as_secs_f64()),
    );
    Ok(())
}

/// The steps a small-multiples plot shows: at most `max` of `n`, evenly spaced, the last
/// always included.
fn panel_steps(n: usize, max: usize) -> Vec<usize> {
    if n <= max {
        return (0..n).collect();
    }
    let mut v: Vec<usize> = (1..=max).map(|k| (k * n).div_ceil(max) - 1).collect();
    v.dedup();
    v
}

fn plot_err(e: impl std::fmt::Display) -> anyhow::Error {
    anyhow!("plot: {e}")
}

/// A plotted curve: (wavelength nm, value) points.
type Curve = Vec<(f64, f64)>;

/// The steps a trace plot shows (at most `max`), their spectra sampled over `range`, and the
/// largest value (the shared y axis; 1 when all are zero). Registers the plot font.
fn trace_curves(
    steps: &[blueshift_doppler::TraceStep],
    range: (f64, f64),
    max: usize,
) -> (Vec<usize>, Vec<Curve>, f64) {
    register_font();
    let pick = panel_steps(steps.len(), max);
    let curves: Vec<Curve> = pick
        .iter()
        .map(|&i| samples(&steps[i].spectrum, range))
        .collect();
    let ymax = curves
        .iter()
        .flatten()
        .map(|p| p.1)
        .filter(|v| v.is_finite())
        .fold(0.0f64, f64::max);
    (pick, curves, if ymax > 0.0 { ymax } else { 1.0 })
}

/// Small multiples of a traced ray: a grid of panels (at most 12), one per selected step,
/// each the spectrum after that step, on shared axes; the step index and the depth (path
/// position of the step's near end) in each panel's title.
fn trace_panels(
    path: &Path,
    title: &str,
    steps: &[blueshift_doppler::TraceStep],
    range: (f64, f64),
) -> Result<()> {
    let (pick, curves, ymax) = trace_curves(steps, range, 12);
    let cols = pick.len().clamp(1, 4);
    let rows = pick.len().div_ceil(cols).max(1);
    let size = (300 * cols as u32, 60 + 230 * rows as u32);
    let mut buf = vec![255u8; (size.0 * size.1 * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, size).into_drawing_area();
        let root = root.titled(title, (FONT, 20)).map_err(plot_err)?;
        let panels = root.split_evenly((rows, cols));
        for ((area, &i), pts) in panels.iter().zip(&pick).zip(&curves) {
            let mut chart = ChartBuilder::on(area)
                .caption(format!("step {i}, depth t = {:.3}", steps[i].t), (FONT, 14))
                .margin(6)
                .x_label_area_size(28)
                .y_label_area_size(52)
                .build_cartesian_2d(range.0..range.1, 0.0..ymax * 1.05)
                .map_err(plot_err)?;
            chart
                .configure_mesh()
                .x_labels(4)
                .y_labels(4)
                .label_style((FONT, 11))
                .y_label_formatter(&|v| format!("{v:.1e}"))
                .draw()
                .map_err(plot_err)?;
            chart
                .draw_series(LineSeries::new(
                    pts.iter().copied(),
                    COLOURS[0].stroke_width(1),
                ))
                .map_err(plot_err)?;
        }
        root.present().map_err(plot_err)?;
    }
    let img = image::RgbImage::from_raw(size.0, size.1, buf).context("plot buffer size")?;
    write_via_temp_path(path, |p| {
        blueshift_tonemap::io::save_rgb8_png(p, &img)
            .with_context(|| format!("cannot write {}", path.display()))
    })
}

/// Most frames of a trace animation (longer traces show evenly spaced steps, the last one
/// always included).
const MAX_FRAMES: usize = 120;

/// The step-by-step accumulation as an animated GIF: one frame per step (at most
/// [`MAX_FRAMES`]), the spectrum after that step on axes shared by all frames, the step and
/// depth in the title; the last frame (the pixel's final spectrum) is held longer.
fn trace_animation(
    path: &Path,
    title: &str,
    steps: &[blueshift_doppler::TraceStep],
    range: (f64, f64),
) -> Result<()> {
    let (pick, curves, ymax) = trace_curves(steps, range, MAX_FRAMES);
    let size = (640u32, 400u32);
    let mut frames = Vec::with_capacity(pick.len());
    for (k, (&i, pts)) in pick.iter().zip(&curves).enumerate() {
        let mut buf = vec![255u8; (size.0 * size.1 * 3) as usize];
        {
            let root = BitMapBackend::with_buffer(&mut buf, size).into_drawing_area();
            let mut chart = ChartBuilder::on(&root)
                .caption(
                    format!(
                        "{title}: step {} of {}, depth t = {:.3}",
                        i + 1,
                        steps.len(),
                        steps[i].t
                    ),
                    (FONT, 16),
                )
                .margin(10)
                .x_label_area_size(36)
                .y_label_area_size(64)
                .build_cartesian_2d(range.0..range.1, 0.0..ymax * 1.05)
                .map_err(plot_err)?;
            chart
                .configure_mesh()
                .x_desc("wavelength (nm)")
                .y_desc("spectral radiance")
                .label_style((FONT, 12))
                .y_label_formatter(&|v| format!("{v:.1e}"))
                .draw()
                .map_err(plot_err)?;
            chart
                .draw_series(LineSeries::new(
                    pts.iter().copied(),
                    COLOURS[0].stroke_width(2),
                ))
                .map_err(plot_err)?;
            root.present().map_err(plot_err)?;
        }
        let rgba: Vec<u8> = buf
            .chunks_exact(3)
            .flat_map(|p| [p[0], p[1], p[2], 255])
            .collect();
        let img = image::RgbaImage::from_raw(size.0, size.1, rgba).context("frame size")?;
        let ms = if k + 1 == pick.len() { 1500 } else { 120 };
        frames.push(image::Frame::from_parts(
            img,
            0,
            0,
            image::Delay::from_numer_denom_ms(ms, 1),
        ));
    }
    write_via_temp_path(path, |p| {
        let file =
            std::fs::File::create(p).with_context(|| format!("cannot write {}", path.display()))?;
        let mut enc =
            image::codecs::gif::GifEncoder::new_with_speed(std::io::BufWriter::new(file), 10);
        enc.set_repeat(image::codecs::gif::Repeat::Infinite)
            .map_err(|e| anyhow!("gif: {e}"))?;
        enc.encode_frames(frames)
            .with_context(|| format!("cannot write {}", path.display()))
    })
}

/// One picked pixel of the demo: its position and its spectra with Doppler on and off.
struct DemoPick {
    xy: (u32, u32),
    on: Vec<(f64, f64)>,
    off: Vec<(f64, f64)>,
}
