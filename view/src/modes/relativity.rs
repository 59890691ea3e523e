//! The relativistic observer over a [`RelativitySession`]: speed, direction of motion,
//! where the observer looks, and the effect toggles.

use std::path::PathBuf;

use blueshift_camera::{Observer, Progress};
use blueshift_relativity::{Camera, Effects, Environment, RelativitySession, Velocity};
use glam::DVec3;
use image::Rgb32FImage;
use serde_json::{Value, json};

use super::{Mode, SaveSet, command_line, preview_sizes, saved_reply};
use crate::protocol::Incoming;
use crate::worker::{Ctx, Stage};
use crate::{Error, Result};

/// An environment for the viewer's relativistic observer.
#[derive(Debug)]
pub struct RelativitySource {
    /// The environment (map or checkerboard).
    pub env: Environment,
    /// The `blueshift relativity` arguments that load it (`ENV` or `--synth checker`).
    pub base_args: Vec<String>,
    /// The files named on the command line (never written by a save).
    pub inputs: Vec<PathBuf>,
    /// Image width and height, pixels.
    pub size: (u32, u32),
    /// Speed in units of c, in [0, 1).
    pub beta: f64,
    /// Vertical field of view, degrees.
    pub fov: f64,
}

pub(crate) struct RelativityMode<'a> {
    src: &'a RelativitySource,
    beta: f64,
    direction: DVec3,
    effects: Effects,
    yaw: f64,
    pitch: f64,
    fov: f64,
    exposure: f64,
    session: RelativitySession,
    last: Option<Rgb32FImage>,
}

/// The viewing direction of yaw and pitch (degrees): yaw 0 pitch 0 looks along -z, yaw
/// turns towards +x, pitch towards +y (the environment's up).
fn look(yaw: f64, pitch: f64) -> DVec3 {
    let (y, p) = (yaw.to_radians(), pitch.to_radians());
    DVec3::new(y.sin() * p.cos(), p.sin(), -y.cos() * p.cos())
}

impl<'a> RelativityMode<'a> {
    pub(crate) fn new(src: &'a RelativitySource) -> Result<Self> {
        let direction = DVec3::NEG_Z;
        let cam = Self::make_camera(0.0, 0.0, src.fov, src.size);
        let v = Velocity::along(direction, src.beta)?;
        let session = RelativitySession::new(src.env.clone(), cam, v, Effects::ALL)?;
        Ok(Self {
            src,
            beta: src.beta,
            direction,
            effects: Effects::ALL,
            yaw: 0.0,
            pitch: 0.0,
            fov: src.fov,
            exposure: 0.0,
            session,
            last: None,
        })
    }

    fn make_camera(yaw: f64, pitch: f64, fov: f64, (width, height): (u32, u32)) -> Camera {
        Camera {
            look: look(yaw, pitch),
            up: DVec3::Y,
            fov_y_deg: fov,
            width,
            height,
        }
    }

    fn state(&self) -> Value {
        json!({
            "type": "relativity", "beta": self.beta, "direction": self.direction.to_array(),
            "effects": { "aberration": self.effects.aberration, "doppler": self.effects.doppler,
                         "searchlight": self.effects.searchlight },
            "yaw": self.yaw, "pitch": self.pitch, "fov": self.fov, "exposure": self.exposure,
        })
    }

    fn effects_list(&self) -> String {
        let mut v = Vec::new();
        if self.effects.aberration {
            v.push("aberration");
        }
        if self.effects.doppler {
            v.push("doppler");
        }
        if self.effects.searchlight {
            v.push("searchlight");
        }
        if v.is_empty() {
            "none".into()
        } else {
            v.join(",")
        }
    }

    fn send_frame(&self, ctx: &Ctx, img: &Rgb32FImage, preview: bool, ms: f64) -> Result<()> {
        let rgb = blueshift_relativity::to_srgb8(img, self.exposure);
        ctx.send_image(
            "frame",
            &rgb,
            json!({ "pass": 1, "spp": 1, "preview": preview }),
        )?;
        ctx.send(&json!({
            "type": "status", "pass": 1, "spp": 1, "target_spp": 1, "noise": null, "ms": ms,
            "device": "cpu", "preview": preview, "done": !preview,
            "level": if preview { "preview" } else { "full" },
        }));
        Ok(())
    }

