//! blueshift's JSON format for a whole transfer function, and [`load`], which reads either
//! that format or a ParaView preset, told apart by content.

use std::path::Path;

use serde_json::Value;

use crate::color::ColorSpace;
use crate::tf::{ColorKnot, DataAxis, OpacityKnot, TransferFunction};
use crate::{Error, Result, paraview};

/// The `format` tag of blueshift's transfer-function JSON.
pub const FORMAT_TAG: &str = "blueshift-transfer-function";
/// The current format version.
pub const FORMAT_VERSION: u32 = 1;
/// Largest file [`load`] reads (64 MiB); a transfer function is a few KiB.
pub const MAX_FILE_BYTES: u64 = 64 << 20;

/// The on-disk shape of blueshift's transfer-function JSON. Example:
///
/// ```json
/// { "format": "blueshift-transfer-function", "version": 1, "name": "demo",
///   "domain": [0.0, 100.0], "data_axis": "linear", "color_space": "hsv",
///   "alpha_g": 0.05, "nan_color": [1.0, 0.0, 1.0],
///   "color": [ { "x": 0.0, "rgb": [0.0, 0.0, 1.0] }, { "x": 100.0, "rgb": [1.0, 0.0, 0.0] } ],
///   "opacity": [ { "x": 0.0, "alpha": 0.0 }, { "x": 100.0, "alpha": 1.0, "midpoint": 0.5, "sharpness": 0.0 } ] }
/// ```
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TransferFunctionFile {
    /// Always [`FORMAT_TAG`].
    pub format: String,
    /// [`FORMAT_VERSION`].
    pub version: u32,
    /// Free-form name.
    #[serde(default)]
    pub name: String,
    /// `[min, max]` in data units.
    pub domain: [f64; 2],
    /// `"linear"` (default) or `"log"`.
    #[serde(default)]
    pub data_axis: DataAxis,
    /// `"rgb"` (default), `"hsv"`, `"lab"`, `"diverging"` or `"step"`.
    #[serde(default)]
    pub color_space: ColorSpace,
    /// Global opacity alpha_g in [0, 1] (default 1).
    #[serde(default = "one")]
    pub alpha_g: f32,
    /// Colour for NaN data (default grey).
    #[serde(default = "grey")]
    pub nan_color: [f32; 3],
    /// Colour knots, sorted by `x`.
    pub color: Vec<ColorKnot>,
    /// Opacity knots, sorted by `x`.
    pub opacity: Vec<OpacityKnot>,
}

fn one() -> f32 {
    1.0
}
fn grey() -> [f32; 3] {
    [0.5, 0.5, 0.5]
}

impl From<&TransferFunction> for TransferFunctionFile {
    fn from(tf: &TransferFunction) -> Self {
        Self {
            format: FORMAT_TAG.into(),
            version: FORMAT_VERSION,
            name: tf.name().into(),
            domain: tf.domain(),
            data_axis: tf.data_axis(),
            color_space: tf.color_space(),
            alpha_g: tf.alpha_g(),
            nan_color: tf.nan_color(),
            color: tf.color_knots().to_vec(),
            opacity: tf.opacity_knots().to_vec(),
        }
    }
}

impl TryFrom<TransferFunctionFile> for TransferFunction {
    type Error = Error;
    fn try_from(f: TransferFunctionFile) -> Result<Self> {
        if f.format != FORMAT_TAG {
            return Err(Error::invalid(format!(
                "format is {:?}, expected {FORMAT_TAG:?}",
                f.format
            )));
        }
        if f.version != FORMAT_VERSION {
            return Err(Error::Unsupported(format!(
                "transfer-function format version {} (this build reads version {FORMAT_VERSION})",
                f.version
            )));
        }
        TransferFunction::new(f.domain, f.color, f.opacity)?
            .with_color_space(f.color_space)
            .with_name(f.name)
            .with_data_axis(f.data_axis)?
            .with_alpha_g(f.alpha_g)?
            .with_nan_color(f.nan_color)
    }
}

