//! CIE colorimetry: colour matching functions, D65, XYZ and RGB (Doppler paper section 3.4).

use std::sync::OnceLock;

use crate::error::{Error, Result, range};
use crate::piecewise::{PiecewiseLinear, product_integral};

/// CIE XYZ tristimulus values. Unnormalised: for a spectrum in W sr^-1 m^-2 nm^-1 they are in
/// W sr^-1 m^-2 times the (dimensionless) colour matching functions, i.e. "spectrum units x nm".
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct Xyz {
    /// X.
    pub x: f64,
    /// Y (luminance up to the factor 683 lm/W).
    pub y: f64,
    /// Z.
    pub z: f64,
}

impl Xyz {
    /// Zero.
    pub const ZERO: Self = Self {
        x: 0.0,
        y: 0.0,
        z: 0.0,
    };

    /// From an array `[X, Y, Z]`.
    #[must_use]
    pub const fn from_array(a: [f64; 3]) -> Self {
        Self {
            x: a[0],
            y: a[1],
            z: a[2],
        }
    }

    /// As an array `[X, Y, Z]`.
    #[must_use]
    pub const fn to_array(self) -> [f64; 3] {
        [self.x, self.y, self.z]
    }

    /// Chromaticity `[x, y] = [X, Y] / (X + Y + Z)`; `None` when `X + Y + Z` is zero.
    #[must_use]
    pub fn chromaticity(self) -> Option<[f64; 2]> {
        let sum = self.x + self.y + self.z;
        (sum != 0.0 && sum.is_finite()).then(|| [self.x / sum, self.y / sum])
    }

    /// Multiplied by a scalar.
    #[must_use]
    pub fn scaled(self, k: f64) -> Self {
        Self {
            x: self.x * k,
            y: self.y * k,
            z: self.z * k,
        }
    }

    /// Linear sRGB (IEC 61966-2-1, D65 white), unclamped.
    #[must_use]
    pub fn to_linear_srgb(self) -> [f64; 3] {
        mat_mul(&xyz_to_linear_srgb_matrix(), self.to_array())
    }

    /// Linear CIE RGB through the Doppler paper's Eq. 10 matrix, unclamped.
    #[must_use]
    pub fn to_cie_rgb(self) -> [f64; 3] {
        mat_mul(&XYZ_TO_CIE_RGB_EQ10, self.to_array())
    }
}

impl std::ops::Add for Xyz {
    type Output = Self;
    fn add(self, o: Self) -> Self {
        Self {
            x: self.x + o.x,
            y: self.y + o.y,
            z: self.z + o.z,
        }
    }
}

impl std::ops::AddAssign for Xyz {
    fn add_assign(&mut self, o: Self) {
        *self = *self + o;
    }
}

/// The Doppler paper's Eq. 10: XYZ to linear CIE RGB (after Lindbloom).
pub const XYZ_TO_CIE_RGB_EQ10: [[f64; 3]; 3] = [
    [2.37067, -0.90004, -0.47063],
    [-0.51389, 1.42530, 0.08858],
    [0.00530, -0.01470, 1.00940],
];

/// XYZ to linear sRGB, derived from the sRGB primaries (0.64, 0.33), (0.30, 0.60),
/// (0.15, 0.06) and the D65 white point (0.3127, 0.3290) of IEC 61966-2-1.
#[must_use]
pub fn xyz_to_linear_srgb_matrix() -> [[f64; 3]; 3] {
    static M: OnceLock<[[f64; 3]; 3]> = OnceLock::new();
    *M.get_or_init(|| invert3(&linear_srgb_to_xyz_matrix()))
}

