//! A single-channel `f32` image (luminance, log luminance) and the filters the operators share.
//!
//! Every loop runs in parallel over rows with rayon; each output value is computed from its
//! inputs in a fixed order, so results are bit-identical on any number of threads.

use image::Rgb32FImage;
use rayon::prelude::*;

/// Rec. 709 / sRGB luminance weights of linear R, G, B (the Y row of the sRGB-to-XYZ matrix).
pub const LUMINANCE_WEIGHTS: [f32; 3] = [0.2126, 0.7152, 0.0722];

/// Luminance Y of one linear-sRGB pixel (Rec. 709 weights).
#[must_use]
#[inline]
pub fn luminance(rgb: [f32; 3]) -> f32 {
    LUMINANCE_WEIGHTS[0] * rgb[0] + LUMINANCE_WEIGHTS[1] * rgb[1] + LUMINANCE_WEIGHTS[2] * rgb[2]
}

/// A row-major single-channel image.
#[derive(Clone, Debug, PartialEq)]
pub struct Plane {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// `width * height` values, row by row, top row first.
    pub data: Vec<f32>,
}

impl Plane {
    /// A plane filled with `value`.
    #[must_use]
    pub fn filled(width: usize, height: usize, value: f32) -> Self {
        Self {
            width,
            height,
            data: vec![value; width * height],
        }
    }

    /// A plane from a function of (x, y).
    #[must_use]
    pub fn from_fn(width: usize, height: usize, f: impl Fn(usize, usize) -> f32 + Sync) -> Self {
        let mut data = vec![0.0; width * height];
        if width > 0 {
            data.par_chunks_mut(width).enumerate().for_each(|(y, row)| {
                for (x, v) in row.iter_mut().enumerate() {
                    *v = f(x, y);
                }
            });
        }
        Self {
            width,
            height,
            data,
        }
    }

