//! The messages of `view/PROTOCOL.md`: parsing and validating what the page sends, and the
//! JSON and binary frames the server sends back.

use serde::Deserialize;
use serde_json::{Value, json};

use crate::{Error, MAX_MESSAGE_BYTES, Result};

/// A camera edit.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct CameraMsg {
    pub eye: [f32; 3],
    pub target: [f32; 3],
    pub up: [f32; 3],
    pub fov: Option<f32>,
    pub zoom: Option<f32>,
}

/// A view preset.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct ViewMsg {
    pub name: String,
    pub zoom: Option<f32>,
}

/// Render settings; every field optional.
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct SettingsMsg {
    pub method: Option<String>,
    pub blend: Option<String>,
    pub spp: Option<u32>,
    #[serde(default, deserialize_with = "nullable")]
    pub noise_target: Option<Option<f64>>,
    pub density_scale: Option<f32>,
    #[serde(default, deserialize_with = "nullable")]
    pub light_dir: Option<Option<[f32; 3]>>,
    pub shading: Option<bool>,
    pub precision: Option<String>,
    pub device: Option<String>,
    pub width: Option<u32>,
    pub height: Option<u32>,
    pub seed: Option<u64>,
    pub exposure: Option<f32>,
    pub tonemap: Option<String>,
    /// The observer's speed (units of c) flying into the picture along the view direction.
    pub beta: Option<f64>,
}

impl SettingsMsg {
    /// Whether only the display mapping changes.
    pub(crate) fn display_only(&self) -> bool {
        let display = SettingsMsg {
            exposure: self.exposure,
            tonemap: self.tonemap.clone(),
            ..SettingsMsg::default()
        };
        format!("{self:?}") == format!("{display:?}")
    }
}

/// Table 1's factors.
#[derive(Clone, Copy, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct FactorsMsg {
    pub velocity: Option<f64>,
    pub temperature: Option<f64>,
    pub emission: Option<f64>,
    pub absorption: Option<f64>,
    pub blackbody: Option<f64>,
}

/// Doppler settings.
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct DopplerMsg {
    pub enabled: Option<bool>,
    pub factors: Option<FactorsMsg>,
    pub integrator: Option<String>,
    pub merge_tolerance: Option<f64>,
    pub exposure: Option<f64>,
    /// The observer's speed (units of c) flying into the picture, along the view direction.
    pub beta: Option<f64>,
}

/// The relativistic observer.
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RelativityMsg {
    pub beta: Option<f64>,
    pub direction: Option<[f64; 3]>,
    pub effects: Option<EffectsMsg>,
    pub yaw: Option<f64>,
    pub pitch: Option<f64>,
    pub fov: Option<f64>,
    pub exposure: Option<f64>,
}

/// Relativistic effect toggles.
#[derive(Clone, Copy, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct EffectsMsg {
    pub aberration: Option<bool>,
    pub doppler: Option<bool>,
    pub searchlight: Option<bool>,
}

/// HDR image mode.
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct TonemapMsg {
    pub operator: Option<String>,
    pub params: Option<serde_json::Map<String, Value>>,
    pub exposure: Option<f32>,
    pub pseudocolour: Option<bool>,
    #[serde(default, deserialize_with = "nullable")]
    pub roi: Option<Option<[f64; 4]>>,
}

/// `--tf-range` from the page.
#[derive(Clone, Debug)]
pub(crate) enum RangeMsg {
    Data,
    Interval(f64, f64),
}

/// One message from the page.
#[derive(Clone, Debug)]
pub(crate) enum Incoming {
    Hello,
    Camera(CameraMsg),
    View(ViewMsg),
    Tf {
        channel: usize,
        tf: Value,
    },
    TfLoad {
        channel: usize,
        text: String,
    },
    TfExport {
        channel: usize,
        paraview: bool,
    },
    TfRange {
        channel: Option<usize>,
        range: RangeMsg,
    },
    Settings(SettingsMsg),
    Doppler(DopplerMsg),
    Pick {
        x: u32,
        y: u32,
    },
    Trace {
        x: u32,
        y: u32,
    },
    Panels,
    Relativity(RelativityMsg),
    Tonemap(TonemapMsg),
    Save {
        name: Option<String>,
    },
    Cancel,
}

