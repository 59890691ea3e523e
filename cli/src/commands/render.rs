//! `blueshift render`: renders a volume scene with Woodcock tracking, multi-density Woodcock
//! tracking (N-DDA or 1-DDA) or the emission-absorption ray marcher, writing an OpenEXR
//! image (linear HDR RGBA, alpha = 1 - transmittance) and optionally a PNG preview.
//!
//! The scene comes from a JSON file (`blueshift render scene.json`), from inline flags, or
//! both (flags override the file). Extinction per unit world length (the volume's spacing
//! unit) is the transfer function's opacity, times its alpha_g, times `--density-scale`; all
//! methods use this definition, so images compare across methods at the same scale.
//!
//! Scene file (unknown keys are refused; paths are relative to the file):
//! ```json
//! { "channels": [ { "volume": "head.nhdr", "tf": "bone.json" } ],
//!   "method": "mdwt-1dda", "blend": "density", "weights": null,
//!   "spp": 64, "seed": 1, "width": 512, "height": 512,
//!   "camera": "perspective", "fov_y_deg": 30, "eye": null, "target": null, "up": null,
//!   "background": [0, 0, 0], "density_scale": 1.0, "macrocell": 4,
//!   "precision": "f32", "step": null, "alpha_g": null, "noise_target": null,
//!   "light": { "direction": [1, 1, -1], "radiance": [1, 1, 1], "ambient": 0.2 },
//!   "shading": false, "heatmaps": ["steps"], "warmup": null, "frames": null }
//! ```
//! A channel is `{ "volume": FILE, "channel": NAME?, "tf": SPEC, "material": M? }` or
//! `{ "synth": NAME, "res": N?, "seed": S?, "channel": NAME?, "tf": SPEC }`. A TF SPEC is a
//! blueshift or ParaView JSON file, `builtin:NAME` (a built-in map stretched over the
//! channel's value range) or `log:NAME` (the same on a logarithmic data axis over the
//! channel's positive values, for data spanning decades). A material `M` for `shading` is
//! `{ "ambient": 1, "diffuse": 0.8, "specular": 0.2, "shininess": 32 }` (any may be left out).

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result, anyhow, bail};
use blueshift_tfedit::{ColorKnot, DataAxis, OpacityKnot, TransferFunction};
use blueshift_tracking::{
    Blend, Camera, DdaMode, DirectionalLight, HeatMap, Integrator, Material, Precision,
    Progressive, Projection, RayMarcher, RenderSettings, Scene, Shading, TrackingOutput,
    TrackingSession,
};
use blueshift_volume::{AnyGrid, synth};
use glam::Vec3;
use serde::Deserialize;

