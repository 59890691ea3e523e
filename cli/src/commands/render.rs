//! `blueshift render`: renders a volume scene with Woodcock tracking, multi-density Woodcock
//! tracking (N-DDA or 1-DDA) or the emission-absorption ray marcher, writing an OpenEXR
//! image (linear HDR RGBA, alpha = 1 - transmittance) and optionally a PNG preview.
//!
//! The scene comes from a JSON file (`blueshift render scene.json`), from inline flags, or
//! both (flags override the file). Extinction per unit world length (the volume's spacing
//! unit) is the transfer function's opacity, times its alpha_g, times `--density-scale`; all
//! methods use this definition, so images compare across methods at the same scale.
//!
//! Scene file: `blueshift_tracking::scene_file` (format, defaults and the loader); this
//! module maps the flags over it, picks the device and writes the outputs.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result, anyhow, bail};
use blueshift_tracking::{
    ChannelSpec, HeatMap, LightSpec, Progressive, RenderSceneFile, Scene, TfRange, TrackingOutput,
    TrackingSession,
};

/// Arguments of `blueshift render`.
#[derive(Clone, Debug, clap::Args)]
pub struct Args {
    /// Scene file (JSON); flags below override its fields.
    pub scene: Option<PathBuf>,
    /// Volume file of a channel (repeat; pairs with --tf in order). Its first channel is used.
    #[arg(long = "volume")]
    pub volumes: Vec<PathBuf>,
    /// A time series of snapshots, one frame each (frame k written as STEM_kkkk.EXT for
    /// every output): volume files (each the one channel's --volume; raw, NRRD, .bsv, AMR
    /// output, ...) or scene files (`.json`, each the frame's scene). Give --tf-range LO:HI
    /// to keep one colour scale over the series. `--distributed frames` spreads the frames
    /// over the ranks.
    #[arg(long, num_args = 1.., value_name = "PATH", conflicts_with = "synth")]
    pub series: Vec<PathBuf>,
    /// Synthetic dataset whose channels are all rendered (three-cubes, galaxy, channels12, ...).
    #[arg(long)]
    pub synth: Option<String>,
    /// Resolution of --synth (voxels per edge).
    #[arg(long, default_value_t = 64)]
    pub res: usize,
    /// Transfer function per channel (repeat), or one for all: JSON file (blueshift or
    /// ParaView preset with opacity Points), builtin:NAME or log:NAME. Built-in maps
    /// (builtin:, log:) are already stretched over each channel's value range; a file keeps
    /// its own domain (see --tf-range).
    #[arg(long = "tf")]
    pub tfs: Vec<String>,
    /// Stretch every transfer function over `data` (each channel's value range, ParaView's
    /// "rescale to data range") or `LO:HI` (data units), keeping each knot's relative
    /// position. Needed for a preset on [0, 1] applied to data such as CT values 0-4000.
    #[arg(long, value_name = "data|LO:HI", allow_hyphen_values = true)]
    pub tf_range: Option<String>,
    /// woodcock | mdwt-ndda | mdwt-1dda | mdwt-summed | marcher [default: mdwt-1dda].
    #[arg(long)]
    pub method: Option<String>,
    /// Channel index tracked by --method woodcock [default: 0].
    #[arg(long)]
    pub channel: Option<usize>,
    /// density | max | mix | weighted | composite (weighted without --weights: majorant
    /// weights, every channel peaking at the weakest channel's extinction) [default: density].
    #[arg(long)]
    pub blend: Option<String>,
    /// Weights for mix/composite, comma-separated, one per channel (default equal).
    #[arg(long, value_delimiter = ',')]
    pub weights: Option<Vec<f32>>,
    /// Samples per pixel (the maximum with --noise-target) [default: 16; 1 for the marcher,
    /// which is deterministic but for its jittered start].
    #[arg(long)]
    pub spp: Option<u32>,
    /// Seed of the random numbers (same seed, same image, any thread count) [default: 0].
    #[arg(long)]
    pub seed: Option<u64>,
    /// Image width in pixels [default: 512].
    #[arg(long)]
    pub width: Option<u32>,
    /// Image height in pixels [default: 512].
    #[arg(long)]
    pub height: Option<u32>,
    /// ortho | perspective [default: perspective]. The default view is yt's: the observer on
    /// the +z side looking towards -z, world +x right and +y up (see --view).
    #[arg(long)]
    pub camera: Option<String>,
    /// Vertical field of view of the perspective camera, degrees; the view is framed for it
    /// [default: 30].
    #[arg(long, allow_hyphen_values = true)]
    pub fov: Option<f32>,
    /// View preset, eye, target, up and zoom.
    #[command(flatten)]
    pub view: super::view_args::ViewArgs,
    /// Background colour R,G,B (linear) [default: 0,0,0].
    #[arg(long, value_delimiter = ',')]
    pub background: Option<Vec<f32>>,
    /// Extinction per unit world length = opacity x this [default: 1].
    #[arg(long)]
    pub density_scale: Option<f32>,
    /// Macrocell edge in voxels [default: 4].
    #[arg(long)]
    pub macrocell: Option<usize>,
    /// Marcher compositing precision: f32 | f16 | u8 [default: f32].
    #[arg(long)]
    pub precision: Option<String>,
    /// Marcher step in world units (default half the smallest spacing).
    #[arg(long)]
    pub step: Option<f32>,
    /// Global opacity alpha_g applied to every transfer function [default: the TF's own, 1].
    #[arg(long)]
    pub alpha_g: Option<f32>,
    /// Direction towards a directional light X,Y,Z (enables shadows; tracking methods only).
    #[arg(
        long,
        alias = "light",
        value_delimiter = ',',
        allow_hyphen_values = true
    )]
    pub light_dir: Option<Vec<f32>>,
    /// Light radiance R,G,B (default 1,1,1).
    #[arg(long, value_delimiter = ',')]
    pub light_radiance: Option<Vec<f32>>,
    /// Light intensity (grey radiance; --light-radiance wins if both are given).
    #[arg(long, allow_hyphen_values = true)]
    pub light_intensity: Option<f32>,
    /// Gradient shading at real collisions with the channels' Blinn-Phong materials (scene
    /// file "material" per channel); lit by --light (shadowed) or a headlight.
    #[arg(long)]
    pub shading: bool,
    /// Write a heat map (repeat): steps | collisions | rejections | time. All go as channels
    /// into OUT.heat.exr, each as a colour-mapped PNG with a colour bar OUT.heat-NAME.png.
    #[arg(long = "heatmap")]
    pub heatmaps: Vec<String>,
    /// Timing protocol: warm-up frames (1 spp each, discarded) before the timed frames.
    #[arg(long)]
    pub warmup: Option<u32>,
    /// Timing protocol: timed frames of 1 spp each, accumulated (replaces --spp); --json
    /// prints the frame times.
    #[arg(long)]
    pub frames: Option<u32>,
    /// Unshadowed ambient light with --light-dir (default 0.2).
    #[arg(long)]
    pub ambient: Option<f32>,
    /// Stop once the RMS standard error of the pixels falls to this.
    #[arg(long)]
    pub noise_target: Option<f64>,
    /// Output OpenEXR file.
    #[arg(long)]
    pub out: PathBuf,
    /// Draw an orientation triad (world x red, y green, z blue, as the camera sees them) in
    /// the PNG preview's bottom-right corner.
    #[arg(long)]
    pub triad: bool,
    /// Also write a PNG preview (exposure, clamp, sRGB; or a tone-mapping operator).
    #[arg(long)]
    pub png: Option<PathBuf>,
    /// A moving observer: relativistic aberration and colour shift of an observer flying
    /// through the volume (CPU).
    #[command(flatten)]
    pub observer: super::observer_args::ObserverArgs,
    /// With a moving observer: brightness scaled by the searchlight effect (D^4).
    #[arg(long)]
    pub searchlight: bool,
    /// Tone mapping of the PNG preview: `exposure` (exposure, clamp, sRGB) or an operator of
    /// blueshift-tonemap with its paper's default parameters: linear, drago, reinhard,
    /// reinhard-local, durand, fattal.
    #[arg(long, default_value = "exposure")]
    pub tonemap: String,
    /// Exposure of the PNG preview in stops.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    pub exposure: f32,
    /// Worker threads (default: all cores); the image does not depend on it.
    #[arg(long)]
    pub threads: Option<usize>,
    /// Print a JSON summary on stdout.
    #[arg(long)]
    pub json: bool,
    /// Out-of-core (.bsv) channels: budget of the brick cache they share, MiB [default: a
    /// quarter of physical memory, at most half of --max-memory]; more than --max-memory is
    /// refused. The image does not depend on it.
    #[arg(long, value_name = "MIB")]
    pub cache_mb: Option<u64>,
    /// Level of detail of .bsv and AMR channels: exact (the finest level: the in-core image;
    /// the default for .bsv), auto (the coarsest level whose voxels are no larger than a
    /// pixel where the volume is nearest to the camera; the default for AMR output, whose
    /// regions are each sampled at their own data's level below it), brick (that rule per
    /// brick of the finest level, where the brick is nearest: far bricks are read coarse;
    /// CPU), or a level number (0 = finest).
    #[arg(long)]
    pub lod: Option<String>,
    /// Progressive levels of detail (every channel a .bsv file; CPU). `levels` (the default):
    /// one quick pass (1 spp) at each level from the coarsest down to the one above the --lod
    /// level, then the full render at the --lod level (exact by default). `bricks` (HDR
    /// VolVis 6.3, refining while bricks load): a quick pass at the coarsest level, then
    /// quick passes in which each brick's region samples the finest level loaded there so
    /// far while the --lod level loads along the view, then the full render. Each step's
    /// level and time go to stderr
    #[arg(long, num_args = 0..=1, default_missing_value = "levels", value_name = "levels|bricks")]
    pub progressive: Option<String>,
    /// Where to render: cpu (default, bit-reproducible), gpu (a wgpu adapter or an error)
    /// or auto (a hardware GPU when present, or the adapter $BLUESHIFT_GPU forces, else the
    /// CPU). The GPU supports every method, blend and light; shading, heat maps and
    /// --frames are CPU-only, and a render over the adapter's limits (buffer sizes,
    /// lavapipe's loop limit) fails on gpu; auto renders those on the CPU.
    #[arg(long, default_value = "cpu")]
    pub device: blueshift_gpu::DeviceChoice,
    /// Spread the render over the ranks of an MPI job (run under `mpirun -np N`; needs a
    /// build with the `mpi` feature): `data` (a k-d split of the volume: the ray marcher marches each rank's piece, composited sort-last; Woodcock forwards each ray to the rank whose piece holds its next tentative collision, bit for bit), `samples` (each rank takes every N-th sample index: the image is the single-process image, bit for bit), `tiles` (bands of rows, also bit for bit), `frames` (the frames of `--series`, `--orbit` or `--ramp`, round robin; each rank writes its own). Rank 0 writes the outputs.
    #[arg(long, value_name = "MODE")]
    pub distributed: Option<String>,
    /// Compositing schedule of `--distributed data`: auto (binary swap for a power-of-two
    /// rank count, radix-k otherwise), direct-send, binary-swap, or radix-k factors `K1,K2,..`
    /// (bottom round first; their product is the rank count).
    #[arg(long, value_name = "SCHEDULE", default_value = "auto")]
    pub compositing: String,
    /// GPU: cap of the device brick pool, MiB [default: the adapter's largest storage
    /// buffer]. The pool holds only bricks that are not constant; when a level's do not fit,
    /// --lod auto renders the finest coarser level that does, other levels fail on gpu (auto
    /// renders them on the CPU).
    #[arg(long, value_name = "MIB")]
    pub gpu_pool_mb: Option<u64>,
}

