//! Tracking scenes (Woodcock, MDWT N-DDA / 1-DDA / summed, the marcher) over a
//! [`TrackingSession`] (CPU) or a [`GpuTrackingSession`].
//!
//! The state is a [`RenderSceneFile`]: every edit changes the file's fields and the session
//! is brought to what [`RenderSceneFile::integrator`] and [`RenderSceneFile::settings`]
//! build from it, so `save` writes a scene file (plus one transfer-function JSON per
//! channel) from which `blueshift render SCENE.json` makes the same image bit for bit.

use std::path::PathBuf;

use blueshift_camera::{Observer, Progress};
use blueshift_gpu::DeviceChoice;
use blueshift_gpu::tracking::GpuTrackingSession;
use blueshift_tfedit::TransferFunction;
use blueshift_tracking::{
    BlendKind, LightSpec, Method, Precision, Progressive, RenderSceneFile, RenderSettings, Scene,
    TrackingSession,
};
use blueshift_volume::Field;
use image::Rgb32FImage;
use serde_json::{Value, json};

use super::{Mode, SaveSet, command_line, histogram, preview_sizes, saved_reply, write_file};
use crate::display;
use crate::protocol::{Incoming, RangeMsg, SettingsMsg};
use crate::worker::{Ctx, Stage};
use crate::{Error, Result};

/// A tracking scene for the viewer: the scene file as the CLI merged it from the command
/// line (its `base` resolves relative paths) and what it built.
#[derive(Debug)]
pub struct TrackingSource {
    /// The merged scene file (channels, method, camera, ...).
    pub file: RenderSceneFile,
    /// The scene it built.
    pub scene: Scene,
    /// The files named on the command line (never written by a save).
    pub inputs: Vec<PathBuf>,
    /// The PNG preview operator of `blueshift render --tonemap`.
    pub tonemap: String,
    /// Exposure of the display in stops.
    pub exposure: f32,
    /// Where to render.
    pub device: DeviceChoice,
}

pub(crate) struct TrackingMode {
    file: RenderSceneFile,
    session: TrackingSession,
    gpu: Option<GpuTrackingSession<'static>>,
    device: DeviceChoice,
    inputs: Vec<PathBuf>,
    tonemap: String,
    exposure: f32,
    histograms: Vec<Value>,
    /// The last full-resolution accumulation and whether it reached its target.
    last: Option<Progressive>,
    /// The observer's speed set by the page (flying into the picture; `None`: the scene
    /// file's `observer_velocity`, if any, untouched).
    beta: Option<f64>,
}

impl std::fmt::Debug for TrackingMode {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("TrackingMode").finish_non_exhaustive()
    }
}

fn parse<T: std::str::FromStr<Err = blueshift_tracking::Error>>(s: &str) -> Result<T> {
    Ok(s.parse::<T>()?)
}

impl TrackingMode {
    pub(crate) fn new(src: &TrackingSource) -> Result<Self> {
        let mut file = src.file.clone();
        // The viewer refines progressively; heat maps and the timing protocol are batch
        // features of `blueshift render`.
        file.heatmaps = None;
        file.frames = None;
        file.warmup = None;
        let scene = src.scene.clone();
        let integrator = file.integrator(&scene)?;
        let settings = file.settings(&scene)?;
        let histograms = scene
            .channels()
            .iter()
            .map(|c| {
                // Out-of-core channels: the histogram of the coarsest level (the means of
                // the finest voxels), so opening the viewer reads a few bricks only.
                let coarse;
                let g = match c.grid().as_bricked() {
                    Some(b) => {
                        coarse = Field::from(b.at_level(b.levels() - 1)?);
                        &coarse
                    }
                    None => c.grid(),
                };
                let mut values = Vec::new();
                g.for_each_block(|v| values.extend_from_slice(v))?;
                Ok(histogram(values.into_iter(), 256))
            })
            .collect::<std::result::Result<_, blueshift_volume::Error>>()
            .map_err(|e| Error::invalid(e.to_string()))?;
        display::operator(&src.tonemap, src.exposure)?;
        let mut mode = Self {
            session: TrackingSession::new(scene, integrator, settings)?,
            file,
            gpu: None,
            device: DeviceChoice::Cpu,
            inputs: src.inputs.clone(),
            tonemap: src.tonemap.clone(),
            exposure: src.exposure,
            beta: None,
            histograms,
            last: None,
        };
        mode.set_device(src.device)?;
        Ok(mode)
    }