/// Arguments of `blueshift render`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Scene file (JSON); flags below override its fields.
    pub scene: Option<PathBuf>,
    /// Volume file of a channel (repeat; pairs with --tf in order). Its first channel is used.
    #[arg(long = "volume")]
    pub volumes: Vec<PathBuf>,
    /// Synthetic dataset whose channels are all rendered (three-cubes, galaxy, channels12, ...).
    #[arg(long)]
    pub synth: Option<String>,
    /// Resolution of --synth (voxels per edge).
    #[arg(long, default_value_t = 64)]
    pub res: usize,
    /// Transfer function per channel (repeat), or one for all: JSON file (blueshift or
    /// ParaView preset with opacity Points), builtin:NAME or log:NAME.
    #[arg(long = "tf")]
    pub tfs: Vec<String>,
    /// woodcock | mdwt-ndda | mdwt-1dda | mdwt-summed | marcher.
    #[arg(long)]
    pub method: Option<String>,
    /// Channel index tracked by --method woodcock.
    #[arg(long)]
    pub channel: Option<usize>,
    /// density | max | mix | weighted | composite (weighted without --weights: majorant
    /// weights, every channel peaking at the weakest channel's extinction).
    #[arg(long)]
    pub blend: Option<String>,
    /// Weights for mix/composite, comma-separated, one per channel (default equal).
    #[arg(long, value_delimiter = ',')]
    pub weights: Option<Vec<f32>>,
    /// Samples per pixel (the maximum with --noise-target).
    #[arg(long)]
    pub spp: Option<u32>,
    /// Seed of the random numbers (same seed, same image, any thread count).
    #[arg(long)]
    pub seed: Option<u64>,
    /// Image width in pixels.
    #[arg(long)]
    pub width: Option<u32>,
    /// Image height in pixels.
    #[arg(long)]
    pub height: Option<u32>,
    /// ortho | perspective (default view along +z through the volume centre).
    #[arg(long)]
    pub camera: Option<String>,
    /// Vertical field of view of the perspective camera, degrees.
    #[arg(long)]
    pub fov: Option<f32>,
    /// Background colour R,G,B (linear).
    #[arg(long, value_delimiter = ',')]
    pub background: Option<Vec<f32>>,
    /// Extinction per unit world length = opacity x this.
    #[arg(long)]
    pub density_scale: Option<f32>,
    /// Macrocell edge in voxels.
    #[arg(long)]
    pub macrocell: Option<usize>,
    /// Marcher compositing precision: f32 | f16 | u8.
    #[arg(long)]
    pub precision: Option<String>,
    /// Marcher step in world units (default half the smallest spacing).
    #[arg(long)]
    pub step: Option<f32>,
    /// Global opacity alpha_g applied to every transfer function.
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
    /// Also write a PNG preview (exposure, clamp, sRGB; or a tone-mapping operator).
    #[arg(long)]
    pub png: Option<PathBuf>,
    /// Tone mapping of the PNG preview: `exposure` (exposure, clamp, sRGB) or an operator of
    /// blueshift-tonemap with its paper's default parameters: linear, drago, reinhard,
    /// reinhard-local, durand, fattal.
    #[arg(long, default_value = "exposure")]
    pub tonemap: String,
    /// Exposure of the PNG preview in stops.
    #[arg(long, default_value_t = 0.0)]
    pub exposure: f32,
    /// Worker threads (default: all cores); the image does not depend on it.
    #[arg(long)]
    pub threads: Option<usize>,
    /// Print a JSON summary on stdout.
    #[arg(long)]
    pub json: bool,
    /// Where to render: cpu (default, bit-reproducible), gpu (a wgpu adapter or an error)
    /// or auto (a hardware GPU when present, or the adapter $BLUESHIFT_GPU forces, else the
    /// CPU). The GPU supports every method, blend and light; shading, heat maps and
    /// --frames are CPU-only, and a render over the adapter's limits (buffer sizes,
    /// lavapipe's loop limit) fails on gpu; auto renders those on the CPU.
    #[arg(long, default_value = "cpu")]
    pub device: blueshift_gpu::DeviceChoice,
}

/// One channel of a scene file.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ChannelSpec {
    /// Volume file.
    pub volume: Option<PathBuf>,
    /// Synthetic dataset name.
    pub synth: Option<String>,
    /// Resolution of the synthetic dataset.
    pub res: Option<usize>,
    /// Seed of the synthetic dataset.
    pub seed: Option<u64>,
    /// Channel name inside the file or dataset (default: the first).
    pub channel: Option<String>,
    /// Transfer function spec.
    pub tf: String,
    /// Blinn-Phong material for --shading.
    pub material: Option<MaterialSpec>,
}

/// A channel's material in a scene file (defaults: ambient 1, diffuse 0.8, specular 0.2,
/// shininess 32).
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MaterialSpec {
    ambient: Option<f32>,
    diffuse: Option<f32>,
    specular: Option<f32>,
    shininess: Option<f32>,
}

/// Light of a scene file.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LightSpec {
    direction: [f32; 3],
    #[serde(default = "ones")]
    radiance: [f32; 3],
    #[serde(default = "ambient_default")]
    ambient: f32,
}

