//! Render scene files: the JSON schema of `blueshift render scene.json` and the loader that
//! turns one into a [`Scene`], an [`Integrator`] and [`RenderSettings`].
//!
//! ```json
//! { "channels": [ { "volume": "head.nhdr", "tf": "bone.json" } ],
//!   "method": "mdwt-1dda", "blend": "density", "weights": null,
//!   "spp": 64, "seed": 1, "width": 512, "height": 512,
//!   "camera": "perspective", "fov_y_deg": 30, "view": "z", "zoom": 1.0,
//!   "eye": null, "target": null, "up": null,
//!   "background": [0, 0, 0], "density_scale": 1.0, "macrocell": 4,
//!   "precision": "f32", "step": null, "alpha_g": null, "noise_target": null,
//!   "light": { "direction": [1, 1, -1], "radiance": [1, 1, 1], "ambient": 0.2 },
//!   "shading": false, "heatmaps": ["steps"], "warmup": null, "frames": null,
//!   "tf_range": null, "observer_velocity": null, "searchlight": null }
//! ```
//! Unknown keys are refused; paths are relative to the file. A channel is
//! `{ "volume": FILE, "channel": NAME?, "tf": SPEC, "material": M? }` or
//! `{ "synth": NAME, "res": N?, "seed": S?, "channel": NAME?, "tf": SPEC }`. A TF SPEC is a
//! blueshift or ParaView JSON file, `builtin:NAME` (a built-in map stretched over the
//! channel's value range) or `log:NAME` (the same on a logarithmic data axis over the
//! channel's positive values, for data spanning decades). A material `M` for `shading` is
//! `{ "ambient": 1, "diffuse": 0.8, "specular": 0.2, "shininess": 32 }` (any may be left out).
//!
//! `tf_range` ([`TfRange`]) stretches every channel's transfer function over `"data"` (the
//! channel's value range, ParaView's "rescale to data range") or `"LO:HI"`; without it a
//! file's TF keeps its own domain (built-in maps are already stretched over the data).
//!
//! The names are [`Method`] (`woodcock`, `mdwt-ndda`, `mdwt-1dda` (default), `mdwt-summed`,
//! `marcher`), [`BlendKind`] (`density` (default), `max`, `mix`, `weighted`, `composite`;
//! `weighted` without `weights` takes [`Blend::majorant_weights`]), [`CameraKind`]
//! (`perspective` (default), `ortho`), [`Precision`] (`f32` (default), `f16`, `u8`) and
//! [`HeatMap`] (`steps`, `collisions`, `rejections`, `time`). Other defaults: 16 samples
//! per pixel (1 for the `marcher`, which is deterministic but for its jittered start), seed 0, 512 x 512 pixels, density scale 1, macrocells of
//! `blueshift_volume::DEFAULT_K` voxels, woodcock's channel 0.
//!
//! Extinction per unit world length (the volume's spacing unit) is the transfer function's
//! opacity, times its alpha_g, times `density_scale`; all methods use this definition.
//!
//! A program that takes flags over a file (as the CLI does) reads the file, builds a second
//! [`RenderSceneFile`] from its flags and applies it with [`RenderSceneFile::override_with`]
//! before [`RenderSceneFile::build`].

use std::path::{Path, PathBuf};

use blueshift_tfedit::{ColorKnot, DataAxis, OpacityKnot, TransferFunction};
use blueshift_volume::{BrickCache, Field, Lod, ooc::BrickedFile, synth};
use glam::Vec3;
use serde::{Deserialize, Serialize};
use std::sync::Arc;

use blueshift_camera::{DEFAULT_FOV_Y_DEG, View, up_for};

use crate::{
    Blend, BlendKind, Camera, DdaMode, DirectionalLight, Error, HeatMap, Integrator, Material,
    Method, Precision, RayMarcher, RenderSettings, Result, Scene, Shading,
};
use blueshift_camera::named_enum;

/// The camera of a scene file: `perspective` or `ortho` (also spelt `orthographic`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
pub enum CameraKind {
    /// Orthographic projection.
    Ortho,
    /// Perspective projection.
    #[default]
    Perspective,
}

named_enum!(CameraKind, "camera", [Ortho => "ortho", Perspective => "perspective"],
    aliases ["orthographic" => Ortho]);

/// One channel of a scene file: a volume file or a synthetic dataset, and its transfer
/// function.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ChannelSpec {
    /// Volume file (relative to the scene file).
    pub volume: Option<PathBuf>,
    /// Synthetic dataset name (`blueshift_volume::synth::by_name`).
    pub synth: Option<String>,
    /// Resolution of the synthetic dataset (default 64).
    pub res: Option<usize>,
    /// Seed of the synthetic dataset (default 1).
    pub seed: Option<u64>,
    /// Channel name inside the file or dataset (default: the first scalar one).
    pub channel: Option<String>,
    /// Transfer function spec: a JSON file, `builtin:NAME` or `log:NAME`.
    pub tf: String,
    /// Blinn-Phong material for `shading`.
    pub material: Option<MaterialSpec>,
}

/// A channel's material in a scene file; fields left out keep [`Material::default`]'s
/// (ambient 1, diffuse 0.8, specular 0.2, shininess 32).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MaterialSpec {
    /// Ambient coefficient.
    pub ambient: Option<f32>,
    /// Diffuse coefficient.
    pub diffuse: Option<f32>,
    /// Specular coefficient.
    pub specular: Option<f32>,
    /// Specular exponent.
    pub shininess: Option<f32>,
}

impl MaterialSpec {
    /// The material, unset fields from [`Material::default`].
    #[must_use]
    pub fn material(&self) -> Material {
        let d = Material::default();
        Material {
            ambient: self.ambient.unwrap_or(d.ambient),
            diffuse: self.diffuse.unwrap_or(d.diffuse),
            specular: self.specular.unwrap_or(d.specular),
            shininess: self.shininess.unwrap_or(d.shininess),
        }
    }
}

/// The directional light of a scene file.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LightSpec {
    /// Direction towards the light (non-zero).
    pub direction: [f32; 3],
    /// Radiance RGB (default 1, 1, 1).
    #[serde(default = "LightSpec::default_radiance")]
    pub radiance: [f32; 3],
    /// Unshadowed ambient light (default [`LightSpec::DEFAULT_AMBIENT`]).
    #[serde(default = "LightSpec::default_ambient")]
    pub ambient: f32,
}

impl LightSpec {
    /// The default ambient light.
    pub const DEFAULT_AMBIENT: f32 = 0.2;
    /// The default radiance.
    pub const DEFAULT_RADIANCE: [f32; 3] = [1.0; 3];

    fn default_radiance() -> [f32; 3] {
        Self::DEFAULT_RADIANCE
    }
    fn default_ambient() -> f32 {
        Self::DEFAULT_AMBIENT
    }
}

