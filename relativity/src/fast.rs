//! The renderer's per-pixel arithmetic without libm transcendentals: an `atan2` by range
//! reduction and a Taylor polynomial (for the equirectangular lookup), and the bilinear
//! equirectangular sample on the map's raw texels.
//!
//! Error bound (tested in `tests/fast.rs` against `f64::atan2`): [`atan2`] differs from the
//! exact angle by at most [`ATAN2_MAX_ERROR_RAD`]. The equirectangular coordinates then
//! differ from [`crate::EquirectMap::sample`]'s by at most `ATAN2_MAX_ERROR_RAD * width / (2
//! pi)` texels horizontally and `ATAN2_MAX_ERROR_RAD * height / pi` vertically (under 1e-7
//! texel for the largest accepted map side, 32,768), so a bilinear sample differs by at most
//! that fraction of the largest texel-to-texel step of the map (plus f32 rounding).

use std::f64::consts::{FRAC_PI_2, FRAC_PI_4, PI, TAU};

use glam::DVec3;

use crate::envmap::EquirectMap;
#[cfg(test)]
use crate::envmap::Rgb;

/// The largest difference of [`atan2`] from the exact angle, radians: [`atan_small`]'s
/// 7.8e-12 plus rounding.
pub const ATAN2_MAX_ERROR_RAD: f64 = 2e-11;

/// `tan(pi / 8)`.
const TAN_PI_8: f64 = 0.414_213_562_373_095_1;

/// `atan(t)` for `|t| <= tan(pi / 8)`: `t p(t^2)`, `p` of degree 6 interpolating
/// `atan(sqrt(u)) / sqrt(u)` at the 7 Chebyshev nodes of `u` in `[0, tan(pi/8)^2]`. Its
/// largest error, measured in 40-digit arithmetic at 2,001 points of `[0, tan(pi/8)]`, is
/// 7.8e-12: below the 1.07e-11 of the Taylor series to `t^23`, with 7 terms instead of 12.
#[inline(always)]
fn atan_small(t: f64) -> f64 {
    const C: [f64; 7] = [
        0.999_999_999_978_398_8,
        -0.333_333_320_976_093_86,
        0.199_998_838_565_513_03,
        -0.142_815_887_726_541_24,
        0.110_404_892_272_182_4,
        -0.084_561_928_869_404_96,
        0.047_073_481_419_680_2,
    ];
    let t2 = t * t;
    let mut p = C[6];
    for &c in C[..6].iter().rev() {
        p = p * t2 + c;
    }
    t * p
}

/// `atan2(y, x)` in `[-pi, pi]` to within [`ATAN2_MAX_ERROR_RAD`], with `f64::atan2`'s
/// quadrants and signed zeros; `atan2(0, 0)` is `0` or `+-pi` as for `f64::atan2`. One
/// division: the ratio `t = min / max` of the magnitudes, or above `tan(pi / 8)` the
/// reduced `(t - 1) / (t + 1) = (min - max) / (min + max)`, then [`atan_small`].
#[must_use]
#[inline(always)]
pub fn atan2(y: f64, x: f64) -> f64 {
    // Written as selects, not branches, so that loops over many angles vectorise (the
    // renderer's lanes); the arithmetic is that of the branches.
    let (ax, ay) = (x.abs(), y.abs());
    // Selects rather than `f64::min`/`max` (whose NaN handling branches). Finite inputs get
    // the same result either way; NaN inputs are not defined here (the renderer's
    // directions are finite).
    let lt = ax < ay;
    let (mn, mx) = (if lt { ax } else { ay }, if lt { ay } else { ax });
    let big = mn > TAN_PI_8 * mx;
    let num = if big { mn - mx } else { mn };
    let den = if big { mn + mx } else { mx };
    let q = num / den;
    let r = if den > 0.0 { q } else { 0.0 };
    let a = atan_small(r) + if big { FRAC_PI_4 } else { 0.0 };
    let a = if ay > ax { FRAC_PI_2 - a } else { a };
    let a = if x.is_sign_negative() { PI - a } else { a };
    a.copysign(y)
}

/// The equirectangular map's texels as one slice and its size, for the renderer's loop.
#[derive(Clone, Copy, Debug)]
pub(crate) struct EquirectTexels<'a> {
    data: &'a [f32],
    width: u32,
    height: u32,
    /// `width`, `height` and `height - 1` as `f64`, for the coordinates' loop.
    wf: f64,
    hf: f64,
    top: f64,
}