    /// The luminance plane of a linear RGB image.
    #[must_use]
    pub fn luminance_of(img: &Rgb32FImage) -> Self {
        let (w, h) = (img.width() as usize, img.height() as usize);
        let raw = img.as_raw();
        let mut data = vec![0.0; w * h];
        if w > 0 {
            data.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
                let src = &raw[y * w * 3..(y + 1) * w * 3];
                for (x, v) in row.iter_mut().enumerate() {
                    *v = luminance([src[3 * x], src[3 * x + 1], src[3 * x + 2]]);
                }
            });
        }
        Self {
            width: w,
            height: h,
            data,
        }
    }

    /// Value at (x, y), coordinates clamped to the edge.
    #[must_use]
    #[inline]
    pub fn at_clamped(&self, x: isize, y: isize) -> f32 {
        let xc = x.clamp(0, self.width as isize - 1) as usize;
        let yc = y.clamp(0, self.height as isize - 1) as usize;
        self.data[yc * self.width + xc]
    }

    /// Applies `f` to every value (in parallel).
    #[must_use]
    pub fn map(&self, f: impl Fn(f32) -> f32 + Sync) -> Self {
        Self {
            width: self.width,
            height: self.height,
            data: self.data.par_iter().map(|&v| f(v)).collect(),
        }
    }

    /// Minimum and maximum value (NaN-free input assumed).
    #[must_use]
    pub fn min_max(&self) -> (f32, f32) {
        self.data
            .iter()
            .fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), &v| {
                (lo.min(v), hi.max(v))
            })
    }

    /// Gaussian blur with standard deviation `sigma_px` (separable, kernel truncated at
    /// 3 sigma, edges clamped). `sigma_px <= 0` returns a copy.
    #[must_use]
    pub fn gaussian_blur(&self, sigma_px: f32) -> Self {
        if sigma_px <= 0.0 || self.data.is_empty() {
            return self.clone();
        }
        let kernel = gaussian_kernel(sigma_px);
        let tmp = self.convolve_rows(&kernel);
        tmp.convolve_columns(&kernel)
    }

    /// Horizontal convolution with a symmetric odd kernel, edges clamped.
    fn convolve_rows(&self, kernel: &[f32]) -> Self {
        let (w, h) = (self.width, self.height);
        let r = kernel.len() / 2;
        let mut out = vec![0.0f32; w * h];
        out.par_chunks_mut(w).enumerate().for_each(|(y, orow)| {
            let row = &self.data[y * w..(y + 1) * w];
            // Padded copy of the row so the inner loop has no branches.
            let mut padded = Vec::with_capacity(w + 2 * r);
            padded.extend(std::iter::repeat_n(row[0], r));
            padded.extend_from_slice(row);
            padded.extend(std::iter::repeat_n(row[w - 1], r));
            for (x, o) in orow.iter_mut().enumerate() {
                let win = &padded[x..x + kernel.len()];
                let mut acc = 0.0f32;
                for (k, v) in kernel.iter().zip(win) {
                    acc += k * v;
                }
                *o = acc;
            }
        });
        Self {
            width: w,
            height: h,
            data: out,
        }
    }

    /// Vertical convolution with a symmetric odd kernel, edges clamped (row-wise
    /// accumulation, so the inner loop runs along contiguous memory).
    fn convolve_columns(&self, kernel: &[f32]) -> Self {
        let (w, h) = (self.width, self.height);
        let r = kernel.len() as isize / 2;
        let mut out = vec![0.0f32; w * h];
        out.par_chunks_mut(w).enumerate().for_each(|(y, orow)| {
            for (i, &k) in kernel.iter().enumerate() {
                let ys = (y as isize + i as isize - r).clamp(0, h as isize - 1) as usize;
                let src = &self.data[ys * w..(ys + 1) * w];
                for (o, s) in orow.iter_mut().zip(src) {
                    *o += k * s;
                }
            }
        });
        Self {
            width: w,
            height: h,
            data: out,
        }
    }

    /// Box-average down-sampling by an integer factor (the last block may be partial).
    #[must_use]
    pub fn downsample_box(&self, factor: usize) -> Self {
        let factor = factor.max(1);
        let nw = self.width.div_ceil(factor);
        let nh = self.height.div_ceil(factor);
        Self::from_fn(nw, nh, |x, y| {
            let (x0, y0) = (x * factor, y * factor);
            let x1 = (x0 + factor).min(self.width);
            let y1 = (y0 + factor).min(self.height);
            let mut acc = 0.0f64;
            for yy in y0..y1 {
                for xx in x0..x1 {
                    acc += f64::from(self.data[yy * self.width + xx]);
                }
            }
            (acc / ((x1 - x0) * (y1 - y0)) as f64) as f32
        })
    }

    /// Bilinear sample at continuous pixel coordinates (pixel centres at integers), edges
    /// clamped.
    #[must_use]
    #[inline]
    pub fn sample_bilinear(&self, x: f32, y: f32) -> f32 {
        let x = x.clamp(0.0, (self.width - 1) as f32);
        let y = y.clamp(0.0, (self.height - 1) as f32);
        let x0 = x.floor() as usize;
        let y0 = y.floor() as usize;
        let x1 = (x0 + 1).min(self.width - 1);
        let y1 = (y0 + 1).min(self.height - 1);
        let fx = x - x0 as f32;
        let fy = y - y0 as f32;
        let a = self.data[y0 * self.width + x0];
        let b = self.data[y0 * self.width + x1];
        let c = self.data[y1 * self.width + x0];
        let d = self.data[y1 * self.width + x1];
        (a * (1.0 - fx) + b * fx) * (1.0 - fy) + (c * (1.0 - fx) + d * fx) * fy
    }

    /// Bilinear resize to `width` x `height` (pixel-centre aligned).
    #[must_use]
    pub fn resize_bilinear(&self, width: usize, height: usize) -> Self {
        let sx = self.width as f32 / width as f32;
        let sy = self.height as f32 / height as f32;
        Self::from_fn(width, height, |x, y| {
            self.sample_bilinear((x as f32 + 0.5) * sx - 0.5, (y as f32 + 0.5) * sy - 0.5)
        })
    }
}

