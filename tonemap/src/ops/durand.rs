//! Durand and Dorsey 2002, "Fast bilateral filtering for the display of high-dynamic-range
//! images" (HDR VolVis reference [7]): base/detail decomposition of log luminance by a fast
//! bilateral filter, contrast reduction of the base only.
//!
//! Units follow the paper: log10 luminance, `sigma_r` in log10 units, the base contrast as
//! a ratio (5:1), the maximum of the base mapped to display 1. One deviation: the base
//! range runs from the 1st percentile of the base, not its minimum, so isolated noise
//! pixels cannot set the compression factor ([`durand_log_lit`]). `pfstmo_durand02` works in
//! natural log and takes its base contrast as a log-unit range, so the same settings there
//! read `--sigma-r 0.921 --base-contrast 1.609 --original` (see `tonemap/peers/RESULTS.md`).

use rayon::prelude::*;

use crate::error::{Error, Result};
use crate::plane::Plane;

/// Parameters of the Durand-Dorsey operator (paper defaults).
#[derive(Clone, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct DurandParams {
    /// Spatial standard deviation `sigma_s` in pixels; `None` = 2 % of the larger image
    /// side (the paper's choice).
    pub sigma_spatial_px: Option<f32>,
    /// Range standard deviation `sigma_r` in log10 luminance units (paper: 0.4).
    pub sigma_range: f32,
    /// Target contrast of the base layer, as a ratio (paper: 5, i.e. `log10(5)` in log
    /// units).
    pub base_contrast: f32,
    /// Saturation exponent `s` in `C_out = (C/L)^s * L_out` (1 keeps colour ratios).
    pub saturation: f32,
}

impl Default for DurandParams {
    fn default() -> Self {
        Self {
            sigma_spatial_px: None,
            sigma_range: 0.4,
            base_contrast: 5.0,
            saturation: 1.0,
        }
    }
}

impl DurandParams {
    pub(crate) fn validate(&self) -> Result<()> {
        if let Some(s) = self.sigma_spatial_px
            && !(s > 0.0 && s <= 1.0e4)
        {
            return Err(Error::parameter(format!(
                "Durand sigma_s must lie in (0, 1e4] pixels, got {s}"
            )));
        }
        if !(self.sigma_range > 0.01 && self.sigma_range <= 100.0) {
            return Err(Error::parameter(format!(
                "Durand sigma_r must lie in (0.01, 100] log10 units, got {}",
                self.sigma_range
            )));
        }
        if !(self.base_contrast > 1.0 && self.base_contrast.is_finite()) {
            return Err(Error::parameter(format!(
                "Durand base contrast must be a finite ratio above 1, got {}",
                self.base_contrast
            )));
        }
        crate::ops::check_saturation(self.saturation)
    }

    /// The spatial sigma for an image of `width` x `height` pixels.
    #[must_use]
    pub fn sigma_spatial_for(&self, width: usize, height: usize) -> f32 {
        self.sigma_spatial_px
            .unwrap_or(0.02 * width.max(height) as f32)
            .max(0.5)
    }
}

/// Percentile of the base layer (over lit pixels) taken as its lower end when the
/// compression factor is computed (see [`durand_log`]); pfstmo_durand02 uses the same.
pub const BASE_LOW_PERCENTILE: f32 = 1.0;

/// Durand-Dorsey on log10 luminance: `base = bilateral(log L)`, `detail = log L - base`,
/// output `log10 Ld = (base - max base) * gamma + detail` with
/// `gamma = log10(contrast) / (max base - low base)` (paper Sec. 6), so the brightest base
/// maps to display 1. Every pixel counts as lit; see [`durand_log_lit`].
#[must_use]
pub fn durand_log(log_l: &Plane, params: &DurandParams) -> Plane {
    durand_log_lit(log_l, None, params)
}

/// [`durand_log`] where only the pixels with `luminance > 0` (when given) enter the base
/// range.
///
/// The low end of the base range is the [`BASE_LOW_PERCENTILE`]th percentile of the base
/// over lit pixels, not its minimum. The paper's minimum is set by isolated pixels: the
/// edge-preserving filter keeps a lone pixel its own base, and real photographs carry
/// noise pixels whose channels the dirty-input rule sets to 0 (Desk.exr: the darkest
/// positive luminance is 10^-6.4 while the 0.1th percentile is 10^-3.1). Those few pixels
/// widened the base range by almost four orders of magnitude (base minimum 10^-6.4, 1st
/// percentile 10^-2.5), shrank `gamma` to 0.082 (0.152 with the 1st-percentile low end)
/// and flattened the whole base (the low frequencies), so every dark region came out lifted
/// towards the highlights: a washed-out picture, hazy along the rail in front of the window.
/// The top stays the maximum (the paper's brightest base maps to display 1).
#[must_use]
pub fn durand_log_lit(log_l: &Plane, luminance: Option<&Plane>, params: &DurandParams) -> Plane {
    let sigma_s = params.sigma_spatial_for(log_l.width, log_l.height);
    let base = fast_bilateral(log_l, sigma_s, params.sigma_range);
    let (bmin_all, bmax) = base.min_max();
    let lit: Vec<f32> = match luminance {
        Some(l) => base
            .data
            .iter()
            .zip(&l.data)
            .filter(|(_, l)| **l > 0.0)
            .map(|(b, _)| *b)
            .collect(),
        None => base.data.clone(),
    };
    let bmin = if lit.is_empty() {
        bmin_all
    } else {
        crate::ops::fattal::percentile(&lit, BASE_LOW_PERCENTILE)
    };
    let span = (bmax - bmin).max(1e-6);
    let gamma = (params.base_contrast.log10() / span).min(1.0);
    Plane::from_fn(log_l.width, log_l.height, |x, y| {
        let i = y * log_l.width + x;
        let b = base.data[i];
        (b - bmax) * gamma + (log_l.data[i] - b)
    })
}

