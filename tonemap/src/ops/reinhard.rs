//! Reinhard, Stark, Shirley and Ferwerda 2002, "Photographic tone reproduction for digital
//! images" (HDR VolVis reference [32]): the global operator (paper Eq. 2-4) and local
//! dodging-and-burning (Eq. 5-9).

use rayon::prelude::*;

use crate::error::{Error, Result};
use crate::plane::Plane;

/// Parameters of the global photographic operator (paper defaults).
#[derive(Clone, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct ReinhardParams {
    /// The key `a` (paper: 0.18, "middle grey"); `L = a / L_w_avg * L_w` (Eq. 2).
    pub key: f32,
    /// `L_white` of Eq. 4 in scaled units; `None` = the largest scaled luminance (the
    /// paper's default), `Some(f32::INFINITY)` gives the simple `L / (1 + L)` of Eq. 3.
    pub white: Option<f32>,
    /// Saturation exponent `s` in `C_out = (C/L)^s * L_out` (1 keeps colour ratios).
    pub saturation: f32,
}

impl Default for ReinhardParams {
    fn default() -> Self {
        Self {
            key: 0.18,
            white: None,
            saturation: 1.0,
        }
    }
}

impl ReinhardParams {
    pub(crate) fn validate(&self) -> Result<()> {
        check_key(self.key)?;
        if let Some(w) = self.white
            && (w.is_nan() || w <= 0.0)
        {
            return Err(Error::parameter(format!(
                "Reinhard white must be positive, got {w}"
            )));
        }
        crate::ops::check_saturation(self.saturation)
    }
}

fn check_key(key: f32) -> Result<()> {
    if key > 0.0 && key.is_finite() {
        Ok(())
    } else {
        Err(Error::parameter(format!(
            "Reinhard key must be positive and finite, got {key}"
        )))
    }
}

/// Eq. 4: `Ld = L (1 + L / L_white^2) / (1 + L)` for scaled luminance `L`.
#[must_use]
pub fn reinhard_curve(l: f64, white: f64) -> f64 {
    let inv_w2 = if white.is_finite() {
        1.0 / (white * white)
    } else {
        0.0
    };
    l * (1.0 + l * inv_w2) / (1.0 + l)
}

/// The inverse of [`reinhard_curve`]: the positive root of
/// `L^2 / L_white^2 + L (1 - Ld) - Ld = 0`.
#[must_use]
pub fn reinhard_curve_inverse(ld: f64, white: f64) -> f64 {
    if ld <= 0.0 {
        return 0.0;
    }
    if !white.is_finite() {
        return if ld < 1.0 { ld / (1.0 - ld) } else { f64::MAX };
    }
    let a = 1.0 / (white * white);
    let b = 1.0 - ld;
    // Numerically stable root of a L^2 + b L - ld = 0 (a > 0, -ld < 0).
    let disc = (b * b + 4.0 * a * ld).sqrt();
    if b >= 0.0 {
        2.0 * ld / (b + disc)
    } else {
        (-b + disc) / (2.0 * a)
    }
}

/// Parameters of local dodging-and-burning (paper Sec. 3.2 defaults).
#[derive(Clone, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct ReinhardLocalParams {
    /// The key `a` (0.18).
    pub key: f32,
    /// Sharpening parameter `phi` of Eq. 7 (8).
    pub phi: f32,
    /// Threshold `epsilon` on the centre-surround difference `|V|` of Eq. 8 (0.05).
    pub epsilon: f32,
    /// Number of scales (8: from 1 pixel up by `scale_ratio`, surrounds up to ~43 pixels).
    pub scales: usize,
    /// Ratio between consecutive scales, which is also the surround/centre ratio
    /// `alpha_2 / alpha_1` (1.6).
    pub scale_ratio: f32,
    /// Saturation exponent `s` in `C_out = (C/L)^s * L_out`.
    pub saturation: f32,
}

impl Default for ReinhardLocalParams {
    fn default() -> Self {
        Self {
            key: 0.18,
            phi: 8.0,
            epsilon: 0.05,
            scales: 8,
            scale_ratio: 1.6,
            saturation: 1.0,
        }
    }
}

impl ReinhardLocalParams {
    pub(crate) fn validate(&self) -> Result<()> {
        check_key(self.key)?;
        if !(self.phi.is_finite() && self.phi >= 0.0 && self.phi <= 64.0) {
            return Err(Error::parameter(format!(
                "Reinhard phi must lie in [0, 64], got {}",
                self.phi
            )));
        }
        if !(self.epsilon > 0.0 && self.epsilon.is_finite()) {
            return Err(Error::parameter(format!(
                "Reinhard epsilon must be positive, got {}",
                self.epsilon
            )));
        }
        if self.scales == 0 || self.scales > 16 {
            return Err(Error::parameter(format!(
                "Reinhard local needs 1 to 16 scales, got {}",
                self.scales
            )));
        }
        if !(self.scale_ratio > 1.0 && self.scale_ratio <= 4.0) {
            return Err(Error::parameter(format!(
                "Reinhard scale ratio must lie in (1, 4], got {}",
                self.scale_ratio
            )));
        }
        crate::ops::check_saturation(self.saturation)
    }
}

/// Local dodging and burning on scaled luminance `l` (`L = a / L_w_avg * L_w`): Eq. 5-9.
///
/// The centre response at scale `s` is `V1 = L * R1` with the Gaussian
/// `R1 = exp(-(x^2 + y^2) / (alpha_1 s)^2)`, `alpha_1 = 1 / (2 sqrt 2)`, that is a standard
/// deviation of `alpha_1 s / sqrt 2 = s / 4` pixels; the surround is the centre of the next
/// scale (`alpha_2 = 1.6 alpha_1`). For each pixel the largest scale with
/// `|V| = |V1 - V2| / (2^phi a / s^2 + V1| < epsilon` is chosen, and
/// `Ld = L / (1 + V1(s_m))`.
#[must_use]
pub fn dodge_and_burn(l: &Plane, params: &ReinhardLocalParams) -> Plane {
    let n = params.scales;
    let scales: Vec<f32> = (0..=n).map(|i| params.scale_ratio.powi(i as i32)).collect();
    let alpha1 = 1.0 / (2.0 * std::f32::consts::SQRT_2);
    let centres: Vec<Plane> = scales
        .iter()
        .map(|&s| l.gaussian_blur(alpha1 * s / std::f32::consts::SQRT_2))
        .collect();
    let num = 2f32.powf(params.phi) * params.key;
    let mut out = vec![0.0f32; l.data.len()];
    let w = l.width;
    out.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (x, o) in row.iter_mut().enumerate() {
            let i = y * w + x;
            let mut chosen = centres[0].data[i];
            for k in 0..n {
                let v1 = centres[k].data[i];
                let v2 = centres[k + 1].data[i];
                let s = scales[k];
                let v = (v1 - v2) / (num / (s * s) + v1);
                if v.abs() >= params.epsilon {
                    break;
                }
                chosen = v1;
            }
            let li = l.data[i];
            *o = li / (1.0 + chosen);
        }
    });
    Plane {
        width: l.width,
        height: l.height,
        data: out,
    }
}