/// Normalised Gaussian kernel of standard deviation `sigma_px`, radius `ceil(3 sigma)`.
#[must_use]
pub fn gaussian_kernel(sigma_px: f32) -> Vec<f32> {
    let r = (3.0 * sigma_px).ceil().max(1.0) as isize;
    let mut k: Vec<f32> = (-r..=r)
        .map(|i| (-(i * i) as f32 / (2.0 * sigma_px * sigma_px)).exp())
        .collect();
    let s: f32 = k.iter().sum();
    k.iter_mut().for_each(|v| *v /= s);
    k
}

/// Replaces the luminance of `img` by `lum_out`, keeping colour ratios with a saturation
/// exponent: `C_out = (C_in / L_in)^s * L_out` (Fattal et al. 2002 Eq. 7, Durand and
/// Dorsey 2002 Sec. 5.3, Schlick 1994). Pixels with `L_in <= 0` come out black.
#[must_use]
pub fn recolour(
    img: &Rgb32FImage,
    lum_in: &Plane,
    lum_out: &Plane,
    saturation: f32,
) -> Rgb32FImage {
    recolour_by(img, lum_in, saturation, |row0, _, out| {
        out.copy_from_slice(&lum_out.data[row0..row0 + out.len()]);
    })
}

/// [`recolour`] with the output luminance given by a global curve `L_out = curve(L_in)`,
/// evaluated in the same row-parallel pass (no intermediate plane).
#[must_use]
pub fn recolour_with(
    img: &Rgb32FImage,
    lum_in: &Plane,
    saturation: f32,
    curve: impl Fn(f32) -> f32 + Sync,
) -> Rgb32FImage {
    recolour_by(img, lum_in, saturation, curve_rows(curve))
}

/// A global curve as a `lum_out` of [`recolour_row`]: the curve over a whole row first, a
/// loop without branches, which vectorises when the curve does (the `fastmath` curves).
pub(crate) fn curve_rows(curve: impl Fn(f32) -> f32) -> impl Fn(usize, &[f32], &mut [f32]) {
    move |_, lin, out| {
        for (o, &l) in out.iter_mut().zip(lin) {
            *o = curve(l);
        }
    }
}

/// [`recolour`] followed by [`fit_to_display`] on every pixel: the
/// recolouring of the local operators (Reinhard local, Durand, Fattal), whose display
/// image must lie in [0, 1] without clipping channels one by one (which changes hue).
///
/// Every output channel lies in [0, 1]; a pixel whose recoloured colour was already inside
/// the display cube is unchanged; otherwise its luminance (capped at 1) and its hue are kept
/// (see [`fit_to_display`]).
#[must_use]
pub fn recolour_in_gamut(
    img: &Rgb32FImage,
    lum_in: &Plane,
    lum_out: &Plane,
    saturation: f32,
) -> Rgb32FImage {
    let mut out = recolour(img, lum_in, lum_out, saturation);
    let w = (out.width() as usize * 3).max(3);
    out.par_chunks_mut(w).for_each(|row| {
        for px in row.chunks_exact_mut(3) {
            let fitted = fit_to_display([px[0], px[1], px[2]]);
            px.copy_from_slice(&fitted);
        }
    });
    out
}