impl Incoming {
    /// The message's `type`, for replies.
    pub(crate) fn kind(&self) -> &'static str {
        match self {
            Incoming::Hello => "hello",
            Incoming::Camera(_) => "camera",
            Incoming::View(_) => "view",
            Incoming::Tf { .. } => "tf",
            Incoming::TfLoad { .. } => "tf_load",
            Incoming::TfExport { .. } => "tf_export",
            Incoming::TfRange { .. } => "tf_range",
            Incoming::Settings(_) => "settings",
            Incoming::Doppler(_) => "doppler",
            Incoming::Pick { .. } => "pick",
            Incoming::Trace { .. } => "trace",
            Incoming::Panels => "panels",
            Incoming::Relativity(_) => "relativity",
            Incoming::Tonemap(_) => "tonemap",
            Incoming::Save { .. } => "save",
            Incoming::Cancel => "cancel",
        }
    }

    /// Whether the message changes the picture (and so cancels the running render). A
    /// settings message that changes only the display mapping (exposure, tone map) is not
    /// an edit: the last HDR frame is mapped again.
    pub(crate) fn is_edit(&self) -> bool {
        if let Incoming::Settings(s) = self {
            return !s.display_only();
        }
        matches!(
            self,
            Incoming::Camera(_)
                | Incoming::View(_)
                | Incoming::Tf { .. }
                | Incoming::TfLoad { .. }
                | Incoming::TfRange { .. }
                | Incoming::Settings(_)
                | Incoming::Doppler(_)
                | Incoming::Relativity(_)
                | Incoming::Tonemap(_)
                | Incoming::Cancel
        )
    }
}

fn nullable<'de, D, T>(d: D) -> std::result::Result<Option<Option<T>>, D::Error>
where
    D: serde::Deserializer<'de>,
    T: Deserialize<'de>,
{
    Option::<T>::deserialize(d).map(Some)
}

fn fields<T: for<'de> Deserialize<'de>>(
    kind: &str,
    obj: serde_json::Map<String, Value>,
) -> Result<T> {
    serde_json::from_value(Value::Object(obj)).map_err(|e| Error::invalid(format!("{kind}: {e}")))
}

fn take_usize(obj: &mut serde_json::Map<String, Value>, kind: &str, key: &str) -> Result<usize> {
    obj.remove(key)
        .and_then(|v| v.as_u64())
        .and_then(|v| usize::try_from(v).ok())
        .ok_or_else(|| Error::invalid(format!("{kind}: '{key}' must be a non-negative integer")))
}

fn take_u32(obj: &mut serde_json::Map<String, Value>, kind: &str, key: &str) -> Result<u32> {
    obj.remove(key)
        .and_then(|v| v.as_u64())
        .and_then(|v| u32::try_from(v).ok())
        .ok_or_else(|| {
            Error::invalid(format!(
                "{kind}: '{key}' must be a pixel index (integer >= 0)"
            ))
        })
}

fn no_more(kind: &str, obj: &serde_json::Map<String, Value>) -> Result<()> {
    match obj.keys().next() {
        Some(k) => Err(Error::invalid(format!("{kind}: unknown field '{k}'"))),
        None => Ok(()),
    }
}

/// Numbers that fit f64 can still overflow f32 (1e39 becomes infinity).
fn finite_f32<'a>(kind: &str, mut v: impl Iterator<Item = &'a f32>) -> Result<()> {
    if v.all(|x| x.is_finite()) {
        Ok(())
    } else {
        Err(Error::invalid(format!(
            "{kind}: a number is too large (beyond single precision)"
        )))
    }
}