/// Linear sRGB to XYZ (the inverse of [`xyz_to_linear_srgb_matrix`]).
#[must_use]
pub fn linear_srgb_to_xyz_matrix() -> [[f64; 3]; 3] {
    let prim = [[0.64, 0.33], [0.30, 0.60], [0.15, 0.06]];
    let white = [0.3127, 0.3290];
    let to_xyz = |c: [f64; 2]| [c[0] / c[1], 1.0, (1.0 - c[0] - c[1]) / c[1]];
    let p: Vec<[f64; 3]> = prim.iter().map(|&c| to_xyz(c)).collect();
    // Columns are the primaries' XYZ, scaled so that RGB = (1, 1, 1) gives the white.
    let m = [
        [p[0][0], p[1][0], p[2][0]],
        [p[0][1], p[1][1], p[2][1]],
        [p[0][2], p[1][2], p[2][2]],
    ];
    let s = mat_mul(&invert3(&m), to_xyz(white));
    let mut out = m;
    for row in &mut out {
        for (j, v) in row.iter_mut().enumerate() {
            *v *= s[j];
        }
    }
    out
}

/// The sRGB transfer function (Doppler paper Eq. 11) for one linear component; input is
/// clamped to `[0, 1]` first.
#[must_use]
pub fn srgb_encode(linear: f64) -> f64 {
    let c = if linear.is_nan() {
        0.0
    } else {
        linear.clamp(0.0, 1.0)
    };
    if c <= 0.003_130_8 {
        12.92 * c
    } else {
        1.055 * c.powf(1.0 / 2.4) - 0.055
    }
}

/// Inverse of [`srgb_encode`] on `[0, 1]`.
#[must_use]
pub fn srgb_decode(encoded: f64) -> f64 {
    let c = if encoded.is_nan() {
        0.0
    } else {
        encoded.clamp(0.0, 1.0)
    };
    if c <= 0.040_45 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

/// Multiplies a 3x3 matrix by a vector.
#[must_use]
pub fn mat_mul(m: &[[f64; 3]; 3], v: [f64; 3]) -> [f64; 3] {
    [
        m[0][0] * v[0] + m[0][1] * v[1] + m[0][2] * v[2],
        m[1][0] * v[0] + m[1][1] * v[1] + m[1][2] * v[2],
        m[2][0] * v[0] + m[2][1] * v[1] + m[2][2] * v[2],
    ]
}

fn invert3(m: &[[f64; 3]; 3]) -> [[f64; 3]; 3] {
    let det = m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
        - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
        + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]);
    let inv = 1.0 / det;
    [
        [
            (m[1][1] * m[2][2] - m[1][2] * m[2][1]) * inv,
            (m[0][2] * m[2][1] - m[0][1] * m[2][2]) * inv,
            (m[0][1] * m[1][2] - m[0][2] * m[1][1]) * inv,
        ],
        [
            (m[1][2] * m[2][0] - m[1][0] * m[2][2]) * inv,
            (m[0][0] * m[2][2] - m[0][2] * m[2][0]) * inv,
            (m[0][2] * m[1][0] - m[0][0] * m[1][2]) * inv,
        ],
        [
            (m[1][0] * m[2][1] - m[1][1] * m[2][0]) * inv,
            (m[0][1] * m[2][0] - m[0][0] * m[2][1]) * inv,
            (m[0][0] * m[1][1] - m[0][1] * m[1][0]) * inv,
        ],
    ]
}

/// Which standard observer.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub enum Observer {
    /// CIE 1931 2-degree standard observer (the default everywhere in blueshift).
    #[default]
    Cie1931TwoDegree,
    /// CIE 1964 10-degree standard observer.
    Cie1964TenDegree,
}

impl Observer {
    /// The observer's colour matching functions.
    #[must_use]
    pub fn cmf(self) -> &'static Cmf {
        match self {
            Self::Cie1931TwoDegree => Cmf::cie1931_2deg(),
            Self::Cie1964TenDegree => Cmf::cie1964_10deg(),
        }
    }
}

/// Colour matching functions tabulated at a uniform step, read as piecewise-linear functions
/// (linear between the tabulated samples, zero outside). Holds prefix integrals of the
/// functions and of their first moments, so the colour of a trapezoid costs O(1).
#[derive(Debug)]
pub struct Cmf {
    name: &'static str,
    start_nm: f64,
    step_nm: f64,
    samples: Vec<[f64; 3]>,
    /// `prefix0[k] = integral from start to sample k of cmf`.
    prefix0: Vec<[f64; 3]>,
    /// `prefix1[k] = integral from start to sample k of (lambda - start) cmf`.
    prefix1: Vec<[f64; 3]>,
}