/// The data interval the transfer functions are stretched over ([`TransferFunction::rescaled`]:
/// every knot keeps its relative position): `data` (each channel's value range: its finite
/// values, its positive ones on a logarithmic axis) or `LO:HI` in data units.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum TfRange {
    /// Each channel's own value range.
    Data,
    /// A fixed interval `[lo, hi]` in data units.
    Interval(f64, f64),
}

impl std::str::FromStr for TfRange {
    type Err = Error;
    /// `data` or `LO:HI` (finite, LO < HI).
    fn from_str(s: &str) -> Result<Self> {
        let t = s.trim();
        if t == "data" {
            return Ok(TfRange::Data);
        }
        let bad = || {
            Error::parameter(format!(
                "tf-range '{t}': expected data or LO:HI with finite LO < HI"
            ))
        };
        let (a, b) = t.split_once(':').ok_or_else(bad)?;
        let (lo, hi) = (
            a.trim().parse::<f64>().map_err(|_| bad())?,
            b.trim().parse::<f64>().map_err(|_| bad())?,
        );
        if lo.is_finite() && hi.is_finite() && lo < hi {
            Ok(TfRange::Interval(lo, hi))
        } else {
            Err(bad())
        }
    }
}

impl std::fmt::Display for TfRange {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            TfRange::Data => f.write_str("data"),
            TfRange::Interval(lo, hi) => write!(f, "{lo}:{hi}"),
        }
    }
}

blueshift_camera::serde_via_str!(TfRange);

/// The smallest and largest positive finite value of a field (`None` if there is none).
fn positive_range(grid: &Field) -> Option<(f64, f64)> {
    let (lo, hi) = grid.positive_range()?;
    Some((f64::from(lo), f64::from(hi.max(lo * 1.0001))))
}

/// The value range a transfer function on `axis` is stretched over for `grid` (a constant
/// grid gets a unit-wide domain).
pub fn data_domain(grid: &Field, axis: DataAxis) -> Option<[f64; 2]> {
    match axis {
        DataAxis::Log => positive_range(grid).map(|(lo, hi)| [lo, hi]),
        _ => grid.finite_range().map(|(lo, hi)| {
            let (lo, hi) = (f64::from(lo), f64::from(hi));
            [lo, if hi > lo { hi } else { lo + 1.0 }]
        }),
    }
}

/// Volumes and transfer functions held in memory, by the `volume` and `tf` strings that
/// name them in a scene ([`RenderSceneFile::build_with`]).
#[derive(Clone, Debug, Default)]
pub struct Preloaded {
    /// Volumes by name.
    pub volumes: std::collections::BTreeMap<String, blueshift_volume::Volume>,
    /// Transfer functions by name.
    pub tfs: std::collections::BTreeMap<String, TransferFunction>,
    /// How `.bsv` channels are read: the shared brick cache (default: one of
    /// [`blueshift_volume::cache::default_budget`] bytes for the scene).
    pub cache: Option<Arc<BrickCache>>,
    /// The memory budget the scene's grids are checked against before they are made
    /// (default: [`blueshift_volume::MemoryBudget::machine_default`]).
    pub budget: Option<blueshift_volume::MemoryBudget>,
}

/// The most channels a render scene may have (the papers' scenes have up to 12); more is
/// refused before anything is loaded.
pub const MAX_CHANNELS: usize = 256;

impl Preloaded {
    fn budget(&self) -> blueshift_volume::MemoryBudget {
        self.budget
            .clone()
            .unwrap_or_else(blueshift_volume::MemoryBudget::machine_default)
    }
}

/// Volumes read while a scene is built, by canonical path (files) or `synth:NAME:RES:SEED`,
/// so channels naming the same file or dataset read it once.
type Loaded = std::collections::HashMap<String, blueshift_volume::Volume>;

/// A render scene file (see the module docs for the format and the defaults).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RenderSceneFile {
    /// The channels (at least one).
    pub channels: Vec<ChannelSpec>,
    /// The integrator.
    pub method: Option<Method>,
    /// Channel index tracked by `woodcock`.
    pub woodcock_channel: Option<usize>,
    /// The blend.
    pub blend: Option<BlendKind>,
    /// Weights of `mix`, `weighted`, `composite` (one per channel; default equal, or the
    /// majorant weights for `weighted`).
    pub weights: Option<Vec<f32>>,
    /// Samples per pixel.
    pub spp: Option<u32>,
    /// Seed of the random numbers.
    pub seed: Option<u64>,
    /// Image width, pixels.
    pub width: Option<u32>,
    /// Image height, pixels.
    pub height: Option<u32>,
    /// Projection of the default view.
    pub camera: Option<CameraKind>,
    /// Vertical field of view of the perspective camera, degrees.
    pub fov_y_deg: Option<f32>,
    /// Camera position (default: the default view's).
    pub eye: Option<[f32; 3]>,
    /// Point looked at.
    pub target: Option<[f32; 3]>,
    /// Up vector.
    pub up: Option<[f32; 3]>,
    /// View preset framing the volume: `x`, `y`, `z` (default), `-x`, `-y`, `-z` or `iso`
    /// (`blueshift_camera::View`; the observer on that side, yt's image axes).
    pub view: Option<String>,
    /// Magnification about the view centre (orthographic: the framed height / zoom;
    /// perspective: `tan(fov / 2)` / zoom).
    pub zoom: Option<f32>,
    /// Background colour (linear RGB).
    pub background: Option<[f32; 3]>,
    /// Extinction per unit world length = opacity x this.
    pub density_scale: Option<f32>,
    /// Macrocell edge in voxels.
    pub macrocell: Option<usize>,
    /// Marcher compositing precision.
    pub precision: Option<Precision>,
    /// Marcher step in world units.
    pub step: Option<f32>,
    /// Global opacity alpha_g applied to every transfer function.
    pub alpha_g: Option<f32>,
    /// Stop once the RMS standard error falls to this.
    pub noise_target: Option<f64>,
    /// Directional light (shadows).
    pub light: Option<LightSpec>,
    /// Gradient shading with the channels' materials.
    pub shading: Option<bool>,
    /// Heat maps to count.
    pub heatmaps: Option<Vec<HeatMap>>,
    /// Timing protocol: warm-up frames (needs `frames`).
    pub warmup: Option<u32>,
    /// Timing protocol: timed frames of 1 spp each (replaces `spp`).
    pub frames: Option<u32>,
    /// Stretch every transfer function over each channel's data range or an interval.
    pub tf_range: Option<TfRange>,
    /// Level of detail of bricked (`.bsv`) channels: `exact` (default: the finest level,
    /// the same image as in core), `auto` (the level whose voxels match the pixel footprint
    /// where the volume is nearest to the camera, `blueshift_volume::lod_level`) or a level
    /// number.
    pub lod: Option<String>,
    /// A moving observer's velocity `[beta_x, beta_y, beta_z]` relative to the volume
    /// (units of c, `|beta| < 1`): aberrated rays and the colour shift of its Doppler factor
    /// ([`blueshift_relativity::MovingObserver`]).
    pub observer_velocity: Option<[f64; 3]>,
    /// With `observer_velocity`: scale brightness by the searchlight effect (`D^4`).
    pub searchlight: Option<bool>,
    /// Folder the relative paths start from (the scene file's; set by
    /// [`RenderSceneFile::from_json`] and [`RenderSceneFile::read`]; `None`: the working
    /// directory).
    #[serde(skip)]
    pub base: Option<PathBuf>,
}

