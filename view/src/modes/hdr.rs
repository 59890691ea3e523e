//! HDR images over a [`TonemapSession`]: the operators with their parameters, exposure,
//! the pseudocolour view with its colour bar, and Drago's region of interest.

use std::path::PathBuf;

use blueshift_tonemap::{Operator, PseudocolourParams, Roi, TonemapSession};
use image::Rgb32FImage;
use serde_json::{Map, Value, json};

use super::{Mode, SaveSet, command_line, saved_reply};
use crate::display::encode_srgb8;
use crate::protocol::{Incoming, TonemapMsg};
use crate::worker::{Ctx, Stage};
use crate::{Error, Result};

/// An HDR image for the viewer.
#[derive(Debug)]
pub struct HdrSource {
    /// The image (linear RGB).
    pub image: Rgb32FImage,
    /// The file it came from.
    pub path: PathBuf,
}

/// The operators by the names `blueshift tonemap --op` takes, with the serde tag of each.
const OPERATORS: &[(&str, &str)] = &[
    ("linear", "Linear"),
    ("drago", "Drago"),
    ("reinhard", "Reinhard"),
    ("reinhard-local", "ReinhardLocal"),
    ("durand", "Durand"),
    ("fattal", "Fattal"),
];

fn defaults(tag: &str) -> Value {
    use blueshift_tonemap::*;
    let op = match tag {
        "Linear" => Operator::Linear(LinearParams::default()),
        "Drago" => Operator::Drago(DragoParams::default()),
        "Reinhard" => Operator::Reinhard(ReinhardParams::default()),
        "ReinhardLocal" => Operator::ReinhardLocal(ReinhardLocalParams::default()),
        "Durand" => Operator::Durand(DurandParams::default()),
        _ => Operator::Fattal(FattalParams::default()),
    };
    serde_json::to_value(op)
        .ok()
        .and_then(|v| v.get(tag).cloned())
        .unwrap_or(Value::Null)
}

pub(crate) struct HdrMode<'a> {
    src: &'a HdrSource,
    session: TonemapSession,
    name: String,
    params: Map<String, Value>,
    pseudocolour: bool,
    last: Option<image::RgbImage>,
}

impl<'a> HdrMode<'a> {
    pub(crate) fn new(src: &'a HdrSource) -> Result<Self> {
        let session = TonemapSession::new(src.image.clone(), Operator::default())?;
        let params = defaults("Drago").as_object().cloned().unwrap_or_default();
        Ok(Self {
            src,
            session,
            name: "drago".into(),
            params,
            pseudocolour: false,
            last: None,
        })
    }

    fn tag(name: &str) -> Result<&'static str> {
        OPERATORS
            .iter()
            .find(|(n, _)| *n == name)
            .map(|(_, t)| *t)
            .ok_or_else(|| {
                let names: Vec<&str> = OPERATORS.iter().map(|(n, _)| *n).collect();
                Error::invalid(format!(
                    "tonemap: operator '{name}' (one of {})",
                    names.join(", ")
                ))
            })
    }

    fn state(&self) -> Value {
        let all: Map<String, Value> = OPERATORS
            .iter()
            .map(|(n, t)| ((*n).to_string(), defaults(t)))
            .collect();
        json!({
            "type": "tonemap", "operator": self.name, "params": self.params,
            "pseudocolour": self.pseudocolour, "defaults": all,
        })
    }

    fn apply(&mut self, m: TonemapMsg) -> Result<()> {
        let name = m.operator.clone().unwrap_or_else(|| self.name.clone());
        let tag = Self::tag(&name)?;
        let mut params = if name == self.name {
            self.params.clone()
        } else {
            defaults(tag).as_object().cloned().unwrap_or_default()
        };
        if let Some(p) = m.params {
            for (k, v) in p {
                if !params.contains_key(&k) {
                    return Err(Error::invalid(format!(
                        "tonemap: {name} has no parameter '{k}'"
                    )));
                }
                // Only what `blueshift tonemap` can be told, so "save" prints a command
                // that makes the same picture.
                if k != "roi" && cli_flag(&k).is_none() && params.get(&k) != Some(&v) {
                    return Err(Error::invalid(format!(
                        "tonemap: {name}'s '{k}' keeps its default here (blueshift tonemap has no flag for it)"
                    )));
                }
                params.insert(k, v);
            }
        }
        if let Some(e) = m.exposure
            && params.contains_key("exposure_stops")
        {
            params.insert("exposure_stops".into(), json!(e));
        }
        if let Some(roi) = m.roi {
            if tag != "Drago" {
                return Err(Error::invalid("tonemap: a region of interest is Drago's"));
            }
            let roi = roi.map(|r| {
                let (x0, y0, x1, y1) = (r[0] as f32, r[1] as f32, r[2] as f32, r[3] as f32);
                Roi {
                    x_px: 0.5 * (x0 + x1),
                    y_px: 0.5 * (y0 + y1),
                    radius_px: (0.5 * (x1 - x0).abs().min((y1 - y0).abs())).max(1.0),
                }
            });
            params.insert(
                "roi".into(),
                serde_json::to_value(roi).unwrap_or(Value::Null),
            );
        }
        let op: Operator = serde_json::from_value(json!({ tag: Value::Object(params.clone()) }))
            .map_err(|e| Error::invalid(format!("tonemap: {name}: {e}")))?;
        self.session.set_operator(op)?;
        self.name = name;
        self.params = params;
        if let Some(p) = m.pseudocolour {
            self.pseudocolour = p;
        }
        Ok(())
    }

    fn command(&self, out: &std::path::Path) -> String {
        let mut args: Vec<String> = vec![
            "blueshift".into(),
            "tonemap".into(),
            self.src.path.display().to_string(),
            "--op".into(),
            self.name.clone(),
        ];
        for (k, v) in &self.params {
            if k == "roi" {
                if let Ok(Some(r)) = serde_json::from_value::<Option<Roi>>(v.clone()) {
                    args.push("--roi".into());
                    args.push(format!("{},{},{}", r.x_px, r.y_px, r.radius_px));
                }
                continue;
            }
            if let (Some(f), Some(n)) = (cli_flag(k), v.as_f64()) {
                args.push(f.into());
                args.push(n.to_string());
            }
        }
        if self.pseudocolour {
            args.push("--pseudocolor".into());
        }
        args.push("--out".into());
        args.push(out.display().to_string());
        command_line(&args)
    }
}