impl<'a> EquirectTexels<'a> {
    pub(crate) fn new(map: &'a EquirectMap) -> Self {
        let img = map.image();
        Self {
            data: img.as_raw(),
            width: img.width(),
            height: img.height(),
            wf: f64::from(img.width()),
            hf: f64::from(img.height()),
            top: f64::from(img.height().saturating_sub(1)),
        }
    }

    #[cfg(test)]
    fn texel(&self, x: u32, y: u32) -> Rgb {
        let i = 3 * (y as usize * self.width as usize + x as usize);
        [self.data[i], self.data[i + 1], self.data[i + 2]]
    }

    /// The continuous texel coordinates `(x, y)` of direction `d` (the arithmetic of
    /// [`EquirectMap::sample`] up to its `floor`), with [`atan2`] for the longitude and the
    /// polar angle (`acos(y) = atan2(sqrt(x^2 + z^2), y)` for a unit direction, and for any
    /// other length): `x` in `[-0.5, width - 0.5]`, `y` clamped to `[0, height - 1]`.
    #[inline(always)]
    // `hypot` guards against overflow that a unit direction cannot reach, at the cost of a
    // libm call per pixel.
    #[allow(clippy::imprecise_flops)]
    pub(crate) fn coords(&self, d: DVec3) -> (f64, f64) {
        let lon = atan2(d.x, -d.z);
        let polar = atan2((d.x * d.x + d.z * d.z).sqrt(), d.y);
        let u = 0.5 + lon / TAU;
        let v = polar / PI;
        let x = u * self.wf - 0.5;
        // `clamp(0, height - 1)` as two selects (no assertion in the loop).
        let y = v * self.hf - 0.5;
        let y = if y < 0.0 { 0.0 } else { y };
        let y = if y > self.top { self.top } else { y };
        (x, y)
    }

    /// The bilinear sample at texel coordinates from [`Self::coords`] (wrapping in x): the
    /// scalar statement of [`Self::gather_lanes`], its reference in the tests.
    #[cfg(test)]
    pub(crate) fn fetch(&self, (x, y): (f64, f64)) -> Rgb {
        let (w, h) = (self.width, self.height);
        // floor without a libm call: x > -1 and y >= 0 here, so truncation corrects by one
        // below zero only.
        let xt = x as i64;
        let xi = if x < xt as f64 { xt - 1 } else { xt };
        let ya = y as u32;
        let fx = (x - xi as f64) as f32;
        let fy = (y - f64::from(ya)) as f32;
        let wi = i64::from(w);
        let xa = if xi < 0 {
            xi + wi
        } else if xi >= wi {
            xi - wi
        } else {
            xi
        };
        let xa = if (0..wi).contains(&xa) {
            xa
        } else {
            xi.rem_euclid(wi)
        };
        let xb = if xa + 1 == wi { 0 } else { xa + 1 };
        let (xa, xb) = (xa as u32, xb as u32);
        let ya = ya.min(h - 1);
        let yb = (ya + 1).min(h - 1);
        let top = lerp3(self.texel(xa, ya), self.texel(xb, ya), fx);
        let bot = lerp3(self.texel(xa, yb), self.texel(xb, yb), fx);
        lerp3(top, bot, fy)
    }

    /// The corner arithmetic of [`Self::fetch`] on `N` lanes of coordinates from
    /// [`Self::coords`]: each lane's four texel indices and bilinear weights. The loop
    /// vectorises (`i32` texel columns, the map's sides being at most 32,768). Each lane gets
    /// [`Self::fetch`]'s corners and weights for every coordinate [`Self::coords`] can give
    /// (`x` in `[-0.5, width - 0.5]` or NaN, `y` in `[0, height - 1]`), where one wrap of the
    /// column suffices.
    #[inline(always)]
    pub(crate) fn corners_lanes<const N: usize>(
        &self,
        x: &[f64; N],
        y: &[f64; N],
        out: &mut Corners<N>,
    ) {
        let w = self.width as i32;
        let last = self.height as i32 - 1;
        for i in 0..N {
            let xt = x[i] as i32;
            let xi = if x[i] < f64::from(xt) {
                xt.wrapping_sub(1)
            } else {
                xt
            };
            let ya = y[i] as i32;
            out.fx[i] = (x[i] - f64::from(xi)) as f32;
            out.fy[i] = (y[i] - f64::from(ya)) as f32;
            let xa = if xi < 0 {
                xi.wrapping_add(w)
            } else if xi >= w {
                xi.wrapping_sub(w)
            } else {
                xi
            };
            // Unreachable for coordinates from `coords` (see above); keeps reads in bounds.
            let xa = if xa >= 0 && xa < w { xa } else { 0 };
            let xb = if xa.wrapping_add(1) == w {
                0
            } else {
                xa.wrapping_add(1)
            };
            let ya = if ya < last { ya } else { last };
            let yb = if ya.wrapping_add(1) < last {
                ya.wrapping_add(1)
            } else {
                last
            };
            let (ra, rb) = (ya.wrapping_mul(w), yb.wrapping_mul(w));
            out.index[0][i] = ra.wrapping_add(xa) as u32;
            out.index[1][i] = ra.wrapping_add(xb) as u32;
            out.index[2][i] = rb.wrapping_add(xa) as u32;
            out.index[3][i] = rb.wrapping_add(xb) as u32;
        }
    }