/// Applies `--gpu-pool-mb` to `ctx` (checked: at least 1 MiB).
pub(crate) fn set_gpu_pool(
    ctx: &blueshift_gpu::GpuContext,
    mb: Option<u64>,
) -> blueshift_gpu::Result<()> {
    match mb {
        Some(0) => Err(blueshift_gpu::Error::InvalidInput(
            "--gpu-pool-mb: must be at least 1".into(),
        )),
        mb => {
            ctx.set_pool_limit(mb.map(|m| m.saturating_mul(1 << 20)));
            Ok(())
        }
    }
}

/// One stderr line on the device brick pool when it is worth saying: an out-of-core scene
/// (`bricked`), a level of detail (`got`), or a pool smaller than the dense volume.
pub(crate) fn report_pool(
    stats: &blueshift_gpu::pool::PoolStats,
    bricked: bool,
    asked: Option<usize>,
    got: Option<usize>,
) {
    if bricked || got.is_some() || stats.pool_bytes < stats.dense_bytes {
        let level = match (asked, got) {
            (Some(a), Some(g)) if a != g => {
                format!(" at level {g} (level {a} does not fit the pool)")
            }
            (_, Some(g)) => format!(" at level {g}"),
            _ => String::new(),
        };
        errln!("{stats}{level}");
    }
}

