//! # blueshift-spectrum
//!
//! Spectra as algebra for spectral (Doppler) volume rendering: exact piecewise-linear
//! spectra, the banded baseline, Planck's law, CIE colorimetry, emission-line catalogues and
//! Doppler shifts. It implements sections 3-5 of the Doppler volume rendering paper
//! (`shared/papers/doppler-volume-rendering.txt`) and goes beyond it where the paper
//! approximates: insertion that does not slow down with thousands of pieces, attenuation that
//! never amplifies, merging with a stated error bound, energy-conserving band shifts and the
//! relativistic Doppler model.
//!
//! ## Where do I start?
//! - [`PiecewiseLinear`]: a spectrum of linear pieces. Add trapezoids and boxes, integrate,
//!   take exact inner products, shift by a [`WavelengthShift`], attenuate, merge.
//! - [`Blackbody`] and [`planck`]: thermal emission, and its piecewise-linear approximation
//!   with a requested error bound.
//! - [`Cmf`] and [`Xyz`]: colour matching functions and conversion to XYZ, sRGB, CIE RGB.
//!
//! ```
//! use blueshift_spectrum::*;
//! // A black body at 5800 K plus H-alpha, receding at 3000 km/s.
//! let bb = Blackbody::new(5800.0)?;
//! let mut s = bb.to_piecewise(360.0, 830.0, 1e-3)?;
//! let h_alpha = EmissionLine::new(656.28, 2.0e4)?;
//! h_alpha.add_to(&mut s, LineProfile::Box { width_nm: 1.0 }, 1.0)?;
//! let shift = WavelengthShift::classical(3.0e6)?;
//! let seen = s.shifted(shift, RadiometricTransform::None);
//! let xyz = Cmf::cie1931_2deg().xyz_of(&seen);
//! assert!(xyz.y > 0.0 && seen.eval(656.28 * shift.value()) > s.eval(656.28 * shift.value()));
//! # Ok::<(), blueshift_spectrum::Error>(())
//! ```
//!
//! ## Glossary: paper terms to types
//! | Doppler paper | blueshift |
//! |---|---|
//! | Eq. 1 Planck's law | [`planck`], [`Blackbody::eval`] |
//! | Eq. 2 Wien's displacement law | [`wien_peak_nm`] |
//! | Eq. 4 relativistic Doppler | [`WavelengthShift::relativistic`], [`DopplerModel::Relativistic`] |
//! | Eq. 5 black body at T_obs = T_emit / s | [`Blackbody::shifted`] |
//! | Eq. 6 first-order Doppler | [`WavelengthShift::classical`] |
//! | Eq. 7 first-order black-body shift | [`Blackbody::shifted_first_order`] |
//! | Eq. 9 XYZ convolution | [`Cmf::xyz_of`], [`Cmf::trapezoid_xyz`], [`Spectrum::to_xyz`] |
//! | Eq. 10 CIE RGB matrix | [`Xyz::to_cie_rgb`], [`XYZ_TO_CIE_RGB_EQ10`] |
//! | Eq. 11 sRGB transfer | [`srgb_encode`] |
//! | Eq. 12-14 piecewise-linear spectrum | [`PiecewiseLinear`], [`Piece`] |
//! | Fig. 4 temperature colour tables | [`temperature_colour_table`], [`LuminanceScaling`] |
//! | Fig. 8 overlap cases | [`PiecewiseLinear::add_trapezoid`] |
//! | Fig. 10 21-piece black body | [`Blackbody::to_piecewise_uniform`], [`Blackbody::to_piecewise`] |
//! | section 4.1 fixed bands, Algorithm 1 shift | [`Banded`], [`Banded::shift_nearest`] |
//! | section 4.2 "Convolution" closed form | [`PiecewiseLinear::dot`] |
//! | thermal Doppler broadening (not in the paper) | [`thermal_sigma_m_per_s`], [`PwlGaussian`], [`LineProfile::Gaussian`] |
//! | D (wavelength ratio) | [`WavelengthShift`]; the frequency ratio is [`DopplerFactor`] |
//!
//! ## Units and conventions
//! Wavelengths are nm (`f64`), spectral radiance is per nm (W sr^-1 m^-2 nm^-1 for black
//! bodies), velocities are m/s with positive radial velocity receding (red shift). XYZ is
//! unnormalised: spectrum units times nm. Unless narrowed, colour conversions cover the whole
//! tabulated CMF range, 360-830 nm. Planck's law uses CODATA/SI constants by default
//! ([`RadiationConstants`]).

mod banded;
mod blackbody;
mod cie;
mod doppler;
mod error;
mod lines;
mod piecewise;
mod profiles;