    /// Asks the processor to bring the texels of the first `n` lanes' corners into its
    /// caches, without waiting for them: the renderer issues this for a whole block of
    /// pixels before it reads any of their texels, so the memory latency of a map larger
    /// than the caches overlaps the block's arithmetic. A hint only: no effect on results.
    #[inline(always)]
    pub(crate) fn prefetch<const N: usize>(&self, c: &Corners<N>, n: usize) {
        #[cfg(target_arch = "x86_64")]
        {
            use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
            let base = self.data.as_ptr();
            // The two rows' first corners; the second corners share their cache lines but
            // at the lines' ends.
            for row in [&c.index[0], &c.index[2]] {
                for &j in &row[..n.min(N)] {
                    let p = base.wrapping_add(3 * j as usize).cast::<i8>();
                    // SAFETY: a prefetch reads nothing and cannot fault, whatever the
                    // address (this one is a texel's, inside the map); SSE, the
                    // instruction's only requirement, is part of every x86-64 processor.
                    #[allow(unsafe_code)]
                    unsafe {
                        _mm_prefetch::<_MM_HINT_T0>(p);
                    }
                }
            }
        }
        #[cfg(not(target_arch = "x86_64"))]
        let _ = (c, n);
    }

    /// The bilinear samples of the first `n` lanes of `c` ([`Self::fetch`]'s bits): `out`
    /// gets red, green and blue per lane (the other lanes, arbitrary values). The texel reads
    /// are scalar loops, corner by corner, into the scratch `texel` (the caller's, so no
    /// zeroing per call), the weights loops over all lanes again.
    #[inline(always)]
    pub(crate) fn gather_lanes<const N: usize>(
        &self,
        c: &Corners<N>,
        n: usize,
        texel: &mut [[[f32; N]; 3]; 4],
        out: &mut [[f32; N]; 3],
    ) {
        // Corner by corner over the lanes, the two rows' first corners first: each loop's
        // body is short, so the processor keeps many lanes' cache misses in flight at once.
        for k in [0, 2, 1, 3] {
            for i in 0..n.min(N) {
                let j = 3 * c.index[k][i] as usize;
                let v = &self.data[j..j + 3];
                texel[k][0][i] = v[0];
                texel[k][1][i] = v[1];
                texel[k][2][i] = v[2];
            }
        }
        let (fx, fy) = (&c.fx, &c.fy);
        for (ch, o) in out.iter_mut().enumerate() {
            let [a, b, cc, d] = [&texel[0][ch], &texel[1][ch], &texel[2][ch], &texel[3][ch]];
            for i in 0..N {
                let top = a[i] + (b[i] - a[i]) * fx[i];
                let bot = cc[i] + (d[i] - cc[i]) * fx[i];
                o[i] = top + (bot - top) * fy[i];
            }
        }
    }
}

/// `N` lanes' bilinear corners on an equirectangular map ([`EquirectTexels::corners_lanes`]):
/// the texel indices of the top-left, top-right, bottom-left and bottom-right corners, and
/// the horizontal and vertical weights.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Corners<const N: usize> {
    pub(crate) index: [[u32; N]; 4],
    pub(crate) fx: [f32; N],
    pub(crate) fy: [f32; N],
}

impl<const N: usize> Default for Corners<N> {
    fn default() -> Self {
        Self {
            index: [[0; N]; 4],
            fx: [0.0; N],
            fy: [0.0; N],
        }
    }
}

#[cfg(test)]
fn lerp3(a: Rgb, b: Rgb, t: f32) -> Rgb {
    [
        a[0] + (b[0] - a[0]) * t,
        a[1] + (b[1] - a[1]) * t,
        a[2] + (b[2] - a[2]) * t,
    ]
}