    fn camera_json(&self) -> Value {
        let c = self.session.settings().camera;
        let (projection, fov) = match c.projection {
            blueshift_camera::Projection::Perspective { fov_y_deg } => ("perspective", fov_y_deg),
            blueshift_camera::Projection::Orthographic { .. } => ("orthographic", 0.0),
        };
        let (lo, hi) = self.session.scene().bounds();
        json!({
            "type": "camera",
            "eye": c.eye.to_array(), "target": c.target.to_array(), "up": c.up.to_array(),
            "fov": fov, "projection": projection, "zoom": self.file.zoom.unwrap_or(1.0),
            "view": self.file.view,
            "bounds": [lo.to_array(), hi.to_array()],
        })
    }

    fn settings_json(&self) -> Value {
        let st = self.session.settings();
        json!({
            "type": "settings",
            "method": self.file.method().to_string(),
            "blend": self.file.blend.unwrap_or_default().to_string(),
            "spp": st.spp, "noise_target": st.noise_target,
            "density_scale": self.session.scene().density_scale(),
            "light_dir": self.file.light.map(|l| l.direction),
            "shading": self.file.shading.unwrap_or(false),
            "precision": self.file.precision.unwrap_or(Precision::F32).to_string(),
            "device": self.device.to_string(),
            "width": st.width, "height": st.height, "seed": st.seed,
            "exposure": self.exposure, "tonemap": self.tonemap,
            "beta": st.observer.map_or(0.0, |o| o.velocity.speed()),
        })
    }

    fn tf_json(&self, channel: usize) -> Value {
        json!({
            "type": "tf", "channel": channel,
            "tf": self.session.scene().channels()[channel].transfer_function(),
        })
    }

    fn devices() -> Value {
        let gpu = blueshift_gpu::GpuContext::shared().ok().map(|c| {
            let i = c.info();
            format!(
                "{} ({:?}{})",
                i.name,
                i.backend,
                if c.is_hardware() { "" } else { ", software" }
            )
        });
        json!({ "cpu": format!("{} threads", rayon::current_num_threads()), "gpu": gpu })
    }

    fn channel(&self, c: usize) -> Result<()> {
        let n = self.session.scene().channel_count();
        if c >= n {
            return Err(Error::invalid(format!(
                "channel {c}: the scene has {n} channel(s)"
            )));
        }
        Ok(())
    }

    /// Brings the session (and the GPU twin) to what the file builds.
    fn sync(&mut self) -> Result<()> {
        let scene = self.session.scene();
        let integrator = self.file.integrator(scene)?;
        if let Some(b) = self.beta {
            // The observer flies into the picture: along the current view direction.
            self.file.observer_velocity = None;
            let cam = self.file.settings(scene)?.camera;
            let d = (cam.target - cam.eye).normalize_or_zero().as_dvec3();
            self.file.observer_velocity = (b > 0.0).then(|| (d * b).to_array());
        }
        let settings = self.file.settings(scene)?;
        // The GPU twin has no moving observer: rebuilt (auto falls back to the CPU).
        let moving = settings.observer.is_some();
        self.session.set_integrator(integrator.clone())?;
        self.session.set_settings(settings.clone())?;
        if moving && self.gpu.is_some() {
            self.set_device(self.device)?;
        } else if let Some(g) = &mut self.gpu {
            g.set_integrator(integrator)?;
            g.set_settings(settings)?;
        }
        Ok(())
    }

    /// Rebuilds the CPU session around its scene after a scene-level edit (light,
    /// shading, density scale), and the GPU twin from it.
    fn rebuild(
        &mut self,
        edit: impl FnOnce(&mut Scene, &RenderSceneFile) -> Result<()>,
    ) -> Result<()> {
        let integrator = self.session.integrator().clone();
        let settings = self.session.settings().clone();
        let mut scene = self.session.scene().clone();
        edit(&mut scene, &self.file)?;
        let integrator = self.file.integrator(&scene).unwrap_or(integrator);
        self.session = TrackingSession::new(scene, integrator, settings)?;
        if self.gpu.is_some() {
            self.gpu = None;
            self.set_device(self.device)?;
        }
        Ok(())
    }

