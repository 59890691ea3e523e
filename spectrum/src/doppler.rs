//! Doppler shifts as typed ratios (DESIGN.md "Shared conventions").
//!
//! - [`WavelengthShift`] `s = lambda_obs / lambda_emit` (the Doppler paper's D, Eq. 4 and Fig. 6).
//!   `s > 1` is a red shift. A positive radial velocity is receding and red-shifts (Eq. 6).
//! - [`DopplerFactor`] `D = nu_obs / nu_emit = 1 / s` (the relativity literature's factor).
//!
//! The two are distinct types; one converts into the other only through `recip()`:
//!
//! ```compile_fail
//! use blueshift_spectrum::{DopplerFactor, WavelengthShift};
//! fn takes_shift(_s: WavelengthShift) {}
//! let d = DopplerFactor::new(1.1).unwrap();
//! takes_shift(d); // error: a frequency ratio is not a wavelength ratio
//! ```
//!
//! ```
//! use blueshift_spectrum::{DopplerFactor, WavelengthShift};
//! fn takes_shift(_s: WavelengthShift) {}
//! let d = DopplerFactor::new(1.1).unwrap();
//! takes_shift(d.recip()); // fine: s = 1 / D
//! ```

use crate::error::{Error, Result};

/// The speed of light in vacuum, m/s (SI, exact).
pub const SPEED_OF_LIGHT_M_PER_S: f64 = 299_792_458.0;

/// Which Doppler formula to use; spelt `classical` or `relativistic` (`FromStr`, `Display`
/// and, with the `serde` feature, serde).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(rename_all = "lowercase"))]
pub enum DopplerModel {
    /// First order in v/c, radial component only: `s = 1 + v_r / c` (Doppler paper Eq. 6).
    #[default]
    Classical,
    /// Special relativity, including the transverse term: `s = gamma (1 + beta . n)` with `n`
    /// the unit line of sight from the observer to the source (Doppler paper Eq. 4).
    Relativistic,
}

impl DopplerModel {
    /// Every model, in the order of [`DopplerModel::NAMES`].
    pub const ALL: [DopplerModel; 2] = [DopplerModel::Classical, DopplerModel::Relativistic];
    /// The spellings of [`DopplerModel::ALL`] (`FromStr`, `Display` and serde).
    pub const NAMES: [&'static str; 2] = ["classical", "relativistic"];

    /// Its spelling: `classical` or `relativistic`.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            DopplerModel::Classical => "classical",
            DopplerModel::Relativistic => "relativistic",
        }
    }
}

impl std::str::FromStr for DopplerModel {
    type Err = Error;
    /// `classical` or `relativistic`; anything else is an [`Error::UnknownName`].
    fn from_str(s: &str) -> Result<Self> {
        DopplerModel::ALL
            .into_iter()
            .find(|m| m.name() == s)
            .ok_or_else(|| Error::UnknownName {
                what: "Doppler model",
                name: s.to_owned(),
                known: "classical, relativistic",
            })
    }
}

impl std::fmt::Display for DopplerModel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// How spectral radiance values change when the wavelength axis is scaled by `s`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(rename_all = "lowercase"))]
pub enum RadiometricTransform {
    /// Values are kept; only the axis is stretched, so the integral is multiplied by `s`.
    #[default]
    None,
    /// The relativistic invariant `I_nu / nu^3` is kept. Per wavelength this means
    /// `I_lambda * lambda^5` is invariant, so values are multiplied by `s^-5` and the
    /// integral by `s^-4 = D^4`. A black body at `T` becomes exactly the black body at `T / s`.
    Invariant,
}

impl RadiometricTransform {
    /// The factor applied to spectral radiance values (per nm) for a shift `s`.
    #[must_use]
    pub fn value_factor(self, shift: WavelengthShift) -> f64 {
        match self {
            Self::None => 1.0,
            Self::Invariant => shift.0.powi(-5),
        }
    }
}

/// Wavelength ratio `s = lambda_obs / lambda_emit` (`s > 1`: red shift). Always finite and > 0.
#[derive(Clone, Copy, Debug, PartialEq, PartialOrd)]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
pub struct WavelengthShift(f64);

/// Frequency ratio `D = nu_obs / nu_emit = 1 / s` (`D > 1`: blue shift). Always finite and > 0.
#[derive(Clone, Copy, Debug, PartialEq, PartialOrd)]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
pub struct DopplerFactor(f64);

impl WavelengthShift {
    /// No shift, `s = 1`.
    pub const IDENTITY: Self = Self(1.0);

    /// A shift from its ratio `s` (must be finite and > 0).
    pub fn new(s: f64) -> Result<Self> {
        crate::error::positive("wavelength shift s", s).map(Self)
    }

    /// The ratio `s`.
    #[must_use]
    pub fn value(self) -> f64 {
        self.0
    }

    /// The frequency ratio `D = 1 / s`.
    #[must_use]
    pub fn recip(self) -> DopplerFactor {
        DopplerFactor(1.0 / self.0)
    }