/// The fast bilateral filter of Durand and Dorsey (paper Sec. 5.1): the range axis is cut
/// into segments of at most `sigma_r`; for each segment value `i_j` the normalised
/// Gaussian-weighted image `J_j = (f(I - i_j) I) * g / (f(I - i_j) * g)` is computed on a
/// grid down-sampled by `z ~ sigma_s / 4` (box splatting), and each pixel interpolates
/// linearly between the two segments that bracket its own value, after bilinear
/// up-sampling. `f` and `g` are Gaussians of standard deviations `sigma_r` (range, in the
/// units of `input`) and `sigma_s` (pixels).
#[must_use]
pub fn fast_bilateral(input: &Plane, sigma_s: f32, sigma_r: f32) -> Plane {
    let (w, h) = (input.width, input.height);
    if w == 0 || h == 0 {
        return input.clone();
    }
    let (lo, hi) = input.min_max();
    let nseg = (((hi - lo) / sigma_r).ceil() as usize).max(1);
    let step = ((hi - lo) / nseg as f32).max(f32::MIN_POSITIVE);
    let levels: Vec<f32> = (0..=nseg).map(|j| lo + step * j as f32).collect();
    let z = ((sigma_s / 4.0).round() as usize).max(1);
    let (gw, gh) = (w.div_ceil(z), h.div_ceil(z));
    let nl = levels.len();
    let cut = 4.0 * sigma_r;
    let inv2r2 = 1.0 / (2.0 * sigma_r * sigma_r);

    // Splat: for every grid row, accumulate weights and weighted values per level.
    // Layout per grid row: [level][gx] for weights then values.
    let mut splat = vec![0.0f32; gh * nl * gw * 2];
    splat
        .par_chunks_mut(nl * gw * 2)
        .enumerate()
        .for_each(|(gy, acc)| {
            let (wacc, vacc) = acc.split_at_mut(nl * gw);
            for y in gy * z..((gy + 1) * z).min(h) {
                let row = &input.data[y * w..(y + 1) * w];
                for (x, &v) in row.iter().enumerate() {
                    let gx = x / z;
                    let jlo = (((v - cut - lo) / step).ceil().max(0.0)) as usize;
                    let jhi = ((((v + cut - lo) / step).floor()) as usize).min(nl - 1);
                    for j in jlo..=jhi {
                        let d = v - levels[j];
                        let g = (-d * d * inv2r2).exp();
                        wacc[j * gw + gx] += g;
                        vacc[j * gw + gx] += g * v;
                    }
                }
            }
        });
    // Blur every level's weight and value grids with the remaining spatial sigma.
    let sigma_grid = sigma_s / z as f32;
    let grids: Vec<(Plane, Plane)> = (0..nl)
        .into_par_iter()
        .map(|j| {
            let pick = |off: usize| {
                Plane::from_fn(gw, gh, |gx, gy| splat[gy * nl * gw * 2 + off + j * gw + gx])
            };
            let wg = pick(0).gaussian_blur(sigma_grid);
            let vg = pick(nl * gw).gaussian_blur(sigma_grid);
            (wg, vg)
        })
        .collect();
    // Slice: bilinear up-sampling and linear interpolation between bracketing levels.
    let scale = 1.0 / z as f32;
    Plane::from_fn(w, h, |x, y| {
        let v = input.data[y * w + x];
        let t = ((v - lo) / step).clamp(0.0, nseg as f32);
        let j = (t.floor() as usize).min(nseg - 1);
        let f = t - j as f32;
        let gx = (x as f32 + 0.5) * scale - 0.5;
        let gy = (y as f32 + 0.5) * scale - 0.5;
        let value = |k: usize| {
            let (wg, vg) = &grids[k];
            let ww = wg.sample_bilinear(gx, gy);
            if ww > 1e-20 {
                vg.sample_bilinear(gx, gy) / ww
            } else {
                v
            }
        };
        value(j) * (1.0 - f) + value(j + 1) * f
    })
}

/// The bilateral filter evaluated directly (O(N r^2)); the reference the fast filter is
/// tested against. Gaussian spatial kernel truncated at 3 sigma, edges excluded.
#[must_use]
pub fn bilateral_direct(input: &Plane, sigma_s: f32, sigma_r: f32) -> Plane {
    let (w, h) = (input.width as isize, input.height as isize);
    let r = (3.0 * sigma_s).ceil() as isize;
    Plane::from_fn(input.width, input.height, |x, y| {
        let c = input.data[y * input.width + x];
        let (mut num, mut den) = (0.0f64, 0.0f64);
        for dy in -r..=r {
            for dx in -r..=r {
                let (xx, yy) = (x as isize + dx, y as isize + dy);
                if xx < 0 || yy < 0 || xx >= w || yy >= h {
                    continue;
                }
                let v = input.data[(yy * w + xx) as usize];
                let gs = (-((dx * dx + dy * dy) as f64) / (2.0 * f64::from(sigma_s).powi(2))).exp();
                let gr = (-f64::from(v - c).powi(2) / (2.0 * f64::from(sigma_r).powi(2))).exp();
                num += gs * gr * f64::from(v);
                den += gs * gr;
            }
        }
        (num / den) as f32
    })
}