/// Parses one text message.
///
/// # Errors
/// [`Error::Invalid`] naming what is wrong: too long, not JSON (serde_json also refuses
/// numbers beyond f64), not an object, an unknown type or field, a wrong value type, a
/// number beyond f32 where the engines take f32.
pub(crate) fn parse(text: &str) -> Result<Incoming> {
    if text.len() > MAX_MESSAGE_BYTES {
        return Err(Error::invalid(format!(
            "message of {} bytes is over the {MAX_MESSAGE_BYTES}-byte limit",
            text.len()
        )));
    }
    let v: Value =
        serde_json::from_str(text).map_err(|e| Error::invalid(format!("not JSON: {e}")))?;
    let Value::Object(mut obj) = v else {
        return Err(Error::invalid(
            "a message must be a JSON object with a \"type\"",
        ));
    };
    let kind = match obj.remove("type") {
        Some(Value::String(s)) => s,
        _ => return Err(Error::invalid("a message needs a string \"type\"")),
    };
    let k = kind.as_str();
    Ok(match k {
        "hello" | "panels" | "cancel" => {
            no_more(k, &obj)?;
            match k {
                "hello" => Incoming::Hello,
                "panels" => Incoming::Panels,
                _ => Incoming::Cancel,
            }
        }
        "camera" => {
            let c: CameraMsg = fields(k, obj)?;
            let all = c
                .eye
                .iter()
                .chain(&c.target)
                .chain(&c.up)
                .chain(&c.fov)
                .chain(&c.zoom);
            finite_f32(k, all)?;
            Incoming::Camera(c)
        }
        "view" => {
            let v: ViewMsg = fields(k, obj)?;
            finite_f32(k, v.zoom.iter())?;
            Incoming::View(v)
        }
        "tf" => {
            let channel = take_usize(&mut obj, k, "channel")?;
            let tf = obj
                .remove("tf")
                .ok_or_else(|| Error::invalid("tf: needs a 'tf' object"))?;
            no_more(k, &obj)?;
            Incoming::Tf { channel, tf }
        }
        "tf_load" => {
            let channel = take_usize(&mut obj, k, "channel")?;
            let text = match obj.remove("text") {
                Some(Value::String(s)) => s,
                _ => return Err(Error::invalid("tf_load: needs the file's 'text'")),
            };
            no_more(k, &obj)?;
            Incoming::TfLoad { channel, text }
        }
        "tf_export" => {
            let channel = take_usize(&mut obj, k, "channel")?;
            let paraview = match obj.remove("format").as_ref().and_then(Value::as_str) {
                Some("paraview") => true,
                Some("blueshift") | None => false,
                Some(other) => {
                    return Err(Error::invalid(format!(
                        "tf_export: format '{other}' (blueshift, paraview)"
                    )));
                }
            };
            no_more(k, &obj)?;
            Incoming::TfExport { channel, paraview }
        }
        "tf_range" => {
            let channel = match obj.remove("channel") {
                None | Some(Value::Null) => None,
                Some(v) => Some(
                    v.as_u64()
                        .and_then(|c| usize::try_from(c).ok())
                        .ok_or_else(|| {
                            Error::invalid("tf_range: 'channel' must be an integer or null")
                        })?,
                ),
            };
            let range = match obj.remove("range") {
                Some(Value::String(s)) if s == "data" => RangeMsg::Data,
                Some(Value::Array(a)) if a.len() == 2 => {
                    let lo = a[0].as_f64();
                    let hi = a[1].as_f64();
                    match (lo, hi) {
                        (Some(lo), Some(hi)) if lo < hi => RangeMsg::Interval(lo, hi),
                        _ => {
                            return Err(Error::invalid(
                                "tf_range: 'range' [lo, hi] needs numbers with lo < hi",
                            ));
                        }
                    }
                }
                _ => return Err(Error::invalid("tf_range: 'range' is \"data\" or [lo, hi]")),
            };
            no_more(k, &obj)?;
            Incoming::TfRange { channel, range }
        }
        "settings" => {
            let st: SettingsMsg = fields(k, obj)?;
            let light = st.light_dir.iter().flatten().flatten();
            finite_f32(k, st.exposure.iter().chain(&st.density_scale).chain(light))?;
            Incoming::Settings(st)
        }
        "doppler" => Incoming::Doppler(fields(k, obj)?),
        "relativity" => Incoming::Relativity(fields(k, obj)?),
        "tonemap" => {
            let t: TonemapMsg = fields(k, obj)?;
            finite_f32(k, t.exposure.iter())?;
            Incoming::Tonemap(t)
        }
        "pick" | "trace" => {
            let x = take_u32(&mut obj, k, "x")?;
            let y = take_u32(&mut obj, k, "y")?;
            no_more(k, &obj)?;
            if k == "pick" {
                Incoming::Pick { x, y }
            } else {
                Incoming::Trace { x, y }
            }
        }
        "save" => {
            let name = match obj.remove("name") {
                None | Some(Value::Null) => None,
                Some(Value::String(s)) => {
                    let ok = (1..=64).contains(&s.len())
                        && s.bytes()
                            .all(|b| b.is_ascii_alphanumeric() || b == b'-' || b == b'_');
                    if !ok {
                        return Err(Error::invalid(format!(
                            "save: name {s:?} must be 1-64 characters of A-Z, a-z, 0-9, '-' and '_' (files go into the save folder only)"
                        )));
                    }
                    Some(s)
                }
                Some(_) => return Err(Error::invalid("save: 'name' must be a string")),
            };
            no_more(k, &obj)?;
            Incoming::Save { name }
        }
        other => {
            return Err(Error::invalid(format!(
                "unknown message type '{other}' (see PROTOCOL.md)"
            )));
        }
    })
}

