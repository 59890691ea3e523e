//! Global curves and their inverses (HDR VolVis Sec. 4, last paragraph: "for global tone
//! mapping methods, the operators are one-to-one mapping functions ... the pixel values in
//! a tone mapped image can be mapped back to the original high dynamic range").

use image::Rgb32FImage;
use rayon::prelude::*;

use crate::ops::drago::drago_curve;
use crate::ops::reinhard::{reinhard_curve, reinhard_curve_inverse};
use crate::plane::{Plane, luminance};

/// Where [`GlobalCurve::luminance_curve`] sends the recoloured image (generic over the
/// curve, so each curve's loop is compiled on its own and vectorises). The curve maps a
/// row's luminances at once: `curve(first pixel, input row, output row)`.
trait CurveOutput {
    type Out;
    fn run<F: Fn(usize, &[f32], &mut [f32]) + Sync + 'static>(self, curve: F) -> Self::Out;
}

/// The floating-point display image ([`crate::plane::recolour_with`]).
struct ToImage<'a>(&'a Rgb32FImage, &'a Plane, f32);

impl CurveOutput for ToImage<'_> {
    type Out = Rgb32FImage;
    fn run<F: Fn(usize, &[f32], &mut [f32]) + Sync + 'static>(self, curve: F) -> Rgb32FImage {
        crate::plane::recolour_by(self.0, self.1, self.2, curve)
    }
}

/// Its 8-bit sRGB codes ([`crate::plane::recolour_with_srgb8`]).
struct ToSrgb8<'a>(&'a Rgb32FImage, &'a Plane, f32);

impl CurveOutput for ToSrgb8<'_> {
    type Out = Vec<u8>;
    fn run<F: Fn(usize, &[f32], &mut [f32]) + Sync + 'static>(self, curve: F) -> Vec<u8> {
        crate::plane::recolour_by_srgb8(self.0, self.1, self.2, curve)
    }
}

/// The second pass over the rows of a source: each row's codes
/// ([`crate::rows::recolour_codes`]).
struct RowCodesOut(f32);

impl CurveOutput for RowCodesOut {
    type Out = crate::rows::RowCodes;
    fn run<F: Fn(usize, &[f32], &mut [f32]) + Sync + 'static>(
        self,
        curve: F,
    ) -> crate::rows::RowCodes {
        crate::rows::recolour_codes(self.0, curve)
    }
}

/// Drago's curve per pixel in f32: the per-image constants resolved once in f64, the
/// logarithms and the power by `fastmath`'s polynomials.
fn drago_f32(
    adaptation: f64,
    scaled_max: f64,
    bias: f64,
    max_display_luminance: f64,
) -> impl Fn(f32) -> f32 + Copy + Sync {
    let inv_adapt = (1.0 / adaptation) as f32;
    let inv_max = (1.0 / scaled_max) as f32;
    let exponent = (bias.ln() / 0.5f64.ln()) as f32;
    let coef = (max_display_luminance * 0.01 / (scaled_max + 1.0).log10()) as f32;
    move |l: f32| {
        use crate::fastmath::{ln, ln_1p, pow};
        let x = l * inv_adapt;
        coef * ln_1p(x) / ln(2.0 + 8.0 * pow(x * inv_max, exponent))
    }
}

/// A luminance curve tabulated at every 2^-10 of an octave (f32 bit patterns whose low 13
/// bits are zero) over the 40 octaves below the image's largest luminance, read by linear
/// interpolation within the octave's step (the value then moves linearly with the bit
/// pattern). For Drago's curve the interpolation error is about 1e-7 of the value (the
/// second derivative in `ln L` is of order one: `(2^-10)^2 / 8`); luminances outside the
/// table are evaluated directly.
struct CurveTable {
    /// The bit pattern of the first node.
    base: u32,
    values: Vec<f32>,
}

impl CurveTable {
    const SHIFT: u32 = 13;
    const OCTAVES: i32 = 40;

    fn new(f: &(impl Fn(f32) -> f32 + Sync), hi: f32) -> Self {
        if !(hi.is_finite() && hi > 0.0) {
            return Self {
                base: 0,
                values: Vec::new(),
            };
        }
        let lo = (hi * 2f32.powi(-Self::OCTAVES)).max(f32::MIN_POSITIVE);
        let first = lo.to_bits() >> Self::SHIFT;
        // Past the bucket of `hi`: its right end too.
        let last = (hi.to_bits() >> Self::SHIFT) + 1;
        // In parallel (some 40 000 curve values: a millisecond between the passes).
        let values = (first..=last)
            .into_par_iter()
            .map(|k| f(f32::from_bits(k << Self::SHIFT)))
            .collect();
        Self {
            base: first << Self::SHIFT,
            values,
        }
    }

