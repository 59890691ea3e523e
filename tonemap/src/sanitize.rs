//! The dirty-input rule and the dynamic range of an image.
//!
//! Real HDR files are dirty: OpenEXR photographs carry small negative values (the Desk
//! photograph has 4,837 pixels of negative luminance), and renderers can leave NaN or
//! infinities. Every operator first applies this rule, per colour channel:
//!
//! | input value | becomes | why |
//! |---|---|---|
//! | NaN | 0 | no information; black is the neutral choice |
//! | negative (including -Inf) | 0 | light is not negative; negatives are noise around zero |
//! | +Inf | the largest finite value of that channel in the image | a saturated highlight |
//!
//! Pixels whose luminance is then 0 stay black in every operator's output (they are
//! excluded from log-averages, so a black background never darkens or brightens the
//! rest), and no operator outputs NaN.

use image::Rgb32FImage;
use rayon::prelude::*;

use crate::plane::{Plane, positive_range};

/// How many channel values the dirty-input rule changed.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct SanitizeReport {
    /// NaN channel values set to 0.
    pub nan: u64,
    /// Negative channel values (including -Inf) set to 0.
    pub negative: u64,
    /// +Inf channel values set to the channel's largest finite value.
    pub positive_infinite: u64,
}

impl SanitizeReport {
    /// Total number of channel values changed.
    #[must_use]
    pub fn total(&self) -> u64 {
        self.nan + self.negative + self.positive_infinite
    }
}

/// Applies the dirty-input rule (see the module docs) and reports what it changed.
#[must_use]
pub fn sanitize(img: &Rgb32FImage) -> (Rgb32FImage, SanitizeReport) {
    let raw = img.as_raw();
    // Largest finite value per channel (max is order-independent, so deterministic).
    let max_finite: [f32; 3] = std::array::from_fn(|c| {
        raw.par_iter()
            .skip(c)
            .step_by(3)
            .copied()
            .filter(|v| v.is_finite())
            .reduce(|| 0.0, f32::max)
    });
    let chunk = (img.width() as usize * 3).max(3);
    let mut out = raw.to_vec();
    let reports: Vec<SanitizeReport> = out
        .par_chunks_mut(chunk)
        .map(|row| {
            let mut r = SanitizeReport::default();
            for (i, v) in row.iter_mut().enumerate() {
                if v.is_nan() {
                    *v = 0.0;
                    r.nan += 1;
                } else if *v < 0.0 {
                    *v = 0.0;
                    r.negative += 1;
                } else if v.is_infinite() {
                    *v = max_finite[i % 3];
                    r.positive_infinite += 1;
                }
            }
            r
        })
        .collect();
    let report = reports
        .iter()
        .fold(SanitizeReport::default(), |a, b| SanitizeReport {
            nan: a.nan + b.nan,
            negative: a.negative + b.negative,
            positive_infinite: a.positive_infinite + b.positive_infinite,
        });
    let img = Rgb32FImage::from_raw(img.width(), img.height(), out).expect("same size");
    (img, report)
}

/// The dynamic range of an image as the HDR VolVis paper reports it: the ratio of the
/// largest to the smallest non-zero luminance (after the dirty-input rule).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct DynamicRange {
    /// Smallest positive luminance (same unit as the image, e.g. cd/m^2 or relative).
    pub min_positive: f32,
    /// Largest luminance.
    pub max: f32,
    /// `max / min_positive` (e.g. 1e5 reads "10^5:1").
    pub ratio: f64,
    /// `log10(ratio)`: orders of magnitude.
    pub orders_of_magnitude: f64,
    /// Number of pixels with zero luminance (excluded from the minimum).
    pub zero_pixels: u64,
}

/// Dynamic range of `img` (`None` if no pixel has positive luminance).
#[must_use]
pub fn dynamic_range(img: &Rgb32FImage) -> Option<DynamicRange> {
    let (clean, _) = sanitize(img);
    let lum = Plane::luminance_of(&clean);
    let (lo, hi) = positive_range(&lum)?;
    let ratio = f64::from(hi) / f64::from(lo);
    let zero_pixels = lum.data.iter().filter(|&&v| v <= 0.0).count() as u64;
    Some(DynamicRange {
        min_positive: lo,
        max: hi,
        ratio,
        orders_of_magnitude: ratio.log10(),
        zero_pixels,
    })
}
