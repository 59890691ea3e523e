//! Black bodies: Planck's law (Doppler paper Eq. 1), Wien (Eq. 2), piecewise-linear
//! approximation (Fig. 10) and black-body Doppler shifts (Eq. 5, 7).

use crate::cie::{Cmf, Xyz};
use crate::doppler::{SPEED_OF_LIGHT_M_PER_S, WavelengthShift};
use crate::error::{Error, Result, positive, range};
use crate::piecewise::{Piece, PiecewiseLinear};

/// Most pieces [`Blackbody::to_piecewise`] makes (1,048,576: 32 MiB).
pub const MAX_BLACKBODY_PIECES: usize = 1 << 20;
/// Planck constant, J s (SI 2019, exact).
pub const PLANCK_J_S: f64 = 6.626_070_15e-34;
/// Boltzmann constant, J/K (SI 2019, exact).
pub const BOLTZMANN_J_PER_K: f64 = 1.380_649e-23;
/// Wien's displacement constant b, m K (CODATA 2018).
pub const WIEN_M_K: f64 = 2.897_771_955e-3;

/// The radiation constants used in Planck's law `B = c1L / lambda^5 / (exp(c2 / lambda T) - 1)`.
///
/// blueshift uses [`RadiationConstants::Codata`] by default (from the exact SI values of h, c
/// and k_B). CIE 15 and colour-science use rounded constants ([`RadiationConstants::Cie15`]);
/// they differ from CODATA by up to about 5e-4 in XYZ at 1000 K, so compare like with like.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub enum RadiationConstants {
    /// `c1L = 2 h c^2` and `c2 = h c / k_B` from the exact SI 2019 constants.
    #[default]
    Codata,
    /// CIE 15:2004: `c1 = 3.741771e-16 W m^2` (so `c1L = c1 / pi` per steradian) and
    /// `c2 = 1.4388e-2 m K`.
    Cie15,
}

impl RadiationConstants {
    /// `(c1L in W m^2 sr^-1, c2 in m K)`.
    #[must_use]
    pub fn values(self) -> (f64, f64) {
        match self {
            Self::Codata => (
                2.0 * PLANCK_J_S * SPEED_OF_LIGHT_M_PER_S * SPEED_OF_LIGHT_M_PER_S,
                PLANCK_J_S * SPEED_OF_LIGHT_M_PER_S / BOLTZMANN_J_PER_K,
            ),
            Self::Cie15 => (3.741_771e-16 / std::f64::consts::PI, 1.4388e-2),
        }
    }
}

/// Planck's law (Doppler paper Eq. 1): spectral radiance of a black body in
/// W sr^-1 m^-2 nm^-1 at `wavelength_nm` and `temperature_k`, with CODATA constants.
/// Refuses a non-positive or non-finite wavelength or temperature.
pub fn planck(wavelength_nm: f64, temperature_k: f64) -> Result<f64> {
    positive("wavelength (nm)", wavelength_nm)?;
    Ok(Blackbody::new(temperature_k)?.eval(wavelength_nm))
}

/// Wien's displacement law (Doppler paper Eq. 2): the wavelength in nm at which `B_lambda`
/// peaks, `b / T` with b = 2.897771955e-3 m K.
pub fn wien_peak_nm(temperature_k: f64) -> Result<f64> {
    positive("temperature (K)", temperature_k)?;
    Ok(WIEN_M_K / temperature_k * 1e9)
}

/// A black body at a temperature. Spectral radiance per nm, W sr^-1 m^-2 nm^-1.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct Blackbody {
    temperature_k: f64,
    constants: RadiationConstants,
}

impl Blackbody {
    /// A black body at `temperature_k` (finite, > 0) with CODATA constants.
    pub fn new(temperature_k: f64) -> Result<Self> {
        Self::with_constants(temperature_k, RadiationConstants::Codata)
    }

    /// A black body with a chosen set of radiation constants.
    pub fn with_constants(temperature_k: f64, constants: RadiationConstants) -> Result<Self> {
        positive("temperature (K)", temperature_k)?;
        Ok(Self {
            temperature_k,
            constants,
        })
    }

    /// Temperature, K.
    #[must_use]
    pub fn temperature_k(&self) -> f64 {
        self.temperature_k
    }

    /// The radiation constants in use.
    #[must_use]
    pub fn constants(&self) -> RadiationConstants {
        self.constants
    }

    /// Spectral radiance at `wavelength_nm`, W sr^-1 m^-2 nm^-1 (0 for a non-positive or
    /// non-finite wavelength).
    #[must_use]
    pub fn eval(&self, wavelength_nm: f64) -> f64 {
        if !(wavelength_nm > 0.0 && wavelength_nm.is_finite()) {
            return 0.0;
        }
        let (c1l, c2) = self.constants.values();
        let lambda_m = wavelength_nm * 1e-9;
        let x = c2 / (lambda_m * self.temperature_k);
        // exp_m1 keeps precision in the Rayleigh-Jeans limit (small x); above x = 0.5,
        // exp(x) - 1 is within 2.6 ulp of it and several times cheaper. Large x gives an
        // infinite denominator: 0.
        #[allow(clippy::imprecise_flops)] // exp - 1 only where it does not cancel (above)
        let denom = if x > 0.5 { x.exp() - 1.0 } else { x.exp_m1() };
        if !denom.is_finite() {
            return 0.0;
        }
        c1l / lambda_m.powi(5) / denom * 1e-9
    }