use super::view_args::triple;

/// A name flag through its `FromStr` (the library's message lists the accepted spellings).
fn parse_name<T>(v: Option<&String>) -> Result<Option<T>>
where
    T: std::str::FromStr<Err = blueshift_tracking::Error>,
{
    Ok(v.map(|s| s.parse::<T>()).transpose()?)
}

/// The scene: the file (if any) with the flags over it.
pub(crate) fn merge(args: &Args) -> Result<RenderSceneFile> {
    let mut f = match &args.scene {
        Some(path) => {
            blueshift_volume::io::check_regular_file(path)
                .with_context(|| format!("cannot read scene file {}", path.display()))?;
            let text = std::fs::read_to_string(path)
                .with_context(|| format!("cannot read scene file {}", path.display()))?;
            RenderSceneFile::from_json(&text, path)?
        }
        None => RenderSceneFile::default(),
    };
    // Inline channels replace the file's (their paths are relative to the working
    // directory); --tf alone replaces the file's transfer functions.
    if !args.volumes.is_empty() || args.synth.is_some() {
        let mut chans = Vec::new();
        for v in &args.volumes {
            chans.push(ChannelSpec {
                volume: Some(v.clone()),
                ..ChannelSpec::default()
            });
        }
        if let Some(name) = &args.synth {
            chans.extend(
                ChannelSpec::synth_channels(name, args.res)
                    .with_context(|| format!("--synth {name}"))?,
            );
        }
        let tfs = &args.tfs;
        if tfs.is_empty() {
            bail!("--tf: give one transfer function per channel (or one for all)");
        }
        if tfs.len() != 1 && tfs.len() != chans.len() {
            bail!(
                "--tf: {} transfer functions for {} channels (give one per channel or one for all)",
                tfs.len(),
                chans.len()
            );
        }
        for (i, c) in chans.iter_mut().enumerate() {
            c.tf = tfs[if tfs.len() == 1 { 0 } else { i }].clone();
        }
        f.channels = chans;
        f.base = None;
    } else if !args.tfs.is_empty() {
        if args.tfs.len() != f.channels.len() {
            bail!(
                "--tf: {} transfer functions for {} channels",
                args.tfs.len(),
                f.channels.len()
            );
        }
        for (c, t) in f.channels.iter_mut().zip(&args.tfs) {
            c.tf = t.clone();
        }
    }
    let background = args
        .background
        .as_deref()
        .map(|b| triple(b, "--background"))
        .transpose()?;
    let light = match &args.light_dir {
        Some(d) => {
            let radiance = match (&args.light_radiance, args.light_intensity) {
                (Some(r), _) => triple(r, "--light-radiance")?,
                (None, Some(i)) if i.is_finite() && i >= 0.0 => [i; 3],
                (None, Some(i)) => bail!("--light-intensity: {i} must be finite and non-negative"),
                (None, None) => LightSpec::DEFAULT_RADIANCE,
            };
            Some(LightSpec {
                direction: triple(d, "--light-dir")?,
                radiance,
                ambient: args.ambient.unwrap_or(LightSpec::DEFAULT_AMBIENT),
            })
        }
        None => None,
    };
    let heatmaps = args
        .heatmaps
        .iter()
        .map(|h| h.parse::<HeatMap>().context("--heatmap"))
        .collect::<Result<Vec<_>>>()?;
    let [view_eye, view_target, view_up] = args.view.points()?;
    f.override_with(RenderSceneFile {
        channels: Vec::new(),
        method: parse_name(args.method.as_ref())?,
        woodcock_channel: args.channel,
        blend: parse_name(args.blend.as_ref())?,
        weights: args.weights.clone(),
        spp: args.spp,
        seed: args.seed,
        width: args.width,
        height: args.height,
        camera: parse_name(args.camera.as_ref())?,
        fov_y_deg: args.fov,
        eye: view_eye,
        target: view_target,
        up: view_up,
        view: args.view.preset()?.map(|v| v.to_string()),
        zoom: args.view.zoom,
        background,
        density_scale: args.density_scale,
        macrocell: args.macrocell,
        precision: parse_name(args.precision.as_ref())?,
        step: args.step,
        alpha_g: args.alpha_g,
        noise_target: args.noise_target,
        light,
        shading: args.shading.then_some(true),
        heatmaps: (!heatmaps.is_empty()).then_some(heatmaps),
        warmup: args.warmup,
        frames: args.frames,
        tf_range: args
            .tf_range
            .as_deref()
            .map(str::parse::<TfRange>)
            .transpose()
            .map_err(|e| match e {
                blueshift_tracking::Error::Parameter(m) => anyhow!("--{m}"),
                other => other.into(),
            })?,
        lod: args.lod.clone(),
        observer_velocity: None,
        searchlight: None,
        base: None,
    });
    if f.channels.is_empty() {
        bail!(
            "channels: none given (use a scene file, --volume FILE --tf TF, or --synth NAME --tf TF)"
        );
    }
    if f.warmup.is_some() && f.frames.is_none() {
        bail!("--warmup: needs --frames N (the timed frames)");
    }
    Ok(f)
}