    fn set_device(&mut self, device: DeviceChoice) -> Result<()> {
        self.device = device;
        self.gpu = None;
        let Some(ctx) = device.context()? else {
            return Ok(());
        };
        let scene = self.session.scene().clone();
        let made = GpuTrackingSession::new(
            ctx,
            scene,
            self.session.integrator().clone(),
            self.session.settings().clone(),
        );
        match made {
            Ok(g) => self.gpu = Some(g),
            Err(e) if device.falls_back_on(&e) => {}
            Err(e) => return Err(e.into()),
        }
        Ok(())
    }

    fn apply_settings(&mut self, s: SettingsMsg) -> Result<Stage> {
        let mut stage = if s.display_only() {
            Stage::Display
        } else {
            Stage::Full
        };
        let old = (self.file.clone(), self.exposure, self.tonemap.clone());
        let old_beta = self.beta;
        let old_density = self.session.scene().density_scale();
        let old_device = self.device;
        let result = (|| -> Result<Stage> {
            if let Some(m) = &s.method {
                self.file.method = Some(parse::<Method>(m)?);
            }
            if let Some(b) = &s.blend {
                self.file.blend = Some(parse::<BlendKind>(b)?);
            }
            if let Some(p) = &s.precision {
                self.file.precision = Some(parse::<Precision>(p)?);
            }
            if let Some(n) = s.spp {
                if !(1..=1 << 20).contains(&n) {
                    return Err(Error::invalid(format!("spp {n}: 1 to 1048576")));
                }
                self.file.spp = Some(n);
            }
            if let Some(n) = s.noise_target {
                self.file.noise_target = n;
            }
            if let Some(seed) = s.seed {
                self.file.seed = Some(seed);
            }
            if let Some(b) = s.beta {
                if !(b.is_finite() && (0.0..1.0).contains(&b)) {
                    return Err(Error::invalid(format!(
                        "settings: beta {b} must be in [0, 1)"
                    )));
                }
                self.beta = Some(b);
                stage = Stage::Preview;
            }
            if s.width.is_some() || s.height.is_some() {
                let w = s.width.or(self.file.width).unwrap_or(512);
                let h = s.height.or(self.file.height).unwrap_or(512);
                super::check_view_size(w, h)?;
                self.file.width = Some(w);
                self.file.height = Some(h);
                stage = Stage::Preview;
            }
            if let Some(e) = s.exposure {
                self.exposure = e;
            }
            if let Some(t) = &s.tonemap {
                display::operator(t, self.exposure)?;
                self.tonemap = t.clone();
            }
            let relight = s.light_dir.is_some() || s.shading.is_some();
            if let Some(l) = s.light_dir {
                self.file.light = l.map(|direction| LightSpec {
                    direction,
                    radiance: self
                        .file
                        .light
                        .map_or(LightSpec::DEFAULT_RADIANCE, |l| l.radiance),
                    ambient: self
                        .file
                        .light
                        .map_or(LightSpec::DEFAULT_AMBIENT, |l| l.ambient),
                });
            }
            if let Some(sh) = s.shading {
                self.file.shading = Some(sh);
            }
            if relight {
                self.rebuild(|scene, file| Ok(file.apply_lighting(scene)?))?;
                stage = Stage::Preview;
            }
            if let Some(d) = s.density_scale {
                self.session.set_density_scale(d)?;
                self.file.density_scale = Some(d);
                if self.gpu.is_some() {
                    self.set_device(self.device)?;
                }
                stage = Stage::Preview;
            }
            if let Some(d) = &s.device {
                let d = d.parse::<DeviceChoice>().map_err(Error::Invalid)?;
                self.set_device(d)?;
                stage = Stage::Preview;
            }
            if s.method.is_some() || s.blend.is_some() || s.precision.is_some() {
                stage = Stage::Preview;
            }
            self.sync()?;
            Ok(stage)
        })();
        if result.is_err() {
            // Keep the old state whole: the file, the display, and the session and its GPU
            // twin rebuilt from them (density scale, light and shading, device).
            (self.file, self.exposure, self.tonemap) = old;
            self.beta = old_beta;
            if self.session.scene().density_scale() != old_density {
                let _ = self.session.set_density_scale(old_density);
            }
            let _ = self.rebuild(|scene, file| Ok(file.apply_lighting(scene)?));
            let _ = self.set_device(old_device);
            let _ = self.sync();
        }
        result
    }

