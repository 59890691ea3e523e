//! Fattal, Lischinski and Werman 2002, "Gradient domain high dynamic range compression"
//! (HDR VolVis reference [8]): large gradients of log luminance are attenuated over a
//! Gaussian pyramid (Eq. 3-5, 8), and the image is recovered by solving the Poisson
//! equation `laplacian I = div G` (Eq. 6) with Neumann boundaries, here directly by DCT.

use rayon::prelude::*;

use crate::error::{Error, Result};
use crate::plane::Plane;
use crate::poisson::solve_poisson_neumann;

/// Parameters of the gradient-domain operator (paper defaults).
#[derive(Clone, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct FattalParams {
    /// `alpha` of Eq. 5 as a fraction of the average gradient magnitude of each pyramid
    /// level (paper: 0.1). Gradients larger than `alpha` are attenuated.
    pub alpha_ratio: f32,
    /// `beta` of Eq. 5 (paper: between 0.8 and 0.9). 1 means no attenuation.
    pub beta: f32,
    /// Saturation exponent `s` of Eq. 7, `C_out = (C/L)^s * L_out` (paper: 0.4 to 0.6).
    pub saturation: f32,
    /// Percentage of pixels clipped to black when the result is scaled to the display.
    pub black_clip_percent: f32,
    /// Percentage of pixels clipped to white when the result is scaled to the display.
    pub white_clip_percent: f32,
}

impl Default for FattalParams {
    fn default() -> Self {
        Self {
            alpha_ratio: 0.1,
            beta: 0.85,
            saturation: 0.5,
            black_clip_percent: 0.1,
            white_clip_percent: 0.5,
        }
    }
}

impl FattalParams {
    pub(crate) fn validate(&self) -> Result<()> {
        if !(self.alpha_ratio > 0.0 && self.alpha_ratio.is_finite()) {
            return Err(Error::parameter(format!(
                "Fattal alpha must be positive, got {}",
                self.alpha_ratio
            )));
        }
        if !(self.beta > 0.0 && self.beta <= 2.0) {
            return Err(Error::parameter(format!(
                "Fattal beta must lie in (0, 2], got {}",
                self.beta
            )));
        }
        crate::ops::check_saturation(self.saturation)?;
        for (name, v) in [
            ("black clip", self.black_clip_percent),
            ("white clip", self.white_clip_percent),
        ] {
            if !(0.0..50.0).contains(&v) {
                return Err(Error::parameter(format!(
                    "Fattal {name} must lie in [0, 50) percent, got {v}"
                )));
            }
        }
        Ok(())
    }
}

/// Smallest side of the coarsest pyramid level (the paper stops at 32 pixels).
const COARSEST_SIDE: usize = 32;
/// Added to gradient magnitudes before Eq. 5 so flat regions do not divide by zero.
const GRADIENT_FLOOR: f32 = 1e-4;

/// The attenuation field `Phi` of Eq. 8 for natural-log luminance `h`.
#[must_use]
pub fn attenuation(h: &Plane, params: &FattalParams) -> Plane {
    // Gaussian pyramid H_0 .. H_d.
    let mut pyramid = vec![h.clone()];
    while pyramid
        .last()
        .is_some_and(|p| p.width.min(p.height) / 2 >= COARSEST_SIDE)
    {
        let p = pyramid.last().expect("not empty");
        let blurred = p.gaussian_blur(1.0);
        pyramid.push(blurred.downsample_box(2));
    }
    let mut phi: Option<Plane> = None;
    for (k, level) in pyramid.iter().enumerate().rev() {
        let scale = 1.0 / 2f32.powi(k as i32 + 1);
        let grad = Plane::from_fn(level.width, level.height, |x, y| {
            let (xi, yi) = (x as isize, y as isize);
            let gx = (level.at_clamped(xi + 1, yi) - level.at_clamped(xi - 1, yi)) * scale;
            let gy = (level.at_clamped(xi, yi + 1) - level.at_clamped(xi, yi - 1)) * scale;
            gx.hypot(gy)
        });
        // Average gradient magnitude of this level (row sums in f64, summed in order).
        let row_sums: Vec<f64> = grad
            .data
            .par_chunks(grad.width)
            .map(|r| r.iter().map(|&v| f64::from(v)).sum())
            .collect();
        let mean = row_sums.iter().sum::<f64>() / grad.data.len() as f64;
        let alpha = (params.alpha_ratio as f64 * mean).max(1e-6) as f32;
        let beta = params.beta;
        let local = grad.map(|g| {
            let g = g + GRADIENT_FLOOR;
            (g / alpha).powf(beta - 1.0)
        });
        phi = Some(match phi {
            None => local,
            Some(coarse) => {
                let up = coarse.resize_bilinear(level.width, level.height);
                Plane {
                    width: level.width,
                    height: level.height,
                    data: up
                        .data
                        .iter()
                        .zip(&local.data)
                        .map(|(a, b)| a * b)
                        .collect(),
                }
            }
        });
    }
    phi.expect("pyramid has at least one level")
}