    /// [`CurveTable::eval`] of every value of `lin` into `out` (the same length): eight
    /// at a time with AVX2 gathers where the CPU has them and all eight lie in the table,
    /// the same values.
    fn eval_row(&self, lin: &[f32], out: &mut [f32], f: &impl Fn(f32) -> f32) {
        let mut done = 0;
        #[cfg(target_arch = "x86_64")]
        if self.values.len() >= 2 && std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: AVX2 detected just above.
            #[allow(unsafe_code)]
            unsafe {
                done = self.eval_lanes_avx2(lin, out, f);
            }
        }
        for (o, &l) in out[done..].iter_mut().zip(&lin[done..]) {
            *o = self.eval(l, f);
        }
    }

    /// [`CurveTable::eval_row`]'s leading multiple of eight values: the same steps in
    /// eight lanes (the subtraction and the product rounded on their own, as `eval` does);
    /// eight values of which one is outside the table go through `eval`. Returns how many
    /// values it did.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    #[allow(unsafe_code)]
    fn eval_lanes_avx2(&self, lin: &[f32], out: &mut [f32], f: &impl Fn(f32) -> f32) -> usize {
        use std::arch::x86_64::{
            _mm256_add_epi32, _mm256_add_ps, _mm256_and_si256, _mm256_castps_si256,
            _mm256_cmpgt_epi32, _mm256_cvtepi32_ps, _mm256_i32gather_ps, _mm256_loadu_ps,
            _mm256_movemask_epi8, _mm256_mul_ps, _mm256_or_si256, _mm256_set1_epi32,
            _mm256_set1_ps, _mm256_srli_epi32, _mm256_storeu_ps, _mm256_sub_epi32, _mm256_sub_ps,
            _mm256_xor_si256,
        };
        let n = lin.len().min(out.len()) / 8 * 8;
        let sign = _mm256_set1_epi32(i32::MIN);
        let base = _mm256_set1_epi32(self.base as i32);
        // Unsigned comparisons as signed ones of values with the sign bit flipped.
        let base_flipped = _mm256_xor_si256(base, sign);
        let last = _mm256_set1_epi32((self.values.len() - 2) as i32);
        let mask = _mm256_set1_epi32((1 << Self::SHIFT) - 1);
        let scale = _mm256_set1_ps(1.0 / (1u32 << Self::SHIFT) as f32);
        let one = _mm256_set1_epi32(1);
        for (l, o) in lin[..n]
            .as_chunks::<8>()
            .0
            .iter()
            .zip(out[..n].as_chunks_mut::<8>().0)
        {
            // SAFETY: `l` and `o` are 8 floats; the gathers run only when every index and
            // the one after it lie in `values` (`i <= len - 2`).
            unsafe {
                let b = _mm256_castps_si256(_mm256_loadu_ps(l.as_ptr()));
                let off = _mm256_sub_epi32(b, base);
                let i = _mm256_srli_epi32::<{ Self::SHIFT as i32 }>(off);
                // Outside: `b < base` or `i > len - 2` (unsigned; `i` < 2^19 is positive).
                let below = _mm256_cmpgt_epi32(base_flipped, _mm256_xor_si256(b, sign));
                let past = _mm256_cmpgt_epi32(i, last);
                if _mm256_movemask_epi8(_mm256_or_si256(below, past)) != 0 {
                    for (o, &l) in o.iter_mut().zip(l) {
                        *o = self.eval(l, f);
                    }
                    continue;
                }
                let frac = _mm256_mul_ps(_mm256_cvtepi32_ps(_mm256_and_si256(off, mask)), scale);
                let a = _mm256_i32gather_ps::<4>(self.values.as_ptr(), i);
                let c = _mm256_i32gather_ps::<4>(self.values.as_ptr(), _mm256_add_epi32(i, one));
                let v = _mm256_add_ps(a, _mm256_mul_ps(_mm256_sub_ps(c, a), frac));
                _mm256_storeu_ps(o.as_mut_ptr(), v);
            }
        }
        n
    }

    #[inline(always)]
    fn eval(&self, l: f32, f: &impl Fn(f32) -> f32) -> f32 {
        let b = l.to_bits();
        // Zero, negatives (sign bit set: huge offsets), NaN and values outside: direct.
        let off = b.wrapping_sub(self.base);
        let i = (off >> Self::SHIFT) as usize;
        if b < self.base || i + 1 >= self.values.len() {
            return f(l);
        }
        let frac = (off & ((1 << Self::SHIFT) - 1)) as f32 * (1.0 / (1u32 << Self::SHIFT) as f32);
        let (a, c) = (self.values[i], self.values[i + 1]);
        a + (c - a) * frac
    }
}