/// Brings a linear RGB colour into the display cube [0, 1]^3 by **constant-luminance
/// desaturation towards the achromatic axis**, by the smallest amount that fits.
///
/// With `Y` the colour's luminance ([`luminance`], Rec. 709 weights, which sum to 1), the
/// result is `Y + t (C - Y)` per channel with the largest `t` in [0, 1] that puts every
/// channel in [0, 1]. Adding or removing grey leaves `Y` unchanged, and the chroma vector
/// `C - Y` only shrinks: the hue (its direction) is kept exactly, and in CIE xy the
/// chromaticity moves along the straight line towards the white point (D65). A channel
/// clip per channel would instead lower the luminance and turn the hue towards the
/// unclipped channels (an orange wood pixel whose red clips goes yellow-white; a dark pixel
/// with red and blue ratios far above 1 turns magenta).
///
/// Colours already inside the cube are returned unchanged. `Y >= 1` cannot be shown with
/// any chroma and gives white `[1, 1, 1]` (the nearest displayable luminance); `Y <= 0` or
/// NaN (in any channel) gives black. Channels below 0 (not produced by the operators, whose inputs are
/// cleaned) are handled the same way as channels above 1.
#[must_use]
pub fn fit_to_display(rgb: [f32; 3]) -> [f32; 3] {
    let in_cube = |c: f32| (0.0..=1.0).contains(&c);
    if rgb.iter().all(|&c| in_cube(c)) {
        return rgb;
    }
    let y = luminance(rgb);
    // `y > 0` is false for NaN too.
    if y.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
        return [0.0; 3];
    }
    if y >= 1.0 {
        return [1.0; 3];
    }
    let mut t = 1.0f32;
    for c in rgb {
        if c > 1.0 {
            t = t.min((1.0 - y) / (c - y));
        } else if c < 0.0 {
            t = t.min(y / (y - c));
        }
    }
    // Rounding can leave a channel a few ulps outside: clamp those (no hue change).
    rgb.map(|c| (y + t * (c - y)).clamp(0.0, 1.0))
}

/// [`recolour_with`] with the output luminances of whole rows at once (`lum_out(first
/// pixel, input row, output row)`).
pub(crate) fn recolour_by(
    img: &Rgb32FImage,
    lum_in: &Plane,
    saturation: f32,
    lum_out: impl Fn(usize, &[f32], &mut [f32]) + Sync,
) -> Rgb32FImage {
    let (w, h) = (img.width(), img.height());
    let src = img.as_raw();
    let mut out = vec![0.0f32; src.len()];
    let wu = w as usize;
    if wu > 0 {
        out.par_chunks_mut(wu * 3).enumerate().for_each_init(
            || vec![0.0f32; wu],
            |louts, (y, orow)| {
                recolour_row(src, lum_in, saturation, &lum_out, y, louts, orow);
            },
        );
    }
    Rgb32FImage::from_raw(w, h, out).expect("buffer size matches dimensions")
}

/// [`recolour_with`] straight to 8-bit sRGB codes (row-major RGB, [`crate::io::srgb8`] of
/// every value): the same bytes as [`crate::io::display_to_srgb8`] of its image, without
/// the floating-point display image (each row goes through a buffer of its own).
#[must_use]
pub fn recolour_with_srgb8(
    img: &Rgb32FImage,
    lum_in: &Plane,
    saturation: f32,
    curve: impl Fn(f32) -> f32 + Sync,
) -> Vec<u8> {
    recolour_by_srgb8(img, lum_in, saturation, curve_rows(curve))
}

/// [`recolour_with_srgb8`] with the output luminances of whole rows at once (`lum_out(first
/// pixel, input row, output row)`).
pub(crate) fn recolour_by_srgb8(
    img: &Rgb32FImage,
    lum_in: &Plane,
    saturation: f32,
    curve: impl Fn(usize, &[f32], &mut [f32]) + Sync,
) -> Vec<u8> {
    let src = img.as_raw();
    let mut out = vec![0u8; src.len()];
    let wu = img.width() as usize;
    if wu > 0 {
        out.par_chunks_mut(wu * 3).enumerate().for_each_init(
            || (vec![0.0f32; wu], vec![0.0f32; 3 * wu]),
            |(louts, orow), (y, codes)| {
                recolour_row(src, lum_in, saturation, &curve, y, louts, orow);
                crate::io::srgb8_row(orow, codes);
            },
        );
    }
    out
}