    fn set_tf(&mut self, channel: usize, tf: TransferFunction) -> Result<()> {
        self.channel(channel)?;
        if let Some(g) = &mut self.gpu {
            g.set_transfer_function(channel, tf.clone())?;
        }
        self.session.set_transfer_function(channel, tf)?;
        // A weighted blend without weights follows the majorants.
        self.sync()
    }

    fn display_image(&self, acc: &Progressive) -> Result<image::RgbImage> {
        let img = acc.mean_image();
        let rgb = Rgb32FImage::from_fn(img.width(), img.height(), |x, y| {
            let p = img.get_pixel(x, y).0;
            image::Rgb([p[0], p[1], p[2]])
        });
        let op = display::operator(&self.tonemap, self.exposure)?;
        let op = match op {
            Some(blueshift_tonemap::Operator::Linear(p)) => Some(
                blueshift_tonemap::Operator::Linear(blueshift_tonemap::LinearParams {
                    white: blueshift_tonemap::default_linear_white(&rgb),
                    ..p
                }),
            ),
            other => other,
        };
        display::to_rgb8(&rgb, op.as_ref(), self.exposure)
    }

    /// Sends the frame and its status. `lod`: the level of detail the frame's passes sampled
    /// (0 the finest) when the scene's channels are out of core, with the number of levels.
    fn send_frame(
        &self,
        ctx: &Ctx,
        acc: &Progressive,
        preview: bool,
        done: bool,
        ms: f64,
        lod: Option<(usize, usize)>,
    ) -> Result<()> {
        let img = self.display_image(acc)?;
        let st = self.session.settings();
        let noise = acc.noise();
        ctx.send_image(
            "frame",
            &img,
            json!({ "pass": acc.samples(), "spp": acc.samples(), "preview": preview }),
        )?;
        ctx.send(&json!({
            "type": "status", "pass": acc.samples(), "spp": acc.samples(),
            // Previews are one pass (a coarser level's runs beside the session's settings).
            "target_spp": if preview { 1 } else { st.spp },
            "noise": noise.is_finite().then_some(noise), "ms": ms,
            "device": self.device_name(), "preview": preview, "done": done,
            "level": if preview { "preview" } else { "full" },
            "lod_level": lod.map(|l| l.0), "lod_levels": lod.map(|l| l.1),
        }));
        Ok(())
    }

    fn device_name(&self) -> String {
        match &self.gpu {
            Some(_) => blueshift_gpu::GpuContext::shared()
                .map(|c| c.info().name.clone())
                .unwrap_or_else(|_| "gpu".into()),
            None => "cpu".into(),
        }
    }

    fn run_session(&self, observer: &dyn Observer<Progressive>) -> Result<Progressive> {
        match &self.gpu {
            Some(g) => match g.render(observer) {
                Ok(out) => Ok(out.image),
                Err(e) => Err(e.into()),
            },
            None => Ok(self.session.render(observer)?.image),
        }
    }

