//! Doppler scenes over a [`DopplerSession`]: the Table 1 factors, the integrator, picks
//! with their exact spectra, traces, and the velocity-coded panel.
//!
//! The camera is rebuilt the way `blueshift doppler` builds it from its flags: the view
//! preset's line-of-sight camera (or the command line's camera), then eye, target and up,
//! then the zoom. `save` therefore prints a `blueshift doppler` command that gives the same
//! EXR bit for bit.

use std::path::PathBuf;

use blueshift_camera::{Camera, Observer, Progress, View};
use blueshift_doppler::{
    DisplayOptions, DopplerImage, DopplerScene, DopplerSession, DopplerSettings, Factors,
    SpectralIntegrator,
};
use blueshift_relativity::{MovingObserver, Velocity};
use glam::Vec3;
use image::RgbImage;
use serde_json::{Value, json};

use super::{Mode, SaveSet, command_line, preview_sizes, saved_reply, spectrum_points, triple};
use crate::protocol::{DopplerMsg, Incoming};
use crate::worker::{Ctx, Stage};
use crate::{Error, Result};

/// Makes the velocity-coded panel of the figures for a scene and its settings (the CLI's
/// figure code: H-alpha moment 1 of a spectral cube, colour-coded, with its key).
/// Returns the panel and a JSON object for its frame header (its colour scale: `vmin`,
/// `vmax`, `unit`, `label`).
pub type PanelFn = Box<
    dyn Fn(&DopplerScene, &DopplerSettings) -> std::result::Result<(RgbImage, Value), String>
        + Send
        + Sync,
>;

/// A Doppler scene for the viewer.
pub struct DopplerSource {
    /// The scene.
    pub scene: DopplerScene,
    /// The settings `blueshift doppler BASE_ARGS` builds (size, camera, integrator, ...).
    pub settings: DopplerSettings,
    /// The `blueshift doppler` arguments that load this scene and make these settings
    /// (without the program name, `--width`, `--height`, the view and factor flags, the
    /// integrator, `--merge-tol` and `--out`, which the viewer adds).
    pub base_args: Vec<String>,
    /// The files named on the command line (never written by a save).
    pub inputs: Vec<PathBuf>,
    /// The display mapping (primaries, exposure rule).
    pub display: DisplayOptions,
    /// Exposure in stops over the display's rule.
    pub exposure: f64,
    /// The velocity panel, when the caller can draw it.
    pub panel: Option<PanelFn>,
}

impl std::fmt::Debug for DopplerSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("DopplerSource")
            .field("base_args", &self.base_args)
            .finish_non_exhaustive()
    }
}

/// The camera state, as the flags of `blueshift doppler` spell it.
#[derive(Clone, Copy, Debug, Default)]
struct CameraState {
    view: Option<View>,
    eye: Option<[f32; 3]>,
    target: Option<[f32; 3]>,
    up: Option<[f32; 3]>,
    zoom: Option<f32>,
}

pub(crate) struct DopplerMode<'a> {
    src: &'a DopplerSource,
    session: DopplerSession,
    /// The command line's camera (before any view flag).
    base_camera: Camera,
    cam: CameraState,
    enabled: bool,
    factors: Factors,
    exposure: f64,
    /// The observer's speed along the view direction (0: at rest; `doppler --beta`).
    beta: f64,
    last: Option<DopplerImage>,
    /// Whether the last full render's samples are the current view's (a factor edit then
    /// re-renders without sampling the volume again, and needs no preview).
    view_current: bool,
}

impl<'a> DopplerMode<'a> {
    pub(crate) fn new(src: &'a DopplerSource) -> Result<Self> {
        let factors = src.scene.factors;
        let session = DopplerSession::new(src.scene.clone(), src.settings.clone())?;
        Ok(Self {
            src,
            base_camera: src.settings.camera,
            session,
            cam: CameraState::default(),
            enabled: true,
            factors,
            exposure: src.exposure,
            beta: 0.0,
            last: None,
            view_current: false,
        })
    }

    fn camera(&self, st: &DopplerSettings) -> Result<Camera> {
        let aspect = st.width as f32 / st.height.max(1) as f32;
        let mut cam = match self.cam.view {
            Some(v) => blueshift_doppler::los_camera(
                self.session.scene(),
                v.normal(),
                aspect,
                st.cell_domain,
            )?,
            None => self.base_camera,
        };
        cam = cam.with_overrides(
            self.cam.eye.map(Vec3::from),
            self.cam.target.map(Vec3::from),
            self.cam.up.map(Vec3::from),
        );
        if let Some(z) = self.cam.zoom {
            cam = cam.zoomed(z)?;
        }
        cam.validate()?;
        Ok(cam)
    }