/// Row `y` of the recolouring into `orow` (`louts`: a buffer of one row of luminances).
fn recolour_row(
    src: &[f32],
    lum_in: &Plane,
    saturation: f32,
    lum_out: &impl Fn(usize, &[f32], &mut [f32]),
    y: usize,
    louts: &mut [f32],
    orow: &mut [f32],
) {
    let wu = louts.len();
    let row0 = y * wu;
    let srow = &src[row0 * 3..(row0 + wu) * 3];
    let lrow = &lum_in.data[row0..row0 + wu];
    recolour_row_of(srow, lrow, row0, saturation, lum_out, louts, orow);
}

/// [`recolour_row`] of one row given as its values `srow` and luminances `lrow`, whose first
/// pixel is pixel `row0` of the image.
pub(crate) fn recolour_row_of(
    srow: &[f32],
    lrow: &[f32],
    row0: usize,
    saturation: f32,
    lum_out: &impl Fn(usize, &[f32], &mut [f32]),
    louts: &mut [f32],
    orow: &mut [f32],
) {
    // Every pixel's output luminance first (`lum_out(first pixel, input row, output row)`),
    // whatever its input.
    lum_out(row0, lrow, louts);
    if saturation == 1.0 {
        // One factor `lout / lin` per pixel (0 where either luminance is not positive, NaN
        // included; capped so a zero channel stays 0), in a loop without branches, then
        // three products.
        for (k, &lin) in louts.iter_mut().zip(lrow) {
            let lout = *k;
            *k = if lin > 0.0 && lout > 0.0 {
                (lout / lin).min(f32::MAX)
            } else {
                0.0
            };
        }
        for (o, (s, &k)) in orow
            .chunks_exact_mut(3)
            .zip(srow.chunks_exact(3).zip(louts.iter()))
        {
            // (A select, not `s * 0`: a non-finite channel of a black pixel stays 0.)
            for c in 0..3 {
                o[c] = if k > 0.0 { s[c] * k } else { 0.0 };
            }
        }
        return;
    }
    for ((o, s), (&lin, &lout)) in orow
        .chunks_exact_mut(3)
        .zip(srow.chunks_exact(3))
        .zip(lrow.iter().zip(louts.iter()))
    {
        if lin <= 0.0 {
            o.fill(0.0);
            continue;
        }
        // `lout > 0` is false for NaN too: such a pixel comes out black.
        if lout.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
            o.fill(0.0);
            continue;
        }
        for c in 0..3 {
            o[c] = (s[c] / lin).powf(saturation) * lout;
        }
    }
}

/// Log-average (geometric mean) of the positive values inside an optional circle
/// `(cx, cy, r)` in pixels. Zero pixels (a render's empty background) are left out, so
/// they cannot drag the adaptation level down. Summed in `f64` per row, then over rows
/// in order: deterministic on any thread count. `None` when no value is positive.
#[must_use]
pub fn log_average(lum: &Plane, circle: Option<(f32, f32, f32)>) -> Option<f64> {
    let w = lum.width;
    if w == 0 {
        return None;
    }
    let rows: Vec<(f64, u64)> = lum
        .data
        .par_chunks(w)
        .enumerate()
        .map_init(
            || vec![0.0f32; w],
            |logs, (y, row)| log_sum_row(row, y, circle, logs),
        )
        .collect();
    log_average_of_rows(&rows)
}

