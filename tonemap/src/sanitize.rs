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
    let mut out = img.clone();
    let report = sanitize_in_place(&mut out);
    (out, report)
}

/// [`sanitize()`] without a copy: applies the dirty-input rule to `img` itself. One
/// row-parallel pass; a second one only when the image holds +Inf (whose replacement, the
/// channel's largest finite value, is known only after the first pass).
pub fn sanitize_in_place(img: &mut Rgb32FImage) -> SanitizeReport {
    let chunk = (img.width() as usize * 3).max(3);
    let rows: Vec<_> = img.par_chunks_mut(chunk).map(clean_row).collect();
    let (report, max_finite) = merge_rows(&rows);
    if report.positive_infinite > 0 {
        replace_infinities(img, chunk, max_finite);
    }
    report
}

/// The dirty-input rule on one row: NaN and negatives become 0, +Inf is counted and left
/// for [`replace_infinities`]. Returns the row's report and largest finite value per
/// channel.
pub(crate) fn clean_row(row: &mut [f32]) -> (SanitizeReport, [f32; 3]) {
    // Without branches, over lanes of four pixels (lane `i` holds channel `i % 3`), so the
    // loop vectorises; the counts per lane fit u32 (a lane sees a quarter of a row).
    const L: usize = 12;
    let (mut nan, mut neg, mut inf) = ([0u32; L], [0u32; L], [0u32; L]);
    let mut mx = [0.0f32; L];
    let mut clean = |v: &mut f32, i: usize| {
        let x = *v;
        let (is_nan, is_neg) = (x.is_nan(), x < 0.0);
        let is_inf = x == f32::INFINITY;
        nan[i] += u32::from(is_nan);
        neg[i] += u32::from(is_neg);
        inf[i] += u32::from(is_inf);
        let out = if is_nan || is_neg { 0.0 } else { x };
        *v = out;
        // `out` is never NaN here: a plain comparison (the hardware's max) suffices.
        let fin = if is_inf { 0.0 } else { out };
        mx[i] = if fin > mx[i] { fin } else { mx[i] };
    };
    let mut chunks = row.chunks_exact_mut(L);
    for ch in &mut chunks {
        for (i, v) in ch.iter_mut().enumerate() {
            clean(v, i);
        }
    }
    for (i, v) in chunks.into_remainder().iter_mut().enumerate() {
        clean(v, i);
    }
    let sum = |a: [u32; L]| a.iter().map(|&n| u64::from(n)).sum::<u64>();
    let r = SanitizeReport {
        nan: sum(nan),
        negative: sum(neg),
        positive_infinite: sum(inf),
    };
    let channel = |c: usize| (c..L).step_by(3).fold(0.0f32, |m, i| m.max(mx[i]));
    (r, [channel(0), channel(1), channel(2)])
}

/// Sums the per-row reports and takes the maximum of the per-row maxima, in row order
/// (max is order-independent, so the result does not depend on the thread count).
pub(crate) fn merge_rows(rows: &[(SanitizeReport, [f32; 3])]) -> (SanitizeReport, [f32; 3]) {
    rows.iter().fold(
        (SanitizeReport::default(), [0.0f32; 3]),
        |(a, m), (b, mb)| {
            (
                SanitizeReport {
                    nan: a.nan + b.nan,
                    negative: a.negative + b.negative,
                    positive_infinite: a.positive_infinite + b.positive_infinite,
                },
                std::array::from_fn(|c| m[c].max(mb[c])),
            )
        },
    )
}

fn replace_infinities(img: &mut Rgb32FImage, chunk: usize, max_finite: [f32; 3]) {
    img.par_chunks_mut(chunk).for_each(|row| {
        for px in row.chunks_exact_mut(3) {
            for (c, v) in px.iter_mut().enumerate() {
                if v.is_infinite() {
                    *v = max_finite[c];
                }
            }
        }
    });
}