    /// The black body seen through a wavelength shift `s` with the relativistic radiance
    /// transform (Doppler paper Eq. 5): exactly the black body at `T / s`.
    #[must_use]
    pub fn shifted(&self, shift: WavelengthShift) -> Self {
        Self {
            temperature_k: self.temperature_k / shift.value(),
            constants: self.constants,
        }
    }

    /// The paper's first-order approximation (Eq. 7): `T' = T (1 - v_r / c)` for a radial
    /// velocity in m/s (positive receding). Refuses `v_r >= c` (T' <= 0) and NaN.
    pub fn shifted_first_order(&self, radial_velocity_m_per_s: f64) -> Result<Self> {
        let t = self.temperature_k * (1.0 - radial_velocity_m_per_s / SPEED_OF_LIGHT_M_PER_S);
        if !(t.is_finite() && t > 0.0) {
            return Err(Error::param(
                "radial velocity (m/s)",
                radial_velocity_m_per_s,
                "first-order black-body shift needs v_r < c",
            ));
        }
        Ok(Self {
            temperature_k: t,
            constants: self.constants,
        })
    }

    /// CIE 1931 XYZ by the CIE 15 summation at the 1 nm table points (360-830 nm).
    #[must_use]
    pub fn xyz(&self) -> Xyz {
        self.xyz_with(Cmf::cie1931_2deg())
    }

    /// XYZ for the given colour matching functions by summation at their table points.
    #[must_use]
    pub fn xyz_with(&self, cmf: &Cmf) -> Xyz {
        cmf.xyz_by_summation(|w| self.eval(w))
    }

    /// `count` equal-width linear pieces over `[min_nm, max_nm]` through exact values at their
    /// ends (the paper's scheme: 21 samples, Fig. 10).
    pub fn to_piecewise_uniform(
        &self,
        min_nm: f64,
        max_nm: f64,
        count: usize,
    ) -> Result<PiecewiseLinear> {
        let (lo, hi) = range("black-body range", min_nm, max_nm)?;
        if count == 0 {
            return Err(Error::param("piece count", 0.0, "must be >= 1"));
        }
        let pieces = (0..count).map(|i| {
            let a = lo + (hi - lo) * i as f64 / count as f64;
            let b = if i + 1 == count {
                hi
            } else {
                lo + (hi - lo) * (i + 1) as f64 / count as f64
            };
            Piece {
                start_nm: a,
                end_nm: b,
                value_start: self.eval(a),
                value_end: self.eval(b),
            }
        });
        PiecewiseLinear::from_pieces(pieces)
    }

    /// A piecewise-linear approximation over `[min_nm, max_nm]` whose relative error
    /// `|approx - B| / B` is at most `max_relative_error` at every wavelength of the range,
    /// with pieces placed adaptively (short where the curve bends, long where it is straight).
    ///
    /// Each candidate piece is checked at 32 interior points against the exact curve with a
    /// safety factor of 2 (the chord error of a smooth function is a smooth bump, so a dense
    /// check with margin bounds it); the test suite verifies the bound on a 100x denser grid.
    /// `max_relative_error` must lie in (0, 1); an approximation that would need more than
    /// [`MAX_BLACKBODY_PIECES`] pieces (an error bound near the f64 precision, or a
    /// temperature whose curve overflows) is an error instead of unbounded work.
    pub fn to_piecewise(
        &self,
        min_nm: f64,
        max_nm: f64,
        max_relative_error: f64,
    ) -> Result<PiecewiseLinear> {
        let (lo, hi) = range("black-body range", min_nm, max_nm)?;
        if !(max_relative_error > 0.0 && max_relative_error < 1.0) {
            return Err(Error::param(
                "maximum relative error",
                max_relative_error,
                "must lie in (0, 1)",
            ));
        }
        if lo <= 0.0 {
            return Err(Error::Range {
                name: "black-body range",
                min_nm: lo,
                max_nm: hi,
                reason: "wavelengths must be > 0",
            });
        }
        // A temperature whose radiance overflows f64 somewhere in the range cannot be
        // approximated at any error: say so up front, naming the temperature.
        let mid = 0.5 * (lo + hi);
        if ![lo, mid, hi].iter().all(|&x| self.eval(x).is_finite()) {
            return Err(Error::param(
                "temperature (K)",
                self.temperature_k,
                "its radiance overflows f64 over the range",
            ));
        }
        let target = 0.5 * max_relative_error;
        let mut pieces = Vec::new();
        let mut stack = vec![(lo, hi, 0u32)];
        let too_many = || {
            Error::param(
                "maximum relative error",
                max_relative_error,
                "needs more than 1,048,576 pieces over the range (raise it, or check the temperature)",
            )
        };
        // Depth-first, right half pushed first so pieces come out in order.
        while let Some((a, b, depth)) = stack.pop() {
            let (va, vb) = (self.eval(a), self.eval(b));
            let ok = depth >= 40
                || (1..32).all(|i| {
                    let x = a + (b - a) * i as f64 / 32.0;
                    let exact = self.eval(x);
                    let approx = va + (vb - va) * i as f64 / 32.0;
                    exact <= 0.0 && approx <= 0.0 || (approx - exact).abs() <= target * exact
                });
            if ok {
                pieces.push(Piece {
                    start_nm: a,
                    end_nm: b,
                    value_start: va,
                    value_end: vb,
                });
            } else {
                if pieces.len() + stack.len() >= MAX_BLACKBODY_PIECES {
                    return Err(too_many());
                }
                let m = 0.5 * (a + b);
                stack.push((m, b, depth + 1));
                stack.push((a, m, depth + 1));
            }
        }
        PiecewiseLinear::from_pieces(pieces)
    }
}