    /// The moving observer of speed `beta` flying into the picture of camera `cam` (none at
    /// rest), with the searchlight when the scene's settings use the invariant transform.
    fn observer(&self, cam: &Camera, beta: f64) -> Result<Option<MovingObserver>> {
        if !(beta.is_finite() && (0.0..1.0).contains(&beta)) {
            return Err(Error::invalid(format!(
                "doppler: beta {beta} must be in [0, 1)"
            )));
        }
        if beta == 0.0 {
            return Ok(None);
        }
        let v = Velocity::along((cam.target - cam.eye).as_dvec3(), beta)
            .map_err(|e| Error::invalid(format!("doppler: beta {beta}: {e}")))?;
        Ok(Some(MovingObserver {
            velocity: v,
            searchlight: self.session.settings().invariant,
        }))
    }

    fn set_camera_state(&mut self, cam: CameraState) -> Result<()> {
        let old = self.cam;
        self.cam = cam;
        let st = self.session.settings().clone();
        match self.camera(&st) {
            Ok(c) => {
                self.session.set_camera(c)?;
                // The observer keeps flying into the picture.
                if self.beta > 0.0 {
                    let mut st = self.session.settings().clone();
                    st.observer = self.observer(&c, self.beta)?;
                    self.session.set_settings(st)?;
                }
                self.view_current = false;
                Ok(())
            }
            Err(e) => {
                self.cam = old;
                Err(e)
            }
        }
    }

    fn effective_factors(&self) -> Factors {
        Factors {
            velocity: if self.enabled {
                self.factors.velocity
            } else {
                0.0
            },
            ..self.factors
        }
    }

    fn camera_json(&self) -> Value {
        let c = self.session.settings().camera;
        let (projection, fov) = match c.projection {
            blueshift_camera::Projection::Perspective { fov_y_deg } => ("perspective", fov_y_deg),
            blueshift_camera::Projection::Orthographic { .. } => ("orthographic", 0.0),
        };
        let (lo, hi) = self.session.scene().frame_bounds(false);
        json!({
            "type": "camera",
            "eye": c.eye.to_array(), "target": c.target.to_array(), "up": c.up.to_array(),
            "fov": fov, "projection": projection, "zoom": self.cam.zoom.unwrap_or(1.0),
            "view": self.cam.view.map(|v| v.to_string()),
            "bounds": [lo.to_array(), hi.to_array()],
        })
    }

    fn lines(&self) -> Vec<(String, f64)> {
        let mut out = Vec::new();
        for sp in self.session.scene().species() {
            for l in sp.emission_lines.iter().chain(&sp.absorption_lines) {
                let name = format!("{} {:.1}", sp.name, l.centre_nm);
                if !out.iter().any(|(n, _): &(String, f64)| *n == name) {
                    out.push((name, l.centre_nm));
                }
            }
        }
        out.sort_by(|a, b| a.1.total_cmp(&b.1));
        out
    }

    fn doppler_json(&self) -> Value {
        let st = self.session.settings();
        let f = self.factors;
        json!({
            "type": "doppler", "enabled": self.enabled,
            "factors": { "velocity": f.velocity, "temperature": f.temperature,
                         "emission": f.emission, "absorption": f.absorption, "blackbody": f.blackbody },
            "integrator": st.integrator.to_string(),
            "merge_tolerance": st.merge_tolerance,
            "exposure": self.exposure,
            "beta": self.beta,
            "lines": self.lines().iter().map(|(n, l)| json!({"name": n, "rest_nm": l})).collect::<Vec<_>>(),
        })
    }

    fn rgb8(&self, img: &DopplerImage) -> Result<RgbImage> {
        let rgb = self.src.display.with_stops(self.exposure, img).to_rgb8(img);
        RgbImage::from_raw(img.width, img.height, rgb)
            .ok_or_else(|| Error::invalid("display image size"))
    }

    fn send_frame(&self, ctx: &Ctx, img: &DopplerImage, preview: bool, ms: f64) -> Result<()> {
        ctx.send_image(
            "frame",
            &self.rgb8(img)?,
            json!({ "pass": 1, "spp": 1, "preview": preview }),
        )?;
        ctx.send(&json!({
            "type": "status", "pass": 1, "spp": 1, "target_spp": 1, "noise": null, "ms": ms,
            "device": "cpu", "preview": preview, "done": !preview,
            "level": if preview { "preview" } else { "full" },
            "pieces": img.pieces.max,
        }));
        Ok(())
    }

