//! Doppler colour shift through spectra.
//!
//! Each texel's linear sRGB is turned into a spectrum by the **spectral primary
//! decomposition** of Mallett and Yuksel (EGSR 2019): three fixed, smooth, non-negative
//! reflectance spectra `rho_r, rho_g, rho_b` (380-780 nm, 5 nm; the authors' published table,
//! `data/mallett2019-cie1931-bt709-380+5+780.csv`) with `rho_r + rho_g + rho_b = 1`. For
//! emitted radiance we use the emission spectra `E_j = rho_j * D65` (sRGB white is D65), so
//! `S = sum_j a_j E_j` with `a = P^-1 M rgb`, where `M` is linear sRGB -> XYZ and `P` holds
//! the XYZ of the `E_j` under the spectrum crate's piecewise-linear CIE 1931 functions: the
//! round trip reproduces the input XYZ exactly (to rounding). `P^-1 M` is close to a
//! multiple of the identity because the published basis was built to reproduce the sRGB
//! primaries.
//!
//! A Doppler factor `D` maps `S(lambda)` to `S'(lambda') = D S(lambda' D)` (integral kept,
//! "Doppler only"); the searchlight effect multiplies by a further `D^4` (together `D^5` per
//! wavelength, the invariant transform, see [`crate::searchlight_per_wavelength`]). Because
//! the upsampling is linear, the whole chain is a 3x3 matrix `K(D)` on linear sRGB, which
//! [`DopplerColourTable`] tabulates over `ln D` and interpolates linearly.
//!
//! **Limitation (stated error):** an RGB triple says nothing about the ultraviolet and
//! infrared, so the upsampled spectrum is zero outside 380-780 nm. For `D` outside about
//! `[0.46, 2.18]` the visible window sees only that zero and `K(D) = 0`, whereas a real
//! thermal source would shift its infrared or ultraviolet into view. See the crate tests
//! for the measured black-body error over a range of `D`.

use std::sync::OnceLock;

use blueshift_spectrum::{
    Cmf, PiecewiseLinear, RadiometricTransform, WavelengthShift, d65, linear_srgb_to_xyz_matrix,
    xyz_to_linear_srgb_matrix,
};

use crate::error::{Error, Result};

const BASIS_CSV: &str = include_str!("../data/mallett2019-cie1931-bt709-380+5+780.csv");

/// A 3x3 matrix on linear RGB, row-major.
pub type Mat3 = [[f64; 3]; 3];

fn mat_mul3(a: &Mat3, b: &Mat3) -> Mat3 {
    let mut m = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            m[i][j] = (0..3).map(|k| a[i][k] * b[k][j]).sum();
        }
    }
    m
}

fn inverse3(m: &Mat3) -> Mat3 {
    let det = m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
        - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
        + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]);
    let mut inv = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            let (a, b) = ((j + 1) % 3, (j + 2) % 3);
            let (c, d) = ((i + 1) % 3, (i + 2) % 3);
            inv[i][j] = (m[a][c] * m[b][d] - m[a][d] * m[b][c]) / det;
        }
    }
    inv
}

/// The spectral primary decomposition of linear sRGB into emission spectra.
#[derive(Clone, Debug)]
pub struct SpectralPrimaries {
    emission: [PiecewiseLinear; 3],
    /// `P^-1 M`: linear sRGB -> basis weights.
    rgb_to_weights: Mat3,
}

impl SpectralPrimaries {
    /// The Mallett-Yuksel 2019 basis times D65, calibrated against the CIE 1931 functions.
    pub fn mallett_yuksel_2019() -> Result<Self> {
        let d65 = d65();
        let mut samples: [Vec<(f64, f64)>; 3] = Default::default();
        for (k, line) in BASIS_CSV.lines().enumerate() {
            let lambda = 380.0 + 5.0 * k as f64;
            for (j, v) in line.split(',').enumerate().take(3) {
                let v: f64 = v.trim().parse().unwrap_or(0.0);
                samples[j].push((lambda, v * d65.eval(lambda)));
            }
        }
        let mut emission: [PiecewiseLinear; 3] = Default::default();
        for j in 0..3 {
            emission[j] = PiecewiseLinear::from_samples(&samples[j])?;
        }
        let cmf = Cmf::cie1931_2deg();
        let mut p = [[0.0; 3]; 3];
        for j in 0..3 {
            let xyz = cmf.xyz_of(&emission[j]).to_array();
            for i in 0..3 {
                p[i][j] = xyz[i];
            }
        }
        let rgb_to_weights = mat_mul3(&inverse3(&p), &linear_srgb_to_xyz_matrix());
        Ok(Self {
            emission,
            rgb_to_weights,
        })
    }