/// Resolves `p` against the scene file's folder.
fn resolve(base: Option<&Path>, p: &Path) -> PathBuf {
    match base {
        Some(b) if p.is_relative() => b.join(p),
        _ => p.to_path_buf(),
    }
}

impl ChannelSpec {
    /// The scalar channels of a synthetic dataset, one spec each (without a transfer
    /// function); vector channels are left out.
    ///
    /// # Errors
    /// An unknown dataset or a bad resolution.
    pub fn synth_channels(name: &str, res: usize) -> Result<Vec<ChannelSpec>> {
        // The channel names only: nothing is computed.
        let stream = synth::stream_by_name(name, res, 1)?;
        Ok(stream
            .channels()
            .iter()
            .filter(|(_, components)| *components == 1)
            .map(|(channel, _)| ChannelSpec {
                synth: Some(name.to_owned()),
                res: Some(res),
                channel: Some(channel.clone()),
                ..ChannelSpec::default()
            })
            .collect())
    }

    /// Loads the channel's grid (`i` is its index, for messages; `base` the folder of
    /// relative paths): its name and grid.
    ///
    /// # Errors
    /// [`Error::Field`] naming `channels[i]`: an unreadable file, an unknown dataset or
    /// channel, both or neither of `volume` and `synth`, no scalar channel.
    pub fn load(&self, i: usize, base: Option<&Path>) -> Result<(String, Field)> {
        self.load_with(i, base, &Preloaded::default())
    }

    /// [`ChannelSpec::load`] where a `volume` naming a key of `memory.volumes` takes that
    /// volume instead of reading a file.
    ///
    /// # Errors
    /// As [`ChannelSpec::load`].
    pub fn load_with(
        &self,
        i: usize,
        base: Option<&Path>,
        memory: &Preloaded,
    ) -> Result<(String, Field)> {
        self.load_cached(i, base, memory, &mut Loaded::new())
    }

    fn load_cached(
        &self,
        i: usize,
        base: Option<&Path>,
        memory: &Preloaded,
        loaded: &mut Loaded,
    ) -> Result<(String, Field)> {
        if let (Some(p), None) = (&self.volume, &self.synth) {
            let p = resolve(base, p);
            if blueshift_volume::amr::is_amr(&p)
                && !memory.volumes.contains_key(p.to_str().unwrap_or_default())
            {
                // AMR output: sampled in place through the brick cache (never resampled).
                let cache = memory
                    .cache
                    .clone()
                    .unwrap_or_else(|| BrickCache::new(blueshift_volume::cache::default_budget()));
                let limits = blueshift_volume::Limits {
                    max_alloc_bytes: memory.budget().bytes(),
                    ..blueshift_volume::Limits::default()
                };
                let (name, f) =
                    blueshift_volume::amr::open_field(&p, self.channel.as_deref(), cache, &limits)
                        .map_err(|e| {
                            Error::field_from(
                                format!("channels[{i}].volume"),
                                Some(format!("cannot read {}", p.display())),
                                e,
                            )
                        })?;
                return Ok((name, f.into()));
            }
            let bricked = p.extension().is_some_and(|e| e == "bsv")
                && !memory.volumes.contains_key(p.to_str().unwrap_or_default());
            if bricked {
                let cache = memory
                    .cache
                    .clone()
                    .unwrap_or_else(|| BrickCache::new(blueshift_volume::cache::default_budget()));
                let err = |e| {
                    Error::field_from(
                        format!("channels[{i}].volume"),
                        Some(format!("cannot read {}", p.display())),
                        e,
                    )
                };
                let f = BrickedFile::open_with_cache(&p, cache).map_err(err)?;
                if let Some(name) = &self.channel
                    && name != f.channel_name()
                {
                    return Err(Error::field(
                        format!("channels[{i}].channel"),
                        format!(
                            "no channel named '{name}' (the file holds '{}')",
                            f.channel_name()
                        ),
                    ));
                }
                return Ok((f.channel_name().to_owned(), f.field(0).map_err(err)?.into()));
            }
        }
        let in_memory = self
            .volume
            .as_deref()
            .and_then(Path::to_str)
            .and_then(|k| memory.volumes.get(k));
        let budget = memory.budget();
        let vol = match (&self.volume, &self.synth) {
            (Some(_), None) if let Some(v) = in_memory => v,
            (Some(p), None) => {
                let p = resolve(base, p);
                let key = std::fs::canonicalize(&p)
                    .unwrap_or_else(|_| p.clone())
                    .to_string_lossy()
                    .into_owned();
                if !loaded.contains_key(&key) {
                    let opts = blueshift_volume::ReadOptions {
                        limits: blueshift_volume::Limits {
                            max_alloc_bytes: budget.bytes(),
                            ..blueshift_volume::Limits::default()
                        },
                        ..blueshift_volume::ReadOptions::default()
                    };
                    let v = blueshift_volume::read_with(&p, &opts).map_err(|e| {
                        Error::field_from(
                            format!("channels[{i}].volume"),
                            Some(format!("cannot read {}", p.display())),
                            e,
                        )
                    })?;
                    loaded.insert(key.clone(), v);
                }
                &loaded[&key]
            }
            (None, Some(name)) => {
                let (res, seed) = (self.res.unwrap_or(64), self.seed.unwrap_or(1));
                let key = format!("synth:{name}:{res}:{seed}");
                if !loaded.contains_key(&key) {
                    let v = synth::by_name_within(name, res, seed, &budget)
                        .map_err(|e| Error::field_from(format!("channels[{i}].synth"), None, e))?;
                    loaded.insert(key.clone(), v);
                }
                &loaded[&key]
            }
            _ => {
                return Err(Error::field(
                    format!("channels[{i}]"),
                    "give exactly one of \"volume\" and \"synth\"",
                ));
            }
        };
        let ch = match &self.channel {
            Some(name) => vol.channel(name).ok_or_else(|| {
                Error::field(
                    format!("channels[{i}].channel"),
                    format!("no channel named '{name}'"),
                )
            })?,
            None => vol
                .channels()
                .iter()
                .find(|c| !c.grid.is_vector())
                .ok_or_else(|| {
                    Error::field(format!("channels[{i}].volume"), "no scalar channel")
                })?,
        };
        Ok((ch.name.clone(), ch.grid.clone().into()))
    }