    /// Writes the HDR frame, its PNG, the transfer functions and the scene file, and
    /// returns the `saved` reply with the command that reproduces the EXR.
    fn save(&self, ctx: &Ctx, name: Option<&str>, acc: &Progressive) -> Result<Value> {
        let n = self.session.scene().channel_count();
        let mut suffixes = vec![".exr".to_string(), ".png".into(), ".json".into()];
        suffixes.extend((0..n).map(|i| format!("-tf{i}.json")));
        let refs: Vec<&str> = suffixes.iter().map(String::as_str).collect();
        let set = SaveSet::new(ctx, name, &refs, &self.inputs)?;
        let mut file = self.file.clone();
        let base = file.base.take();
        let mut files = Vec::new();
        for (i, (spec, ch)) in file
            .channels
            .iter_mut()
            .zip(self.session.scene().channels())
            .enumerate()
        {
            let tf_path = set.path(&format!("-tf{i}.json"));
            write_file(&tf_path, ch.transfer_function().to_json_string().as_bytes())?;
            files.push(tf_path.clone());
            spec.tf = tf_path.display().to_string();
            if let Some(v) = &spec.volume {
                let p = match &base {
                    Some(b) if v.is_relative() => b.join(v),
                    _ => v.clone(),
                };
                spec.volume = Some(std::fs::canonicalize(&p).unwrap_or(p));
            }
        }
        // The transfer functions are saved with their alpha_g and range applied.
        file.alpha_g = None;
        file.tf_range = None;
        file.spp = Some(acc.samples());
        file.noise_target = None;
        let scene_path = set.path(".json");
        let text = serde_json::to_string_pretty(&file)
            .map_err(|e| Error::invalid(format!("cannot write the scene file: {e}")))?;
        write_file(&scene_path, format!("{text}\n").as_bytes())?;
        files.push(scene_path.clone());
        let img = acc.mean_image();
        let exr = set.path(".exr");
        blueshift_tonemap::io::write_exr_f32_channels(
            &exr,
            img.width(),
            img.height(),
            4,
            img.as_raw(),
            blueshift_tonemap::io::ExrSpace::LinearSrgb,
        )?;
        files.push(exr.clone());
        let png = set.path(".png");
        super::write_png(&png, &self.display_image(acc)?)?;
        files.push(png.clone());
        set.commit(&files);
        let mut args: Vec<String> = vec![
            "blueshift".into(),
            "render".into(),
            scene_path.display().to_string(),
            "--out".into(),
            exr.display().to_string(),
        ];
        if self.gpu.is_some() {
            args.extend(["--device".into(), "gpu".into()]);
        }
        Ok(saved_reply(&files, &command_line(&args), Some(&scene_path)))
    }

    fn export_tf(&self, channel: usize, paraview: bool) -> Result<Value> {
        self.channel(channel)?;
        let tf = self.session.scene().channels()[channel].transfer_function();
        let text = if paraview {
            blueshift_tfedit::paraview::to_paraview_string(tf)
        } else {
            tf.to_json_string()
        };
        Ok(json!({
            "type": "tf_text", "channel": channel,
            "format": if paraview { "paraview" } else { "blueshift" }, "text": text,
        }))
    }
}

/// Streams the passes and serves `save`, `hello` and `tf_export` between them.
struct Streamer<'a> {
    mode: &'a TrackingMode,
    ctx: &'a Ctx,
    preview: bool,
    target: u32,
    /// The level of detail and the number of levels (out-of-core scenes).
    lod: Option<(usize, usize)>,
    last_pass: std::sync::Mutex<std::time::Instant>,
    /// The time of the last pass, ms (for the final status).
    last_ms: std::sync::Mutex<f64>,
}

impl Observer<Progressive> for Streamer<'_> {
    fn progress(&self, _: Progress) {}

    fn pass(&self, _pass: u32, acc: &Progressive, _noise: Option<f64>) {
        let ms = {
            let mut t = self.last_pass.lock().unwrap_or_else(|e| e.into_inner());
            let ms = t.elapsed().as_secs_f64() * 1e3;
            *t = std::time::Instant::now();
            ms
        };
        let done = acc.samples() >= self.target;
        *self.last_ms.lock().unwrap_or_else(|e| e.into_inner()) = ms;
        if self.ctx.frame_due(done || self.preview)
            && let Err(e) = self
                .mode
                .send_frame(self.ctx, acc, self.preview, false, ms, self.lod)
        {
            self.ctx.error(&e.to_string(), None);
        }
        if self.preview {
            return;
        }
        self.ctx.poll(|m| match m {
            Incoming::Save { name } => Some(
                self.mode
                    .save(self.ctx, name.as_deref(), acc)
                    .map(|v| self.ctx.send(&v)),
            ),
            Incoming::Hello => {
                self.ctx
                    .send(&crate::worker::info_with_dir(self.mode, self.ctx));
                Some(Ok(()))
            }
            Incoming::TfExport { channel, paraview } => Some(
                self.mode
                    .export_tf(*channel, *paraview)
                    .map(|v| self.ctx.send(&v)),
            ),
            _ => None,
        });
    }

    fn cancelled(&self) -> bool {
        self.ctx.cancel.is_cancelled()
    }
}