    /// The emission spectrum of a linear sRGB triple (W sr^-1 m^-2 nm^-1 per unit of the
    /// RGB scale whose white has `Y = 1`). Spectra cannot be negative, so colours outside
    /// the sRGB gamut (a basis weight below `-2e-3` of the largest) are refused; smaller
    /// negative weights are set to zero. (Against the spectrum crate's 1 nm CIE functions
    /// the published basis, fitted at 5 nm, needs weights down to `-1.4e-3` of the largest
    /// for the pure primaries; clipping them changes such colours by under 0.3%.) (The renderer does not need this: it
    /// works with the linear matrices, which accept any RGB.)
    pub fn upsample(&self, rgb: [f64; 3]) -> Result<PiecewiseLinear> {
        let w = self.weights(rgb);
        let max = w.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
        let mut s = PiecewiseLinear::new();
        for j in 0..3 {
            let wj = if w[j] < 0.0 && w[j] >= -2e-3 * max {
                0.0
            } else {
                w[j]
            };
            if wj < 0.0 {
                return Err(Error::param(
                    "basis weight of an RGB colour",
                    wj,
                    "the colour is outside the sRGB gamut and has no non-negative spectrum",
                ));
            }
            s.add(&self.emission[j].scaled(wj)?);
        }
        Ok(s)
    }

    /// The basis weights `a = P^-1 M rgb` of a linear sRGB triple.
    #[must_use]
    pub fn weights(&self, rgb: [f64; 3]) -> [f64; 3] {
        blueshift_spectrum::mat_mul(&self.rgb_to_weights, rgb)
    }

    /// The exact colour matrix `K(D)` (Doppler only, integral kept; multiply by `D^4` for the
    /// searchlight effect): linear sRGB in, linear sRGB seen through `D` out.
    pub fn doppler_matrix(&self, doppler_factor: f64) -> Result<Mat3> {
        let d = blueshift_spectrum::DopplerFactor::new(doppler_factor)?;
        let shift: WavelengthShift = d.recip();
        let cmf = Cmf::cie1931_2deg();
        let mut pd = [[0.0; 3]; 3];
        for j in 0..3 {
            let shifted = self.emission[j].shifted(shift, RadiometricTransform::None);
            let xyz = cmf.xyz_of(&shifted).scaled(doppler_factor).to_array();
            for i in 0..3 {
                pd[i][j] = xyz[i];
            }
        }
        Ok(mat_mul3(
            &xyz_to_linear_srgb_matrix(),
            &mat_mul3(&pd, &self.rgb_to_weights),
        ))
    }
}

/// `K(D)` tabulated over `ln D` for interactive rendering.
///
/// The renderer reads a second table made from this one: [`LINEAR_D_ENTRIES`] matrices
/// (`f32`) uniform in `D` over `[TABLE_D_MIN, TABLE_D_MAX]`, so a pixel's `D` indexes it
/// without a logarithm ([`DopplerColourTable::apply_linear_d`]).
#[derive(Clone, Debug)]
pub struct DopplerColourTable {
    ln_min: f64,
    ln_max: f64,
    step: f64,
    mats: Vec<Mat3>,
    /// `K(D)` at `TABLE_D_MIN + k * d_step` (row-major 3x3), from [`Self::matrix`].
    by_d: Vec<[f32; 9]>,
    /// The same entries by matrix element, each with its successor
    /// (`pairs[e][k] = [by_d[k][e], by_d[k + 1][e]]`, the last entry repeated), for the
    /// renderer's lanes ([`Self::apply_linear_d_lanes`]): each element is one array that a
    /// vector of lanes indexes, and one 8-byte read gives a lane both ends of its interval.
    pairs: Box<[[[f32; 2]; LINEAR_D_ENTRIES]]>,
    d_step: f64,
    /// `1 / d_step`: the entry of `D` is a product, not a division.
    d_scale: f64,
}

/// Entries of the table uniform in `D` that the renderer reads
/// ([`DopplerColourTable::apply_linear_d`]).
pub const LINEAR_D_ENTRIES: usize = 8192;

