//! Gaussian line profiles (thermal Doppler broadening, user widths) as piecewise-linear
//! pieces with a stated error bound, atomic masses and named lines.
//!
//! ## Convention
//! Thermal broadening of a species of mass `m` at temperature `T` is a Gaussian in
//! line-of-sight velocity with standard deviation `sigma_v = sqrt(k T / m)`. The
//! astronomers' (and yt's `PPVCube`) "thermal velocity" is `v_th = sqrt(2 k T / m) =
//! sqrt(2) sigma_v`, the profile being `exp(-v^2 / v_th^2) / (sqrt(pi) v_th)`: the same
//! Gaussian. In wavelength, `sigma_nm = lambda * sigma_v / c`.
//!
//! ## Error bound of [`PwlGaussian`]
//! The unit-area Gaussian `g(x) = exp(-x^2 / 2) / sqrt(2 pi)` (x in units of sigma) is
//! interpolated linearly on knots spaced `h` over `[-L, L]`, with the two end knots set to
//! 0 (so the profile is continuous), then all knot values are scaled by `1 + eps` so the
//! pieces' area is exactly 1 (the line keeps its strength as its area, to rounding).
//! Then `sup |g_pwl - g| <= g(0) * (h^2 / 8 + exp(-(L - h)^2 / 2) + |eps| (1 + h^2 / 8))`
//! (linear interpolation error `h^2 max|g''| / 8` with `max|g''| = g(0)`; the last piece
//! runs from the last inner knot to 0 where the Gaussian is below `g(L - h)`; the area
//! rescale adds `|eps| g`). [`PwlGaussian::sup_error_relative`] returns this bound; the
//! default (h = 1/4, L = 4: 32 pieces) gives 0.87 % of the peak.

use crate::doppler::SPEED_OF_LIGHT_M_PER_S;
use crate::error::{Error, Result, non_negative, positive};
use crate::lines::{Catalogue, EmissionLine};
use crate::piecewise::PiecewiseLinear;

/// One unified atomic mass unit, kg (CODATA 2018).
pub const ATOMIC_MASS_UNIT_KG: f64 = 1.660_539_066_60e-27;

/// The 1-sigma thermal velocity `sqrt(k T / m)`, m/s, for `temperature_k` (>= 0) and
/// `mass_amu` (> 0). The astronomers' `v_th = sqrt(2 k T / m)` is `sqrt(2)` times this.
pub fn thermal_sigma_m_per_s(temperature_k: f64, mass_amu: f64) -> Result<f64> {
    non_negative("temperature (K)", temperature_k)?;
    positive("atomic mass (amu)", mass_amu)?;
    Ok(
        (crate::blackbody::BOLTZMANN_J_PER_K * temperature_k / (mass_amu * ATOMIC_MASS_UNIT_KG))
            .sqrt(),
    )
}

/// A Gaussian's standard deviation in wavelength for a velocity dispersion
/// `sigma_m_per_s` at wavelength `centre_nm`: `centre_nm * sigma / c`.
#[must_use]
pub fn velocity_sigma_to_nm(centre_nm: f64, sigma_m_per_s: f64) -> f64 {
    centre_nm * sigma_m_per_s / SPEED_OF_LIGHT_M_PER_S
}

/// A unit-area Gaussian as piecewise-linear pieces (see the module docs for the bound).
#[derive(Clone, Debug, PartialEq)]
pub struct PwlGaussian {
    /// Knot positions in units of sigma, ascending, symmetric.
    x: Vec<f64>,
    /// Knot values of the unit-area, unit-sigma profile (first and last are 0).
    g: Vec<f64>,
    /// Area below each knot (0 at the first, 1 at the last).
    cum: Vec<f64>,
    bound: f64,
}

impl Default for PwlGaussian {
    fn default() -> Self {
        Self::new(4, 4.0).expect("default Gaussian parameters are valid")
    }
}