/// A global operator resolved for one image: its parameters and the image statistics it
/// uses. Keep it with a tone-mapped picture to recover HDR values later.
#[derive(Clone, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub enum GlobalCurve {
    /// `Ld = scale * Lw`, per channel.
    Linear {
        /// `2^stops / white`.
        scale: f64,
    },
    /// Drago Eq. 4 on `Lw / adaptation`.
    Drago {
        /// World adaptation luminance `L_wa` divided by `2^exposure_stops`, image units.
        adaptation: f64,
        /// `L_w_max / adaptation`.
        scaled_max: f64,
        /// Bias `b`.
        bias: f64,
        /// `Ld_max` in cd/m^2.
        max_display_luminance: f64,
        /// Saturation exponent.
        saturation: f32,
    },
    /// Reinhard Eq. 2 + 4.
    Reinhard {
        /// `a / L_w_avg`.
        scale: f64,
        /// `L_white` in scaled units (may be infinite).
        white: f64,
        /// Saturation exponent.
        saturation: f32,
    },
}

impl GlobalCurve {
    /// Display luminance for world luminance `lw` (image units).
    #[must_use]
    pub fn map_luminance(&self, lw: f64) -> f64 {
        match *self {
            GlobalCurve::Linear { scale } => lw * scale,
            GlobalCurve::Drago {
                adaptation,
                scaled_max,
                bias,
                max_display_luminance,
                ..
            } => drago_curve(lw / adaptation, scaled_max, bias, max_display_luminance),
            GlobalCurve::Reinhard { scale, white, .. } => reinhard_curve(lw * scale, white),
        }
    }

    /// World luminance for display luminance `ld`: the inverse of
    /// [`GlobalCurve::map_luminance`] (closed form for linear and Reinhard, bisection to
    /// double precision for Drago, whose curve has no closed-form inverse).
    #[must_use]
    pub fn unmap_luminance(&self, ld: f64) -> f64 {
        if ld <= 0.0 {
            return 0.0;
        }
        match *self {
            GlobalCurve::Linear { scale } => ld / scale,
            GlobalCurve::Drago {
                adaptation,
                scaled_max,
                ..
            } => {
                let limit = self.monotone_limit();
                let mut hi = if limit.is_finite() {
                    limit
                } else {
                    // Increasing everywhere searched: grow the bracket from the maximum.
                    let mut hi = scaled_max * adaptation;
                    let mut n = 0;
                    while self.map_luminance(hi) < ld && n < 200 {
                        hi *= 2.0;
                        n += 1;
                    }
                    hi
                };
                if self.map_luminance(hi) <= ld {
                    return hi;
                }
                let mut lo = 0.0;
                for _ in 0..80 {
                    let mid = 0.5 * (lo + hi);
                    if self.map_luminance(mid) < ld {
                        lo = mid;
                    } else {
                        hi = mid;
                    }
                }
                0.5 * (lo + hi)
            }
            GlobalCurve::Reinhard { scale, white, .. } => reinhard_curve_inverse(ld, white) / scale,
        }
    }

    /// The world luminance (image units) up to which the curve is strictly increasing, and
    /// so invertible: infinite for linear and Reinhard. Drago's Eq. 4 rises to a peak and
    /// then falls slightly when `L_w_max / L_wa` is large (about 1e4 and up at bias 0.85),
    /// so display values above the peak have no unique inverse; this returns the peak,
    /// found on a log grid (2,000 points from 1e-9 to 4 times the maximum) and refined by
    /// bisection on the slope.
    #[must_use]
    pub fn monotone_limit(&self) -> f64 {
        let GlobalCurve::Drago {
            adaptation,
            scaled_max,
            ..
        } = *self
        else {
            return f64::INFINITY;
        };
        let top = 4.0 * scaled_max * adaptation;
        let bottom = top * 1e-9;
        let n = 2000;
        let at = |k: usize| bottom * (top / bottom).powf(k as f64 / n as f64);
        let mut prev = self.map_luminance(at(0));
        for k in 1..=n {
            let cur = self.map_luminance(at(k));
            if cur <= prev {
                // The peak lies in [at(k-2), at(k)]: bisect on the sign of the slope.
                let (mut lo, mut hi) = (at(k.saturating_sub(2)), at(k));
                for _ in 0..80 {
                    let mid = 0.5 * (lo + hi);
                    let h = mid * 1e-7;
                    if self.map_luminance(mid + h) > self.map_luminance(mid - h) {
                        lo = mid;
                    } else {
                        hi = mid;
                    }
                }
                return lo;
            }
            prev = cur;
        }
        f64::INFINITY
    }