    /// Builds the channel's transfer function for its grid (`i` is its index, for
    /// messages; `base` the folder of relative paths).
    ///
    /// # Errors
    /// [`Error::Field`] naming `channels[i].tf`: an unreadable file, an unknown built-in
    /// map, a grid without finite (builtin) or positive (log) values.
    pub fn transfer_function(
        &self,
        i: usize,
        grid: &Field,
        base: Option<&Path>,
    ) -> Result<TransferFunction> {
        self.transfer_function_with(i, grid, base, &Preloaded::default())
    }

    /// [`ChannelSpec::transfer_function`] where a `tf` naming a key of `memory.tfs` takes
    /// that transfer function.
    ///
    /// # Errors
    /// As [`ChannelSpec::transfer_function`].
    pub fn transfer_function_with(
        &self,
        i: usize,
        grid: &Field,
        base: Option<&Path>,
        memory: &Preloaded,
    ) -> Result<TransferFunction> {
        let spec = self.tf.as_str();
        if let Some(tf) = memory.tfs.get(spec) {
            return Ok(tf.clone());
        }
        let what = || format!("channels[{i}].tf '{spec}'");
        let tf_err = |e: blueshift_tfedit::Error| Error::field_from(what(), None, e);
        if let Some(name) = spec.strip_prefix("builtin:") {
            let (lo, hi) = grid
                .finite_range()
                .ok_or_else(|| Error::field(what(), "no finite values"))?;
            let hi = if hi > lo { hi } else { lo + 1.0 };
            return blueshift_tfedit::builtin_over(name, [f64::from(lo), f64::from(hi)])
                .map_err(tf_err);
        }
        if let Some(name) = spec.strip_prefix("log:") {
            let (lo, hi) = positive_range(grid)
                .ok_or_else(|| Error::field(what(), "no positive values for a logarithmic axis"))?;
            let b = blueshift_tfedit::builtin(name).map_err(tf_err)?;
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
                .map_err(tf_err);
        }
        let p = resolve(base, Path::new(spec));
        blueshift_tfedit::load(&p).map_err(tf_err)
    }
}

impl RenderSceneFile {
    /// Parses scene JSON read from `path` (named in errors; its folder becomes
    /// [`RenderSceneFile::base`]).
    ///
    /// # Errors
    /// [`Error::SceneFile`]: bad JSON, an unknown key, a bad name (`method`, `blend`, ...).
    pub fn from_json(text: &str, path: &Path) -> Result<Self> {
        let mut f: RenderSceneFile = serde_json::from_str(text).map_err(|e| Error::SceneFile {
            path: path.display().to_string(),
            message: e.to_string(),
        })?;
        f.base = path.parent().map(Path::to_path_buf);
        Ok(f)
    }

    /// Reads and parses a scene file.
    ///
    /// # Errors
    /// [`Error::SceneFile`]: an unreadable file, or as [`RenderSceneFile::from_json`].
    pub fn read(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        blueshift_volume::io::check_regular_file(path).map_err(|e| Error::SceneFile {
            path: path.display().to_string(),
            message: format!("cannot read: {e}"),
        })?;
        let text = std::fs::read_to_string(path).map_err(|e| Error::SceneFile {
            path: path.display().to_string(),
            message: format!("cannot read: {e}"),
        })?;
        Self::from_json(&text, path)
    }

    /// Applies `flags` over this file: each field `flags` sets replaces this one's; a
    /// non-empty `flags.channels` replaces the channels and the base folder (with
    /// `flags.base`).
    pub fn override_with(&mut self, flags: RenderSceneFile) {
        let RenderSceneFile {
            channels,
            method,
            woodcock_channel,
            blend,
            weights,
            spp,
            seed,
            width,
            height,
            camera,
            fov_y_deg,
            eye,
            target,
            up,
            view,
            zoom,
            background,
            density_scale,
            macrocell,
            precision,
            step,
            alpha_g,
            noise_target,
            light,
            shading,
            heatmaps,
            warmup,
            frames,
            tf_range,
            lod,
            observer_velocity,
            searchlight,
            base,
        } = flags;
        if !channels.is_empty() {
            self.channels = channels;
            self.base = base;
        }
        macro_rules! over {
            ($($field:ident),+) => {
                $(if $field.is_some() {
                    self.$field = $field;
                })+
            };
        }
        over!(
            method,
            woodcock_channel,
            blend,
            weights,
            spp,
            seed,
            width,
            height,
            camera,
            fov_y_deg,
            eye,
            target,
            up,
            view,
            zoom,
            background,
            density_scale,
            macrocell,
            precision,
            step,
            alpha_g,
            noise_target,
            light,
            shading,
            heatmaps,
            warmup,
            frames,
            tf_range,
            lod,
            observer_velocity,
            searchlight
        );
    }

    /// The camera: the `view` preset (default `z`) framing the scene's box at `fov_y_deg`,
    /// then `eye`, `target` and `up` where given (an `eye` without `up` whose view is
    /// parallel to the preset's up takes yt's up for its own direction), then `zoom`.
    fn camera_for(&self, scene: &Scene, width: u32, height: u32, ortho: bool) -> Result<Camera> {
        let (lo, hi) = scene.frame_bounds();
        self.camera_for_box(lo, hi, width, height, ortho)
    }

    fn camera_for_box(
        &self,
        lo: Vec3,
        hi: Vec3,
        width: u32,
        height: u32,
        ortho: bool,
    ) -> Result<Camera> {
        let view = match &self.view {
            Some(v) => v
                .parse::<View>()
                .map_err(|e| Error::parameter(e.to_string()))?,
            None => View::Z,
        };
        let n = view.normal();
        let fov = self.fov_y_deg.unwrap_or(DEFAULT_FOV_Y_DEG);
        let aspect = width as f32 / height.max(1) as f32;
        let mut cam = Camera::framing(lo, hi, n, up_for(n), aspect, ortho, fov)?.with_overrides(
            self.eye.map(Vec3::from),
            self.target.map(Vec3::from),
            self.up.map(Vec3::from),
        );
        if let Some(z) = self.zoom {
            cam = cam.zoomed(z)?;
        }
        Ok(cam)
    }

    /// The method (default `mdwt-1dda`).
    #[must_use]
    pub fn method(&self) -> Method {
        self.method.unwrap_or_default()
    }

    /// The heat maps (default none).
    #[must_use]
    pub fn heatmaps(&self) -> Vec<HeatMap> {
        self.heatmaps.clone().unwrap_or_default()
    }

    /// Sets `scene`'s background, directional light and gradient shading from this file
    /// (none where the file has none).
    ///
    /// # Errors
    /// [`Error::Field`] for a zero `light.direction`, [`Error::Parameter`] for a bad material.
    pub fn apply_lighting(&self, scene: &mut Scene) -> Result<()> {
        scene.background = self.background.unwrap_or_default();
        scene.light = None;
        if let Some(l) = &self.light {
            if Vec3::from(l.direction).try_normalize().is_none() {
                return Err(Error::field(
                    "light.direction",
                    format!("{:?} must be a non-zero finite vector", l.direction),
                ));
            }
            scene.light = Some(DirectionalLight {
                direction: Vec3::from(l.direction),
                radiance: l.radiance,
                ambient: l.ambient,
            });
        }
        scene.shading = None;
        if self.shading.unwrap_or(false) {
            let mut materials = Vec::with_capacity(self.channels.len());
            for (i, c) in self.channels.iter().enumerate() {
                let m = c
                    .material
                    .as_ref()
                    .map_or_else(Material::default, MaterialSpec::material);
                m.validate(&format!("channels[{i}].material"))?;
                materials.push(m);
            }
            scene.shading = Some(Shading {
                materials,
                shadows: true,
            });
        }
        Ok(())
    }