/// The sum of the logarithms of row `y`'s positive values inside `circle` and their number
/// (`logs`: a buffer of one row). In f32 (the data's precision) over the whole row first (a
/// loop that vectorises), then summed in f64 ([`sum_logs`]).
pub(crate) fn log_sum_row(
    row: &[f32],
    y: usize,
    circle: Option<(f32, f32, f32)>,
    logs: &mut [f32],
) -> (f64, u64) {
    for (l, &v) in logs.iter_mut().zip(row) {
        *l = crate::fastmath::ln(v);
    }
    let inside = circle.map(|(cx, cy, r)| {
        move |x: usize| {
            let dx = x as f32 + 0.5 - cx;
            let dy = y as f32 + 0.5 - cy;
            // Outside only where the distance is larger (not where it is NaN).
            (dx * dx + dy * dy).partial_cmp(&(r * r)) != Some(std::cmp::Ordering::Greater)
        }
    });
    sum_logs(row, logs, inside)
}

/// The sum of `logs[x]` over the pixels `x` whose `row[x]` is positive and `inside(x)` (every
/// pixel without `inside`), and their number: four partial sums (pixel `x` into sum `x % 4`)
/// added at the end (one chain of f64 additions was a third of [`log_sum_row`]'s time).
fn sum_logs(row: &[f32], logs: &[f32], inside: Option<impl Fn(usize) -> bool>) -> (f64, u64) {
    let mut s = [0.0f64; 4];
    let mut n = 0u64;
    let (vs, v_rest) = row.as_chunks::<4>();
    let (ls, l_rest) = logs[..row.len()].as_chunks::<4>();
    // The rest in a last chunk padded with zeros (not positive: not counted).
    let (mut last_v, mut last_l) = ([0.0f32; 4], [0.0f32; 4]);
    last_v[..v_rest.len()].copy_from_slice(v_rest);
    last_l[..l_rest.len()].copy_from_slice(l_rest);
    for (vs, ls, k0) in [(vs, ls, 0), (&[last_v][..], &[last_l][..], vs.len())] {
        match &inside {
            None => add_logs(vs, ls, &mut s, &mut n),
            Some(inside) => {
                for (k, (v, l)) in vs.iter().zip(ls).enumerate() {
                    for i in 0..4 {
                        // `&`, not `&&`: no branch.
                        let keep = (v[i] > 0.0) & inside(4 * (k0 + k) + i);
                        s[i] += if keep { f64::from(l[i]) } else { 0.0 };
                        n += u64::from(keep);
                    }
                }
            }
        }
    }
    ((s[0] + s[1]) + (s[2] + s[3]), n)
}

/// [`sum_logs`]'s step over every pixel of `vs` (logarithms `ls`): lane `i` of each chunk
/// into `s[i]`, `+0.0` for a pixel not counted (so the sums are those of the scalar step).
/// Four lanes at a time with SSE2 (part of every x86-64 CPU), where the compiler's loop
/// stayed scalar.
fn add_logs(vs: &[[f32; 4]], ls: &[[f32; 4]], s: &mut [f64; 4], n: &mut u64) {
    #[cfg(all(target_arch = "x86_64", target_feature = "sse2"))]
    {
        // SAFETY: SSE2 is enabled for the whole build (as on every x86-64 target).
        #[allow(unsafe_code)]
        unsafe {
            add_logs_sse2(vs, ls, s, n);
        }
    }
    #[cfg(not(all(target_arch = "x86_64", target_feature = "sse2")))]
    for (v, l) in vs.iter().zip(ls) {
        for i in 0..4 {
            let keep = v[i] > 0.0;
            s[i] += if keep { f64::from(l[i]) } else { 0.0 };
            *n += u64::from(keep);
        }
    }
}

