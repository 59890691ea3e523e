//! # blueshift-tonemap
//!
//! Tone mapping of high-dynamic-range images for display, as HDR VolVis (Yuan et al.)
//! Sec. 4 uses it: the operators of Drago et al. 2003, Reinhard et al. 2002 (global and
//! local), Durand and Dorsey 2002 and Fattal et al. 2002, each with its paper's parameters
//! and defaults; linear exposure and exposure series; the inverse of the global operators;
//! pseudocolour of log luminance with a colour bar; the dynamic range; and HDR image I/O
//! (OpenEXR, Radiance `.hdr`, PFM, 8/16-bit PNG, numbered EXR sequences).
//!
//! Images cross crate boundaries as the `image` crate's [`image::Rgb32FImage`]: linear
//! RGB (Rec. 709 / sRGB primaries), any positive unit.
//!
//! ## Where do I start?
//! - [`io::read_hdr_image`] reads `.exr`, `.hdr` or `.pfm`.
//! - [`Operator`] holds an operator and its parameters; [`Operator::apply`] tone-maps.
//! - [`io::write_png`] encodes the display image (sRGB transfer, 8 or 16 bits).
//!
//! ```
//! use blueshift_tonemap::{DragoParams, Operator};
//! use image::Rgb32FImage;
//!
//! // A 16x1 ramp over four orders of magnitude.
//! let hdr = Rgb32FImage::from_fn(16, 1, |x, _| {
//!     let v = 10f32.powf(x as f32 / 4.0 - 2.0);
//!     image::Rgb([v, v, v])
//! });
//! let display = Operator::Drago(DragoParams::default()).apply(&hdr).unwrap();
//! // Drago maps the brightest pixel to Ld_max / 100 = 1.
//! assert!((display.get_pixel(15, 0)[0] - 1.0).abs() < 1e-4);
//! ```
//!
//! ## Glossary (paper term -> type)
//! | paper | here |
//! |---|---|
//! | HDR VolVis Fig. 4a, pseudocolour of intensity | [`pseudocolour()`], [`PseudocolourParams`] |
//! | HDR VolVis Fig. 4b, exposure levels | [`exposure_series()`], [`ExposureSeries`] |
//! | HDR VolVis Fig. 4c/d, region of interest | [`DragoParams::roi`], [`Roi`] |
//! | HDR VolVis Sec. 4, inverse of a global operator | [`GlobalCurve::invert`] |
//! | Drago 2003 Eq. 4, bias `b`, `Ld_max`, `L_wa` | [`DragoParams`], [`ops::drago::drago_curve`] |
//! | Reinhard 2002 Eq. 2-4, key `a`, `L_white` | [`ReinhardParams`] |
//! | Reinhard 2002 Eq. 5-9, `phi`, `epsilon`, scales | [`ReinhardLocalParams`], [`ops::reinhard::dodge_and_burn`] |
//! | Durand 2002, `sigma_s`, `sigma_r`, target contrast | [`DurandParams`], [`ops::durand::fast_bilateral`] |
//! | Fattal 2002 Eq. 5 `alpha`, `beta`; Eq. 7 `s`; Eq. 8 `Phi` | [`FattalParams`], [`ops::fattal::attenuation`] |
//! | Fattal 2002 Poisson equation (Neumann) | [`poisson::solve_poisson_neumann`] |
//! | dynamic range (max / min non-zero) | [`dynamic_range()`], [`DynamicRange`] |
//! | dirty input (negative, NaN, Inf) | [`sanitize()`] (the rule is in [`sanitize`](mod@sanitize)) |
//!
//! ## Determinism
//! All image loops run in parallel over rows with rayon. Each output value is computed in
//! a fixed order, and reductions (log-averages, means) sum per row in `f64` and then over
//! rows in order, so the result does not depend on the number of threads.
//!
//! ## Features
//! - `serde`: derive `Serialize`/`Deserialize` on parameter structs and [`GlobalCurve`].

pub mod error;
mod exr_yc;
mod exr_zip;
pub mod fastmath;
pub mod inverse;
pub mod io;
pub mod ops;
mod piz;
pub mod plane;
pub mod poisson;
pub mod pseudocolour;
mod rows;
pub mod sanitize;
pub mod session;
pub mod zlib;

pub use error::{Error, Result};
pub use inverse::GlobalCurve;
pub use ops::linear::{LINEAR_WHITE_PERCENTILE, MAX_EXPOSURE_SERIES, default_linear_white};
pub use ops::{
    DragoParams, DurandParams, ExposureSeries, FattalParams, LinearParams, Operator,
    ReinhardLocalParams, ReinhardParams, Roi, RowsToneMap, exposure_series,
};
pub use plane::{LUMINANCE_WEIGHTS, Plane, luminance};
pub use pseudocolour::{Palette, PseudocolourParams, pseudocolour};
pub use sanitize::{
    CleanImage, CleanStats, DynamicRange, SanitizeReport, dynamic_range, sanitize,
    sanitize_in_place,
};
pub use session::TonemapSession;

/// A fixed-seed xorshift generator for the unit tests' random inputs.
#[cfg(test)]
pub(crate) fn xorshift(mut state: u64) -> impl FnMut() -> u64 {
    move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        state
    }
}