const CIE1931: &str = include_str!("../data/cie1931_2deg_xyz_cmf_1nm.csv");
const CIE1964: &str = include_str!("../data/cie1964_10deg_xyz_cmf_1nm.csv");
const D65: &str = include_str!("../data/cie_d65_spd_5nm.csv");

impl Cmf {
    /// CIE 1931 2-degree colour matching functions, 360-830 nm at 1 nm (CIE 15 / CVRL data as
    /// shipped by colour-science 0.4.7).
    pub fn cie1931_2deg() -> &'static Cmf {
        static C: OnceLock<Cmf> = OnceLock::new();
        C.get_or_init(|| Cmf::parse_builtin("CIE 1931 2-degree", CIE1931))
    }

    /// CIE 1964 10-degree colour matching functions, 360-830 nm at 1 nm.
    pub fn cie1964_10deg() -> &'static Cmf {
        static C: OnceLock<Cmf> = OnceLock::new();
        C.get_or_init(|| Cmf::parse_builtin("CIE 1964 10-degree", CIE1964))
    }

    fn parse_builtin(name: &'static str, text: &str) -> Cmf {
        let rows = parse_csv_rows(text, name, 4).expect("built-in CMF table is well formed");
        let start = rows[0].1[0];
        let step = rows[1].1[0] - rows[0].1[0];
        let samples = rows.iter().map(|(_, r)| [r[1], r[2], r[3]]).collect();
        Self::from_uniform(name, start, step, samples)
    }

    /// Builds colour matching functions from samples at `start_nm + k * step_nm`.
    pub fn new(
        name: &'static str,
        start_nm: f64,
        step_nm: f64,
        samples: Vec<[f64; 3]>,
    ) -> Result<Self> {
        crate::error::positive("CMF step (nm)", step_nm)?;
        if !start_nm.is_finite() {
            return Err(Error::param("CMF start (nm)", start_nm, "must be finite"));
        }
        if samples.len() < 2 {
            return Err(Error::param(
                "CMF sample count",
                samples.len() as f64,
                "needs at least 2 samples",
            ));
        }
        if let Some(bad) = samples.iter().flatten().find(|v| !v.is_finite()) {
            return Err(Error::param("CMF sample", *bad, "must be finite"));
        }
        Ok(Self::from_uniform(name, start_nm, step_nm, samples))
    }

    fn from_uniform(
        name: &'static str,
        start_nm: f64,
        step_nm: f64,
        samples: Vec<[f64; 3]>,
    ) -> Self {
        let n = samples.len();
        let mut prefix0 = vec![[0.0; 3]; n];
        let mut prefix1 = vec![[0.0; 3]; n];
        for k in 0..n - 1 {
            let x = k as f64 * step_nm;
            for c in 0..3 {
                let (g0, g1) = (samples[k][c], samples[k + 1][c]);
                let i0 = step_nm * (g0 + g1) / 2.0;
                let i1 = x * i0 + step_nm * step_nm * (g0 + 2.0 * g1) / 6.0;
                prefix0[k + 1][c] = prefix0[k][c] + i0;
                prefix1[k + 1][c] = prefix1[k][c] + i1;
            }
        }
        Self {
            name,
            start_nm,
            step_nm,
            samples,
            prefix0,
            prefix1,
        }
    }

    /// The observer's name.
    #[must_use]
    pub fn name(&self) -> &'static str {
        self.name
    }

    /// The tabulated range `(first, last)` wavelength in nm.
    #[must_use]
    pub fn range_nm(&self) -> (f64, f64) {
        (
            self.start_nm,
            self.start_nm + (self.samples.len() - 1) as f64 * self.step_nm,
        )
    }

    /// The tabulated samples `(wavelength_nm, [x, y, z])`.
    pub fn samples(&self) -> impl Iterator<Item = (f64, [f64; 3])> + '_ {
        self.samples
            .iter()
            .enumerate()
            .map(|(k, v)| (self.start_nm + k as f64 * self.step_nm, *v))
    }

    /// `[x_bar, y_bar, z_bar]` at `wavelength_nm`, linear between samples, zero outside.
    #[must_use]
    pub fn eval(&self, wavelength_nm: f64) -> [f64; 3] {
        let (lo, hi) = self.range_nm();
        if !(wavelength_nm >= lo && wavelength_nm <= hi) {
            return [0.0; 3];
        }
        let t = (wavelength_nm - lo) / self.step_nm;
        let k = (t.floor() as usize).min(self.samples.len() - 2);
        let f = t - k as f64;
        let (a, b) = (self.samples[k], self.samples[k + 1]);
        [
            a[0] + (b[0] - a[0]) * f,
            a[1] + (b[1] - a[1]) * f,
            a[2] + (b[2] - a[2]) * f,
        ]
    }

    /// One channel as a piecewise-linear function (0 = x, 1 = y, 2 = z).
    #[must_use]
    pub fn channel(&self, channel: usize) -> PiecewiseLinear {
        let samples: Vec<(f64, f64)> = self
            .samples()
            .map(|(w, v)| (w, v[channel.min(2)]))
            .collect();
        PiecewiseLinear::from_samples(&samples).expect("CMF samples are valid")
    }

    /// Exact XYZ of the trapezoid going linearly from `value_start` at `start_nm` to
    /// `value_end` at `end_nm` (zero elsewhere), against the piecewise-linear CMFs, in O(1):
    /// partial table intervals at both ends in closed form, the intervals in between from the
    /// prefix integrals of the CMFs and their first moments.
    #[must_use]
    pub fn trapezoid_xyz(
        &self,
        start_nm: f64,
        end_nm: f64,
        value_start: f64,
        value_end: f64,
    ) -> Xyz {
        let (lo, hi) = self.range_nm();
        let a = start_nm.max(lo);
        let b = end_nm.min(hi);
        if b.partial_cmp(&a) != Some(std::cmp::Ordering::Greater) {
            return Xyz::ZERO;
        }
        let line = |x: f64| crate::piecewise::lerp(start_nm, end_nm, value_start, value_end, x);
        let last = self.samples.len() - 2;
        let ia = (((a - lo) / self.step_nm).floor() as usize).min(last);
        let ib = (((b - lo) / self.step_nm).floor() as usize).min(last);
        let x_of = |k: usize| lo + k as f64 * self.step_nm;
        let mut out = [0.0; 3];
        let mut partial = |u: f64, w: f64, k: usize| {
            if w <= u {
                return;
            }
            let (fu, fw) = (line(u), line(w));
            let (x0, x1) = (x_of(k), x_of(k + 1));
            for (c, o) in out.iter_mut().enumerate() {
                let g = |x: f64| {
                    crate::piecewise::lerp(x0, x1, self.samples[k][c], self.samples[k + 1][c], x)
                };
                *o += product_integral(u, w, fu, fw, g(u), g(w));
            }
        };
        if ia == ib {
            partial(a, b, ia);
        } else {
            partial(a, x_of(ia + 1), ia);
            partial(x_of(ib), b, ib);
            // Full intervals ia+1 .. ib: the line is alpha + beta (lambda - lo).
            let beta = (value_end - value_start) / (end_nm - start_nm);
            let alpha = value_start + beta * (lo - start_nm);
            for (c, o) in out.iter_mut().enumerate() {
                let m0 = self.prefix0[ib][c] - self.prefix0[ia + 1][c];
                let m1 = self.prefix1[ib][c] - self.prefix1[ia + 1][c];
                *o += alpha * m0 + beta * m1;
            }
        }
        Xyz::from_array(out)
    }

    /// Exact XYZ of a piecewise-linear spectrum over the whole tabulated range.
    #[must_use]
    pub fn xyz_of(&self, spectrum: &PiecewiseLinear) -> Xyz {
        let (lo, hi) = self.range_nm();
        self.xyz_of_in(spectrum, lo, hi)
            .expect("the tabulated range is valid")
    }

    /// Exact XYZ of a piecewise-linear spectrum over `[min_nm, max_nm]` (a narrower range than
    /// the tabulated one; outside the table the CMFs are zero).
    pub fn xyz_of_in(&self, spectrum: &PiecewiseLinear, min_nm: f64, max_nm: f64) -> Result<Xyz> {
        let (lo, hi) = range("conversion range", min_nm, max_nm)?;
        let mut xyz = Xyz::ZERO;
        for p in spectrum.pieces() {
            let a = p.start_nm.max(lo);
            let b = p.end_nm.min(hi);
            if b > a {
                xyz += self.trapezoid_xyz(a, b, p.at(a), p.at(b));
            }
        }
        Ok(xyz)
    }

    /// XYZ by the CIE 15 summation `sum_k S(lambda_k) cmf(lambda_k) step` over the tabulated
    /// wavelengths (the definition used for smooth spectra such as black bodies, and what
    /// colour-science's `sd_to_XYZ` integration computes with `k = 1`).
    pub fn xyz_by_summation(&self, spectrum: impl Fn(f64) -> f64) -> Xyz {
        let mut out = [0.0; 3];
        for (w, v) in self.samples() {
            let s = spectrum(w);
            for c in 0..3 {
                out[c] += s * v[c] * self.step_nm;
            }
        }
        Xyz::from_array(out)
    }
}