    /// The saturation exponent used for colour.
    #[must_use]
    pub fn saturation(&self) -> f32 {
        match *self {
            GlobalCurve::Linear { .. } => 1.0,
            GlobalCurve::Drago { saturation, .. } | GlobalCurve::Reinhard { saturation, .. } => {
                saturation
            }
        }
    }

    /// Applies the curve to a sanitized image and its luminance.
    pub(crate) fn apply_clean(&self, img: &Rgb32FImage, lum: &Plane) -> Rgb32FImage {
        if let GlobalCurve::Linear { scale } = *self {
            let s = scale as f32;
            let data = img.as_raw().par_iter().map(|v| v * s).collect();
            return Rgb32FImage::from_raw(img.width(), img.height(), data).expect("same size");
        }
        self.luminance_curve(ToImage(img, lum, self.saturation()))
    }

    /// [`GlobalCurve::apply_clean`] as 8-bit sRGB codes ([`crate::io::display_to_srgb8`] of
    /// its image, the same bytes), without the floating-point display image.
    pub(crate) fn apply_clean_srgb8(&self, img: &Rgb32FImage, lum: &Plane) -> Vec<u8> {
        if let GlobalCurve::Linear { scale } = *self {
            let s = scale as f32;
            let mut out = vec![0u8; img.as_raw().len()];
            let row = (3 * img.width() as usize).max(1);
            out.par_chunks_mut(row)
                .zip(img.as_raw().par_chunks(row))
                .for_each_init(
                    || vec![0.0f32; row],
                    |scaled, (codes, src)| {
                        for (o, v) in scaled.iter_mut().zip(src) {
                            *o = v * s;
                        }
                        crate::io::srgb8_row(&scaled[..src.len()], codes);
                    },
                );
            return out;
        }
        self.luminance_curve(ToSrgb8(img, lum, self.saturation()))
    }

    /// How the second pass over a source's rows makes each row's codes (those of
    /// [`GlobalCurve::apply_clean_srgb8`]).
    pub(crate) fn row_codes(&self) -> crate::rows::RowCodes {
        if let GlobalCurve::Linear { scale } = *self {
            return crate::rows::scale_codes(scale as f32);
        }
        self.luminance_curve(RowCodesOut(self.saturation()))
    }

    /// Runs `out` with the luminance curve of Drago or Reinhard. One fused row-parallel
    /// pass: the curve and the recolouring per pixel. The per-image constants are resolved
    /// once in f64; the per-pixel arithmetic runs in f32 (the output precision), Drago's
    /// logarithms and power by `fastmath`'s polynomials, which vectorise (agreement with
    /// `map_luminance` is tested to 1e-5 relative).
    fn luminance_curve<O: CurveOutput>(&self, out: O) -> O::Out {
        match *self {
            GlobalCurve::Drago {
                adaptation,
                scaled_max,
                bias,
                max_display_luminance,
                ..
            } => {
                let direct = drago_f32(adaptation, scaled_max, bias, max_display_luminance);
                // Read from a table of the curve (three logarithms and an exponential per
                // pixel were half of a Drago run).
                let table = CurveTable::new(&direct, (scaled_max * adaptation) as f32);
                out.run(move |_, lin, lout| table.eval_row(lin, lout, &direct))
            }
            GlobalCurve::Reinhard { scale, white, .. } => {
                let scale = scale as f32;
                let inv_w2 = if white.is_finite() {
                    (1.0 / (white * white)) as f32
                } else {
                    0.0
                };
                out.run(crate::plane::curve_rows(move |l| {
                    let x = l * scale;
                    x * (1.0 + x * inv_w2) / (1.0 + x)
                }))
            }
            GlobalCurve::Linear { .. } => unreachable!("Linear maps channels: the callers"),
        }
    }