    fn save(&self, ctx: &Ctx, name: Option<&str>) -> Result<Value> {
        let Some(img) = &self.last else {
            return Err(Error::invalid("save: no finished frame yet"));
        };
        let set = SaveSet::new(ctx, name, &[".exr", ".png"], &self.src.inputs)?;
        let exr = set.path(".exr");
        blueshift_tonemap::io::write_exr_f32_channels(
            &exr,
            img.width(),
            img.height(),
            3,
            img.as_raw(),
            blueshift_tonemap::io::ExrSpace::LinearSrgb,
        )?;
        let png = set.path(".png");
        super::write_png(&png, &blueshift_relativity::to_srgb8(img, self.exposure))?;
        let files = vec![exr.clone(), png];
        set.commit(&files);
        let c = self.session.camera();
        let v3 = |v: DVec3| format!("{},{},{}", v.x, v.y, v.z);
        let mut args: Vec<String> = vec!["blueshift".into(), "relativity".into()];
        args.extend(self.src.base_args.iter().cloned());
        for (k, v) in [
            ("--beta", self.beta.to_string()),
            ("--direction", v3(self.direction)),
            ("--look", v3(c.look)),
            ("--up", v3(c.up)),
            ("--fov", c.fov_y_deg.to_string()),
            ("--width", c.width.to_string()),
            ("--height", c.height.to_string()),
            ("--effects", self.effects_list()),
            ("--out", exr.display().to_string()),
        ] {
            args.push(k.into());
            args.push(v);
        }
        Ok(saved_reply(&files, &command_line(&args), None))
    }
}

struct Cancel<'a>(&'a Ctx);

impl Observer<Rgb32FImage> for Cancel<'_> {
    fn progress(&self, _: Progress) {}
    fn pass(&self, _: u32, _: &Rgb32FImage, _: Option<f64>) {}
    fn cancelled(&self) -> bool {
        self.0.cancel.is_cancelled()
    }
}

impl Mode for RelativityMode<'_> {
    fn info(&self) -> Value {
        let (w, h) = self.src.size;
        json!({
            "type": "info", "version": 1, "mode": "relativity", "width": w, "height": h,
            "channels": [], "camera": null,
            "settings": { "type": "settings", "width": w, "height": h, "device": "cpu" },
            "doppler": null, "relativity": self.state(), "tonemap": null,
            "devices": { "cpu": format!("{} threads", rayon::current_num_threads()), "gpu": null },
            "views": [],
        })
    }

    fn handle(&mut self, msg: Incoming, ctx: &Ctx) -> Result<Option<Stage>> {
        match msg {
            Incoming::Relativity(m) => {
                let beta = m.beta.unwrap_or(self.beta);
                let direction = m.direction.map_or(self.direction, DVec3::from_array);
                let v = Velocity::along(direction, beta)?;
                let (yaw, pitch, fov) = (
                    m.yaw.unwrap_or(self.yaw),
                    m.pitch.unwrap_or(self.pitch).clamp(-89.0, 89.0),
                    m.fov.unwrap_or(self.fov),
                );
                let cam = Self::make_camera(yaw, pitch, fov, self.src.size);
                self.session.set_camera(cam)?;
                self.session.set_velocity(v);
                let mut fx = self.effects;
                if let Some(e) = m.effects {
                    fx.aberration = e.aberration.unwrap_or(fx.aberration);
                    fx.doppler = e.doppler.unwrap_or(fx.doppler);
                    fx.searchlight = e.searchlight.unwrap_or(fx.searchlight);
                }
                self.session.set_effects(fx);
                self.effects = fx;
                (self.beta, self.direction, self.yaw, self.pitch, self.fov) =
                    (beta, direction.normalize(), yaw, pitch, fov);
                if let Some(e) = m.exposure {
                    self.exposure = e;
                }
                ctx.send(&self.state());
                Ok(Some(Stage::Preview))
            }
            Incoming::Save { name } => {
                ctx.send(&self.save(ctx, name.as_deref())?);
                Ok(None)
            }
            other => Err(Error::invalid(format!(
                "{}: not available in relativity mode",
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
        let full = self.session.camera().clone();
        let previews = if stage == Stage::Preview {
            preview_sizes(full.width, full.height)
        } else {
            Vec::new()
        };
        for (w, h) in previews {
            self.session.set_camera(Camera {
                width: w,
                height: h,
                ..full.clone()
            })?;
            let t = std::time::Instant::now();
            let r = self.session.render(&Cancel(ctx));
            self.session.set_camera(full.clone())?;
            self.send_frame(ctx, &r?, true, t.elapsed().as_secs_f64() * 1e3)?;
        }
        let t = std::time::Instant::now();
        let img = self.session.render(&Cancel(ctx))?;
        self.send_frame(ctx, &img, false, t.elapsed().as_secs_f64() * 1e3)?;
        self.last = Some(img);
        Ok(())
    }
}