impl PwlGaussian {
    /// Knots `1 / pieces_per_sigma` apart over `[-half_width_sigmas, half_width_sigmas]`
    /// (`pieces_per_sigma` in 1..=64, `half_width_sigmas` in [1, 10]).
    pub fn new(pieces_per_sigma: usize, half_width_sigmas: f64) -> Result<Self> {
        if !(1..=64).contains(&pieces_per_sigma) {
            return Err(Error::param(
                "pieces per sigma",
                pieces_per_sigma as f64,
                "must be 1..=64",
            ));
        }
        if !(half_width_sigmas.is_finite() && (1.0..=10.0).contains(&half_width_sigmas)) {
            return Err(Error::param(
                "Gaussian half width (sigmas)",
                half_width_sigmas,
                "must be in [1, 10]",
            ));
        }
        let h = 1.0 / pieces_per_sigma as f64;
        let n_half = (half_width_sigmas / h).ceil() as usize;
        let l = n_half as f64 * h;
        let norm = 1.0 / (2.0 * std::f64::consts::PI).sqrt();
        let x: Vec<f64> = (0..=2 * n_half)
            .map(|i| (i as f64 - n_half as f64) * h)
            .collect();
        let mut g: Vec<f64> = x.iter().map(|&x| norm * (-0.5 * x * x).exp()).collect();
        g[0] = 0.0;
        g[2 * n_half] = 0.0;
        let area: f64 = g.windows(2).map(|w| 0.5 * h * (w[0] + w[1])).sum();
        let eps = 1.0 / area - 1.0;
        for v in &mut g {
            *v /= area;
        }
        let mut cum = vec![0.0; g.len()];
        for i in 1..g.len() {
            cum[i] = cum[i - 1] + 0.5 * h * (g[i - 1] + g[i]);
        }
        let bound =
            h * h / 8.0 + (-0.5 * (l - h) * (l - h)).exp() + eps.abs() * (1.0 + h * h / 8.0);
        Ok(Self { x, g, cum, bound })
    }

    /// The exact area of the unit profile below `z` (in sigmas from the centre): the
    /// integral of the pieces, a piecewise quadratic from 0 to 1.
    #[must_use]
    pub fn cdf(&self, z: f64) -> f64 {
        let (x0, xn) = (self.x[0], self.x[self.x.len() - 1]);
        if z <= x0 || z.is_nan() {
            return 0.0;
        }
        if z >= xn {
            return self.cum[self.cum.len() - 1];
        }
        let h = self.x[1] - self.x[0];
        let i = (((z - x0) / h) as usize).min(self.x.len() - 2);
        let d = z - self.x[i];
        let slope = (self.g[i + 1] - self.g[i]) / h;
        self.cum[i] + d * (self.g[i] + 0.5 * slope * d)
    }

    /// Number of pieces.
    #[must_use]
    pub fn piece_count(&self) -> usize {
        self.x.len() - 1
    }

    /// The bound on `sup |profile - exact Gaussian|` relative to the exact peak.
    #[must_use]
    pub fn sup_error_relative(&self) -> f64 {
        self.bound
    }

    /// Half width of the support, in sigmas.
    #[must_use]
    pub fn half_width_sigmas(&self) -> f64 {
        self.x[self.x.len() - 1]
    }

    /// Calls `piece(lo, hi, value_lo, value_hi)` for each piece of the Gaussian of area
    /// `area` and standard deviation `sigma` (same unit as `centre`) centred at `centre`.
    /// The pieces' areas sum to `area` (to rounding). Nothing is emitted for `sigma <= 0`.
    pub fn for_each_piece<E>(
        &self,
        centre: f64,
        sigma: f64,
        area: f64,
        mut piece: impl FnMut(f64, f64, f64, f64) -> std::result::Result<(), E>,
    ) -> std::result::Result<(), E> {
        if sigma <= 0.0 || !sigma.is_finite() {
            return Ok(());
        }
        let k = area / sigma;
        for i in 0..self.x.len() - 1 {
            piece(
                centre + self.x[i] * sigma,
                centre + self.x[i + 1] * sigma,
                k * self.g[i],
                k * self.g[i + 1],
            )?;
        }
        Ok(())
    }