impl Mode for TrackingMode {
    fn info(&self) -> Value {
        let scene = self.session.scene();
        let channels: Vec<Value> = scene
            .channels()
            .iter()
            .zip(&self.histograms)
            .map(|(c, h)| {
                let range = c.grid().finite_range().map(|(a, b)| [a, b]);
                json!({ "name": c.name(), "range": range, "histogram": h, "tf": c.transfer_function() })
            })
            .collect();
        let st = self.session.settings();
        json!({
            "type": "info", "version": 1, "mode": "tracking",
            "width": st.width, "height": st.height,
            "channels": channels,
            "camera": self.camera_json(),
            "settings": self.settings_json(),
            "doppler": null, "relativity": null, "tonemap": null,
            "devices": Self::devices(),
            "views": blueshift_camera::View::NAMES,
            "methods": Method::NAMES, "blends": BlendKind::NAMES, "precisions": Precision::NAMES,
            "tonemaps": display::TONEMAPS,
        })
    }

    fn handle(&mut self, msg: Incoming, ctx: &Ctx) -> Result<Option<Stage>> {
        match msg {
            Incoming::Camera(c) => {
                let old = self.file.clone();
                self.file.eye = Some(c.eye);
                self.file.target = Some(c.target);
                self.file.up = Some(c.up);
                if let Some(f) = c.fov {
                    self.file.fov_y_deg = Some(f);
                }
                if let Some(z) = c.zoom {
                    self.file.zoom = Some(z);
                }
                if let Err(e) = self.sync() {
                    self.file = old;
                    let _ = self.sync();
                    return Err(e);
                }
                ctx.send(&self.camera_json());
                Ok(Some(Stage::Preview))
            }
            Incoming::View(v) => {
                let view = v.name.parse::<blueshift_camera::View>()?;
                let old = self.file.clone();
                self.file.view = Some(view.to_string());
                self.file.eye = None;
                self.file.target = None;
                self.file.up = None;
                self.file.zoom = v.zoom;
                if let Err(e) = self.sync() {
                    self.file = old;
                    let _ = self.sync();
                    return Err(e);
                }
                ctx.send(&self.camera_json());
                Ok(Some(Stage::Preview))
            }
            Incoming::Tf { channel, tf } => {
                let tf: TransferFunction =
                    serde_json::from_value(tf).map_err(|e| Error::invalid(format!("tf: {e}")))?;
                self.set_tf(channel, tf)?;
                ctx.send(&self.tf_json(channel));
                Ok(Some(Stage::Preview))
            }
            Incoming::TfLoad { channel, text } => {
                let (tf, _) = blueshift_tfedit::parse_any(&text)?;
                self.set_tf(channel, tf)?;
                ctx.send(&self.tf_json(channel));
                Ok(Some(Stage::Preview))
            }
            Incoming::TfRange { channel, range } => {
                let n = self.session.scene().channel_count();
                let which: Vec<usize> = match channel {
                    Some(c) => {
                        self.channel(c)?;
                        vec![c]
                    }
                    None => (0..n).collect(),
                };
                for c in which {
                    let ch = &self.session.scene().channels()[c];
                    let tf = ch.transfer_function();
                    let domain = match range {
                        RangeMsg::Data => {
                            blueshift_tracking::scene_file::data_domain(ch.grid(), tf.data_axis())
                                .ok_or_else(|| {
                                Error::invalid(format!("tf_range: channel {c} has no values"))
                            })?
                        }
                        RangeMsg::Interval(lo, hi) => [lo, hi],
                    };
                    let tf = tf.rescaled(domain)?;
                    self.set_tf(c, tf)?;
                    ctx.send(&self.tf_json(c));
                }
                Ok(Some(Stage::Preview))
            }
            Incoming::TfExport { channel, paraview } => {
                ctx.send(&self.export_tf(channel, paraview)?);
                Ok(None)
            }
            Incoming::Settings(s) => {
                let stage = self.apply_settings(s)?;
                ctx.send(&self.settings_json());
                Ok(Some(stage))
            }
            Incoming::Save { name } => {
                let Some(acc) = &self.last else {
                    return Err(Error::invalid(
                        "save: no finished frame yet; wait for the first pass",
                    ));
                };
                ctx.send(&self.save(ctx, name.as_deref(), acc)?);
                Ok(None)
            }
            other => Err(Error::invalid(format!(
                "{}: not available for a tracking scene",
                other.kind()
            ))),
        }
    }

    fn invalidate(&mut self) {
        self.last = None;
    }