/// Runs `blueshift render`.
pub fn run(args: Args) -> Result<()> {
    // --out is always OpenEXR: another image format's name would hold EXR bytes.
    if let Some(ext) = args
        .out
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        && ["png", "jpg", "jpeg", "hdr", "pfm", "tif", "tiff"].contains(&ext.as_str())
    {
        bail!(
            "--out writes OpenEXR, not .{ext}: name it .exr (--png OUT.png adds a tone-mapped \
             PNG): {}",
            args.out.display()
        );
    }
    let mode = crate::dist::mode(args.distributed.as_deref())?;
    use blueshift_dist::Mode;
    crate::dist::check_mode(
        mode,
        &[Mode::Data, Mode::Samples, Mode::Tiles, Mode::Frames],
        "render",
    )?;
    use super::observer_args::{Series, frame_path, run_frames};
    let outputs = |a: &mut Args, k: usize| {
        a.out = frame_path(&a.out, k);
        a.png = a.png.as_deref().map(|p| frame_path(p, k));
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
        if p.extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("json"))
        {
            a.scene = Some(p.to_path_buf());
        } else {
            if a.volumes.len() > 1 {
                bail!(
                    "--series {}: a volume series replaces the one --volume; for several \
                     channels give one scene file per snapshot",
                    p.display()
                );
            }
            a.volumes = vec![p.to_path_buf()];
        }
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

/// Checks the outputs of frames (each one's image, PNG and heat maps) against all their
/// inputs (volumes, scene and transfer function files) and `more` inputs, in one pass.
fn check_frame_outputs(frames: &[&Args], more: &[&Path]) -> Result<()> {
    let heat: Vec<Vec<PathBuf>> = frames
        .iter()
        .map(|a| crate::commands::render_heat::heat_outputs(&a.out, &a.heatmaps))
        .collect();
    let mut outputs: Vec<&Path> = Vec::new();
    let mut inputs: Vec<&Path> = more.to_vec();
    for (args, heat) in frames.iter().zip(&heat) {
        outputs.push(args.out.as_path());
        outputs.extend(args.png.as_deref());
        outputs.extend(heat.iter().map(PathBuf::as_path));
        inputs.extend(args.volumes.iter().map(PathBuf::as_path));
        inputs.extend(args.scene.as_deref());
        // Transfer function files (not `builtin:` / `log:` names, which name no file).
        inputs.extend(args.tfs.iter().map(Path::new).filter(|p| p.is_file()));
    }
    crate::output::check_outputs(&outputs, &inputs)
}

fn run_frame(args: Args) -> Result<()> {
    if !args.exposure.is_finite() {
        bail!(
            "--exposure {}: must be a finite number of stops",
            args.exposure
        );
    }
    // Refuse a bad preview operator before spending time on the render.
    if !TONEMAPS.contains(&args.tonemap.as_str()) {
        bail!(
            "--tonemap {:?}: expected one of {}",
            args.tonemap,
            TONEMAPS.join(", ")
        );
    }
    // Refuse an output that cannot be written before loading or rendering anything.
    check_frame_outputs(&[&args], &[])?;
    match crate::limits::thread_pool(args.threads)? {
        Some(pool) => pool.install(|| run_inner(&args)),
        None => run_inner(&args),
    }
}

/// Bytes per pixel a render holds: the accumulation's mean and variance (RGBA f64), one
/// pass (RGBA f32), the mean image written as EXR (RGBA f32) and the PNG preview (RGBA8).
const RENDER_BYTES_PER_PIXEL: u64 = 64 + 16 + 16 + 4;
/// More bytes per pixel with heat maps (their RGBA f64 accumulation).
const HEAT_BYTES_PER_PIXEL: u64 = 32;

/// Checks a `width` x `height` render's image memory against the budget.
fn check_image_memory(width: u32, height: u32, heat: bool) -> Result<()> {
    let per = RENDER_BYTES_PER_PIXEL + if heat { HEAT_BYTES_PER_PIXEL } else { 0 };
    crate::limits::check(
        format_args!("this render ({width}x{height} image, {per} bytes per pixel)"),
        blueshift_volume::budget::image_bytes(width.into(), height.into(), per),
    )
}

/// The brick cache of out-of-core channels for `--cache-mb` (checked: at least 1 MiB).
pub(crate) fn brick_cache(
    cache_mb: Option<u64>,
) -> Result<std::sync::Arc<blueshift_volume::BrickCache>> {
    // Within the memory budget (--max-memory, default 3/4 of physical memory).
    let budget = crate::limits::budget().bytes();
    let bytes = match cache_mb {
        None => (blueshift_volume::cache::default_budget() as u64).min(budget / 2),
        Some(0) => bail!("--cache-mb: must be at least 1"),
        Some(mb) if mb.saturating_mul(1 << 20) > budget => bail!(
            "--cache-mb {mb}: more than the memory budget of {} MiB (--max-memory)",
            budget >> 20
        ),
        Some(mb) => mb << 20,
    };
    let bytes = usize::try_from(bytes).unwrap_or(usize::MAX);
    Ok(blueshift_volume::BrickCache::new(bytes))
}

/// Refuses bricked fields one of whose bricks alone exceeds `--max-memory`: the brick cache
/// holds at least one brick whatever `--cache-mb` says (a 256^3 volume converted with
/// `--brick 1024` is one brick of 258^3 floats, 69 MB).
pub(crate) fn check_brick_sizes<'a>(
    fields: impl IntoIterator<Item = &'a blueshift_volume::Field>,
) -> Result<()> {
    for f in fields {
        if let Some(b) = f.as_bricked() {
            let l = b.source().layout();
            let s = l.stored_edge() as u64;
            crate::limits::budget()
                .check(
                    format_args!("one brick of edge {} (with its apron, in f32)", l.brick),
                    s.saturating_pow(3).saturating_mul(4),
                )
                .map_err(|e| anyhow::anyhow!("{e}: convert with a smaller --brick"))?;
        }
    }
    Ok(())
}