    fn check_pixel(&self, x: u32, y: u32) -> Result<()> {
        let st = self.session.settings();
        if x >= st.width || y >= st.height {
            return Err(Error::invalid(format!(
                "pixel {x},{y} is outside the {}x{} image",
                st.width, st.height
            )));
        }
        Ok(())
    }

    fn spectrum(&mut self, x: u32, y: u32) -> Result<Value> {
        self.check_pixel(x, y)?;
        let on = self.session.pixel_spectrum(x, y)?;
        self.session.set_factors(Factors {
            velocity: 0.0,
            ..self.effective_factors()
        })?;
        let off = self.session.pixel_spectrum(x, y);
        self.session.set_factors(self.effective_factors())?;
        let off = off?;
        let lines = self.lines();
        let centroids: Vec<Value> = lines
            .iter()
            .enumerate()
            .map(|(i, (name, rest))| {
                // The window: up to 10 nm either side, never past half-way to a neighbour.
                let mut half = 10.0f64;
                if i > 0 {
                    half = half.min(0.5 * (rest - lines[i - 1].1));
                }
                if i + 1 < lines.len() {
                    half = half.min(0.5 * (lines[i + 1].1 - rest));
                }
                let half = half.max(0.5);
                json!({ "name": name, "rest_nm": rest,
                        "window_nm": [rest - half, rest + half],
                        "centroid_nm": on.centroid(rest - half, rest + half) })
            })
            .collect();
        let xyz = blueshift_spectrum::Cmf::cie1931_2deg().xyz_of(&on);
        let (w, v) = spectrum_points(&on);
        let (wo, vo) = spectrum_points(&off);
        Ok(json!({
            "type": "spectrum", "x": x, "y": y, "wavelengths": w, "values": v,
            "off": { "wavelengths": wo, "values": vo },
            "lines": centroids, "xyz": [xyz.x, xyz.y, xyz.z],
            "range_nm": [self.session.settings().range_nm.0, self.session.settings().range_nm.1],
        }))
    }

    fn trace(&self, x: u32, y: u32) -> Result<Value> {
        self.check_pixel(x, y)?;
        let steps = self.session.trace(x, y)?;
        let n = steps.len();
        let keep: Vec<usize> = if n <= 24 {
            (0..n).collect()
        } else {
            let mut k: Vec<usize> = (0..24).map(|i| i * (n - 1) / 23).collect();
            k.dedup();
            k
        };
        let out: Vec<Value> = keep
            .iter()
            .map(|&i| {
                let s = &steps[i];
                let (w, v) = spectrum_points(&s.spectrum);
                json!({ "t": s.t, "radial_velocity": s.radial_velocity_m_per_s,
                        "wavelengths": w, "values": v })
            })
            .collect();
        Ok(json!({ "type": "trace", "x": x, "y": y, "total_steps": n, "steps": out }))
    }

    fn apply_doppler(&mut self, m: DopplerMsg) -> Result<Stage> {
        let mut stage = Stage::Full;
        let (old_enabled, old_factors, old_exposure) = (self.enabled, self.factors, self.exposure);
        let old_beta = self.beta;
        let old_settings = self.session.settings().clone();
        let result = (|| -> Result<()> {
            if let Some(e) = m.enabled {
                self.enabled = e;
            }
            if let Some(f) = m.factors {
                let set = |v: Option<f64>, slot: &mut f64, name: &str| -> Result<()> {
                    if let Some(v) = v {
                        if !(v.is_finite() && v >= 0.0) {
                            return Err(Error::invalid(format!(
                                "doppler: factor {name} {v} must be finite and >= 0"
                            )));
                        }
                        *slot = v;
                    }
                    Ok(())
                };
                set(f.velocity, &mut self.factors.velocity, "velocity")?;
                set(f.temperature, &mut self.factors.temperature, "temperature")?;
                set(f.emission, &mut self.factors.emission, "emission")?;
                set(f.absorption, &mut self.factors.absorption, "absorption")?;
                set(f.blackbody, &mut self.factors.blackbody, "blackbody")?;
            }
            if let Some(e) = m.exposure {
                self.exposure = e;
            }
            let mut st = self.session.settings().clone();
            let mut changed = false;
            if let Some(i) = &m.integrator {
                st.integrator = i.parse::<SpectralIntegrator>()?;
                changed = true;
            }
            if let Some(t) = m.merge_tolerance {
                st.merge_tolerance = t;
                changed = true;
            }
            if let Some(b) = m.beta {
                st.observer = self.observer(&st.camera, b)?;
                self.beta = b;
                changed = true;
            }
            if changed {
                self.session.set_settings(st)?;
                self.view_current = false;
                stage = Stage::Preview;
            }
            self.session.set_factors(self.effective_factors())?;
            Ok(())
        })();
        if let Err(e) = result {
            (self.enabled, self.factors, self.exposure) = (old_enabled, old_factors, old_exposure);
            self.beta = old_beta;
            let _ = self.session.set_settings(old_settings);
            let _ = self.session.set_factors(self.effective_factors());
            return Err(e);
        }
        if m.factors.is_none()
            && m.enabled.is_none()
            && m.integrator.is_none()
            && m.merge_tolerance.is_none()
            && m.beta.is_none()
        {
            stage = Stage::Display;
        }
        Ok(stage)
    }