    /// The integrator this file names (method, blend and weights, marcher step and
    /// precision), prepared against `scene` as a check.
    ///
    /// # Errors
    /// [`Error::Parameter`] for weights or a channel that do not fit the scene.
    pub fn integrator(&self, scene: &Scene) -> Result<Integrator> {
        let n = scene.channel_count();
        let kind = self.blend.unwrap_or_default();
        let weights = match (kind, &self.weights) {
            (BlendKind::Weighted, None) => Blend::majorant_weights(scene),
            (_, w) => w.clone().unwrap_or_else(|| Blend::equal_weights(n)),
        };
        let blend = kind.with_weights(weights);
        let integrator = match self.method() {
            Method::Woodcock => Integrator::Woodcock {
                channel: self.woodcock_channel.unwrap_or(0),
            },
            Method::Marcher => Integrator::Marcher(RayMarcher {
                step: self.step,
                precision: self.precision.unwrap_or(Precision::F32),
                blend,
                ..RayMarcher::default()
            }),
            Method::MdwtNDda => Integrator::Mdwt {
                dda: DdaMode::NDda,
                blend,
            },
            Method::MdwtOneDda => Integrator::Mdwt {
                dda: DdaMode::OneDda,
                blend,
            },
            Method::MdwtSummed => Integrator::Mdwt {
                dda: DdaMode::Summed,
                blend,
            },
        };
        integrator.prepared(scene)?;
        Ok(integrator)
    }

    /// The render settings this file names for `scene` (size, spp, seed, noise target,
    /// camera, heat maps, timing protocol), validated.
    ///
    /// # Errors
    /// [`Error::Parameter`] for sizes, spp, the camera or `warmup` without `frames`.
    pub fn settings(&self, scene: &Scene) -> Result<RenderSettings> {
        let width = self.width.unwrap_or(512);
        let height = self.height.unwrap_or(512);
        let ortho = self.camera.unwrap_or_default() == CameraKind::Ortho;
        let mut settings = RenderSettings::default_for(scene, width, height, ortho);
        // The marcher is deterministic but for its jittered start: more samples cost time
        // for a fraction of a per cent.
        let default_spp = if self.method() == Method::Marcher {
            1
        } else {
            16
        };
        settings.spp = self.spp.unwrap_or(default_spp);
        settings.seed = self.seed.unwrap_or(0);
        settings.noise_target = self.noise_target;
        settings.camera = self.camera_for(scene, width, height, ortho)?;
        if self.warmup.is_some() && self.frames.is_none() {
            return Err(Error::parameter("warmup: needs frames (the timed frames)"));
        }
        settings.heatmaps = self.heatmaps.as_ref().is_some_and(|h| !h.is_empty());
        settings.timed_frames = self.frames;
        settings.warmup = self.warmup.unwrap_or(0);
        settings.observer = match self.observer_velocity {
            Some(b) => Some(blueshift_relativity::MovingObserver {
                velocity: blueshift_relativity::Velocity::new(glam::DVec3::from_array(b))
                    .map_err(|e| Error::parameter(format!("observer_velocity: {e}")))?,
                searchlight: self.searchlight.unwrap_or(false),
            }),
            None if self.searchlight.is_some() => {
                return Err(Error::parameter("searchlight: needs observer_velocity"));
            }
            None => None,
        };
        settings.validate()?;
        Ok(settings)
    }

    /// The level of detail `lod` asks for, for these channels seen through this file's camera.
    ///
    /// # Errors
    /// An unknown `lod` spelling.
    pub fn lod(&self) -> Result<Lod> {
        // AMR channels default to the level the view needs: their finest level (2048^3 for
        // the Enzo snapshot) is far finer than any image.
        let amr = self.channels.iter().any(|c| {
            c.synth.is_none()
                && c.volume.as_deref().is_some_and(|p| {
                    blueshift_volume::amr::is_amr(&resolve(self.base.as_deref(), p))
                })
        });
        let default = if amr { Lod::Auto } else { Lod::Exact };
        self.lod
            .as_deref()
            .map_or(Ok(default), str::parse)
            .map_err(|e: blueshift_volume::Error| Error::field_from("lod", None, e))
    }

    /// Moves every bricked channel to the level `lod` picks (all channels must be bricked
    /// with the same levels for a coarser one; mixed with dense channels they stay exact, and
    /// the CLI refuses a level asked for there).
    fn choose_level(&self, loaded: &mut [(String, Field)]) -> Result<()> {
        let lod = self.lod()?;
        if lod == Lod::Exact || loaded.iter().any(|(_, f)| f.as_bricked().is_none()) {
            return Ok(());
        }
        let Some(first) = loaded.first().and_then(|(_, f)| f.as_bricked()) else {
            return Ok(());
        };
        // The levels every channel has alike: files in smaller bricks have more levels.
        let mut geoms = first.source().geometries().to_vec();
        for (_, f) in loaded.iter() {
            if let Some(b) = f.as_bricked() {
                let n = crate::scene::common_levels(b.source().geometries(), &geoms);
                geoms.truncate(n.max(1));
            }
        }
        let (lo, hi) = geoms[0].world_bounds();
        let width = self.width.unwrap_or(512);
        let height = self.height.unwrap_or(512);
        let ortho = self.camera.unwrap_or_default() == CameraKind::Ortho;
        let cam = self.camera_for_box(lo, hi, width, height, ortho)?;
        let level = lod.pick(&geoms, cam.pixel_footprint(lo, hi, height));
        for (i, (_, f)) in loaded.iter_mut().enumerate() {
            if let Some(b) = f.as_bricked() {
                let moved = if lod == Lod::Brick {
                    // Each brick its own level: the footprint where the brick is nearest.
                    b.per_region(|blo, bhi| {
                        blueshift_volume::lod_level(&geoms, cam.pixel_footprint(blo, bhi, height))
                    })
                } else {
                    b.at_level(level)
                };
                *f = moved
                    .map_err(|e| Error::field_from(format!("channels[{i}].volume"), None, e))?
                    .into();
            }
        }
        Ok(())
    }

    /// Loads the channels and transfer functions and builds the scene, the integrator and
    /// the settings, validated ([`RenderSettings::validate`], the integrator against the
    /// scene).
    ///
    /// # Errors
    /// [`Error::Field`] naming a channel's `volume`, `synth`, `channel` or `tf`, `alpha_g`
    /// or `light.direction`; [`Error::Scene`] (channels of different geometry, no
    /// channels), [`Error::Parameter`] (weights, sizes, spp, materials, `warmup` without
    /// `frames`).
    pub fn build(&self) -> Result<(Scene, Integrator, RenderSettings)> {
        self.build_with(&Preloaded::default())
    }

