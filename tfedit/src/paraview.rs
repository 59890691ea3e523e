//! ParaView colour-map presets: the JSON written by ParaView's "Save preset" / "Export" and
//! read by "Import" (`vtkSMTransferFunctionProxy::GetStateAsPreset` / `ApplyPreset`).
//!
//! A file is a JSON array of preset objects (a single object is accepted too). A preset has
//! `Name`, `ColorSpace` (`RGB`, `HSV`, `Lab`, `Diverging`, `Step`; `Lab/CIEDE2000`,
//! `CIELAB` and `Prolab` are read as `Lab`), `RGBPoints` (quadruples `x, r, g, b` in data
//! units), optionally `Points` (the opacity curve, quadruples `x, alpha, midpoint,
//! sharpness`), `NanColor` and `UseLogScale`. Categorical presets (`IndexedColors`) are
//! refused.
//!
//! A preset without `Points` gets ParaView's default opacity for a new array: a straight
//! ramp from 0 at the first colour knot to 1 at the last one.

use serde_json::{Map, Value, json};

use crate::color::ColorSpace;
use crate::tf::{ColorKnot, DataAxis, OpacityKnot, TransferFunction};
use crate::{Error, Result};

/// Whether a parsed JSON document looks like a ParaView preset (an array of objects, or an
/// object with `RGBPoints`, `Points`, `IndexedColors` or `ColorSpace`).
#[must_use]
pub fn is_paraview_preset(doc: &Value) -> bool {
    match doc {
        Value::Array(items) => items.first().is_some_and(Value::is_object),
        Value::Object(m) => ["RGBPoints", "Points", "IndexedColors", "ColorSpace"]
            .iter()
            .any(|k| m.contains_key(*k)),
        _ => false,
    }
}

/// Parses ParaView preset JSON text and converts the preset named `name` (the first one if
/// `None`).
pub fn from_paraview_str(text: &str, name: Option<&str>) -> Result<TransferFunction> {
    let doc: Value = serde_json::from_str(text)
        .map_err(|e| Error::invalid(format!("ParaView preset: not valid JSON: {e}")))?;
    from_paraview_value(&doc, name)
}

/// The preset names in a ParaView preset document, in file order.
pub fn paraview_preset_names(doc: &Value) -> Vec<String> {
    presets(doc)
        .iter()
        .map(|p| {
            p.get("Name")
                .and_then(Value::as_str)
                .unwrap_or("")
                .to_string()
        })
        .collect()
}

fn presets(doc: &Value) -> Vec<&Map<String, Value>> {
    match doc {
        Value::Array(items) => items.iter().filter_map(Value::as_object).collect(),
        Value::Object(m) => vec![m],
        _ => Vec::new(),
    }
}

/// Converts a parsed ParaView preset document (see the module docs).
pub fn from_paraview_value(doc: &Value, name: Option<&str>) -> Result<TransferFunction> {
    let list = presets(doc);
    if list.is_empty() {
        return Err(Error::invalid(
            "ParaView preset: expected an array of preset objects or one preset object",
        ));
    }
    let preset = match name {
        None => list[0],
        Some(n) => *list
            .iter()
            .find(|p| p.get("Name").and_then(Value::as_str) == Some(n))
            .ok_or_else(|| {
                Error::invalid(format!(
                    "ParaView preset: no preset named {n:?} (the file has {:?})",
                    paraview_preset_names(doc)
                ))
            })?,
    };
    convert(preset)
}

fn numbers(
    preset: &Map<String, Value>,
    key: &str,
    group: usize,
    pname: &str,
) -> Result<Option<Vec<f64>>> {
    let Some(v) = preset.get(key) else {
        return Ok(None);
    };
    let arr = v.as_array().ok_or_else(|| {
        Error::invalid(format!("ParaView preset {pname:?}: {key} is not an array"))
    })?;
    if arr.len() % group != 0 {
        return Err(Error::invalid(format!(
            "ParaView preset {pname:?}: {key} has {} numbers, not a multiple of {group}",
            arr.len()
        )));
    }
    let mut out = Vec::with_capacity(arr.len());
    for (i, x) in arr.iter().enumerate() {
        let f = x.as_f64().ok_or_else(|| {
            Error::invalid(format!(
                "ParaView preset {pname:?}: {key} entry {i} ({x}) is not a number"
            ))
        })?;
        out.push(f);
    }
    Ok(Some(out))
}