#[cfg(all(target_arch = "x86_64", target_feature = "sse2"))]
#[target_feature(enable = "sse2")]
fn add_logs_sse2(vs: &[[f32; 4]], ls: &[[f32; 4]], s: &mut [f64; 4], n: &mut u64) {
    use std::arch::x86_64::{
        __m128, __m128d, _mm_add_pd, _mm_and_ps, _mm_cmpgt_ps, _mm_cvtps_pd, _mm_movehl_ps,
        _mm_movemask_ps, _mm_setzero_ps,
    };
    let mut lo: __m128d = bytemuck::cast([s[0], s[1]]);
    let mut hi: __m128d = bytemuck::cast([s[2], s[3]]);
    let zero = _mm_setzero_ps();
    for (v, l) in vs.iter().zip(ls) {
        let keep = _mm_cmpgt_ps(bytemuck::cast::<[f32; 4], __m128>(*v), zero);
        // The logarithm where counted, +0.0 elsewhere.
        let kept = _mm_and_ps(bytemuck::cast::<[f32; 4], __m128>(*l), keep);
        lo = _mm_add_pd(lo, _mm_cvtps_pd(kept));
        hi = _mm_add_pd(hi, _mm_cvtps_pd(_mm_movehl_ps(kept, kept)));
        *n += u64::from(_mm_movemask_ps(keep).count_ones());
    }
    let [a, b]: [f64; 2] = bytemuck::cast(lo);
    let [c, d]: [f64; 2] = bytemuck::cast(hi);
    *s = [a, b, c, d];
}

/// [`log_average`] from the rows' [`log_sum_row`] results, summed in row order.
pub(crate) fn log_average_of_rows(rows: &[(f64, u64)]) -> Option<f64> {
    let (s, n) = rows
        .iter()
        .fold((0.0, 0u64), |(a, b), &(s, n)| (a + s, b + n));
    (n > 0).then(|| (s / n as f64).exp())
}

/// The smallest positive value and the largest value (`None` if none is positive).
#[must_use]
pub fn positive_range(lum: &Plane) -> Option<(f32, f32)> {
    let w = lum.width.max(1);
    let rows: Vec<(f32, f32)> = lum
        .data
        .par_chunks(w)
        .map(|row| {
            row.iter().fold((f32::INFINITY, 0.0f32), |(lo, hi), &v| {
                (if v > 0.0 { lo.min(v) } else { lo }, hi.max(v))
            })
        })
        .collect();
    let (lo, hi) = rows
        .iter()
        .fold((f32::INFINITY, 0.0f32), |(a, b), &(lo, hi)| {
            (a.min(lo), b.max(hi))
        });
    (hi > 0.0 && lo.is_finite()).then_some((lo, hi))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The log sums (four lanes at a time where the CPU allows) are the four partial sums
    /// added one pixel at a time, bit for bit, with and without a circle, on rows of every
    /// length up to 41 with zeros, negatives, NaN and values over many octaves.
    #[test]
    fn log_sums_are_the_partial_sums_pixel_by_pixel() {
        let mut next = crate::xorshift(0x853c_49e6_748f_ea9b);
        for len in 0..=41 {
            let row: Vec<f32> = (0..len)
                .map(|_| match next() % 8 {
                    0 => 0.0,
                    1 => -1.5,
                    2 => f32::NAN,
                    _ => f32::from_bits(0x3000_0000 + (next() % 0x1800_0000) as u32),
                })
                .collect();
            for circle in [None, Some((7.0, 2.0, 5.5))] {
                let mut logs = vec![0.0f32; len];
                let got = log_sum_row(&row, 3, circle, &mut logs);
                let mut s = [0.0f64; 4];
                let mut n = 0u64;
                for (x, &v) in row.iter().enumerate() {
                    let inside = circle.is_none_or(|(cx, cy, r)| {
                        let (dx, dy) = (x as f32 + 0.5 - cx, 3.5 - cy);
                        dx * dx + dy * dy <= r * r
                    });
                    if v > 0.0 && inside {
                        s[x % 4] += f64::from(crate::fastmath::ln(v));
                        n += 1;
                    }
                }
                let want = ((s[0] + s[1]) + (s[2] + s[3]), n);
                assert_eq!(
                    (got.0.to_bits(), got.1),
                    (want.0.to_bits(), want.1),
                    "{len}"
                );
            }
        }
    }
}