/// `LINEAR_D_ENTRIES - 1`: masks an entry index into the table.
const LINEAR_D_MASK: u32 = LINEAR_D_ENTRIES as u32 - 1;
const _: () = assert!(LINEAR_D_ENTRIES.is_power_of_two());

/// Eight lanes' pairs `p[idx[i]]`: the first elements in lane order, then the second.
///
/// # Safety
/// Every index in `idx` must be below `LINEAR_D_ENTRIES`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[allow(unsafe_code)]
unsafe fn gather_pairs(
    p: &[[f32; 2]; LINEAR_D_ENTRIES],
    idx: std::arch::x86_64::__m256i,
) -> (std::arch::x86_64::__m256, std::arch::x86_64::__m256) {
    use std::arch::x86_64::{
        _mm256_castpd_ps, _mm256_castps_pd, _mm256_castsi256_ps, _mm256_castsi256_si128,
        _mm256_extracti128_si256, _mm256_i32gather_epi64, _mm256_permute4x64_pd, _mm256_shuffle_ps,
    };
    let base = p.as_ptr().cast::<i64>();
    // SAFETY: each index addresses one 8-byte pair inside `p` (the caller's bound); a
    // gather needs no alignment.
    let (lo, hi) = unsafe {
        (
            _mm256_i32gather_epi64::<8>(base, _mm256_castsi256_si128(idx)),
            _mm256_i32gather_epi64::<8>(base, _mm256_extracti128_si256::<1>(idx)),
        )
    };
    // lo = [a0 b0 a1 b1 | a2 b2 a3 b3], hi = [a4 b4 a5 b5 | a6 b6 a7 b7].
    let (lo, hi) = (_mm256_castsi256_ps(lo), _mm256_castsi256_ps(hi));
    // Within each 128-bit half: [a0 a1 a4 a5 | a2 a3 a6 a7], then the 64-bit quarters put in
    // order 0, 2, 1, 3.
    let firsts = _mm256_shuffle_ps::<0b10_00_10_00>(lo, hi);
    let seconds = _mm256_shuffle_ps::<0b11_01_11_01>(lo, hi);
    let order = |v| _mm256_castpd_ps(_mm256_permute4x64_pd::<0b11_01_10_00>(_mm256_castps_pd(v)));
    (order(firsts), order(seconds))
}

/// The largest difference, relative to the matrix's largest entry (at least 1e-3), of
/// [`DopplerColourTable::apply_linear_d`]'s matrix from the exact `K(D)`
/// ([`SpectralPrimaries::doppler_matrix`]) for the global table, over `D` in
/// `[TABLE_D_MIN, TABLE_D_MAX]` (`tests/fast.rs` measures it on a dense grid of `D`: 1.91e-4
/// at `D = 0.553`, where the `ln D` table of 2048 entries errs by 1.92e-4 itself; the
/// resampling adds under 1e-5).
pub const LINEAR_D_MAX_ERROR: f64 = 2.5e-4;

/// `K(D) = 0` exactly below this `D`: 830 nm observed came from below 380 nm.
pub const TABLE_D_MIN: f64 = 0.45;
/// `K(D) = 0` exactly above this `D`: 360 nm observed came from above 780 nm.
pub const TABLE_D_MAX: f64 = 2.2;

impl DopplerColourTable {
    /// Tabulates `K(D)` at `entries` points (>= 2) uniform in `ln D` over
    /// `[TABLE_D_MIN, TABLE_D_MAX]`.
    pub fn new(primaries: &SpectralPrimaries, entries: usize) -> Result<Self> {
        let entries = entries.clamp(2, 1 << 16);
        let ln_min = TABLE_D_MIN.ln();
        let ln_max = TABLE_D_MAX.ln();
        let step = (ln_max - ln_min) / (entries - 1) as f64;
        let mats = (0..entries)
            .map(|k| primaries.doppler_matrix((ln_min + step * k as f64).exp()))
            .collect::<Result<Vec<_>>>()?;
        let mut table = Self {
            ln_min,
            ln_max,
            step,
            mats,
            by_d: Vec::new(),
            pairs: Box::default(),
            d_step: (TABLE_D_MAX - TABLE_D_MIN) / (LINEAR_D_ENTRIES - 1) as f64,
            d_scale: (LINEAR_D_ENTRIES - 1) as f64 / (TABLE_D_MAX - TABLE_D_MIN),
        };
        table.by_d = (0..LINEAR_D_ENTRIES)
            .map(|k| {
                // The last node is TABLE_D_MAX itself (no rounding past the range's end).
                let d = if k + 1 == LINEAR_D_ENTRIES {
                    TABLE_D_MAX
                } else {
                    TABLE_D_MIN + table.d_step * k as f64
                };
                let m = table.matrix(d);
                std::array::from_fn(|i| m[i / 3][i % 3] as f32)
            })
            .collect();
        let mut pairs = vec![[[0.0_f32; 2]; LINEAR_D_ENTRIES]; 9];
        for (k, m) in table.by_d.iter().enumerate() {
            let next = table.by_d.get(k + 1).unwrap_or(m);
            for (e, p) in pairs.iter_mut().enumerate() {
                p[k] = [m[e], next[e]];
            }
        }
        table.pairs = pairs.into_boxed_slice();
        Ok(table)
    }