pub use banded::{BandLayout, BandWeights, Banded};
pub use blackbody::{
    BOLTZMANN_J_PER_K, Blackbody, MAX_BLACKBODY_PIECES, PLANCK_J_S, RadiationConstants, WIEN_M_K,
    planck, wien_peak_nm,
};
pub use cie::{
    Cmf, LuminanceScaling, Observer, XYZ_TO_CIE_RGB_EQ10, Xyz, d65, linear_srgb_to_xyz_matrix,
    mat_mul, srgb_decode, srgb_encode, temperature_colour_table, xyz_to_linear_srgb_matrix,
};
pub use doppler::{
    DopplerFactor, DopplerModel, RadiometricTransform, SPEED_OF_LIGHT_M_PER_S, WavelengthShift,
};
pub use error::{Error, Result};
pub use lines::{
    Catalogue, EmissionLine, LINE_LIST_COLUMNS, LineProfile, add_lines, parse_line_list,
    read_line_list,
};
pub use piecewise::{MAX_PIECES, Piece, PiecewiseLinear, merge_pieces, sum_trapezoids};
pub use profiles::{
    ATOMIC_MASS_UNIT_KG, NamedLine, PwlGaussian, named_line, thermal_sigma_m_per_s,
    velocity_sigma_to_nm,
};

/// The small interface shared by every spectrum type (CONVENTIONS C5): evaluate, bound, and
/// convert to colour. Kernels take `impl Spectrum` generics; there is no `dyn` in hot paths.
pub trait Spectrum {
    /// Spectral radiance at `wavelength_nm`.
    fn eval(&self, wavelength_nm: f64) -> f64;
    /// An upper bound of the values (exact for piecewise-linear and banded spectra).
    fn max_value(&self) -> f64;
    /// XYZ for the given colour matching functions over their whole tabulated range.
    fn to_xyz_with(&self, cmf: &Cmf) -> Xyz;
    /// CIE 1931 2-degree XYZ over 360-830 nm.
    fn to_xyz(&self) -> Xyz {
        self.to_xyz_with(Cmf::cie1931_2deg())
    }
}

impl Spectrum for PiecewiseLinear {
    fn eval(&self, wavelength_nm: f64) -> f64 {
        PiecewiseLinear::eval(self, wavelength_nm)
    }
    fn max_value(&self) -> f64 {
        PiecewiseLinear::max_value(self)
    }
    /// Exact: the closed-form product integral with the piecewise-linear CMFs.
    fn to_xyz_with(&self, cmf: &Cmf) -> Xyz {
        cmf.xyz_of(self)
    }
}

impl Spectrum for Banded {
    fn eval(&self, wavelength_nm: f64) -> f64 {
        Banded::eval(self, wavelength_nm)
    }
    fn max_value(&self) -> f64 {
        Banded::max_value(self)
    }
    /// Exact for the step function against the piecewise-linear CMFs.
    fn to_xyz_with(&self, cmf: &Cmf) -> Xyz {
        Banded::to_xyz_with(self, cmf)
    }
}

impl Spectrum for Blackbody {
    fn eval(&self, wavelength_nm: f64) -> f64 {
        Blackbody::eval(self, wavelength_nm)
    }
    /// The value at Wien's peak.
    fn max_value(&self) -> f64 {
        self.eval(WIEN_M_K / self.temperature_k() * 1e9)
    }
    /// CIE 15 summation at the table's 1 nm points.
    fn to_xyz_with(&self, cmf: &Cmf) -> Xyz {
        self.xyz_with(cmf)
    }
}

/// A closed set of spectrum kinds for scene and CLI files, dispatched by `match`.
#[derive(Clone, Debug, PartialEq)]
pub enum AnySpectrum {
    /// A black body.
    Blackbody(Blackbody),
    /// A piecewise-linear spectrum.
    PiecewiseLinear(PiecewiseLinear),
    /// A banded spectrum.
    Banded(Banded),
    /// One emission line with its profile.
    Line(EmissionLine, LineProfile),
}

impl Spectrum for AnySpectrum {
    fn eval(&self, wavelength_nm: f64) -> f64 {
        match self {
            Self::Blackbody(b) => b.eval(wavelength_nm),
            Self::PiecewiseLinear(p) => p.eval(wavelength_nm),
            Self::Banded(b) => b.eval(wavelength_nm),
            Self::Line(l, prof) => l.to_piecewise(*prof).map_or(0.0, |p| p.eval(wavelength_nm)),
        }
    }
    fn max_value(&self) -> f64 {
        match self {
            Self::Blackbody(b) => Spectrum::max_value(b),
            Self::PiecewiseLinear(p) => p.max_value(),
            Self::Banded(b) => b.max_value(),
            Self::Line(l, prof) => l.to_piecewise(*prof).map_or(0.0, |p| p.max_value()),
        }
    }
    fn to_xyz_with(&self, cmf: &Cmf) -> Xyz {
        match self {
            Self::Blackbody(b) => b.xyz_with(cmf),
            Self::PiecewiseLinear(p) => cmf.xyz_of(p),
            Self::Banded(b) => b.to_xyz_with(cmf),
            Self::Line(l, prof) => l.to_piecewise(*prof).map_or(Xyz::ZERO, |p| cmf.xyz_of(&p)),
        }
    }
}