    fn render(&mut self, stage: Stage, ctx: &Ctx) -> Result<()> {
        let full: RenderSettings = self.session.settings().clone();
        if stage == Stage::Display {
            if let Some(acc) = &self.last {
                self.send_frame(ctx, acc, false, true, 0.0, self.session.scene().lod())?;
            }
            return Ok(());
        }
        self.last = None;
        let previews = if stage == Stage::Preview {
            preview_sizes(full.width, full.height)
        } else {
            Vec::new()
        };
        // Out of core on the CPU (HDR VolVis 6.3): each preview samples the level the LOD
        // rule picks for its own pixels (4 or 2 times the full image's), never finer than
        // the scene's, while the I/O thread loads the full render's bricks along its rays.
        let lod = self.session.scene().lod();
        let cpu_lod = lod.filter(|_| self.gpu.is_none());
        if cpu_lod.is_some() && !previews.is_empty() {
            self.prefetch_full(&full)?;
        }
        for (w, h) in previews {
            let mut p = full.clone();
            p.width = w;
            p.height = h;
            p.spp = 1;
            p.noise_target = None;
            let level = cpu_lod.map(|(level, count)| (self.preview_level(&p, level), count));
            // A coarser level than the scene's renders through its own session.
            let coarse = level
                .map(|l| l.0)
                .filter(|&l| Some(l) != lod.map(|x| x.0))
                .map(|l| -> Result<TrackingSession> {
                    let scene = self.session.scene().at_level(l)?;
                    Ok(TrackingSession::new(
                        scene,
                        self.session.integrator().clone(),
                        p.clone(),
                    )?)
                })
                .transpose()?;
            if coarse.is_none() {
                self.set_render_settings(p)?;
            }
            let streamer = Streamer {
                mode: self,
                ctx,
                preview: true,
                target: 1,
                lod: level.or(lod),
                last_pass: std::sync::Mutex::new(std::time::Instant::now()),
                last_ms: std::sync::Mutex::new(0.0),
            };
            let r = match &coarse {
                Some(session) => session.render(&streamer).map(|_| ()).map_err(Error::from),
                None => self.run_session(&streamer).map(|_| ()),
            };
            if coarse.is_none() {
                self.set_render_settings(full.clone())?;
            }
            r?;
        }
        let streamer = Streamer {
            mode: self,
            ctx,
            preview: false,
            target: full.spp,
            lod,
            last_pass: std::sync::Mutex::new(std::time::Instant::now()),
            last_ms: std::sync::Mutex::new(0.0),
        };
        let acc = self.run_session(&streamer)?;
        let ms = *streamer.last_ms.lock().unwrap_or_else(|e| e.into_inner());
        self.send_frame(ctx, &acc, false, true, ms, lod)?;
        self.last = Some(acc);
        Ok(())
    }
}

impl TrackingMode {
    /// The level a preview of settings `p` samples: [`blueshift_volume::lod_level`] for the
    /// preview's pixel footprint where the volume is nearest, at least the scene's `level`.
    fn preview_level(&self, p: &RenderSettings, level: usize) -> usize {
        let scene = self.session.scene();
        let Some(b) = scene.channels().first().and_then(|c| c.grid().as_bricked()) else {
            return level;
        };
        let geoms = b.source().geometries();
        let (lo, hi) = scene.frame_bounds();
        let footprint = p.camera.pixel_footprint(lo, hi, p.height);
        blueshift_volume::lod_level(geoms, footprint)
            .max(level)
            .min(geoms.len().saturating_sub(1))
    }

    /// Queues the bricks the full render of `full` meets along every 16th pixel's ray on
    /// the brick cache's I/O thread (out-of-core channels only).
    fn prefetch_full(&self, full: &RenderSettings) -> Result<()> {
        let fields: Vec<&blueshift_volume::BrickedField> = self
            .session
            .scene()
            .channels()
            .iter()
            .filter_map(|c| c.grid().as_bricked())
            .collect();
        if !fields.is_empty() {
            let rays = full.camera.sparse_rays(full.width, full.height, 16);
            blueshift_volume::BrickedField::prefetch_along(&fields, &rays);
        }
        Ok(())
    }

    fn set_render_settings(&mut self, s: RenderSettings) -> Result<()> {
        self.session.set_settings(s.clone())?;
        if let Some(g) = &mut self.gpu {
            g.set_settings(s)?;
        }
        Ok(())
    }
}