fn parse_space(s: &str, pname: &str) -> Result<ColorSpace> {
    Ok(match s {
        "RGB" => ColorSpace::Rgb,
        "HSV" => ColorSpace::Hsv,
        "Lab" | "CIELAB" | "Lab/CIEDE2000" | "Prolab" => ColorSpace::Lab,
        "Diverging" => ColorSpace::Diverging,
        "Step" => ColorSpace::Step,
        other => {
            return Err(Error::invalid(format!(
                "ParaView preset {pname:?}: unknown ColorSpace {other:?} (expected RGB, HSV, Lab, Diverging or Step)"
            )));
        }
    })
}

fn space_name(s: ColorSpace) -> &'static str {
    match s {
        ColorSpace::Rgb => "RGB",
        ColorSpace::Hsv => "HSV",
        ColorSpace::Lab => "Lab",
        ColorSpace::Diverging => "Diverging",
        ColorSpace::Step => "Step",
    }
}

fn sort_points(points: &mut [(f64, usize)]) {
    // ParaView sorts control points by x when it loads them; keep file order for ties.
    points.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
}

fn convert(preset: &Map<String, Value>) -> Result<TransferFunction> {
    let pname = preset
        .get("Name")
        .and_then(Value::as_str)
        .unwrap_or("")
        .to_string();
    if preset.contains_key("IndexedColors") && !preset.contains_key("RGBPoints") {
        return Err(Error::Unsupported(format!(
            "ParaView preset {pname:?} is categorical (IndexedColors); only continuous maps (RGBPoints) are supported"
        )));
    }
    let rgb = numbers(preset, "RGBPoints", 4, &pname)?.ok_or_else(|| {
        Error::invalid(format!("ParaView preset {pname:?}: RGBPoints is missing"))
    })?;
    if rgb.is_empty() {
        return Err(Error::invalid(format!(
            "ParaView preset {pname:?}: RGBPoints is empty"
        )));
    }
    let pts = numbers(preset, "Points", 4, &pname)?;
    let space = match preset.get("ColorSpace") {
        None => ColorSpace::Rgb,
        Some(Value::String(s)) => parse_space(s, &pname)?,
        Some(other) => {
            return Err(Error::invalid(format!(
                "ParaView preset {pname:?}: ColorSpace {other} is not a string"
            )));
        }
    };
    let log = match preset.get("UseLogScale") {
        None => false,
        Some(v) => v
            .as_bool()
            .or_else(|| v.as_f64().map(|f| f != 0.0))
            .ok_or_else(|| {
                Error::invalid(format!(
                    "ParaView preset {pname:?}: UseLogScale {v} is not a boolean"
                ))
            })?,
    };

    let mut order: Vec<(f64, usize)> = rgb
        .chunks_exact(4)
        .enumerate()
        .map(|(i, c)| (c[0], i))
        .collect();
    for (x, i) in &order {
        if !x.is_finite() {
            return Err(Error::invalid(format!(
                "ParaView preset {pname:?}: RGBPoints point {i} has position {x}"
            )));
        }
    }
    sort_points(&mut order);
    let mut color = Vec::with_capacity(order.len());
    for &(x, i) in &order {
        let c = &rgb[i * 4..i * 4 + 4];
        let mut k = [0f32; 3];
        for j in 0..3 {
            let v = c[j + 1];
            if !(0.0..=1.0).contains(&v) {
                return Err(Error::invalid(format!(
                    "ParaView preset {pname:?}: RGBPoints point {i} (x = {x}): component {j} is {v}, outside [0, 1]"
                )));
            }
            k[j] = v as f32;
        }
        color.push(ColorKnot { x, rgb: k });
    }
    let mut lo = color[0].x;
    let mut hi = color[color.len() - 1].x;

    let opacity = match pts {
        Some(p) if !p.is_empty() => {
            let mut order: Vec<(f64, usize)> = p
                .chunks_exact(4)
                .enumerate()
                .map(|(i, c)| (c[0], i))
                .collect();
            for (x, i) in &order {
                if !x.is_finite() {
                    return Err(Error::invalid(format!(
                        "ParaView preset {pname:?}: Points point {i} has position {x}"
                    )));
                }
            }
            sort_points(&mut order);
            let mut out = Vec::with_capacity(order.len());
            for &(x, i) in &order {
                let c = &p[i * 4..i * 4 + 4];
                for (what, v) in [("opacity", c[1]), ("midpoint", c[2]), ("sharpness", c[3])] {
                    if !(0.0..=1.0).contains(&v) {
                        return Err(Error::invalid(format!(
                            "ParaView preset {pname:?}: Points point {i} (x = {x}): {what} {v} is outside [0, 1]"
                        )));
                    }
                }
                out.push(OpacityKnot {
                    x,
                    alpha: c[1] as f32,
                    midpoint: c[2] as f32,
                    sharpness: c[3] as f32,
                });
            }
            lo = lo.min(out[0].x);
            hi = hi.max(out[out.len() - 1].x);
            out
        }
        _ => vec![OpacityKnot::new(lo, 0.0), OpacityKnot::new(hi, 1.0)],
    };
    if lo >= hi {
        return Err(Error::invalid(format!(
            "ParaView preset {pname:?}: all points sit at x = {lo}; a transfer function needs a range"
        )));
    }
    let mut tf = TransferFunction::new([lo, hi], color, opacity)
        .map_err(|e| Error::invalid(format!("ParaView preset {pname:?}: {e}")))?
        .with_color_space(space)
        .with_name(pname.clone());
    if log {
        tf = tf
            .with_data_axis(DataAxis::Log)
            .map_err(|e| Error::invalid(format!("ParaView preset {pname:?}: {e}")))?;
    }
    if let Some(nan) = numbers(preset, "NanColor", 3, &pname)? {
        if nan.len() != 3 {
            return Err(Error::invalid(format!(
                "ParaView preset {pname:?}: NanColor has {} numbers, not 3 (red, green, blue)",
                nan.len()
            )));
        }
        let c = [nan[0] as f32, nan[1] as f32, nan[2] as f32];
        tf = tf
            .with_nan_color(c)
            .map_err(|e| Error::invalid(format!("ParaView preset {pname:?}: {e}")))?;
    }
    if let Some(v) = preset.get(ALPHA_G_KEY) {
        let a = v.as_f64().ok_or_else(|| {
            Error::invalid(format!(
                "ParaView preset {pname:?}: {ALPHA_G_KEY} {v} is not a number"
            ))
        })?;
        tf = tf
            .with_alpha_g(a as f32)
            .map_err(|e| Error::invalid(format!("ParaView preset {pname:?}: {e}")))?;
    }
    Ok(tf)
}