impl serde::Serialize for TransferFunction {
    fn serialize<S: serde::Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
        TransferFunctionFile::from(self).serialize(s)
    }
}

impl<'de> serde::Deserialize<'de> for TransferFunction {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        let f = TransferFunctionFile::deserialize(d)?;
        TransferFunction::try_from(f).map_err(serde::de::Error::custom)
    }
}

impl TransferFunction {
    /// blueshift's JSON text for this transfer function (pretty-printed).
    #[must_use]
    pub fn to_json_string(&self) -> String {
        let mut s =
            serde_json::to_string_pretty(&TransferFunctionFile::from(self)).unwrap_or_default();
        s.push('\n');
        s
    }

    /// Parses blueshift's JSON text.
    pub fn from_json_str(text: &str) -> Result<Self> {
        let doc: Value = serde_json::from_str(text)
            .map_err(|e| Error::invalid(format!("not valid JSON: {e}")))?;
        from_blueshift_value(doc)
    }
}

fn from_blueshift_value(doc: Value) -> Result<TransferFunction> {
    let f: TransferFunctionFile = serde_json::from_value(doc)
        .map_err(|e| Error::invalid(format!("blueshift transfer function: {e}")))?;
    TransferFunction::try_from(f)
}

/// Which format a document is in.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    /// blueshift's JSON ([`TransferFunctionFile`]).
    Blueshift,
    /// A ParaView colour-map preset ([`crate::paraview`]).
    ParaView,
}

/// Tells the two formats apart by content: an object whose `format` is
/// [`FORMAT_TAG`] is blueshift's; an array of objects, or an object with `RGBPoints`,
/// `Points`, `IndexedColors` or `ColorSpace`, is ParaView's.
#[must_use]
pub fn detect(doc: &Value) -> Option<Format> {
    if doc.get("format").and_then(Value::as_str) == Some(FORMAT_TAG) {
        Some(Format::Blueshift)
    } else if paraview::is_paraview_preset(doc) {
        Some(Format::ParaView)
    } else {
        None
    }
}

/// Parses transfer-function text in either format (see [`detect`]); for ParaView files the
/// first preset is taken.
pub fn parse_any(text: &str) -> Result<(TransferFunction, Format)> {
    let doc: Value = serde_json::from_str(text)
        .map_err(|e| Error::invalid(format!("not valid JSON: {e}")))?;
    match detect(&doc) {
        Some(Format::Blueshift) => Ok((from_blueshift_value(doc)?, Format::Blueshift)),
        Some(Format::ParaView) => Ok((paraview::from_paraview_value(&doc, None)?, Format::ParaView)),
        None => Err(Error::invalid(format!(
            "neither a blueshift transfer function (an object with \"format\": {FORMAT_TAG:?}) nor a ParaView preset (an array of objects with \"RGBPoints\")"
        ))),
    }
}

/// Loads a transfer function from a file in either format, told apart by content: this is
/// the entry point for renderers. A ParaView preset with opacity `Points` gives that
/// opacity curve; without them, a 0-to-1 ramp.
pub fn load(path: impl AsRef<Path>) -> Result<TransferFunction> {
    let path = path.as_ref();
    let io = |what: &str, e: std::io::Error| Error::Io {
        context: format!("cannot {what} {}", path.display()),
        source: e,
    };
    let meta = std::fs::metadata(path).map_err(|e| io("read", e))?;
    if meta.len() > MAX_FILE_BYTES {
        return Err(Error::invalid(format!(
            "{} is {} bytes, more than the {MAX_FILE_BYTES}-byte limit for a transfer function file",
            path.display(),
            meta.len()
        )));
    }
    let text = std::fs::read_to_string(path).map_err(|e| {
        if e.kind() == std::io::ErrorKind::InvalidData {
            Error::invalid(format!("{} is not UTF-8 text", path.display()))
        } else {
            io("read", e)
        }
    })?;
    parse_any(&text)
        .map(|(tf, _)| tf)
        .map_err(|e| match e {
            Error::Invalid(m) => Error::Invalid(format!("{m} (in {})", path.display())),
            other => other,
        })
}