    /// Recovers HDR values from a display-linear image made by this curve.
    ///
    /// Colour is inverted exactly: with `C_d = (C/L)^s L_d`, the display luminance is
    /// `L_d = Y(C_d^(1/s))^s` and `C = L (C_d / L_d)^(1/s)`. Precision is limited by what
    /// the display image kept (clipping above 1, 8-bit quantisation). Non-finite or
    /// negative display values are treated as 0.
    #[must_use]
    pub fn invert(&self, display: &Rgb32FImage) -> Rgb32FImage {
        let (w, h) = (display.width(), display.height());
        let inv_s = 1.0 / f64::from(self.saturation());
        let data: Vec<f32> = display
            .as_raw()
            .par_chunks(3)
            .flat_map_iter(|px| {
                let c: [f64; 3] = std::array::from_fn(|i| {
                    let v = f64::from(px[i]);
                    if v.is_finite() && v > 0.0 { v } else { 0.0 }
                });
                let out: [f32; 3] = if let GlobalCurve::Linear { scale } = *self {
                    std::array::from_fn(|i| (c[i] / scale) as f32)
                } else {
                    let lifted = c.map(|v| v.powf(inv_s) as f32);
                    let ld = f64::from(luminance(lifted)).powf(1.0 / inv_s);
                    if ld > 0.0 {
                        let lw = self.unmap_luminance(ld);
                        std::array::from_fn(|i| (lw * (c[i] / ld).powf(inv_s)) as f32)
                    } else {
                        [0.0; 3]
                    }
                };
                out
            })
            .collect();
        Rgb32FImage::from_raw(w, h, data).expect("same size")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The tabulated Drago curve against the curve itself (the f64 formula): within 1e-6
    /// of the value over the table's 40 octaves (interpolation and the direct f32
    /// evaluation's own error), the direct evaluation outside them, exact at the nodes.
    #[test]
    fn the_curve_table_follows_the_curve() {
        let (adapt, max) = (0.37f64, 5.0e4f64);
        let (bias, ld_max) = (0.85f64, 100.0f64);
        let scaled_max = max / adapt;
        let direct = drago_f32(adapt, scaled_max, bias, ld_max);
        let table = CurveTable::new(&direct, max as f32);
        assert!(!table.values.is_empty());
        let mut worst = 0.0f64;
        for i in 0..200_000 {
            // 45 octaves below the maximum up to it.
            let l = (max * 2f64.powf(-45.0 * f64::from(i) / 199_999.0)) as f32;
            let got = f64::from(table.eval(l, &direct));
            let want =
                crate::ops::drago::drago_curve(f64::from(l) / adapt, scaled_max, bias, ld_max);
            worst = worst.max((got - want).abs() / want);
        }
        assert!(worst < 1e-6, "worst relative error {worst:e}");
        for k in [0usize, 1, 977, table.values.len() - 2] {
            let node = f32::from_bits(table.base + ((k as u32) << CurveTable::SHIFT));
            assert_eq!(table.eval(node, &direct).to_bits(), direct(node).to_bits());
        }
        for l in [0.0f32, -1.0, f32::NAN, 1e-30, 2.0 * max as f32] {
            let (a, b) = (table.eval(l, &direct), direct(l));
            assert!(a.to_bits() == b.to_bits(), "{l}: {a} vs {b}");
        }
    }

    /// A row through the table (eight lanes where the CPU has AVX2) gives each value's
    /// `eval`, bit for bit: values in the table, its first and last nodes and just past
    /// them, and any bit pattern (NaN, infinities, negatives, subnormals), in runs of eight
    /// that are all inside, all outside or mixed, in rows whose lengths are not multiples
    /// of eight.
    #[test]
    fn table_rows_equal_the_tables_values() {
        let (adapt, max) = (0.37f64, 5.0e4f64);
        let direct = drago_f32(adapt, max / adapt, 0.85, 100.0);
        let table = CurveTable::new(&direct, max as f32);
        let first = table.base;
        let last = table.base + ((table.values.len() as u32 - 1) << CurveTable::SHIFT);
        let mut next = crate::xorshift(0x9e37_79b9_7f4a_7c15);
        let mut lin = Vec::new();
        for run in 0..3000 {
            for _ in 0..8 {
                let r = next();
                let inside = f32::from_bits(first + (r >> 32) as u32 % (last - first));
                lin.push(match run % 3 {
                    0 => inside,
                    1 => f32::from_bits(r as u32),
                    _ if r.is_multiple_of(5) => f32::from_bits(r as u32),
                    _ => inside,
                });
            }
        }
        for b in [first, first + 1, last - 1, last, last + 1, first - 1] {
            lin.push(f32::from_bits(b));
        }
        lin.extend([
            0.0,
            -0.0,
            f32::INFINITY,
            -f32::INFINITY,
            f32::NAN,
            max as f32,
        ]);
        for len in [lin.len(), 13, 7, 0] {
            let mut got = vec![0.0f32; len];
            table.eval_row(&lin[..len], &mut got, &direct);
            for (g, &l) in got.iter().zip(&lin) {
                assert_eq!(g.to_bits(), table.eval(l, &direct).to_bits(), "{l:e}");
            }
        }
    }
}