    /// [`RenderSceneFile::build`] with channels' volumes and transfer functions taken from
    /// `memory` where their `volume` and `tf` strings name its keys (how the Python package
    /// renders numpy arrays through the same loader as scene files).
    ///
    /// # Errors
    /// As [`RenderSceneFile::build`].
    pub fn build_with(&self, memory: &Preloaded) -> Result<(Scene, Integrator, RenderSettings)> {
        let base = self.base.as_deref();
        if self.channels.len() > MAX_CHANNELS {
            return Err(Error::field(
                "channels",
                format!(
                    "{} channels, at most {MAX_CHANNELS} (MAX_CHANNELS)",
                    self.channels.len()
                ),
            ));
        }
        let budget = memory.budget();
        let mut volumes = Loaded::new();
        let mut loaded = Vec::with_capacity(self.channels.len());
        // Every channel holds its own copy of its grid: their sum must fit the budget.
        let mut bytes = 0u64;
        for (i, c) in self.channels.iter().enumerate() {
            let (name, field) = c.load_cached(i, base, memory, &mut volumes)?;
            if let Some(g) = field.as_dense() {
                bytes = bytes.saturating_add(blueshift_volume::budget::grid_bytes(
                    g.geometry().dims,
                    g.scalar_type().size_bytes(),
                    1,
                ));
                budget
                    .check(format_args!("this scene's {} channels", i + 1), bytes)
                    .map_err(|e| Error::field_from("channels", None, e))?;
            }
            loaded.push((name, field));
        }
        drop(volumes);
        self.choose_level(&mut loaded)?;
        let mut triples = Vec::with_capacity(self.channels.len());
        for ((i, c), (name, grid)) in self.channels.iter().enumerate().zip(loaded) {
            let mut tf = c.transfer_function_with(i, &grid, base, memory)?;
            if let Some(range) = self.tf_range {
                let domain = match range {
                    TfRange::Data => data_domain(&grid, tf.data_axis()).ok_or_else(|| {
                        Error::field(
                            "tf_range",
                            format!("channels[{i}] has no values to stretch the TF over"),
                        )
                    })?,
                    TfRange::Interval(lo, hi) => [lo, hi],
                };
                tf = tf
                    .rescaled(domain)
                    .map_err(|e| Error::field_from("tf_range", None, e))?;
            }
            if let Some(a) = self.alpha_g {
                tf = tf
                    .with_alpha_g(a)
                    .map_err(|e| Error::field_from("alpha_g", None, e))?;
            }
            triples.push((name, grid, tf));
        }
        let k = self.macrocell.unwrap_or(blueshift_volume::DEFAULT_K);
        let mut scene = Scene::new(triples, self.density_scale.unwrap_or(1.0), k)?;
        self.apply_lighting(&mut scene)?;
        let integrator = self.integrator(&scene)?;
        let settings = self.settings(&scene)?;
        Ok((scene, integrator, settings))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::DdaMode;
    use crate::Projection;

    /// Every spelling of `T` through `FromStr`, `Display` and serde_json, and a bad one
    /// refused with `what: unknown 'bogus' (the, spellings)`.
    fn round_trip<T>(all: &[T], names: &[&str], what: &str)
    where
        T: Copy
            + PartialEq
            + std::fmt::Debug
            + std::fmt::Display
            + std::str::FromStr<Err = Error>
            + Serialize
            + for<'de> Deserialize<'de>,
    {
        assert_eq!(all.len(), names.len());
        for (v, name) in all.iter().zip(names) {
            assert_eq!(name.parse::<T>().unwrap(), *v, "{name}");
            assert_eq!(v.to_string(), *name);
            let json = serde_json::to_string(v).unwrap();
            assert_eq!(json, format!("\"{name}\""));
            assert_eq!(serde_json::from_str::<T>(&json).unwrap(), *v);
        }
        let e = "bogus".parse::<T>().unwrap_err();
        assert_eq!(
            e.to_string(),
            format!("{what}: unknown 'bogus' ({})", names.join(", "))
        );
        let e = serde_json::from_str::<T>("\"bogus\"")
            .unwrap_err()
            .to_string();
        assert!(e.contains(&names.join(", ")), "{e}");
    }

    #[test]
    fn every_spelling_round_trips_and_bad_ones_list_the_accepted() {
        let m = [
            "woodcock",
            "mdwt-ndda",
            "mdwt-1dda",
            "mdwt-summed",
            "marcher",
        ];
        assert_eq!(Method::NAMES, m);
        round_trip(Method::ALL, &m, "method");
        let b = ["density", "max", "mix", "weighted", "composite"];
        assert_eq!(BlendKind::NAMES, b);
        round_trip(BlendKind::ALL, &b, "blend");
        round_trip(Precision::ALL, &["f32", "f16", "u8"], "precision");
        round_trip(DdaMode::ALL, &["ndda", "1dda", "summed"], "dda mode");
        round_trip(CameraKind::ALL, &["ortho", "perspective"], "camera");
        assert_eq!(
            "orthographic".parse::<CameraKind>().unwrap(),
            CameraKind::Ortho
        );
        // Heat maps keep their message (the CLI prints it after `--heatmap: `).
        for h in HeatMap::ALL {
            assert_eq!(h.name().parse::<HeatMap>().unwrap(), h);
            assert_eq!(h.to_string(), h.name());
            let json = serde_json::to_string(&h).unwrap();
            assert_eq!(serde_json::from_str::<HeatMap>(&json).unwrap(), h);
        }
        assert_eq!(
            "heat".parse::<HeatMap>().unwrap_err().to_string(),
            "invalid parameter: heat map: unknown 'heat' (steps, collisions, rejections, time)"
        );
        // Method, DDA mode and integrator agree; a blend knows its kind.
        for m in Method::ALL {
            if let Some(d) = m.dda() {
                assert_eq!(Method::mdwt(d), *m);
            }
        }
        for k in BlendKind::ALL {
            assert_eq!(k.with_weights(vec![1.0]).kind(), *k);
        }
        let i = Integrator::Mdwt {
            dda: DdaMode::Summed,
            blend: Blend::Max,
        };
        assert_eq!(i.method(), Method::MdwtSummed);
    }

    fn nrrd(dir: &Path, name: &str, n: usize, f: impl Fn(usize) -> f32) {
        let mut bytes = format!(
            "NRRD0004\ntype: float\ndimension: 3\nsizes: {n} {n} {n}\nspacings: 1 1 1\nendian: little\nencoding: raw\n\n"
        )
        .into_bytes();
        for i in 0..n * n * n {
            bytes.extend_from_slice(&f(i).to_le_bytes());
        }
        std::fs::write(dir.join(name), bytes).unwrap();
    }

    const TF: &str = r#"{ "format": "blueshift-transfer-function", "version": 1,
        "domain": [0, 1], "color": [ { "x": 0, "rgb": [1, 0, 0] } ],
        "opacity": [ { "x": 0, "alpha": 0.5 } ] }"#;