/// An `error` reply.
pub(crate) fn error_json(message: &str, request: Option<&str>) -> String {
    json!({ "type": "error", "message": message, "request": request }).to_string()
}

/// A binary frame: the little-endian header length, the JSON header, the PNG.
pub(crate) fn binary_frame(header: &Value, png: &[u8]) -> Vec<u8> {
    let h = header.to_string();
    let mut out = Vec::with_capacity(4 + h.len() + png.len());
    out.extend_from_slice(&(h.len() as u32).to_le_bytes());
    out.extend_from_slice(h.as_bytes());
    out.extend_from_slice(png);
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn malformed_messages_are_refused_with_a_reason() {
        for (text, says) in [
            ("not json", "not JSON"),
            ("[1,2]", "JSON object"),
            ("{\"x\":1}", "\"type\""),
            ("{\"type\":\"warp\"}", "unknown message type 'warp'"),
            ("{\"type\":\"pick\",\"x\":-1,\"y\":2}", "pixel index"),
            (
                "{\"type\":\"pick\",\"x\":1,\"y\":2,\"z\":3}",
                "unknown field 'z'",
            ),
            (
                "{\"type\":\"camera\",\"eye\":[1,2],\"target\":[0,0,0],\"up\":[0,1,0]}",
                "camera",
            ),
            ("{\"type\":\"settings\",\"spp\":1e999}", "out of range"),
            (
                "{\"type\":\"save\",\"name\":\"../etc/passwd\"}",
                "save folder only",
            ),
            ("{\"type\":\"tf_range\",\"range\":[3,1]}", "lo < hi"),
            (
                "{\"type\":\"settings\",\"exposure\":1e39}",
                "single precision",
            ),
            (
                "{\"type\":\"camera\",\"eye\":[1e39,0,0],\"target\":[0,0,0],\"up\":[0,1,0]}",
                "single precision",
            ),
        ] {
            let e = parse(text).unwrap_err().to_string();
            assert!(e.contains(says), "{text}: {e}");
        }
        let big = format!(
            "{{\"type\":\"hello\",\"pad\":\"{}\"}}",
            "x".repeat(MAX_MESSAGE_BYTES)
        );
        assert!(parse(&big).unwrap_err().to_string().contains("limit"));
    }

    #[test]
    fn well_formed_messages_parse() {
        assert!(matches!(
            parse("{\"type\":\"pick\",\"x\":3,\"y\":4}").unwrap(),
            Incoming::Pick { x: 3, y: 4 }
        ));
        let s = parse("{\"type\":\"settings\",\"noise_target\":null,\"spp\":8}").unwrap();
        let Incoming::Settings(s) = s else { panic!() };
        assert_eq!(s.noise_target, Some(None));
        assert_eq!(s.spp, Some(8));
        assert!(
            parse("{\"type\":\"settings\",\"spp\":8}")
                .unwrap()
                .is_edit()
        );
        assert!(!parse("{\"type\":\"save\"}").unwrap().is_edit());
        assert!(
            !parse("{\"type\":\"settings\",\"exposure\":1}")
                .unwrap()
                .is_edit()
        );
        assert!(
            parse("{\"type\":\"settings\",\"exposure\":1,\"seed\":2}")
                .unwrap()
                .is_edit()
        );
    }

    #[test]
    fn a_binary_frame_is_length_header_png() {
        let f = binary_frame(&json!({"kind": "frame"}), &[1, 2, 3]);
        let n = u32::from_le_bytes([f[0], f[1], f[2], f[3]]) as usize;
        let h: Value = serde_json::from_slice(&f[4..4 + n]).unwrap();
        assert_eq!(h["kind"], "frame");
        assert_eq!(&f[4 + n..], &[1, 2, 3]);
    }
}