    fn save(&self, ctx: &Ctx, name: Option<&str>) -> Result<Value> {
        let Some(img) = &self.last else {
            return Err(Error::invalid("save: no finished frame yet"));
        };
        let set = SaveSet::new(ctx, name, &[".exr", ".png"], &self.src.inputs)?;
        let exr = set.path(".exr");
        let data: Vec<f32> = img
            .xyz
            .iter()
            .flat_map(|p| [p[0] as f32, p[1] as f32, p[2] as f32, 1.0])
            .collect();
        blueshift_tonemap::io::write_exr_f32_channels(
            &exr,
            img.width,
            img.height,
            4,
            &data,
            blueshift_tonemap::io::ExrSpace::Xyz,
        )?;
        let png = set.path(".png");
        super::write_png(&png, &self.rgb8(img)?)?;
        let files = vec![exr.clone(), png];
        set.commit(&files);
        let st = self.session.settings();
        let f = self.effective_factors();
        let mut args: Vec<String> = vec!["blueshift".into(), "doppler".into()];
        args.extend(self.src.base_args.iter().cloned());
        let mut flag = |k: &str, v: String| {
            args.push(k.into());
            args.push(v);
        };
        flag("--width", st.width.to_string());
        flag("--height", st.height.to_string());
        if let Some(v) = self.cam.view {
            flag("--view", v.to_string());
        }
        for (k, v) in [
            ("--eye", self.cam.eye),
            ("--target", self.cam.target),
            ("--up", self.cam.up),
        ] {
            if let Some(v) = v {
                flag(k, triple(v));
            }
        }
        if let Some(z) = self.cam.zoom {
            flag("--zoom", z.to_string());
        }
        flag("--integrator", st.integrator.to_string());
        flag("--merge-tol", st.merge_tolerance.to_string());
        flag("--velocity-factor", f.velocity.to_string());
        flag("--temperature-factor", f.temperature.to_string());
        flag("--emission-factor", f.emission.to_string());
        flag("--absorption-factor", f.absorption.to_string());
        flag("--blackbody-factor", f.blackbody.to_string());
        if self.beta > 0.0 {
            flag("--beta", self.beta.to_string());
        }
        flag("--out", exr.display().to_string());
        Ok(saved_reply(&files, &command_line(&args), None))
    }
}

/// Cancels a Doppler render between rows.
struct Rows<'a>(&'a Ctx);

impl Observer<DopplerImage> for Rows<'_> {
    fn progress(&self, _: Progress) {}
    fn pass(&self, _: u32, _: &DopplerImage, _: Option<f64>) {}
    fn cancelled(&self) -> bool {
        self.0.cancel.is_cancelled()
    }
}

