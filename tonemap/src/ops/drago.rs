//! Drago, Myszkowski, Annen and Chiba 2003, "Adaptive logarithmic mapping for displaying
//! high contrast scenes" (HDR VolVis reference [6]), with the region-of-interest variant of
//! HDR VolVis Fig. 4c/4d.

use crate::error::{Error, Result};
use crate::ops::check_finite;

/// A user circle in pixel coordinates (x to the right, y down, origin at the top-left
/// corner of the image).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct Roi {
    /// Centre x in pixels.
    pub x_px: f32,
    /// Centre y in pixels.
    pub y_px: f32,
    /// Radius in pixels.
    pub radius_px: f32,
}

/// Parameters of Drago's adaptive logarithmic mapping (defaults from the paper).
#[derive(Clone, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct DragoParams {
    /// Bias `b` of the bias power function, in (0, 1); the paper recommends 0.85.
    pub bias: f32,
    /// Maximum display luminance `Ld_max` in cd/m^2 (paper: 100); the brightest pixel maps
    /// to `Ld_max / 100`.
    pub max_display_luminance: f32,
    /// Exposure in stops applied to the world luminance after dividing by the adaptation
    /// luminance (the paper's exposure factor; 0 = none).
    pub exposure_stops: f32,
    /// Region of interest: the world adaptation luminance `L_wa` is the log-average inside
    /// this circle instead of over the whole image (HDR VolVis Fig. 4c/4d).
    pub roi: Option<Roi>,
    /// Saturation exponent `s` in `C_out = (C/L)^s * L_out` (1 keeps colour ratios, as the
    /// paper does).
    pub saturation: f32,
}

impl Default for DragoParams {
    fn default() -> Self {
        Self {
            bias: 0.85,
            max_display_luminance: 100.0,
            exposure_stops: 0.0,
            roi: None,
            saturation: 1.0,
        }
    }
}

impl DragoParams {
    pub(crate) fn validate(&self) -> Result<()> {
        if !(self.bias > 0.0 && self.bias < 1.0) {
            return Err(Error::parameter(format!(
                "Drago bias must lie in (0, 1), got {}",
                self.bias
            )));
        }
        if !(self.max_display_luminance.is_finite() && self.max_display_luminance > 0.0) {
            return Err(Error::parameter(format!(
                "Drago max display luminance must be positive, got {}",
                self.max_display_luminance
            )));
        }
        check_finite("exposure_stops", self.exposure_stops)?;
        crate::ops::check_saturation(self.saturation)?;
        if let Some(r) = self.roi
            && !(r.x_px.is_finite() && r.y_px.is_finite() && r.radius_px > 0.0)
        {
            return Err(Error::parameter(format!(
                "region of interest needs a finite centre and a positive radius, got {r:?}"
            )));
        }
        Ok(())
    }
}

/// Drago's curve (paper Eq. 4) for luminance already divided by the adaptation luminance:
/// `Ld = (Ld_max/100) / log10(Lw_max + 1) * ln(Lw + 1) / ln(2 + 8 (Lw/Lw_max)^(ln b / ln 0.5))`.
#[must_use]
pub fn drago_curve(lw: f64, lw_max: f64, bias: f64, ld_max: f64) -> f64 {
    let exponent = bias.ln() / 0.5f64.ln();
    let interp = (2.0 + 8.0 * (lw / lw_max).powf(exponent)).ln();
    (ld_max * 0.01) / (lw_max + 1.0).log10() * lw.ln_1p() / interp
}