    /// Calls `kink(x, slope_change)` at each knot of the Gaussian of area `area` and standard
    /// deviation `sigma` centred at `centre`, in ascending `x`: the profile is
    /// `sum_i slope_change_i * max(x - x_i, 0)` (zero below the first knot; the changes sum
    /// to zero, so it is zero past the last), and its integral up to `e` is
    /// `sum_i slope_change_i * max(e - x_i, 0)^2 / 2`. Nothing is called for `sigma <= 0`.
    pub fn for_each_kink(
        &self,
        centre: f64,
        sigma: f64,
        area: f64,
        mut kink: impl FnMut(f64, f64),
    ) {
        if sigma <= 0.0 || !sigma.is_finite() {
            return;
        }
        let h = self.x[1] - self.x[0];
        let k = area / (sigma * sigma * h);
        let n = self.x.len();
        let mut prev = 0.0;
        for i in 0..n {
            // Slope (per unit z, times h) of the piece right of knot i; 0 past the last.
            let next = if i + 1 < n {
                self.g[i + 1] - self.g[i]
            } else {
                0.0
            };
            kink(centre + self.x[i] * sigma, k * (next - prev));
            prev = next;
        }
    }

    /// Adds the Gaussian (area `area` >= 0, `sigma` > 0) to a spectrum.
    pub fn add_to(
        &self,
        spectrum: &mut PiecewiseLinear,
        centre_nm: f64,
        sigma_nm: f64,
        area: f64,
    ) -> Result<()> {
        positive("Gaussian sigma (nm)", sigma_nm)?;
        non_negative("line area", area)?;
        self.for_each_piece(centre_nm, sigma_nm, area, |a, b, h0, h1| {
            spectrum.add_trapezoid(a, b, h0, h1)
        })
    }
}

impl Catalogue {
    /// Standard atomic weight of the catalogue's element, amu (IUPAC 2021 conventional
    /// values: H 1.008, He 4.002602, C 12.011).
    #[must_use]
    pub fn atomic_mass_amu(self) -> f64 {
        match self {
            Self::HydrogenBalmer => 1.008,
            Self::HeliumI => 4.002_602,
            Self::CarbonI => 12.011,
        }
    }
}

/// A named line: its catalogue and the line (air wavelength, relative strength).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NamedLine {
    /// The catalogue (species) the line belongs to.
    pub catalogue: Catalogue,
    /// The line.
    pub line: EmissionLine,
}