/// The compressed natural-log luminance `I` (zero mean) for natural-log luminance `h`:
/// `G = grad H * Phi` with forward differences (zero flux across the border),
/// `div G` with backward differences, then the Neumann Poisson solve.
///
/// A forward difference `H(x+1) - H(x)` lives on the edge between the two pixels, so it is
/// attenuated by `Phi` at that edge's midpoint, `(Phi(x) + Phi(x+1)) / 2` (likewise in y).
/// Taking `Phi(x)` alone, the value at the left (top) pixel, biases the field: the rising
/// and the falling edge of a bright object are scaled by `Phi` on different sides of the
/// object, so their attenuated steps no longer cancel, the field gains a curl, and the
/// least-squares Poisson solve spreads that inconsistency over the whole image as a smooth
/// ramp: a low-frequency glow to the right of and below bright features. With the
/// midpoint the operator commutes with mirroring the image.
///
/// With `beta = 1` (no attenuation) `I = H - mean(H)` up to the solver's rounding.
///
/// # Errors
/// [`Error::Parameter`] for invalid parameters or an empty plane.
pub fn compressed_log_luminance(h: &Plane, params: &FattalParams) -> Result<Plane> {
    params.validate()?;
    let (w, hgt) = (h.width, h.height);
    if w == 0 || hgt == 0 {
        return Err(Error::EmptyImage);
    }
    let phi = attenuation(h, params);
    let at = |x: usize, y: usize| h.data[y * w + x];
    let phi_at = |x: usize, y: usize| phi.data[y * w + x];
    let gx = Plane::from_fn(w, hgt, |x, y| {
        if x + 1 < w {
            (at(x + 1, y) - at(x, y)) * 0.5 * (phi_at(x, y) + phi_at(x + 1, y))
        } else {
            0.0
        }
    });
    let gy = Plane::from_fn(w, hgt, |x, y| {
        if y + 1 < hgt {
            (at(x, y + 1) - at(x, y)) * 0.5 * (phi_at(x, y) + phi_at(x, y + 1))
        } else {
            0.0
        }
    });
    let mut div = vec![0.0f64; w * hgt];
    div.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (x, d) in row.iter_mut().enumerate() {
            let mut v = f64::from(gx.data[y * w + x]) + f64::from(gy.data[y * w + x]);
            if x > 0 {
                v -= f64::from(gx.data[y * w + x - 1]);
            }
            if y > 0 {
                v -= f64::from(gy.data[(y - 1) * w + x]);
            }
            *d = v;
        }
    });
    let u = solve_poisson_neumann(&div, w, hgt)?;
    Ok(Plane {
        width: w,
        height: hgt,
        data: u.into_iter().map(|v| v as f32).collect(),
    })
}

/// The display luminance of Fattal's compressed luminance `l_out`: the lit pixels' (those
/// whose input `luminance` is positive) `black_clip_percent` percentile maps to 0 and their
/// `100 - white_clip_percent` percentile to 1, clipped below at 0. Where the two are equal
/// (a flat image: nothing to stretch) every pixel is 1, white as Drago and the linear
/// operator show it, rather than the stretch's 0 / 0. Shared by the CPU and GPU paths.
#[must_use]
pub fn display_stretch(l_out: &Plane, luminance: &Plane, params: &FattalParams) -> Plane {
    let lit: Vec<f32> = l_out
        .data
        .iter()
        .zip(&luminance.data)
        .filter(|(_, l)| **l > 0.0)
        .map(|(v, _)| *v)
        .collect();
    let lo = percentile(&lit, params.black_clip_percent);
    let hi = percentile(&lit, 100.0 - params.white_clip_percent);
    if hi > lo {
        let span = (hi - lo).max(f32::MIN_POSITIVE);
        l_out.map(|v| ((v - lo) / span).max(0.0))
    } else {
        l_out.map(|_| 1.0)
    }
}

/// The value below which `percent` % of `values` lie (nearest rank on a sorted copy).
#[must_use]
pub fn percentile(values: &[f32], percent: f32) -> f32 {
    if values.is_empty() {
        return 0.0;
    }
    let mut v = values.to_vec();
    let k = ((percent / 100.0) * (v.len() - 1) as f32).round() as usize;
    let k = k.min(v.len() - 1);
    let (_, kth, _) = v.select_nth_unstable_by(k, f32::total_cmp);
    *kth
}