/// One line on stderr about the out-of-core reads of a render (nothing for in-core scenes).
pub(crate) fn report_cache(cache: &blueshift_volume::BrickCache, level: Option<usize>) {
    let s = cache.stats();
    if s.total_reads() == 0 && s.hits == 0 {
        return;
    }
    let reads: Vec<String> = s
        .reads
        .iter()
        .enumerate()
        .filter(|(_, n)| **n > 0)
        .map(|(l, n)| format!("{n} at level {l}"))
        .collect();
    let rss = peak_rss_bytes().map_or_else(String::new, |b| {
        format!(
            "; process peak resident {:.1} MiB",
            b as f64 / f64::from(1u32 << 20)
        )
    });
    errln!(
        "out-of-core: level {} sampled; bricks read: {} ({} prefetched); cache peak {:.1} MiB of {:.1} MiB{rss}",
        level.map_or_else(|| "-".to_owned(), |l| l.to_string()),
        if reads.is_empty() {
            "none".to_owned()
        } else {
            reads.join(", ")
        },
        s.prefetched,
        s.peak_bytes as f64 / f64::from(1u32 << 20),
        cache.budget() as f64 / f64::from(1u32 << 20),
    );
}

/// The process's peak resident memory (`VmHWM` of `/proc/self/status`; `None` off Linux).
pub(crate) fn peak_rss_bytes() -> Option<u64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = s.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