/// Looks up a line by name: `H-alpha`/`Halpha`/`Ha` (656.28 nm), `H-beta` (486.13),
/// `H-gamma` (434.05), `H-delta` (410.17), `HeI-5876`/`He5876` (587.56), `HeI-6678`
/// (667.82), `HeI-4471` (447.15) (case-insensitive; `-`, `_` and spaces ignored). The line
/// is taken from the built-in catalogue (the nearest catalogue line to the name's nominal
/// wavelength).
pub fn named_line(name: &str) -> Result<NamedLine> {
    let n: String = name
        .chars()
        .filter(|c| !matches!(c, '-' | '_' | ' '))
        .collect::<String>()
        .to_ascii_lowercase();
    let (catalogue, nominal) = match n.as_str() {
        "halpha" | "ha" | "hα" => (Catalogue::HydrogenBalmer, 656.28),
        "hbeta" | "hb" | "hβ" => (Catalogue::HydrogenBalmer, 486.13),
        "hgamma" | "hg" | "hγ" => (Catalogue::HydrogenBalmer, 434.05),
        "hdelta" | "hd" | "hδ" => (Catalogue::HydrogenBalmer, 410.17),
        "hei5876" | "he5876" => (Catalogue::HeliumI, 587.56),
        "hei6678" | "he6678" => (Catalogue::HeliumI, 667.82),
        "hei4471" | "he4471" => (Catalogue::HeliumI, 447.15),
        _ => {
            return Err(Error::UnknownName {
                what: "line",
                name: name.to_owned(),
                known: "H-alpha, H-beta, H-gamma, H-delta, HeI-5876, HeI-6678, HeI-4471",
            });
        }
    };
    let line = catalogue
        .lines()
        .into_iter()
        .min_by(|a, b| {
            (a.centre_nm - nominal)
                .abs()
                .total_cmp(&(b.centre_nm - nominal).abs())
        })
        .ok_or_else(|| Error::param("catalogue size", 0.0, "catalogue is empty"))?;
    if (line.centre_nm - nominal).abs() > 0.1 {
        return Err(Error::param(
            "line wavelength (nm)",
            nominal,
            "not in the built-in catalogue",
        ));
    }
    Ok(NamedLine { catalogue, line })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn gauss(x: f64) -> f64 {
        (-0.5 * x * x).exp() / (2.0 * std::f64::consts::PI).sqrt()
    }

    #[test]
    fn pwl_gaussian_keeps_area_and_meets_its_bound() {
        for (pps, l) in [(4, 4.0), (2, 4.0), (8, 5.0)] {
            let g = PwlGaussian::new(pps, l).unwrap();
            let (c, sigma, area) = (656.28, 0.037, 2.5);
            let mut s = PiecewiseLinear::new();
            g.add_to(&mut s, c, sigma, area).unwrap();
            assert!(
                ((s.total() - area) / area).abs() < 1e-12,
                "area {}",
                s.total()
            );
            let peak = area / sigma * gauss(0.0);
            let mut err: f64 = 0.0;
            for i in -4000..=4000 {
                let x = f64::from(i) * 0.002;
                let exact = area / sigma * gauss(x);
                err = err.max((s.eval(c + x * sigma) - exact).abs());
            }
            let rel = err / peak;
            assert!(rel <= g.sup_error_relative(), "{pps},{l}: {rel} > bound");
            // The bound is not loose by more than a factor ~2 (h^2/8 is attained at 0).
            assert!(rel > 0.3 * g.sup_error_relative(), "{pps},{l}: {rel}");
        }
        assert!(PwlGaussian::default().sup_error_relative() < 0.0088);
        // The line profile keeps the line's strength as its area.
        let line = EmissionLine::new(486.1332, 0.35).unwrap();
        let s = line
            .to_piecewise(crate::LineProfile::Gaussian { sigma_nm: 0.02 })
            .unwrap();
        assert!((s.total() - 0.35).abs() < 1e-12);
        assert!(
            line.to_piecewise(crate::LineProfile::Gaussian { sigma_nm: 0.0 })
                .is_err()
        );
    }

    #[test]
    fn cdf_is_the_integral_of_the_pieces() {
        let g = PwlGaussian::default();
        let mut s = PiecewiseLinear::new();
        g.add_to(&mut s, 0.0, 1.0, 1.0).unwrap();
        for i in -50..50 {
            let (a, b) = (f64::from(i) * 0.097, f64::from(i) * 0.097 + 0.31);
            let exact = s.integrate(a, b).unwrap();
            assert!((g.cdf(b) - g.cdf(a) - exact).abs() < 1e-13, "{a} {b}");
        }
        assert!((g.cdf(10.0) - 1.0).abs() < 1e-13 && g.cdf(-10.0) == 0.0);
    }

    #[test]
    fn thermal_width_of_hydrogen_at_1e4_k() {
        // sqrt(k * 1e4 K / (1.008 u)) = 9.082 km/s; v_th = sqrt(2kT/m) = 12.84 km/s, the
        // textbook 12.8 km/s hydrogen thermal speed at 1e4 K.
        let s = thermal_sigma_m_per_s(1e4, Catalogue::HydrogenBalmer.atomic_mass_amu()).unwrap();
        assert!((s - 9_082.1).abs() < 0.5, "{s}");
        assert!(((2.0f64).sqrt() * s - 12_844.0).abs() < 1.0);
        assert!(thermal_sigma_m_per_s(-1.0, 1.0).is_err());
        assert!(thermal_sigma_m_per_s(1.0, 0.0).is_err());
    }

    #[test]
    fn named_lines() {
        let h = named_line("H-alpha").unwrap();
        assert_eq!(h.catalogue, Catalogue::HydrogenBalmer);
        assert!((h.line.centre_nm - 656.2816).abs() < 1e-9);
        assert_eq!(named_line("halpha").unwrap(), h);
        assert!(named_line("Hbeta").unwrap().line.centre_nm - 486.1332 < 1e-9);
        assert!(named_line("OIII").is_err());
    }
}