/// The CIE standard illuminant D65, relative spectral power (100 at 560 nm), 300-780 nm at
/// 5 nm (CIE 15:2004 table, as shipped by colour-science 0.4.7), linear between samples.
pub fn d65() -> &'static PiecewiseLinear {
    static D: OnceLock<PiecewiseLinear> = OnceLock::new();
    D.get_or_init(|| {
        let rows = parse_csv_rows(D65, "D65", 2).expect("built-in D65 table is well formed");
        let samples: Vec<(f64, f64)> = rows.iter().map(|(_, r)| (r[0], r[1])).collect();
        PiecewiseLinear::from_samples(&samples).expect("D65 samples are valid")
    })
}

/// Parses a numeric CSV with a header row (lines starting with `#` are comments); each row
/// must have `columns` finite numbers.
pub(crate) fn parse_csv_rows(
    text: &str,
    source_name: &str,
    columns: usize,
) -> Result<Vec<(usize, Vec<f64>)>> {
    let mut rows = Vec::new();
    let mut header_seen = false;
    for (i, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        if !header_seen {
            header_seen = true;
            if line
                .split(',')
                .next()
                .is_some_and(|f| f.trim().parse::<f64>().is_err())
            {
                continue;
            }
        }
        let fields: Vec<&str> = line.split(',').map(str::trim).collect();
        if fields.len() < columns {
            return Err(Error::Parse {
                source_name: source_name.to_owned(),
                line: i + 1,
                message: format!("expected {columns} columns, found {}", fields.len()),
            });
        }
        let mut row = Vec::with_capacity(columns);
        for f in &fields[..columns] {
            let v: f64 = f.parse().map_err(|_| Error::Parse {
                source_name: source_name.to_owned(),
                line: i + 1,
                message: format!("{f:?} is not a number"),
            })?;
            if !v.is_finite() {
                return Err(Error::Parse {
                    source_name: source_name.to_owned(),
                    line: i + 1,
                    message: format!("{f:?} is not finite"),
                });
            }
            row.push(v);
        }
        rows.push((i + 1, row));
    }
    Ok(rows)
}

