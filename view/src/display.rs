//! Display mapping of the HDR frames (the HDR frame stays on the server) and the PNG
//! encoding of the streamed frames.

use blueshift_tonemap::{
    DragoParams, DurandParams, FattalParams, LinearParams, Operator, ReinhardLocalParams,
    ReinhardParams,
};
use image::{Rgb32FImage, RgbImage};

use crate::{Error, Result};

/// The display operators of the tracking view, as `blueshift render --tonemap` names them.
pub const TONEMAPS: &[&str] = &[
    "exposure",
    "linear",
    "drago",
    "reinhard",
    "reinhard-local",
    "durand",
    "fattal",
];

/// An operator of blueshift-tonemap with its paper's default parameters (`exposure`:
/// `None`, plain exposure and clamp).
///
/// # Errors
/// [`Error::Invalid`] for a name not in [`TONEMAPS`].
pub fn operator(name: &str, exposure_stops: f32) -> Result<Option<Operator>> {
    Ok(match name {
        "exposure" => None,
        "linear" => Some(Operator::Linear(LinearParams {
            exposure_stops,
            white: None,
        })),
        "drago" => Some(Operator::Drago(DragoParams::default())),
        "reinhard" => Some(Operator::Reinhard(ReinhardParams::default())),
        "reinhard-local" => Some(Operator::ReinhardLocal(ReinhardLocalParams::default())),
        "durand" => Some(Operator::Durand(DurandParams::default())),
        "fattal" => Some(Operator::Fattal(FattalParams::default())),
        other => {
            return Err(Error::invalid(format!(
                "tonemap '{other}' (one of {})",
                TONEMAPS.join(", ")
            )));
        }
    })
}

/// Linear values in [0, 1] to 8-bit sRGB (clipped: +inf white; NaN black), as every
/// blueshift PNG encodes them.
pub fn encode_srgb8(v: f32) -> u8 {
    (blueshift_tonemap::io::srgb_encode(v) * 255.0).round() as u8
}

/// A linear HDR image for display: `op` (or exposure in stops and a clamp), sRGB, 8 bits.
///
/// # Errors
/// The operator's own.
pub fn to_rgb8(img: &Rgb32FImage, op: Option<&Operator>, stops: f32) -> Result<RgbImage> {
    let display = match op {
        // Straight to the sRGB codes (the same bytes as `encode_srgb8` of `op.apply`).
        Some(op) => {
            let codes = op.apply_clean_srgb8(&blueshift_tonemap::CleanImage::new(img))?;
            return RgbImage::from_raw(img.width(), img.height(), codes)
                .ok_or_else(|| Error::invalid("a display image of the wrong size"));
        }
        None => {
            let gain = stops.exp2();
            Rgb32FImage::from_fn(img.width(), img.height(), |x, y| {
                image::Rgb(img.get_pixel(x, y).0.map(|v| v * gain))
            })
        }
    };
    Ok(RgbImage::from_fn(
        display.width(),
        display.height(),
        |x, y| image::Rgb(display.get_pixel(x, y).0.map(encode_srgb8)),
    ))
}

/// PNG bytes of an 8-bit RGB image (frames are re-sent often): blueshift's PNG writer,
/// compressed in parallel ([`blueshift_tonemap::io::encode_png`]).
///
/// # Errors
/// [`Error::Invalid`] when the encoder fails.
pub fn png_bytes(img: &RgbImage) -> Result<Vec<u8>> {
    let mut out = Vec::with_capacity(img.as_raw().len() / 2 + 1024);
    blueshift_tonemap::io::encode_png(
        &mut out,
        img.width(),
        img.height(),
        png::ColorType::Rgb,
        png::BitDepth::Eight,
        img.as_raw(),
    )
    .map_err(|e| Error::invalid(format!("cannot encode a PNG frame: {e}")))?;
    Ok(out)
}