fn run_inner(args: &Args) -> Result<()> {
    let f = merge(args)?;
    let cache = brick_cache(args.cache_mb)?;
    let memory = blueshift_tracking::scene_file::Preloaded {
        cache: Some(cache.clone()),
        budget: Some(crate::limits::budget().clone()),
        ..Default::default()
    };
    // `--distributed data` with the marcher: each rank reads only its piece's AMR blocks
    // (Woodcock's forwarded rays need the majorants of the whole volume on every rank).
    let data_parallel = crate::dist::mode(args.distributed.as_deref())?
        == Some(blueshift_dist::Mode::Data)
        && f.method != Some(blueshift_tracking::Method::Woodcock);
    let (scene, integrator, mut settings) = if data_parallel {
        crate::dist::load_scoped(&args.compositing, &[], || Ok(f.build_with(&memory)?))?
    } else {
        f.build_with(&memory)?
    };
    check_brick_sizes(scene.channels().iter().map(|c| c.grid()))?;
    settings.camera = args.view.orbited(settings.camera)?;
    let view = (settings.camera.target - settings.camera.eye).normalize_or_zero();
    let searchlight = args.searchlight || f.searchlight.unwrap_or(false);
    if let Some(o) = args.observer.observer(view, None, searchlight)? {
        settings.observer = Some(o);
    } else if args.searchlight && settings.observer.is_none() {
        bail!("--searchlight needs a moving observer (--observer-velocity, --beta or --ramp)");
    }
    let lod = f.lod()?;
    // As doppler: a level of detail asked for where a channel is in memory (which has its
    // finest level only) is refused rather than ignored.
    if f.lod.is_some()
        && !matches!(
            lod,
            blueshift_volume::Lod::Exact | blueshift_volume::Lod::Level(0)
        )
        && scene
            .channels()
            .iter()
            .any(|c| c.grid().as_bricked().is_none())
    {
        bail!("--lod {lod}: levels of detail need every channel of the scene in .bsv files");
    }
    let level = scene
        .channels()
        .iter()
        .find_map(|c| c.grid().as_bricked().map(|b| b.level()));
    let by_bricks = match args.progressive.as_deref() {
        None | Some("levels") => false,
        Some("bricks") => true,
        Some(other) => bail!("--progressive {other}: levels or bricks"),
    };
    if args.progressive.is_some() {
        if scene.lod().is_none() {
            bail!("--progressive: levels of detail need every channel in a .bsv file");
        }
        let per_brick = scene.channels().iter().any(|c| {
            c.grid()
                .as_bricked()
                .is_some_and(|b| b.level_map().is_some())
        });
        if per_brick {
            bail!("--lod brick: --progressive renders whole levels");
        }
    }
    // Distributed: each rank reads only the bricks its piece samples (no whole-view prefetch).
    if level.is_some() && args.distributed.is_none() {
        prefetch_view(&scene, &settings);
    }
    let settings_camera = settings.camera;
    if f.tf_range.is_none() {
        warn_tf_domains(&scene);
    }
    let heatmaps = f.heatmaps();
    check_image_memory(settings.width, settings.height, !heatmaps.is_empty())?;
    let method = integrator.method().name();
    let n = scene.channels().len();
    let (width, height) = (settings.width, settings.height);
    let device = args.device;
    let supported = blueshift_gpu::tracking::supports(&scene, &settings);
    // gpu hands the scene to the device; auto keeps it for the CPU in case the adapter
    // cannot run this render.
    let slot = std::cell::RefCell::new(Some(scene));
    let take = || {
        slot.borrow_mut()
            .take()
            .ok_or_else(|| anyhow!("scene already used"))
    };
    let bar = crate::progress::Progress::new(
        settings.timed_frames.map_or(u64::from(settings.spp), |f| {
            u64::from(f) + u64::from(settings.warmup)
        }),
        "{bar:30} {pos}/{len} passes  {msg}  [{elapsed}]",
        "render",
        "passes",
    );
    let show = |done: u32, noise: f64| {
        bar.set_position(u64::from(done));
        if noise.is_finite() {
            bar.set_message(format!("noise {noise:.4}"));
        }
    };
    let start = Instant::now();
    let distributed = match crate::dist::mode(args.distributed.as_deref())? {
        Some(mode) => {
            if args.progressive.is_some() {
                bail!("--distributed: not with --progressive");
            }
            match crate::dist::tracking(mode, take()?, &integrator, &settings, &args.compositing)? {
                // Not rank 0: rank 0 writes the outputs.
                None => return Ok(()),
                Some(acc) => Some(blueshift_gpu::Ran {
                    value: TrackingOutput {
                        image: acc,
                        frame_times: None,
                    },
                    device: blueshift_camera::DeviceKind::Cpu,
                    fallback: None,
                }),
            }
        }
        None => None,
    };
    let ran = if let Some(ran) = distributed {
        ran
    } else {
        blueshift_gpu::run_with_fallback(
            device,
            || supported.clone(),
            |ctx| {
                let scene = match device {
                    blueshift_gpu::DeviceChoice::Auto => slot.borrow().clone(),
                    _ => slot.borrow_mut().take(),
                }
                .ok_or_else(|| blueshift_gpu::Error::InvalidInput("no scene".into()))?;
                set_gpu_pool(ctx, args.gpu_pool_mb)?;
                if args.progressive.is_some() {
                    // Every pass a view of one device pool: only the bricks a pass adds
                    // are uploaded.
                    let observer = Steps::new(&show, &scene);
                    let mut session = blueshift_gpu::tracking::GpuTrackingSession::new_progressive(
                        ctx,
                        scene,
                        integrator.clone(),
                        settings.clone(),
                    )?;
                    let out = if by_bricks {
                        let mut on_step = |_, at: usize, regions: usize| {
                            *observer
                                .note
                                .lock()
                                .unwrap_or_else(std::sync::PoisonError::into_inner) =
                                format!(", {at} of {regions} bricks at the final level");
                        };
                        session.render_bricks(&observer, &mut on_step)?
                    } else {
                        session.render_lod(&observer)?
                    };
                    drop(observer);
                    report_pool(&session.scene().pool_stats(), true, level, level);
                    return Ok(out);
                }
                let tracker = blueshift_gpu::tracking::GpuTracker::new(ctx)?;
                let (gs, got) = if lod == blueshift_volume::Lod::Auto {
                    tracker.upload_fitting(scene)?
                } else if lod == blueshift_volume::Lod::Brick {
                    // A pool too small for the per-brick view: every region coarser.
                    let (gs, k) = tracker.upload_fitting_regions(scene)?;
                    if k > 0 {
                        errln!(
                            "--lod brick: every brick {k} level(s) coarser than the rule asks, \
                             to fit the GPU brick pool"
                        );
                    }
                    (gs, level)
                } else {
                    (tracker.upload(scene)?, level)
                };
                report_pool(&gs.pool_stats(), level.is_some(), level, got);
                let image = tracker.render_progressive(&gs, &integrator, &settings, show)?;
                Ok(TrackingOutput {
                    image,
                    frame_times: None,
                })
            },
            || -> Result<TrackingOutput> {
                let session = TrackingSession::new(take()?, integrator.clone(), settings.clone())?;
                if args.progressive.is_some() {
                    let observer = Steps::new(&show, session.scene());
                    if by_bricks {
                        let mut on_step = |_, at: usize, regions: usize| {
                            *observer
                                .note
                                .lock()
                                .unwrap_or_else(std::sync::PoisonError::into_inner) =
                                format!(", {at} of {regions} bricks at the final level");
                        };
                        return Ok(session.render_bricks(&observer, &mut on_step)?);
                    }
                    return Ok(session.render_lod(&observer)?);
                }
                Ok(session.render(&OnPass(&bar))?)
            },
        )
        .map_err(crate::commands::doppler::device_error)?
    };
    bar.finish();
    if let Some(why) = &ran.fallback {
        errln!("--device auto: {why}; rendering on the CPU");
    }
    let seconds = start.elapsed().as_secs_f64();
    report_cache(&cache, level);
    let on_gpu = ran.device == blueshift_camera::DeviceKind::Gpu;
    let TrackingOutput {
        image: acc,
        frame_times: times,
    } = ran.value;
    let img = acc.mean_image();
    // The heat maps, the EXR and its --png preview are one set: all staged, then renamed
    // (the EXR last).
    let mut set = crate::output::OutputSet::new();
    let (heat_files, heat_paths) =
        crate::commands::render_heat::write_heatmaps(&mut set, &args.out, &acc, &heatmaps)?;
    if let Some(png) = &args.png {
        let triad = if args.triad {
            Some(crate::figure::triad_overlay(
                img.width(),
                img.height(),
                &settings_camera,
            )?)
        } else {
            None
        };
        write_png_preview(
            &mut set,
            &img,
            png,
            &args.tonemap,
            args.exposure,
            triad.as_deref(),
        )?;
    }
    crate::output::stage_exr_f32(
        &mut set,
        &args.out,
        (img.width(), img.height()),
        4,
        img.as_raw(),
    )?;
    set.commit()?;
    for p in &heat_paths {
        crate::output::wrote(p);
    }
    let noise = acc.noise();
    let adapter = on_gpu
        .then(|| {
            device
                .context()
                .ok()
                .flatten()
                .map(|c| c.info().name.clone())
        })
        .flatten();
    if args.json {
        let mut summary = serde_json::json!({
            "out": args.out,
            "png": args.png,
            "method": method,
            "channels": n,
            "width": width,
            "height": height,
            "spp": acc.samples(),
            "device": ran.device.to_string(),
            "noise": if noise.is_finite() { Some(noise) } else { None },
            "seconds": seconds,
            "heatmaps": heat_files,
            "timings": times.as_ref().map(|t| serde_json::json!({
                "warmup": t.warmup,
                "frames": t.frames.len(),
                "mean_s": t.mean(),
                "median_s": t.median(),
                "frame_s": t.frames,
            })),
        });
        if let Some(a) = &adapter {
            summary["adapter"] = serde_json::json!(a);
        }
        outln!("{summary}");
    }
    let on = adapter.map(|a| format!(" on {a}")).unwrap_or_default();
    // One sample has no noise estimate: say nothing rather than "noise inf".
    let noise = if noise.is_finite() {
        format!(", noise {noise:.4}")
    } else {
        String::new()
    };
    crate::output::wrote_with(
        &args.out,
        &format!("{} spp{noise}, {seconds:.2} s{on}", acc.samples()),
    );
    if let Some(png) = &args.png {
        crate::output::wrote(png);
    }
    Ok(())
}