    /// A folder like examples/enzo: `s/scene.json` naming `../a.nrrd`, `../b.nrrd` and its
    /// own `tf.json` (paths relative to the scene file).
    fn fixture(scene: &str) -> (tempfile::TempDir, PathBuf) {
        let dir = tempfile::tempdir().unwrap();
        nrrd(dir.path(), "a.nrrd", 8, |_| 0.5);
        nrrd(dir.path(), "b.nrrd", 8, |i| 1.0 + (i % 7) as f32);
        std::fs::create_dir(dir.path().join("s")).unwrap();
        std::fs::write(dir.path().join("s/tf.json"), TF).unwrap();
        let path = dir.path().join("s/scene.json");
        std::fs::write(&path, scene).unwrap();
        (dir, path)
    }

    const ENZO_LIKE: &str = r#"{
      "channels": [
        { "volume": "../a.nrrd", "tf": "tf.json" },
        { "volume": "../b.nrrd", "tf": "log:viridis" },
        { "volume": "../a.nrrd", "tf": "builtin:grey", "material": { "shininess": 8 } }
      ],
      "method": "mdwt-1dda",
      "blend": "density",
      "spp": 64,
      "width": 24,
      "height": 16,
      "camera": "perspective",
      "density_scale": 20,
      "background": [0, 0, 0.5]
    }"#;

    #[test]
    fn an_enzo_like_scene_file_builds_scene_integrator_and_settings() {
        let (_dir, path) = fixture(ENZO_LIKE);
        let f = RenderSceneFile::read(&path).unwrap();
        assert_eq!(f.channels.len(), 3);
        assert_eq!(f.method, Some(Method::MdwtOneDda));
        assert_eq!(f.channels[2].material.unwrap().material().shininess, 8.0);
        let (scene, integrator, settings) = f.build().unwrap();
        assert_eq!(scene.channels().len(), 3);
        assert_eq!(scene.density_scale(), 20.0);
        assert_eq!(scene.background, [0.0, 0.0, 0.5]);
        assert!(scene.light.is_none() && scene.shading.is_none());
        assert_eq!(
            integrator,
            Integrator::Mdwt {
                dda: DdaMode::OneDda,
                blend: Blend::Density
            }
        );
        assert_eq!(
            (settings.width, settings.height, settings.spp),
            (24, 16, 64)
        );
        assert_eq!(settings.seed, 0);
        assert!(matches!(
            settings.camera.projection,
            Projection::Perspective { .. }
        ));
        // The defaults: 512 x 512, 16 spp, mdwt-1dda, density.
        let min =
            r#"{ "channels": [ { "synth": "three-cubes", "res": 8, "tf": "builtin:grey" } ] }"#;
        let f = RenderSceneFile::from_json(min, Path::new("x/min.json")).unwrap();
        assert_eq!(f.base.as_deref(), Some(Path::new("x")));
        let (_, integrator, settings) = f.build().unwrap();
        assert_eq!(integrator.method(), Method::MdwtOneDda);
        assert_eq!(
            (settings.width, settings.height, settings.spp),
            (512, 512, 16)
        );
        // A file round-trips through serde.
        let f = RenderSceneFile::read(&path).unwrap();
        let text = serde_json::to_string(&f).unwrap();
        let back = RenderSceneFile::from_json(&text, &path).unwrap();
        assert_eq!(back, f);
    }

    #[test]
    fn the_committed_enzo_example_loads() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/enzo/scene.json");
        let f = RenderSceneFile::read(&path).unwrap();
        assert_eq!(f.channels.len(), 3);
        assert_eq!(f.method(), Method::MdwtOneDda);
        assert_eq!(f.blend, Some(BlendKind::Density));
        assert_eq!(f.camera, Some(CameraKind::Perspective));
        assert_eq!((f.spp, f.width, f.height), (Some(64), Some(256), Some(256)));
        let data = f
            .base
            .as_ref()
            .unwrap()
            .join(f.channels[0].volume.as_ref().unwrap());
        if !data.exists() {
            eprintln!(
                "SKIP: the Enzo data ({}) is not beside this checkout",
                data.display()
            );
            return;
        }
        let (scene, integrator, settings) = f.build().unwrap();
        assert_eq!(scene.channels().len(), 3);
        assert_eq!(scene.density_scale(), 20.0);
        assert_eq!(integrator.method(), Method::MdwtOneDda);
        assert_eq!(
            (settings.width, settings.height, settings.spp),
            (256, 256, 64)
        );
    }

    #[test]
    fn tf_range_stretches_each_tf_over_its_channel_or_an_interval() {
        // b.nrrd holds 1..7; tf.json is on [0, 1]; log:viridis already spans 1..7.
        let scene = r#"{ "channels": [ { "volume": "../b.nrrd", "tf": "tf.json" },
            { "volume": "../b.nrrd", "tf": "log:viridis" } ], "tf_range": "data" }"#;
        let (_dir, path) = fixture(scene);
        let f = RenderSceneFile::read(&path).unwrap();
        assert_eq!(f.tf_range, Some(TfRange::Data));
        let (s, _, _) = f.build().unwrap();
        assert_eq!(s.channels()[0].transfer_function().domain(), [1.0, 7.0]);
        let log = s.channels()[1].transfer_function().domain();
        assert!((log[0] - 1.0).abs() < 1e-9 && (log[1] - 7.0).abs() < 1e-6);
        let mut f = f;
        f.tf_range = Some("-2:3".parse().unwrap());
        // A log axis refuses a non-positive interval, naming the field.
        let e = f.build().err();
        assert!(e.is_some_and(|e| e.to_string().contains("tf_range")));
        f.channels.truncate(1);
        let (s, _, _) = f.build().unwrap();
        assert_eq!(s.channels()[0].transfer_function().domain(), [-2.0, 3.0]);
        for bad in ["3:2", "1", "a:b", "0:inf", "date"] {
            assert!(bad.parse::<TfRange>().is_err(), "{bad}");
        }
        assert_eq!(TfRange::Interval(0.5, 2.0).to_string(), "0.5:2");
    }

    #[test]
    fn the_marcher_defaults_to_one_sample_per_pixel() {
        let min = r#"{ "channels": [ { "synth": "three-cubes", "res": 8, "tf": "builtin:grey" } ],
            "method": "marcher" }"#;
        let f = RenderSceneFile::from_json(min, Path::new("min.json")).unwrap();
        assert_eq!(f.build().unwrap().2.spp, 1);
    }

    #[test]
    fn flags_override_the_file() {
        let (dir, path) = fixture(ENZO_LIKE);
        let mut f = RenderSceneFile::read(&path).unwrap();
        f.override_with(RenderSceneFile {
            method: Some(Method::Marcher),
            precision: Some(Precision::U8),
            blend: Some(BlendKind::Max),
            camera: Some(CameraKind::Ortho),
            spp: Some(3),
            ..RenderSceneFile::default()
        });
        assert_eq!(
            f.channels.len(),
            3,
            "no channels in the flags: the file's stay"
        );
        assert_eq!(f.width, Some(24), "unset flags keep the file's");
        let (_, integrator, settings) = f.build().unwrap();
        let Integrator::Marcher(m) = integrator else {
            panic!("not the marcher");
        };
        assert_eq!((m.precision, m.blend), (Precision::U8, Blend::Max));
        assert_eq!(settings.spp, 3);
        assert!(matches!(
            settings.camera.projection,
            Projection::Orthographic { .. }
        ));
        // Channels from the flags replace the file's and their paths start at `base`.
        f.override_with(RenderSceneFile {
            channels: vec![ChannelSpec {
                volume: Some(dir.path().join("b.nrrd")),
                tf: "builtin:grey".into(),
                ..ChannelSpec::default()
            }],
            ..RenderSceneFile::default()
        });
        assert_eq!((f.channels.len(), f.base.as_deref()), (1, None));
        assert_eq!(f.build().unwrap().0.channels().len(), 1);
        // Weighted without weights: the majorant weights (one per channel).
        f.blend = Some(BlendKind::Weighted);
        f.method = None;
        let (_, integrator, _) = f.build().unwrap();
        assert!(matches!(
            integrator,
            Integrator::Mdwt { blend: Blend::Weighted { ref weights }, .. } if weights.len() == 1
        ));
        let synth = ChannelSpec::synth_channels("three-cubes", 8).unwrap();
        assert_eq!(synth.len(), 3);
        assert!(ChannelSpec::synth_channels("nope", 8).is_err());
    }

    fn file_error(json: &str) -> String {
        let (_dir, path) = fixture(json);
        match RenderSceneFile::read(&path) {
            Err(e @ Error::SceneFile { .. }) => e.to_string(),
            other => panic!("expected a scene-file error, got {other:?}"),
        }
    }

    #[test]
    fn unknown_fields_and_bad_names_are_refused_with_the_spellings() {
        let one = r#"{ "volume": "../a.nrrd", "tf": "tf.json" }"#;
        for (json, needle) in [
            (r#"{ "channels": [], "colour": 1 }"#.to_owned(), "unknown field `colour`"),
            (
                r#"{ "channels": [ { "volume": "../a.nrrd", "tf": "tf.json", "gain": 2 } ] }"#
                    .to_owned(),
                "unknown field `gain`",
            ),
            (
                format!(r#"{{ "channels": [{one}], "light": {{ "direction": [1, 0, 0], "colour": 1 }} }}"#),
                "unknown field `colour`",
            ),
            (
                r#"{ "channels": [ { "volume": "../a.nrrd", "tf": "tf.json", "material": { "shine": 2 } } ] }"#
                    .to_owned(),
                "unknown field `shine`",
            ),
            (
                format!(r#"{{ "channels": [{one}], "base": "x" }}"#),
                "unknown field `base`",
            ),
            (
                format!(r#"{{ "channels": [{one}], "method": "mdwt" }}"#),
                "method: unknown 'mdwt' (woodcock, mdwt-ndda, mdwt-1dda, mdwt-summed, marcher)",
            ),
            (
                format!(r#"{{ "channels": [{one}], "blend": "sum" }}"#),
                "blend: unknown 'sum' (density, max, mix, weighted, composite)",
            ),
            (
                format!(r#"{{ "channels": [{one}], "precision": "f64" }}"#),
                "precision: unknown 'f64' (f32, f16, u8)",
            ),
            (
                format!(r#"{{ "channels": [{one}], "camera": "fisheye" }}"#),
                "camera: unknown 'fisheye' (ortho, perspective)",
            ),
            (
                format!(r#"{{ "channels": [{one}], "heatmaps": ["heat"] }}"#),
                "heat map: unknown 'heat' (steps, collisions, rejections, time)",
            ),
        ] {
            let e = file_error(&json);
            assert!(e.starts_with("scene file "), "{e}");
            assert!(e.contains(needle), "{json}: '{e}' lacks '{needle}'");
        }
    }

    #[test]
    fn build_errors_name_the_field() {
        let build = |json: &str| {
            let (_dir, path) = fixture(json);
            RenderSceneFile::read(&path).unwrap().build().unwrap_err()
        };
        for (json, start) in [
            (
                r#"{ "channels": [ { "volume": "../nope.nrrd", "tf": "tf.json" } ] }"#,
                "channels[0].volume: cannot read ",
            ),
            (
                r#"{ "channels": [ { "volume": "../a.nrrd", "synth": "galaxy", "tf": "tf.json" } ] }"#,
                "channels[0]: give exactly one of \"volume\" and \"synth\"",
            ),
            (
                r#"{ "channels": [ { "volume": "../a.nrrd", "channel": "x", "tf": "tf.json" } ] }"#,
                "channels[0].channel: no channel named 'x'",
            ),
            (
                r#"{ "channels": [ { "volume": "../a.nrrd", "tf": "tf.json" }, { "volume": "../a.nrrd", "tf": "missing.json" } ] }"#,
                "channels[1].tf 'missing.json'",
            ),
            (
                r#"{ "channels": [ { "synth": "nope", "tf": "tf.json" } ] }"#,
                "channels[0].synth",
            ),
            (
                r#"{ "channels": [ { "volume": "../a.nrrd", "tf": "tf.json" } ], "alpha_g": -1 }"#,
                "alpha_g",
            ),
            (
                r#"{ "channels": [ { "volume": "../a.nrrd", "tf": "tf.json" } ], "light": { "direction": [0, 0, 0] } }"#,
                "light.direction: [0.0, 0.0, 0.0] must be a non-zero finite vector",
            ),
            (
                r#"{ "channels": [ { "volume": "../a.nrrd", "tf": "tf.json" } ], "warmup": 2 }"#,
                "invalid parameter: warmup",
            ),
            (
                r#"{ "channels": [ { "volume": "../a.nrrd", "tf": "tf.json" } ], "spp": 0 }"#,
                "invalid parameter: spp",
            ),
            (
                r#"{ "channels": [ { "volume": "../a.nrrd", "tf": "tf.json" } ], "blend": "mix", "weights": [1, 2] }"#,
                "invalid parameter: mix: 2 weights for 1 channels",
            ),
        ] {
            let e = build(json).to_string();
            assert!(
                e.starts_with(start),
                "{json}: '{e}' does not start with '{start}'"
            );
        }
        // The source stays attached: the reader's error follows the field.
        let e = build(r#"{ "channels": [ { "volume": "../nope.nrrd", "tf": "tf.json" } ] }"#);
        assert!(std::error::Error::source(&e).is_some());
    }
}