impl Mode for DopplerMode<'_> {
    fn info(&self) -> Value {
        let st = self.session.settings();
        json!({
            "type": "info", "version": 1, "mode": "doppler",
            "width": st.width, "height": st.height,
            "channels": [],
            "camera": self.camera_json(),
            "settings": { "type": "settings", "width": st.width, "height": st.height, "device": "cpu" },
            "doppler": self.doppler_json(),
            "relativity": null, "tonemap": null,
            "devices": { "cpu": format!("{} threads", rayon::current_num_threads()), "gpu": null },
            "views": View::NAMES,
            "integrators": ["pwl", "banded:64", "banded-ec:64"],
            "panels": self.src.panel.is_some(),
        })
    }

    fn handle(&mut self, msg: Incoming, ctx: &Ctx) -> Result<Option<Stage>> {
        match msg {
            Incoming::Camera(c) => {
                if c.fov.is_some() {
                    return Err(Error::invalid(
                        "camera: the Doppler view is orthographic (a line-of-sight camera); use zoom",
                    ));
                }
                self.set_camera_state(CameraState {
                    eye: Some(c.eye),
                    target: Some(c.target),
                    up: Some(c.up),
                    zoom: c.zoom.or(self.cam.zoom),
                    ..self.cam
                })?;
                ctx.send(&self.camera_json());
                Ok(Some(Stage::Preview))
            }
            Incoming::View(v) => {
                let view = v.name.parse::<View>()?;
                self.set_camera_state(CameraState {
                    view: Some(view),
                    zoom: v.zoom,
                    ..CameraState::default()
                })?;
                ctx.send(&self.camera_json());
                Ok(Some(Stage::Preview))
            }
            Incoming::Settings(s) => {
                let unsupported = [
                    ("method", s.method.is_some()),
                    ("blend", s.blend.is_some()),
                    ("spp", s.spp.is_some()),
                    ("noise_target", s.noise_target.is_some()),
                    ("density_scale", s.density_scale.is_some()),
                    ("light_dir", s.light_dir.is_some()),
                    ("shading", s.shading.is_some()),
                    ("precision", s.precision.is_some()),
                    ("seed", s.seed.is_some()),
                    ("tonemap", s.tonemap.is_some()),
                    ("device", s.device.as_deref().is_some_and(|d| d != "cpu")),
                ];
                if let Some((name, _)) = unsupported.iter().find(|(_, set)| *set) {
                    return Err(Error::invalid(format!(
                        "settings: '{name}' does not apply to a Doppler scene (the viewer renders it on the CPU, deterministically; the Doppler message sets its factors and integrator)"
                    )));
                }
                let mut st = self.session.settings().clone();
                st.width = s.width.unwrap_or(st.width);
                st.height = s.height.unwrap_or(st.height);
                super::check_view_size(st.width, st.height)?;
                st.camera = self.camera(&st)?;
                let resized = (st.width, st.height)
                    != (
                        self.session.settings().width,
                        self.session.settings().height,
                    );
                if resized {
                    self.session.set_settings(st)?;
                }
                if let Some(e) = s.exposure {
                    self.exposure = f64::from(e);
                }
                ctx.send(&self.info());
                if resized {
                    self.view_current = false;
                    Ok(Some(Stage::Preview))
                } else {
                    Ok(Some(Stage::Display))
                }
            }
            Incoming::Doppler(m) => {
                let stage = self.apply_doppler(m)?;
                ctx.send(&self.doppler_json());
                Ok(Some(if self.view_current {
                    stage
                } else {
                    stage.max(Stage::Preview)
                }))
            }
            Incoming::Pick { x, y } => {
                let v = self.spectrum(x, y)?;
                ctx.send(&v);
                Ok(None)
            }
            Incoming::Trace { x, y } => {
                ctx.send(&self.trace(x, y)?);
                Ok(None)
            }
            Incoming::Panels => {
                let Some(panel) = &self.src.panel else {
                    return Err(Error::invalid("panels: not available for this scene"));
                };
                let mut scene = self.session.scene().clone();
                scene.factors = self.effective_factors();
                let (img, meta) = panel(&scene, self.session.settings()).map_err(Error::Invalid)?;
                ctx.send_image("velocity", &img, meta)?;
                Ok(None)
            }
            Incoming::Save { name } => {
                ctx.send(&self.save(ctx, name.as_deref())?);
                Ok(None)
            }
            other => Err(Error::invalid(format!(
                "{}: not available for a Doppler scene",
                other.kind()
            ))),
        }
    }

    fn invalidate(&mut self) {
        self.last = None;
    }

    fn render(&mut self, stage: Stage, ctx: &Ctx) -> Result<()> {
        if stage == Stage::Display {
            if let Some(img) = &self.last {
                self.send_frame(ctx, img, false, 0.0)?;
            }
            return Ok(());
        }
        let full = self.session.settings().clone();
        let previews = if stage == Stage::Preview && !self.view_current {
            preview_sizes(full.width, full.height)
        } else {
            Vec::new()
        };
        for (w, h) in previews {
            let mut p = full.clone();
            p.width = w;
            p.height = h;
            let t = std::time::Instant::now();
            self.session.set_settings(p)?;
            let r = self.session.render(&Rows(ctx));
            self.session.set_settings(full.clone())?;
            let img = r?;
            self.send_frame(ctx, &img, true, t.elapsed().as_secs_f64() * 1e3)?;
        }
        let t = std::time::Instant::now();
        let img = self.session.render(&Rows(ctx))?;
        self.send_frame(ctx, &img, false, t.elapsed().as_secs_f64() * 1e3)?;
        self.last = Some(img);
        self.view_current = true;
        Ok(())
    }
}