    /// Classical first-order shift (Doppler paper Eq. 6): `s = 1 + v_r / c`, with the radial
    /// velocity `v_r` in m/s, positive when the source recedes. Refuses `v_r <= -c` (which
    /// would give `s <= 0`) and non-finite values.
    pub fn classical(radial_velocity_m_per_s: f64) -> Result<Self> {
        if !radial_velocity_m_per_s.is_finite() {
            return Err(Error::param(
                "radial velocity (m/s)",
                radial_velocity_m_per_s,
                "must be finite",
            ));
        }
        let s = 1.0 + radial_velocity_m_per_s / SPEED_OF_LIGHT_M_PER_S;
        if s <= 0.0 {
            return Err(Error::param(
                "radial velocity (m/s)",
                radial_velocity_m_per_s,
                "the first-order shift 1 + v/c must be > 0 (v > -c)",
            ));
        }
        Ok(Self(s))
    }

    /// Relativistic shift (Doppler paper Eq. 4): `s = gamma (1 + beta cos(theta))`, with
    /// `beta = |v| / c` of the source in the observer's frame and `theta` the angle, in that
    /// frame, between the source's velocity and the line of sight from the observer to the
    /// source (`cos(theta) = 1`: receding, red shift; `cos(theta) = 0`: the transverse shift
    /// `s = gamma`). Refuses `|beta| >= 1`, NaN, and `|cos(theta)| > 1`.
    pub fn relativistic(beta: f64, cos_theta: f64) -> Result<Self> {
        check_beta(beta)?;
        if !(cos_theta.is_finite() && cos_theta.abs() <= 1.0) {
            return Err(Error::param("cos(theta)", cos_theta, "must lie in [-1, 1]"));
        }
        let gamma = 1.0 / (1.0 - beta * beta).sqrt();
        Ok(Self(gamma * (1.0 + beta * cos_theta)))
    }

    /// Relativistic shift of a purely radial motion: `s = sqrt((1 + beta) / (1 - beta))` with
    /// `beta = v_r / c` (positive receding).
    pub fn relativistic_radial(radial_velocity_m_per_s: f64) -> Result<Self> {
        let beta = radial_velocity_m_per_s / SPEED_OF_LIGHT_M_PER_S;
        check_beta(beta)?;
        Ok(Self(((1.0 + beta) / (1.0 - beta)).sqrt()))
    }

    /// The shift of light from a source moving with `velocity_m_per_s` (observer's frame),
    /// seen along `line_of_sight`, the direction from the observer to the source (need not be
    /// normalised, must not be zero). The radial velocity is `v . n`, positive receding.
    pub fn from_velocity(
        model: DopplerModel,
        velocity_m_per_s: [f64; 3],
        line_of_sight: [f64; 3],
    ) -> Result<Self> {
        let len = dot3(line_of_sight, line_of_sight).sqrt();
        if !(len.is_finite() && len > 0.0) {
            return Err(Error::param(
                "line-of-sight length",
                len,
                "must be finite and > 0",
            ));
        }
        let v_r = dot3(velocity_m_per_s, line_of_sight) / len;
        match model {
            DopplerModel::Classical => Self::classical(v_r),
            DopplerModel::Relativistic => {
                let speed = dot3(velocity_m_per_s, velocity_m_per_s).sqrt();
                let beta = speed / SPEED_OF_LIGHT_M_PER_S;
                check_beta(beta)?;
                let gamma = 1.0 / (1.0 - beta * beta).sqrt();
                Ok(Self(gamma * (1.0 + v_r / SPEED_OF_LIGHT_M_PER_S)))
            }
        }
    }

    /// The shift for a radial velocity under `model` (relativistic: purely radial motion).
    pub fn from_radial_velocity(model: DopplerModel, radial_velocity_m_per_s: f64) -> Result<Self> {
        match model {
            DopplerModel::Classical => Self::classical(radial_velocity_m_per_s),
            DopplerModel::Relativistic => Self::relativistic_radial(radial_velocity_m_per_s),
        }
    }

    /// Composition: light shifted by `self` then by `other` is shifted by the product.
    #[must_use]
    pub fn then(self, other: Self) -> Self {
        Self(self.0 * other.0)
    }
}

impl DopplerFactor {
    /// A factor from its ratio `D` (must be finite and > 0).
    pub fn new(d: f64) -> Result<Self> {
        crate::error::positive("Doppler factor D", d).map(Self)
    }

    /// The ratio `D`.
    #[must_use]
    pub fn value(self) -> f64 {
        self.0
    }

    /// The wavelength ratio `s = 1 / D`.
    #[must_use]
    pub fn recip(self) -> WavelengthShift {
        WavelengthShift(1.0 / self.0)
    }
}

fn check_beta(beta: f64) -> Result<()> {
    if beta.is_finite() && beta.abs() < 1.0 {
        Ok(())
    } else {
        Err(Error::param("beta = v/c", beta, "|beta| must be < 1"))
    }
}

fn dot3(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

#[cfg(test)]
mod tests {
    use super::DopplerModel;

    #[test]
    fn doppler_model_spellings_round_trip() {
        for (m, name) in DopplerModel::ALL.into_iter().zip(DopplerModel::NAMES) {
            assert_eq!(name.parse::<DopplerModel>().unwrap(), m);
            assert_eq!(m.to_string(), name);
            assert_eq!(m.name(), name);
            #[cfg(feature = "serde")]
            {
                let json = serde_json::to_string(&m).unwrap();
                assert_eq!(json, format!("\"{name}\""));
                assert_eq!(serde_json::from_str::<DopplerModel>(&json).unwrap(), m);
            }
        }
        assert_eq!(
            "newtonian".parse::<DopplerModel>().unwrap_err().to_string(),
            "unknown Doppler model \"newtonian\" (known: classical, relativistic)"
        );
    }
}