/// The extra member blueshift writes for alpha_g when it is not 1 (ParaView ignores
/// members it does not know).
pub const ALPHA_G_KEY: &str = "BlueshiftGlobalOpacity";

/// Converts a transfer function to a ParaView preset object (`Name`, `ColorSpace`,
/// `NanColor`, `RGBPoints`, `Points`, and `UseLogScale` for a log axis).
#[must_use]
pub fn to_paraview_value(tf: &TransferFunction) -> Value {
    let mut rgb = Vec::with_capacity(tf.color_knots().len() * 4);
    for k in tf.color_knots() {
        rgb.push(json!(k.x));
        rgb.extend(k.rgb.iter().map(|&c| json!(f64::from(c))));
    }
    let mut pts = Vec::with_capacity(tf.opacity_knots().len() * 4);
    for k in tf.opacity_knots() {
        pts.extend([
            json!(k.x),
            json!(f64::from(k.alpha)),
            json!(f64::from(k.midpoint)),
            json!(f64::from(k.sharpness)),
        ]);
    }
    let mut m = Map::new();
    m.insert("Name".into(), json!(tf.name()));
    m.insert("ColorSpace".into(), json!(space_name(tf.color_space())));
    m.insert("NanColor".into(), json!(tf.nan_color().map(f64::from)));
    m.insert("RGBPoints".into(), Value::Array(rgb));
    m.insert("Points".into(), Value::Array(pts));
    if tf.data_axis() == DataAxis::Log {
        m.insert("UseLogScale".into(), json!(true));
    }
    if tf.alpha_g() != 1.0 {
        m.insert(ALPHA_G_KEY.into(), json!(f64::from(tf.alpha_g())));
    }
    Value::Object(m)
}

/// A ParaView preset file's text for one transfer function: a one-element array, like
/// ParaView's export.
#[must_use]
pub fn to_paraview_string(tf: &TransferFunction) -> String {
    let doc = Value::Array(vec![to_paraview_value(tf)]);
    let mut s = serde_json::to_string_pretty(&doc).unwrap_or_default();
    s.push('\n');
    s
}