/// The fraction of a channel's value range its transfer function must cover before the
/// render runs without a warning.
const TF_MIN_COVER: f64 = 0.01;

/// Warns on stderr about each channel whose transfer function's domain misses its data (or
/// covers under [`TF_MIN_COVER`] of it): values beyond the domain take the end knots, so a
/// ParaView preset on [0, 1] over CT values 0-3926 renders an opaque silhouette.
fn warn_tf_domains(scene: &Scene) {
    for (i, c) in scene.channels().iter().enumerate() {
        let Some((lo, hi)) = c.grid().finite_range() else {
            continue;
        };
        let [tlo, thi] = c.transfer_function().domain();
        let (dlo, dhi) = (f64::from(lo), f64::from(hi));
        let overlap = (dhi.min(thi) - dlo.max(tlo)).max(0.0);
        let how = if dhi > dlo {
            let cover = overlap / (dhi - dlo);
            if cover >= TF_MIN_COVER {
                continue;
            }
            if overlap > 0.0 || (dlo..=dhi).contains(&tlo) || (dlo..=dhi).contains(&thi) {
                format!("covers only {:.2} % of", 100.0 * cover)
            } else {
                "does not overlap".to_owned()
            }
        } else if (tlo..=thi).contains(&dlo) {
            continue;
        } else {
            "does not contain".to_owned()
        };
        errln!(
            "warning: channel {i} ({}): the transfer function's domain [{tlo}, {thi}] {how} the data range [{lo}, {hi}]; use --tf-range data to stretch it over the data (built-in maps are already stretched)",
            c.name()
        );
    }
}

/// Forwards each finished pass (samples, noise) to the progress bar.
/// The CPU render's observer: the bar counts every pass (warm-up frames included), shows the
/// noise, and the render loop stops once SIGINT/SIGTERM is in.
struct OnPass<'a>(&'a crate::progress::Progress);

impl blueshift_camera::Observer<Progressive> for OnPass<'_> {
    fn progress(&self, p: blueshift_camera::Progress) {
        if p.total > 0 {
            self.0.set_length(p.total);
        }
        self.0.set_position(p.done);
    }

    fn pass(&self, _pass: u32, _acc: &Progressive, noise: Option<f64>) {
        // The loop's own estimate: computing it again here was a second serial pass over
        // the image after every pass.
        if let Some(noise) = noise.filter(|n| n.is_finite()) {
            self.0.set_message(format!("noise {noise:.4}"));
        }
    }

    fn cancelled(&self) -> bool {
        crate::signals::cancelled()
    }

    /// A progress bar needs no image per pass: passes may run in sweeps.
    fn every_pass(&self) -> bool {
        false
    }
}

/// The one stderr line of a `--progressive` pass: its level, the level's dims, its time and
/// the time since the run began.
pub(crate) fn progressive_line(
    pass: u32,
    level: usize,
    dims: &[[usize; 3]],
    what: &str,
    began: Instant,
    start: Instant,
) {
    let d = dims.get(level).copied().unwrap_or_default();
    errln!(
        "progressive: pass {pass}, level {level} ({}x{}x{}){what}: {:.2} s ({:.2} s since the start)",
        d[0],
        d[1],
        d[2],
        began.elapsed().as_secs_f64(),
        start.elapsed().as_secs_f64()
    );
}