/// The `blueshift tonemap` flag of an operator parameter (serde name).
fn cli_flag(k: &str) -> Option<&'static str> {
    Some(match k {
        "bias" => "--bias",
        "max_display_luminance" => "--ld-max",
        "exposure_stops" => "--exposure",
        "key" => "--key",
        "white" => "--white",
        "phi" => "--phi",
        "epsilon" => "--epsilon",
        "scales" => "--scales",
        "sigma_spatial_px" => "--sigma-s",
        "sigma_range" => "--sigma-r",
        "base_contrast" => "--contrast",
        "alpha_ratio" => "--alpha",
        "beta" => "--beta",
        "saturation" => "--saturation",
        _ => return None,
    })
}

impl Mode for HdrMode<'_> {
    fn info(&self) -> Value {
        let img = &self.src.image;
        json!({
            "type": "info", "version": 1, "mode": "hdr",
            "width": img.width(), "height": img.height(),
            "channels": [], "camera": null,
            "settings": { "type": "settings", "width": img.width(), "height": img.height(), "device": "cpu" },
            "doppler": null, "relativity": null, "tonemap": self.state(),
            "devices": { "cpu": format!("{} threads", rayon::current_num_threads()), "gpu": null },
            "views": [],
        })
    }

    fn handle(&mut self, msg: Incoming, ctx: &Ctx) -> Result<Option<Stage>> {
        match msg {
            Incoming::Tonemap(m) => {
                self.apply(m)?;
                ctx.send(&self.state());
                Ok(Some(Stage::Full))
            }
            Incoming::Save { name } => {
                let Some(img) = &self.last else {
                    return Err(Error::invalid("save: no finished frame yet"));
                };
                let set = SaveSet::new(
                    ctx,
                    name.as_deref(),
                    &[".png"],
                    std::slice::from_ref(&self.src.path),
                )?;
                let png = set.path(".png");
                super::write_png(&png, img)?;
                set.commit(std::slice::from_ref(&png));
                let cmd = self.command(&png);
                ctx.send(&saved_reply(&[png], &cmd, None));
                Ok(None)
            }
            other => Err(Error::invalid(format!(
                "{}: not available for an HDR image",
                other.kind()
            ))),
        }
    }

    fn invalidate(&mut self) {
        self.last = None;
    }

    fn render(&mut self, _stage: Stage, ctx: &Ctx) -> Result<()> {
        let t = std::time::Instant::now();
        let rgb = if self.pseudocolour {
            blueshift_tonemap::pseudocolour(&self.src.image, &PseudocolourParams::default())?
        } else {
            let display = self.session.run()?;
            image::RgbImage::from_fn(display.width(), display.height(), |x, y| {
                image::Rgb(display.get_pixel(x, y).0.map(encode_srgb8))
            })
        };
        ctx.send_image(
            "frame",
            &rgb,
            json!({ "pass": 1, "spp": 1, "preview": false }),
        )?;
        ctx.send(&json!({
            "type": "status", "pass": 1, "spp": 1, "target_spp": 1, "noise": null,
            "ms": t.elapsed().as_secs_f64() * 1e3, "device": "cpu", "preview": false,
            "done": true, "level": "full",
        }));
        self.last = Some(rgb);
        Ok(())
    }
}