/// How the colours of a temperature colour table are scaled (Doppler paper Fig. 4).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub enum LuminanceScaling {
    /// Each temperature's XYZ divided by its own Y (Fig. 4a): hue only, constant luminance.
    PerTemperature,
    /// All XYZ divided by the Y of one reference temperature (Fig. 4b uses 1500 K), so
    /// hotter bodies are brighter (and clip).
    Reference {
        /// The reference temperature, K.
        temperature_k: f64,
    },
}

/// A temperature colour table (Doppler paper Fig. 4): `count` black bodies from `t_min_k` to
/// `t_max_k` (linear in T), converted to linear sRGB after the given luminance scaling and
/// multiplied by `factor` (the figure's vertical axis, in [0, 1]). Unclamped.
pub fn temperature_colour_table(
    t_min_k: f64,
    t_max_k: f64,
    count: usize,
    scaling: LuminanceScaling,
    factor: f64,
) -> Result<Vec<[f64; 3]>> {
    crate::error::positive("minimum temperature (K)", t_min_k)?;
    crate::error::positive("maximum temperature (K)", t_max_k)?;
    crate::error::non_negative("colour factor", factor)?;
    if count == 0 {
        return Err(Error::param("table size", 0.0, "must be >= 1"));
    }
    let reference_y = match scaling {
        LuminanceScaling::PerTemperature => None,
        LuminanceScaling::Reference { temperature_k } => {
            Some(crate::blackbody::Blackbody::new(temperature_k)?.xyz().y)
        }
    };
    (0..count)
        .map(|i| {
            let t = if count == 1 {
                t_min_k
            } else {
                t_min_k + (t_max_k - t_min_k) * i as f64 / (count - 1) as f64
            };
            let xyz = crate::blackbody::Blackbody::new(t)?.xyz();
            let y = reference_y.unwrap_or(xyz.y);
            Ok(xyz.scaled(factor / y).to_linear_srgb())
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn srgb_matrix_maps_d65_white_to_one() {
        let w = Xyz {
            x: 0.3127 / 0.3290,
            y: 1.0,
            z: (1.0 - 0.3127 - 0.3290) / 0.3290,
        };
        for c in w.to_linear_srgb() {
            assert!((c - 1.0).abs() < 1e-12);
        }
        // IEC 61966-2-1 publishes the rounded matrix 3.2406 -1.5372 -0.4986 / -0.9689 1.8758 0.0415 / 0.0557 -0.2040 1.0570.
        let m = xyz_to_linear_srgb_matrix();
        let published = [
            [3.2406, -1.5372, -0.4986],
            [-0.9689, 1.8758, 0.0415],
            [0.0557, -0.2040, 1.0570],
        ];
        for i in 0..3 {
            for j in 0..3 {
                assert!((m[i][j] - published[i][j]).abs() < 6e-4, "{i}{j}");
            }
        }
    }

    #[test]
    fn srgb_transfer_function_round_trips_and_is_continuous() {
        for i in 0..=1000 {
            let x = i as f64 / 1000.0;
            assert!((srgb_decode(srgb_encode(x)) - x).abs() < 1e-12);
        }
        let below = srgb_encode(0.003_130_8);
        let above = srgb_encode(0.003_130_8 + 1e-12);
        assert!((below - above).abs() < 1e-6);
    }

    #[test]
    fn trapezoid_xyz_equals_dot_with_cmf_channels() {
        let cmf = Cmf::cie1931_2deg();
        let chans = [cmf.channel(0), cmf.channel(1), cmf.channel(2)];
        for &(a, b, va, vb) in &[
            (400.2, 400.7, 1.0, 3.0),
            (359.0, 900.0, 2.0, 0.5),
            (500.0, 501.0, 1.0, 1.0),
            (455.5, 610.25, 0.0, 7.0),
            (829.5, 835.0, 1.0, 1.0),
        ] {
            let xyz = cmf.trapezoid_xyz(a, b, va, vb).to_array();
            let t = PiecewiseLinear::from_pieces([crate::Piece {
                start_nm: a,
                end_nm: b,
                value_start: va,
                value_end: vb,
            }])
            .unwrap();
            for c in 0..3 {
                let d = t.dot(&chans[c]);
                assert!(
                    (xyz[c] - d).abs() <= 1e-11 * d.abs().max(1e-3),
                    "{a}-{b} c{c}: {} vs {d}",
                    xyz[c]
                );
            }
        }
    }

    #[test]
    fn d65_chromaticity_is_the_published_white_point() {
        // CIE 15: D65 is x = 0.31271, y = 0.32902 for the 1931 observer (5 nm summation).
        let cmf = Cmf::cie1931_2deg();
        let xyz = cmf.xyz_by_summation(|w| if w <= 780.0 { d65().eval(w) } else { 0.0 });
        let [x, y] = xyz.chromaticity().unwrap();
        assert!(
            (x - 0.31271).abs() < 2e-4 && (y - 0.32902).abs() < 2e-4,
            "{x} {y}"
        );
    }
}