/// `--progressive`: one stderr line per preview step, the final level's passes to the bar.
struct Steps<'a, F> {
    show: &'a F,
    start: Instant,
    /// `(step, level, started)` of the step running.
    current: std::sync::Mutex<(u32, usize, Instant)>,
    final_level: usize,
    dims: Vec<[usize; 3]>,
    /// Said after the next quick step's level (`--progressive bricks`: the share of bricks
    /// at the final level).
    note: std::sync::Mutex<String>,
}

impl<'a, F> Steps<'a, F> {
    fn new(show: &'a F, scene: &blueshift_tracking::Scene) -> Self {
        let dims = scene
            .channels()
            .first()
            .and_then(|c| c.grid().as_bricked())
            .map(|b| b.source().geometries().iter().map(|g| g.dims).collect())
            .unwrap_or_default();
        Steps {
            show,
            start: Instant::now(),
            current: std::sync::Mutex::new((0, 0, Instant::now())),
            final_level: scene.lod().map_or(0, |l| l.0),
            dims,
            note: std::sync::Mutex::new(String::new()),
        }
    }

    fn line(&self, step: u32, level: usize, began: Instant, what: &str) {
        progressive_line(step, level, &self.dims, what, began, self.start);
    }
}

impl<F: Fn(u32, f64) + Sync> blueshift_camera::Observer<Progressive> for Steps<'_, F> {
    fn level(&self, step: u32, level: usize) {
        *self
            .current
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner) = (step, level, Instant::now());
    }
    fn pass(&self, pass: u32, acc: &Progressive, _noise: Option<f64>) {
        let (step, level, began) = *self
            .current
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        if level == self.final_level {
            (self.show)(pass, acc.noise());
        } else {
            let note = std::mem::take(
                &mut *self
                    .note
                    .lock()
                    .unwrap_or_else(std::sync::PoisonError::into_inner),
            );
            let what = if note.is_empty() {
                ", 1 spp".to_string()
            } else {
                format!(" and finer where loaded{note}, 1 spp")
            };
            self.line(step, level, began, &what);
        }
    }
}

impl<F> Drop for Steps<'_, F> {
    fn drop(&mut self) {
        let (step, level, began) = *self
            .current
            .get_mut()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        if step > 0 && level == self.final_level {
            self.line(step, level, began, "");
        }
    }
}

// The names `--tonemap` accepts: the viewer's display operators.
use blueshift_view::display::TONEMAPS;

/// Writes the PNG preview of an HDR render: plain exposure + clamp + sRGB, or a tone-mapping
/// operator of blueshift-tonemap (the alpha channel is dropped; the background shows).
fn write_png_preview(
    set: &mut crate::output::OutputSet,
    img: &image::Rgba32FImage,
    png: &Path,
    tonemap: &str,
    exposure: f32,
    overlay: Option<&[u8]>,
) -> Result<()> {
    use blueshift_tonemap::{LinearParams, Operator};
    let op = blueshift_view::display::operator(tonemap, exposure)
        .map_err(|e| anyhow::anyhow!("--{e}"))?;
    let gain = 2f32.powf(exposure);
    let rgb = image::Rgb32FImage::from_fn(img.width(), img.height(), |x, y| {
        let p = img.get_pixel(x, y).0;
        image::Rgb([p[0], p[1], p[2]])
    });
    // The linear operator's white: the 99th percentile, as `blueshift tonemap` takes it.
    let op = match op {
        Some(Operator::Linear(p)) => Some(Operator::Linear(LinearParams {
            white: blueshift_tonemap::default_linear_white(&rgb),
            ..p
        })),
        other => other,
    };
    let display = match op {
        Some(op) => op
            .apply(&rgb)
            .with_context(|| format!("--tonemap {tonemap}"))?,
        None => image::Rgb32FImage::from_fn(rgb.width(), rgb.height(), |x, y| {
            let p = rgb.get_pixel(x, y).0;
            image::Rgb(p.map(|v| (v * gain).clamp(0.0, 1.0)))
        }),
    };
    let display = match overlay {
        None => display,
        Some(o) => {
            // The overlay's sRGB-encoded colours, decoded so the PNG writer encodes them back.
            let mut d = display;
            for (p, c) in d.pixels_mut().zip(o.chunks_exact(3)) {
                if c.iter().any(|&v| v > 0) {
                    p.0 = [0, 1, 2]
                        .map(|k| blueshift_spectrum::srgb_decode(f64::from(c[k]) / 255.0) as f32);
                }
            }
            d
        }
    };
    set.via_path(png, |p| {
        blueshift_tonemap::io::write_png(p, &display, blueshift_tonemap::io::PngDepth::Eight)
            .with_context(|| format!("cannot write {}", png.display()))
    })
}

/// Queues the bricks of every out-of-core channel along a sparse grid of the view's rays
/// (every 16th pixel, rows in render order) on the cache's I/O thread, so the first pass
/// finds most bricks loaded.
pub(crate) fn prefetch_view(
    scene: &blueshift_tracking::Scene,
    settings: &blueshift_tracking::RenderSettings,
) {
    let fields: Vec<&blueshift_volume::BrickedField> = scene
        .channels()
        .iter()
        .filter_map(|c| c.grid().as_bricked())
        .collect();
    let rays = settings
        .camera
        .sparse_rays(settings.width, settings.height, 16);
    blueshift_volume::BrickedField::prefetch_along(&fields, &rays);
}