fn ones() -> [f32; 3] {
    [1.0; 3]
}
fn ambient_default() -> f32 {
    0.2
}

/// A scene file (see the module docs).
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SceneFile {
    channels: Vec<ChannelSpec>,
    method: Option<String>,
    woodcock_channel: Option<usize>,
    blend: Option<String>,
    weights: Option<Vec<f32>>,
    spp: Option<u32>,
    seed: Option<u64>,
    width: Option<u32>,
    height: Option<u32>,
    camera: Option<String>,
    fov_y_deg: Option<f32>,
    eye: Option<[f32; 3]>,
    target: Option<[f32; 3]>,
    up: Option<[f32; 3]>,
    background: Option<[f32; 3]>,
    density_scale: Option<f32>,
    macrocell: Option<usize>,
    precision: Option<String>,
    step: Option<f32>,
    alpha_g: Option<f32>,
    noise_target: Option<f64>,
    light: Option<LightSpec>,
    shading: Option<bool>,
    heatmaps: Option<Vec<String>>,
    warmup: Option<u32>,
    frames: Option<u32>,
}

fn triple(v: &[f32], what: &str) -> Result<[f32; 3]> {
    match v {
        [a, b, c] if v.iter().all(|x| x.is_finite()) => Ok([*a, *b, *c]),
        _ => bail!("{what}: expected three finite numbers, got {v:?}"),
    }
}

/// Resolves `p` against the scene file's folder.
fn resolve(base: Option<&Path>, p: &Path) -> PathBuf {
    match base {
        Some(b) if p.is_relative() => b.join(p),
        _ => p.to_path_buf(),
    }
}