/// A sanitized image with its luminance and statistics, computed in one pass, so that the
/// CLI and the operators never clean the same image twice.
#[derive(Clone, Debug)]
pub struct CleanImage {
    /// The image after the dirty-input rule.
    pub image: Rgb32FImage,
    /// Its luminance (Rec. 709 weights, [`crate::LUMINANCE_WEIGHTS`]).
    pub luminance: Plane,
    /// What the dirty-input rule changed.
    pub report: SanitizeReport,
    /// Smallest positive and largest luminance (`None` if no pixel is lit).
    pub positive_range: Option<(f32, f32)>,
    /// Number of pixels of zero luminance.
    pub zero_pixels: u64,
}

impl CleanImage {
    /// Cleans a copy of `img`.
    #[must_use]
    pub fn new(img: &Rgb32FImage) -> Self {
        Self::from_image(img.clone())
    }

    /// Cleans `img` in place (no copy), computing its luminance in the same pass.
    #[must_use]
    pub fn from_image(mut img: Rgb32FImage) -> Self {
        let (w, h) = (img.width() as usize, img.height() as usize);
        let chunk = (w * 3).max(3);
        let mut lum = Plane::filled(w, h, 0.0);
        // One pass per row: the dirty-input rule, the luminance and its statistics.
        let rows: Vec<_> = img
            .par_chunks_mut(chunk)
            .zip(lum.data.par_chunks_mut(w.max(1)))
            .map(|(row, out)| {
                let r = clean_row(row);
                (r, fill_luminance(row, out))
            })
            .collect();
        let cleaned: Vec<_> = rows.iter().map(|r| r.0).collect();
        let (report, max_finite) = merge_rows(&cleaned);
        let (positive_range, zero_pixels) = if report.positive_infinite > 0 {
            replace_infinities(&mut img, chunk, max_finite);
            lum = Plane::luminance_of(&img);
            let zeros = lum
                .data
                .par_chunks(w.max(1))
                .map(|row| row.iter().filter(|&&v| v <= 0.0).count() as u64)
                .sum();
            (positive_range(&lum), zeros)
        } else {
            merge_luminance_rows(rows.iter().map(|r| r.1))
        };
        Self {
            image: img,
            luminance: lum,
            report,
            positive_range,
            zero_pixels,
        }
    }

    /// Its statistics without the pixels.
    #[must_use]
    pub fn stats(&self) -> CleanStats {
        CleanStats {
            report: self.report,
            positive_range: self.positive_range,
            zero_pixels: self.zero_pixels,
        }
    }

    /// The dynamic range (`None` if no pixel has positive luminance).
    #[must_use]
    pub fn dynamic_range(&self) -> Option<DynamicRange> {
        self.stats().dynamic_range()
    }
}

/// The smallest positive and largest luminance (as `plane::positive_range` gives them) and
/// the number of unlit pixels from the rows' [`fill_luminance`] results.
pub(crate) fn merge_luminance_rows(
    rows: impl Iterator<Item = (f32, f32, u64)>,
) -> (Option<(f32, f32)>, u64) {
    let (lo, hi, zeros) = rows.fold(
        (f32::INFINITY, 0.0f32, 0u64),
        |(lo, hi, z), (rlo, rhi, rz)| (lo.min(rlo), hi.max(rhi), z + rz),
    );
    ((hi > 0.0 && lo.is_finite()).then_some((lo, hi)), zeros)
}

/// What [`CleanImage`] knows of an image besides its pixels and luminance (also given by
/// [`crate::Operator::apply_rows_srgb8`], which keeps neither).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct CleanStats {
    /// What the dirty-input rule changed.
    pub report: SanitizeReport,
    /// Smallest positive and largest luminance (`None` if no pixel is lit).
    pub positive_range: Option<(f32, f32)>,
    /// Number of pixels of zero luminance.
    pub zero_pixels: u64,
}