    /// The shared table (Mallett-Yuksel primaries, 2048 entries), built on first use.
    #[must_use]
    pub fn global() -> &'static Self {
        static T: OnceLock<DopplerColourTable> = OnceLock::new();
        T.get_or_init(|| {
            let p = SpectralPrimaries::mallett_yuksel_2019()
                .expect("the built-in basis table is well formed");
            Self::new(&p, 2048).expect("table factors are finite and positive")
        })
    }

    /// The interpolated `K(D)`; zero outside the tabulated range (see the module docs).
    #[must_use]
    pub fn matrix(&self, doppler_factor: f64) -> Mat3 {
        let l = doppler_factor.ln();
        if !(l >= self.ln_min && l <= self.ln_max) {
            return [[0.0; 3]; 3];
        }
        let x = (l - self.ln_min) / self.step;
        let k = (x.floor() as usize).min(self.mats.len() - 2);
        let t = x - k as f64;
        let (a, b) = (&self.mats[k], &self.mats[k + 1]);
        let mut m = [[0.0; 3]; 3];
        for i in 0..3 {
            for j in 0..3 {
                m[i][j] = a[i][j] + (b[i][j] - a[i][j]) * t;
            }
        }
        m
    }

    /// `K(D)` applied to a linear RGB texel with the table uniform in `D` (linear
    /// interpolation of [`LINEAR_D_ENTRIES`] `f32` matrices made from [`Self::matrix`]; no
    /// logarithm): what [`crate::render`] uses. Zero outside `[TABLE_D_MIN, TABLE_D_MAX]`,
    /// like [`Self::apply`]; within [`LINEAR_D_MAX_ERROR`] of the largest entry of the exact
    /// matrix for the global table.
    #[must_use]
    #[inline(always)]
    pub fn apply_linear_d(&self, doppler_factor: f64, rgb: [f32; 3]) -> [f32; 3] {
        if !(TABLE_D_MIN..=TABLE_D_MAX).contains(&doppler_factor) {
            return [0.0; 3];
        }
        let x = (doppler_factor - TABLE_D_MIN) * self.d_scale;
        let k = (x as usize).min(LINEAR_D_ENTRIES - 2);
        let t = (x - k as f64) as f32;
        let (a, b) = (&self.by_d[k], &self.by_d[k + 1]);
        std::array::from_fn(|i| {
            let row =
                |m: &[f32; 9]| m[3 * i] * rgb[0] + m[3 * i + 1] * rgb[1] + m[3 * i + 2] * rgb[2];
            let (ra, rb) = (row(a), row(b));
            ra + (rb - ra) * t
        })
    }

    /// [`Self::apply_linear_d`]'s index arithmetic on `N` lanes: per lane, all ones where `D`
    /// is inside the table's range (zero elsewhere), the entry `k` (at most
    /// `LINEAR_D_ENTRIES - 2`; 0 outside the range) and the weight of entry `k + 1`.
    #[inline(always)]
    fn linear_d_lanes_index<const N: usize>(
        &self,
        doppler_factor: &[f64; N],
    ) -> ([u32; N], [u32; N], [f32; N]) {
        let mut inside = [0_u32; N];
        let mut k = [0_u32; N];
        let mut t = [0.0_f32; N];
        for i in 0..N {
            let d = doppler_factor[i];
            let is_in = (TABLE_D_MIN..=TABLE_D_MAX).contains(&d);
            inside[i] = if is_in { u32::MAX } else { 0 };
            let x = (d - TABLE_D_MIN) * self.d_scale;
            // `x` is in [0, LINEAR_D_ENTRIES - 1] inside the range; other lanes read entry 0.
            let xi = if is_in { x as i32 } else { 0 };
            let ki = if xi < LINEAR_D_ENTRIES as i32 - 2 {
                xi
            } else {
                LINEAR_D_ENTRIES as i32 - 2
            };
            // The mask, a power of two minus one, changes no index but bounds every index
            // by the table's length for the gathers of the AVX2 variant.
            k[i] = ki as u32 & LINEAR_D_MASK;
            t[i] = (x - f64::from(ki)) as f32;
        }
        (inside, k, t)
    }

    /// [`Self::apply_linear_d`] on `N` lanes (`rgb` red, green and blue per lane), with each
    /// lane's bits: the index arithmetic and the matrix products run as loops over all
    /// lanes, which vectorise (the matrix elements gathered from [`Self::pairs`]).
    #[inline(always)]
    pub(crate) fn apply_linear_d_lanes<const N: usize>(
        &self,
        doppler_factor: &[f64; N],
        rgb: &mut [[f32; N]; 3],
    ) {
        let (inside, k, t) = self.linear_d_lanes_index(doppler_factor);
        let [r, g, b] = *rgb;
        for (c, out) in rgb.iter_mut().enumerate() {
            let e = &self.pairs[3 * c..3 * c + 3];
            let (e0, e1, e2) = (&e[0], &e[1], &e[2]);
            for i in 0..N {
                // Masked again where it is read, so the compiler sees the bound (no bounds
                // checks: the loop vectorises with gathers).
                let k = (k[i] & LINEAR_D_MASK) as usize;
                let ra = e0[k][0] * r[i] + e1[k][0] * g[i] + e2[k][0] * b[i];
                let rb = e0[k][1] * r[i] + e1[k][1] * g[i] + e2[k][1] * b[i];
                let v = ra + (rb - ra) * t[i];
                out[i] = if inside[i] != 0 { v } else { 0.0 };
            }
        }
    }

    /// [`Self::apply_linear_d_lanes`] written with AVX2 intrinsics, with its bits (the same
    /// products and sums in the same order, no fused multiply-adds): each lane's pair of
    /// entries comes in one 8-byte gather, where the compiler's loops gather the two ends
    /// separately, 4-byte element by element, which costs twice the loads.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    #[allow(unsafe_code)]
    pub(crate) fn apply_linear_d_lanes_avx2<const N: usize>(
        &self,
        doppler_factor: &[f64; N],
        rgb: &mut [[f32; N]; 3],
    ) {
        use std::arch::x86_64::{
            __m256, _mm256_add_ps, _mm256_and_ps, _mm256_castsi256_ps, _mm256_loadu_ps,
            _mm256_loadu_si256, _mm256_mul_ps, _mm256_storeu_ps, _mm256_sub_ps,
        };
        const { assert!(N.is_multiple_of(8), "lanes in whole vectors of 8") };
        let (inside, k, t) = self.linear_d_lanes_index(doppler_factor);
        let [r, g, b] = *rgb;
        // SAFETY (every pointer access below): `j + 8 <= N` for `j` a multiple of 8 below
        // `N`, a multiple of 8, so each 8-lane load and store lies within its `[_; N]`
        // array; the loads and stores are the unaligned kind.
        let load = |a: &[f32; N], j: usize| unsafe { _mm256_loadu_ps(a.as_ptr().add(j)) };
        for j in (0..N).step_by(8) {
            let (rv, gv, bv, tv) = (load(&r, j), load(&g, j), load(&b, j), load(&t, j));
            let (idx, keep) = unsafe {
                (
                    _mm256_loadu_si256(k.as_ptr().add(j).cast()),
                    _mm256_castsi256_ps(_mm256_loadu_si256(inside.as_ptr().add(j).cast())),
                )
            };
            for (c, out) in rgb.iter_mut().enumerate() {
                let e = &self.pairs[3 * c..3 * c + 3];
                let [(a0, b0), (a1, b1), (a2, b2)] = [&e[0], &e[1], &e[2]].map(|p| {
                    // SAFETY: every index in `idx` is at most LINEAR_D_MASK (masked in
                    // `linear_d_lanes_index`), below the LINEAR_D_ENTRIES pairs of `p`.
                    unsafe { gather_pairs(p, idx) }
                });
                let ra = _mm256_add_ps(
                    _mm256_add_ps(_mm256_mul_ps(a0, rv), _mm256_mul_ps(a1, gv)),
                    _mm256_mul_ps(a2, bv),
                );
                let rb = _mm256_add_ps(
                    _mm256_add_ps(_mm256_mul_ps(b0, rv), _mm256_mul_ps(b1, gv)),
                    _mm256_mul_ps(b2, bv),
                );
                let v: __m256 = _mm256_add_ps(ra, _mm256_mul_ps(_mm256_sub_ps(rb, ra), tv));
                // `v & 0` is +0.0, what the scalar code writes outside the range.
                unsafe { _mm256_storeu_ps(out.as_mut_ptr().add(j), _mm256_and_ps(v, keep)) };
            }
        }
    }

    /// Whether [`Self::apply_linear_d`] maps every colour to black at `D` (outside the
    /// range, or both neighbouring matrices zero).
    #[must_use]
    pub fn is_black_linear_d(&self, doppler_factor: f64) -> bool {
        if !(TABLE_D_MIN..=TABLE_D_MAX).contains(&doppler_factor) {
            return true;
        }
        let k =
            (((doppler_factor - TABLE_D_MIN) * self.d_scale) as usize).min(LINEAR_D_ENTRIES - 2);
        self.by_d[k]
            .iter()
            .chain(&self.by_d[k + 1])
            .all(|&v| v == 0.0)
    }

    /// Applies `K(D)` to a linear RGB texel.
    #[must_use]
    pub fn apply(&self, doppler_factor: f64, rgb: [f32; 3]) -> [f32; 3] {
        let m = self.matrix(doppler_factor);
        let v = rgb.map(f64::from);
        std::array::from_fn(|i| (m[i][0] * v[0] + m[i][1] * v[1] + m[i][2] * v[2]) as f32)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Both lane variants give [`DopplerColourTable::apply_linear_d`]'s bits on every lane:
    /// `D` across the range and past both ends, at the nodes, NaN and infinities.
    #[test]
    fn lane_variants_equal_the_scalar_bits() {
        let table = DopplerColourTable::global();
        let mut ds: Vec<f64> = (0..4000)
            .map(|i| 0.3 + 2.1 * f64::from(i) / 3999.0)
            .collect();
        ds.extend([
            TABLE_D_MIN,
            TABLE_D_MAX,
            TABLE_D_MAX - 1e-12,
            f64::NAN,
            f64::INFINITY,
            -1.0,
        ]);
        ds.extend((0..64).map(|k| TABLE_D_MIN + k as f64 * 127.0 * table.d_step));
        for (n, chunk) in ds.chunks(16).enumerate() {
            let mut d = [1.0_f64; 16];
            d[..chunk.len()].copy_from_slice(chunk);
            let colour = |i: usize| {
                let x = (n * 16 + i) as f32;
                [
                    0.1 + (x * 0.37) % 1.0,
                    0.5 + (x * 0.11) % 2.0,
                    (x * 0.73) % 0.9,
                ]
            };
            let mut lanes = [[0.0_f32; 16]; 3];
            for i in 0..16 {
                let c = colour(i);
                (lanes[0][i], lanes[1][i], lanes[2][i]) = (c[0], c[1], c[2]);
            }
            let want: Vec<[u32; 3]> = (0..16)
                .map(|i| table.apply_linear_d(d[i], colour(i)).map(f32::to_bits))
                .collect();
            let mut portable = lanes;
            table.apply_linear_d_lanes(&d, &mut portable);
            let mut variants = vec![("portable", portable)];
            #[cfg(target_arch = "x86_64")]
            if std::arch::is_x86_feature_detected!("avx2") {
                let mut avx2 = lanes;
                // SAFETY: AVX2 detected just above.
                #[allow(unsafe_code)]
                unsafe {
                    table.apply_linear_d_lanes_avx2(&d, &mut avx2);
                }
                variants.push(("avx2", avx2));
            }
            for (name, got) in variants {
                for (i, w) in want.iter().enumerate() {
                    let g = [got[0][i], got[1][i], got[2][i]].map(f32::to_bits);
                    assert_eq!(&g, w, "{name}, D = {}", d[i]);
                }
            }
        }
    }
}