fn merge(args: &Args) -> Result<(SceneFile, Option<PathBuf>)> {
    let (mut f, base) = match &args.scene {
        Some(path) => {
            let text = std::fs::read_to_string(path)
                .with_context(|| format!("cannot read scene file {}", path.display()))?;
            let f: SceneFile = serde_json::from_str(&text)
                .with_context(|| format!("scene file {}", path.display()))?;
            (f, path.parent().map(Path::to_path_buf))
        }
        None => (SceneFile::default(), None),
    };
    // Inline channels replace the file's.
    if !args.volumes.is_empty() || args.synth.is_some() {
        let mut chans = Vec::new();
        for v in &args.volumes {
            chans.push(ChannelSpec {
                volume: Some(v.clone()),
                ..ChannelSpec::default()
            });
        }
        if let Some(name) = &args.synth {
            let vol =
                synth::by_name(name, args.res, 1).with_context(|| format!("--synth {name}"))?;
            for c in vol.channels() {
                if c.grid.is_vector() {
                    continue;
                }
                chans.push(ChannelSpec {
                    synth: Some(name.clone()),
                    res: Some(args.res),
                    channel: Some(c.name.clone()),
                    ..ChannelSpec::default()
                });
            }
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
    macro_rules! over {
        ($field:ident, $arg:expr) => {
            if let Some(v) = $arg.clone() {
                f.$field = Some(v);
            }
        };
    }
    over!(method, args.method);
    over!(woodcock_channel, args.channel);
    over!(blend, args.blend);
    over!(weights, args.weights);
    over!(spp, args.spp);
    over!(seed, args.seed);
    over!(width, args.width);
    over!(height, args.height);
    over!(camera, args.camera);
    over!(fov_y_deg, args.fov);
    over!(density_scale, args.density_scale);
    over!(macrocell, args.macrocell);
    over!(precision, args.precision);
    over!(step, args.step);
    over!(alpha_g, args.alpha_g);
    over!(noise_target, args.noise_target);
    over!(warmup, args.warmup);
    over!(frames, args.frames);
    if args.shading {
        f.shading = Some(true);
    }
    if !args.heatmaps.is_empty() {
        f.heatmaps = Some(args.heatmaps.clone());
    }
    if let Some(b) = &args.background {
        f.background = Some(triple(b, "--background")?);
    }
    if let Some(d) = &args.light_dir {
        let radiance = match (&args.light_radiance, args.light_intensity) {
            (Some(r), _) => triple(r, "--light-radiance")?,
            (None, Some(i)) if i.is_finite() && i >= 0.0 => [i; 3],
            (None, Some(i)) => bail!("--light-intensity: {i} must be finite and non-negative"),
            (None, None) => ones(),
        };
        f.light = Some(LightSpec {
            direction: triple(d, "--light-dir")?,
            radiance,
            ambient: args.ambient.unwrap_or(ambient_default()),
        });
    }
    if f.channels.is_empty() {
        bail!(
            "channels: none given (use a scene file, --volume FILE --tf TF, or --synth NAME --tf TF)"
        );
    }
    let base = if args.volumes.is_empty() && args.synth.is_none() {
        base
    } else {
        None
    };
    Ok((f, base))
}

fn load_channel(i: usize, c: &ChannelSpec, base: Option<&Path>) -> Result<(String, AnyGrid)> {
    let vol = match (&c.volume, &c.synth) {
        (Some(p), None) => {
            let p = resolve(base, p);
            blueshift_volume::read(&p)
                .with_context(|| format!("channels[{i}].volume: cannot read {}", p.display()))?
        }
        (None, Some(name)) => synth::by_name(name, c.res.unwrap_or(64), c.seed.unwrap_or(1))
            .with_context(|| format!("channels[{i}].synth"))?,
        _ => bail!("channels[{i}]: give exactly one of \"volume\" and \"synth\""),
    };
    let ch = match &c.channel {
        Some(name) => vol
            .channel(name)
            .ok_or_else(|| anyhow!("channels[{i}].channel: no channel named '{name}'"))?,
        None => vol
            .channels()
            .iter()
            .find(|c| !c.grid.is_vector())
            .ok_or_else(|| anyhow!("channels[{i}].volume: no scalar channel"))?,
    };
    Ok((ch.name.clone(), ch.grid.clone()))
}

/// Builds a transfer function from a spec for a channel's grid.
fn load_tf(i: usize, spec: &str, grid: &AnyGrid, base: Option<&Path>) -> Result<TransferFunction> {
    let what = || format!("channels[{i}].tf '{spec}'");
    if let Some(name) = spec.strip_prefix("builtin:") {
        let (lo, hi) = grid
            .finite_range()
            .ok_or_else(|| anyhow!("{}: no finite values", what()))?;
        let hi = if hi > lo { hi } else { lo + 1.0 };
        return blueshift_tfedit::builtin_over(name, [f64::from(lo), f64::from(hi)])
            .with_context(what);
    }
    if let Some(name) = spec.strip_prefix("log:") {
        let g = *grid.geometry();
        let (mut lo, mut hi) = (f32::INFINITY, 0.0f32);
        for k in 0..g.voxel_count() {
            let v = grid.scalar_at(k);
            if v.is_finite() && v > 0.0 {
                lo = lo.min(v);
                hi = hi.max(v);
            }
        }
        if hi <= 0.0 {
            bail!("{}: no positive values for a logarithmic axis", what());
        }
        let (lo, hi) = (f64::from(lo), f64::from(hi.max(lo * 1.0001)));
        let b = blueshift_tfedit::builtin(name).with_context(what)?;
        let map = |x: f64| lo * (hi / lo).powf(x);
        let color: Vec<ColorKnot> = b
            .color_knots()
            .iter()
            .map(|k| ColorKnot { x: map(k.x), ..*k })
            .collect();
        let opacity: Vec<OpacityKnot> = b
            .opacity_knots()
            .iter()
            .map(|k| OpacityKnot { x: map(k.x), ..*k })
            .collect();
        return TransferFunction::new([lo, hi], color, opacity)
            .and_then(|t| t.with_data_axis(DataAxis::Log))
            .map(|t| t.with_color_space(b.color_space()))
            .with_context(what);
    }
    let p = resolve(base, Path::new(spec));
    blueshift_tfedit::load(&p).with_context(what)
}

fn parse_blend(name: &str, weights: Option<Vec<f32>>, n: usize) -> Result<Blend> {
    let w = weights.unwrap_or_else(|| Blend::equal_weights(n));
    Ok(match name {
        "density" => Blend::Density,
        "max" => Blend::Max,
        "mix" => Blend::Mix { weights: w },
        "composite" => Blend::Composite { weights: w },
        "weighted" => Blend::Weighted { weights: w },
        other => bail!("blend: unknown '{other}' (density, max, mix, weighted, composite)"),
    })
}

/// Runs `blueshift render`.
pub fn run(args: Args) -> Result<()> {
    // Refuse a bad preview operator before spending time on the render.
    if !TONEMAPS.contains(&args.tonemap.as_str()) {
        bail!(
            "--tonemap {:?}: expected one of {}",
            args.tonemap,
            TONEMAPS.join(", ")
        );
    }
    match args.threads {
        Some(0) => bail!("--threads: must be at least 1"),
        Some(t) => rayon::ThreadPoolBuilder::new()
            .num_threads(t)
            .build()
            .context("cannot start worker threads")?
            .install(|| run_inner(&args)),
        None => run_inner(&args),
    }
}

fn run_inner(args: &Args) -> Result<()> {
    let (f, base) = merge(args)?;
    let base = base.as_deref();
    let mut triples = Vec::new();
    for (i, c) in f.channels.iter().enumerate() {
        let (name, grid) = load_channel(i, c, base)?;
        let mut tf = load_tf(i, &c.tf, &grid, base)?;
        if let Some(a) = f.alpha_g {
            tf = tf.with_alpha_g(a).context("alpha_g")?;
        }
        triples.push((name, grid, tf));
    }
    let n = triples.len();
    let k = f.macrocell.unwrap_or(blueshift_volume::DEFAULT_K);
    let mut scene = Scene::new(triples, f.density_scale.unwrap_or(1.0), k)?;
    if let Some(b) = f.background {
        scene.background = b;
    }
    if let Some(l) = &f.light {
        if Vec3::from(l.direction).try_normalize().is_none() {
            bail!(
                "light.direction: {:?} must be a non-zero finite vector",
                l.direction
            );
        }
        scene.light = Some(DirectionalLight {
            direction: Vec3::from(l.direction),
            radiance: l.radiance,
            ambient: l.ambient,
        });
    }
    if f.shading.unwrap_or(false) {
        let mut materials = Vec::with_capacity(n);
        for (i, c) in f.channels.iter().enumerate() {
            let d = Material::default();
            let m = c.material.as_ref().map_or(d, |m| Material {
                ambient: m.ambient.unwrap_or(d.ambient),
                diffuse: m.diffuse.unwrap_or(d.diffuse),
                specular: m.specular.unwrap_or(d.specular),
                shininess: m.shininess.unwrap_or(d.shininess),
            });
            m.validate(&format!("channels[{i}].material"))?;
            materials.push(m);
        }
        scene.shading = Some(Shading {
            materials,
            shadows: true,
        });
    }
    let heatmaps = f
        .heatmaps
        .iter()
        .flatten()
        .map(|h| h.parse::<HeatMap>().context("--heatmap"))
        .collect::<Result<Vec<_>>>()?;
    let weights = match (f.blend.as_deref(), &f.weights) {
        (Some("weighted"), None) => Some(Blend::majorant_weights(&scene)),
        _ => f.weights.clone(),
    };
    let blend = parse_blend(f.blend.as_deref().unwrap_or("density"), weights, n)?;
    let method = f.method.as_deref().unwrap_or("mdwt-1dda");
    let precision = match f.precision.as_deref().unwrap_or("f32") {
        "f32" => Precision::F32,
        "f16" => Precision::F16,
        "u8" => Precision::U8,
        other => bail!("precision: unknown '{other}' (f32, f16, u8)"),
    };
    let integrator = match method {
        "woodcock" => Integrator::Woodcock {
            channel: f.woodcock_channel.unwrap_or(0),
        },
        "mdwt-ndda" => Integrator::Mdwt {
            dda: DdaMode::NDda,
            blend,
        },
        "mdwt-1dda" => Integrator::Mdwt {
            dda: DdaMode::OneDda,
            blend,
        },
        "mdwt-summed" => Integrator::Mdwt {
            dda: DdaMode::Summed,
            blend,
        },
        "marcher" => Integrator::Marcher(RayMarcher {
            step: f.step,
            precision,
            blend,
            ..RayMarcher::default()
        }),
        other => bail!(
            "method: unknown '{other}' (woodcock, mdwt-ndda, mdwt-1dda, mdwt-summed, marcher)"
        ),
    };
    let width = f.width.unwrap_or(512);
    let height = f.height.unwrap_or(512);
    let ortho = match f.camera.as_deref().unwrap_or("perspective") {
        "ortho" | "orthographic" => true,
        "perspective" => false,
        other => bail!("camera: unknown '{other}' (ortho, perspective)"),
    };
    let mut settings = RenderSettings::default_for(&scene, width, height, ortho);
    settings.spp = f.spp.unwrap_or(16);
    settings.seed = f.seed.unwrap_or(0);
    settings.noise_target = f.noise_target;
    let cam: &mut Camera = &mut settings.camera;
    if let (Some(fov), Projection::Perspective { fov_y_deg }) = (f.fov_y_deg, &mut cam.projection) {
        *fov_y_deg = fov;
    }
    if let Some(e) = f.eye {
        cam.eye = Vec3::from(e);
    }
    if let Some(t) = f.target {
        cam.target = Vec3::from(t);
    }
    if let Some(u) = f.up {
        cam.up = Vec3::from(u);
    }
    if f.warmup.is_some() && f.frames.is_none() {
        bail!("--warmup: needs --frames N (the timed frames)");
    }
    settings.heatmaps = !heatmaps.is_empty();
    settings.timed_frames = f.frames;
    settings.warmup = f.warmup.unwrap_or(0);
    settings.validate()?;
    integrator.prepared(&scene)?;

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
    let bar = indicatif::ProgressBar::new(u64::from(settings.timed_frames.unwrap_or(settings.spp)));
    bar.set_style(
        indicatif::ProgressStyle::with_template("{bar:30} {pos}/{len} passes  {msg}  [{elapsed}]")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    let show = |done: u32, noise: f64| {
        bar.set_position(u64::from(done));
        if noise.is_finite() {
            bar.set_message(format!("noise {noise:.4}"));
        }
    };
    let start = Instant::now();
    let ran = blueshift_gpu::run_with_fallback(
        device,
        || supported.clone(),
        |ctx| {
            let scene = match device {
                blueshift_gpu::DeviceChoice::Auto => slot.borrow().clone(),
                _ => slot.borrow_mut().take(),
            }
            .ok_or_else(|| blueshift_gpu::Error::InvalidInput("no scene".into()))?;
            let tracker = blueshift_gpu::tracking::GpuTracker::new(ctx)?;
            let gs = tracker.upload(scene)?;
            let image = tracker.render_progressive(&gs, &integrator, &settings, show)?;
            Ok(TrackingOutput {
                image,
                frame_times: None,
            })
        },
        || -> Result<TrackingOutput> {
            let session = TrackingSession::new(take()?, integrator.clone(), settings.clone())?;
            let observer = OnPass(&show);
            Ok(session.render(&observer)?)
        },
    )
    .map_err(crate::commands::doppler::device_error)?;
    bar.finish_and_clear();
    if let Some(why) = &ran.fallback {
        eprintln!("--device auto: {why}; rendering on the CPU");
    }
    let seconds = start.elapsed().as_secs_f64();
    let on_gpu = ran.device == blueshift_camera::DeviceKind::Gpu;
    let TrackingOutput {
        image: acc,
        frame_times: times,
    } = ran.value;
    let heat_files = crate::commands::render_heat::write_heatmaps(&args.out, &acc, &heatmaps)?;
    let img = acc.mean_image();
    crate::output::write_exr_f32(&args.out, img.width(), img.height(), 4, img.as_raw())?;
    if let Some(png) = &args.png {
        write_png_preview(&img, png, &args.tonemap, args.exposure)?;
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
        println!("{summary}");
    } else {
        let on = adapter.map(|a| format!(" on {a}")).unwrap_or_default();
        eprintln!(
            "wrote {} ({} spp, noise {noise:.4}, {seconds:.2} s{on})",
            args.out.display(),
            acc.samples(),
        );
    }
    Ok(())
}

/// Forwards each finished pass (samples, noise) to the progress bar.
struct OnPass<'a, F>(&'a F);

impl<F: Fn(u32, f64) + Sync> blueshift_camera::Observer<Progressive> for OnPass<'_, F> {
    fn pass(&self, pass: u32, acc: &Progressive, _noise: Option<f64>) {
        (self.0)(pass, acc.noise());
    }
}

/// The names `--tonemap` accepts.
const TONEMAPS: [&str; 7] = [
    "exposure",
    "linear",
    "drago",
    "reinhard",
    "reinhard-local",
    "durand",
    "fattal",
];

/// Writes the PNG preview of an HDR render: plain exposure + clamp + sRGB, or a tone-mapping
/// operator of blueshift-tonemap (the alpha channel is dropped; the background shows).
fn write_png_preview(
    img: &image::Rgba32FImage,
    png: &Path,
    tonemap: &str,
    exposure: f32,
) -> Result<()> {
    use blueshift_tonemap::{
        DragoParams, DurandParams, FattalParams, LinearParams, Operator, ReinhardLocalParams,
        ReinhardParams,
    };
    let op = match tonemap {
        "exposure" => None,
        "linear" => Some(Operator::Linear(LinearParams {
            exposure_stops: exposure,
            ..LinearParams::default()
        })),
        "drago" => Some(Operator::Drago(DragoParams::default())),
        "reinhard" => Some(Operator::Reinhard(ReinhardParams::default())),
        "reinhard-local" => Some(Operator::ReinhardLocal(ReinhardLocalParams::default())),
        "durand" => Some(Operator::Durand(DurandParams::default())),
        "fattal" => Some(Operator::Fattal(FattalParams::default())),
        other => bail!(
            "--tonemap {other:?}: expected exposure, linear, drago, reinhard, reinhard-local, durand or fattal"
        ),
    };
    let gain = 2f32.powf(exposure);
    let rgb = image::Rgb32FImage::from_fn(img.width(), img.height(), |x, y| {
        let p = img.get_pixel(x, y).0;
        image::Rgb([p[0], p[1], p[2]])
    });
    let display = match op {
        Some(op) => op
            .apply(&rgb)
            .with_context(|| format!("--tonemap {tonemap}"))?,
        None => image::Rgb32FImage::from_fn(rgb.width(), rgb.height(), |x, y| {
            let p = rgb.get_pixel(x, y).0;
            image::Rgb(p.map(|v| (v * gain).clamp(0.0, 1.0)))
        }),
    };
    blueshift_tonemap::io::write_png(png, &display, blueshift_tonemap::io::PngDepth::Eight)
        .with_context(|| format!("cannot write {}", png.display()))
}