impl CleanStats {
    /// The dynamic range (`None` if no pixel has positive luminance).
    #[must_use]
    pub fn dynamic_range(&self) -> Option<DynamicRange> {
        let (lo, hi) = self.positive_range?;
        let ratio = f64::from(hi) / f64::from(lo);
        Some(DynamicRange {
            min_positive: lo,
            max: hi,
            ratio,
            orders_of_magnitude: ratio.log10(),
            zero_pixels: self.zero_pixels,
        })
    }
}

/// Fills `out` with the luminance of `rgb_row` and returns its smallest positive value
/// (infinite if none), its largest value (from 0) and how many are not positive.
pub(crate) fn fill_luminance(rgb_row: &[f32], out: &mut [f32]) -> (f32, f32, u64) {
    luminance_into(rgb_row, out);
    luminance_row_stats(out)
}

/// Fills `out` with the luminance of `rgb_row`.
pub(crate) fn luminance_into(rgb_row: &[f32], out: &mut [f32]) {
    for (o, px) in out.iter_mut().zip(rgb_row.chunks_exact(3)) {
        *o = crate::plane::luminance([px[0], px[1], px[2]]);
    }
}

/// The smallest positive value of a row of luminances (infinite if none), its largest
/// value (from 0) and how many are not positive.
pub(crate) fn luminance_row_stats(lum: &[f32]) -> (f32, f32, u64) {
    // In eight lanes without branches (value `x` into lane `x % 8`), so the loop vectorises
    // (one branch per pixel was a twentieth of a tone-mapping run); the smallest and largest
    // of the lanes are those of the row, NaN never taken.
    const L: usize = 8;
    let (mut lo, mut hi, mut zeros) = ([f32::INFINITY; L], [0.0f32; L], [0u32; L]);
    let (whole, rest) = lum.as_chunks::<L>();
    let mut last = [0.0f32; L];
    last[..rest.len()].copy_from_slice(rest);
    // The rest in a last chunk padded with zeros, which count as unlit: taken off after.
    for c in whole.iter().chain([&last]) {
        for i in 0..L {
            let v = c[i];
            // `&`, not `&&`: both comparisons made, no branch.
            lo[i] = if (v > 0.0) & (v < lo[i]) { v } else { lo[i] };
            hi[i] = if v > hi[i] { v } else { hi[i] };
            zeros[i] += u32::from(v <= 0.0);
        }
    }
    for z in &mut zeros[rest.len()..] {
        *z -= 1;
    }
    (
        lo.into_iter().fold(f32::INFINITY, f32::min),
        hi.into_iter().fold(0.0, f32::max),
        zeros.iter().map(|&n| u64::from(n)).sum(),
    )
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
    CleanImage::new(img).dynamic_range()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The lanes' statistics are those of one pass over the row in order: on rows of every
    /// length up to 40 cut from values with zeros of both signs, negatives, NaN, infinity
    /// and subnormals.
    #[test]
    fn luminance_row_stats_equal_one_pass_in_order() {
        let values = [
            0.5,
            0.0,
            -0.0,
            -2.0,
            f32::NAN,
            3.0,
            1e-40,
            f32::INFINITY,
            0.25,
            7.0,
            1e-3,
            -f32::NAN,
        ];
        let row: Vec<f32> = (0..40)
            .map(|i| values[(i * 7 + i / 5) % values.len()])
            .collect();
        for start in 0..row.len() {
            let part = &row[start..];
            let (mut lo, mut hi, mut zeros) = (f32::INFINITY, 0.0f32, 0u64);
            for &v in part {
                if v > 0.0 && v < lo {
                    lo = v;
                }
                if v > hi {
                    hi = v;
                }
                zeros += u64::from(v <= 0.0);
            }
            let got = luminance_row_stats(part);
            assert_eq!(
                (got.0.to_bits(), got.1.to_bits(), got.2),
                (lo.to_bits(), hi.to_bits(), zeros),
                "from {start}"
            );
        }
    }
}
