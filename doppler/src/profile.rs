//! Line profiles inside a ray segment: the paper's box, thermal Doppler broadening and a
//! user Gaussian width.
//!
//! Within a segment the line's centre moves linearly from `s_a * lambda_0` to
//! `s_b * lambda_0` while its emitted area changes linearly from one end to the other: the
//! unbroadened result is a trapezoid (see `pwl::line_trapezoid`). A Gaussian profile of
//! standard deviation `sigma` (linear in the path, from the ends' temperatures) is convolved
//! with it by splitting the sweep into `M = ceil(4 * sweep / sigma)` equal sub-intervals
//! (`M <= 64`) and placing one [`PwlGaussian`] per sub-interval at the sub-interval's
//! area centroid with the sub-interval's exact area. Area (and the first moment) are kept
//! exactly; replacing a sub-interval's box of width `d <= sigma / 4` by a Gaussian at its
//! centroid errs by at most `d^2 / (24 sigma^2) <= 0.26 %` of the Gaussian's peak, on top
//! of the 0.87 % of [`PwlGaussian`]. A sweep wider than `16 sigma` is emitted as the plain
//! trapezoid (the Gaussian only rounds its edges over about `sigma`, moving less than
//! `sigma / sweep < 6.3 %` of the area by about `sigma`).

use blueshift_spectrum::{BOLTZMANN_J_PER_K, Catalogue, PwlGaussian, SPEED_OF_LIGHT_M_PER_S};

use super::model::DopplerScene;
use crate::{Error, Result};

/// Line broadening applied to every emission and absorption line of a scene (piecewise-linear
/// integrator and cubes; the banded integrators refuse it).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Broadening {
    /// Thermal Doppler broadening, `sigma_v = sqrt(k T / m)` (yt's `v_th^2 = 2 k T / m`),
    /// from the scene's temperature field (the black-body temperature channel times the
    /// temperature factor) and each species' atomic mass.
    pub thermal: bool,
    /// An extra Gaussian velocity dispersion (1 sigma), m/s, added in quadrature (0: none).
    pub sigma_m_per_s: f64,
    /// Atomic masses by species name, amu, overriding the catalogue masses (species named
    /// `H`, `He`, `C` take [`Catalogue::atomic_mass_amu`]).
    pub masses_amu: Vec<(String, f64)>,
}

impl Broadening {
    /// True when lines keep the paper's box profile.
    #[must_use]
    pub fn is_none(&self) -> bool {
        !self.thermal && self.sigma_m_per_s == 0.0
    }
}

/// The line-broadening tables (part of [`crate::Prepared`]), built with the checks of the
/// broadening settings.
#[derive(Debug)]
pub struct Profiles {
    /// The piecewise-linear unit Gaussian every broadened line is placed as.
    pub gauss: PwlGaussian,
    /// Per species: `k / m` in (m/s)^2 per K (0 without thermal broadening).
    pub k_over_m: Vec<f64>,
    /// User dispersion squared, (m/s)^2.
    pub sigma2_user: f64,
    /// Whether any broadening applies (else lines keep the paper's box).
    pub active: bool,
}

impl Profiles {
    /// The tables for `scene` and broadening `b`.
    ///
    /// # Errors
    /// A non-finite or negative sigma, a temperature field with negative values, thermal
    /// broadening without a temperature field, a species without a known atomic mass.
    pub fn new(scene: &DopplerScene, b: &Broadening) -> Result<Self> {
        if !(b.sigma_m_per_s.is_finite() && b.sigma_m_per_s >= 0.0) {
            return Err(Error::parameter(format!(
                "line sigma {} m/s must be finite and >= 0",
                b.sigma_m_per_s
            )));
        }
        let mut k_over_m = vec![0.0; scene.species.len()];
        if let Some((_, temp)) = &scene.blackbody
            && let Some((lo, _)) = temp.finite_range()
            && lo < 0.0
        {
            return Err(Error::scene(format!(
                "the temperature field has negative values (min {lo} K)"
            )));
        }
        if b.thermal {
            let Some((_, temp)) = &scene.blackbody else {
                return Err(Error::scene(
                    "thermal broadening needs a temperature field (the scene's black-body \
                 temperature: keep `bb` among the species; a black-body factor of 0 keeps \
                 it dark)",
                ));
            };
            let _ = temp;
            for (i, sp) in scene.species.iter().enumerate() {
                let m = match b.masses_amu.iter().find(|(n, _)| n == &sp.name) {
                    Some(&(_, m)) => m,
                    None => Catalogue::parse(&sp.name)
                        .map(Catalogue::atomic_mass_amu)
                        .map_err(|_| {
                            Error::parameter(format!(
                                "species '{}' has no known atomic mass: give one",
                                sp.name
                            ))
                        })?,
                };
                if !(m.is_finite() && m > 0.0) {
                    return Err(Error::parameter(format!(
                        "atomic mass {m} of '{}' must be finite and > 0",
                        sp.name
                    )));
                }
                k_over_m[i] = BOLTZMANN_J_PER_K / (m * blueshift_spectrum::ATOMIC_MASS_UNIT_KG);
            }
        }
        Ok(Self {
            gauss: PwlGaussian::default(),
            k_over_m,
            sigma2_user: b.sigma_m_per_s * b.sigma_m_per_s,
            active: !b.is_none(),
        })
    }

    /// Velocity dispersion of species `m` at temperature `t_k`, m/s.
    #[must_use]
    pub fn sigma_v(&self, m: usize, t_k: f64) -> f64 {
        (self.k_over_m[m] * t_k.max(0.0) + self.sigma2_user).sqrt()
    }
}

/// What [`emit_line`] produces.
#[derive(Clone, Copy, Debug)]
pub(crate) enum Emit {
    /// A trapezoid `(lo, hi, h_lo, h_hi)`.
    Trapezoid(f64, f64, f64, f64),
    /// The [`PwlGaussian`] at `(centre, sigma, area)` (wavelengths in nm).
    Gaussian(f64, f64, f64),
}

/// Emits one line's contribution over a segment as trapezoids and Gaussians:
/// centre `centre` seen through shifts `sa`, `sb`, emitted areas `area_a`, `area_b` at the
/// ends (the segment emits their mean), velocity dispersions `sig_a`, `sig_b` (m/s) at the
/// ends, `min_width` the box width used without broadening.
#[allow(clippy::too_many_arguments)]
pub(crate) fn emit_line<E>(
    centre: f64,
    sa: f64,
    sb: f64,
    area_a: f64,
    area_b: f64,
    sig_a: f64,
    sig_b: f64,
    min_width: f64,
    sink: &mut impl FnMut(Emit) -> std::result::Result<(), E>,
) -> std::result::Result<(), E> {
    let (la, lb) = (sa * centre, sb * centre);
    // Widths below 1e-9 of the wavelength (0.3 m/s) are raised to it: narrower Gaussians'
    // pieces would collapse below the wavelength's rounding and lose the line.
    let floor = 1e-9 * la.max(lb);
    let width = |l: f64, sig: f64| {
        let w = l * sig / SPEED_OF_LIGHT_M_PER_S;
        if w > 0.0 { w.max(floor) } else { w }
    };
    let (sna, snb) = (width(la, sig_a), width(lb, sig_b));
    let sigma_mean = 0.5 * (sna + snb);
    let sweep = (lb - la).abs();
    if sigma_mean <= 0.0 || sweep >= 16.0 * sigma_mean {
        let min_width = if sigma_mean > 0.0 { 0.0 } else { min_width };
        let (lo, hi, h0, h1) =
            super::pwl::line_trapezoid(centre, sa, sb, area_a, area_b, min_width);
        if hi > lo {
            return sink(Emit::Trapezoid(lo, hi, h0, h1));
        }
        // A zero-width sweep with a zero minimum width cannot happen (sigma_mean > 0 then
        // takes the Gaussian branch below).
        return Ok(());
    }
    let m = ((4.0 * sweep / sigma_mean).ceil() as usize).clamp(1, 64);
    let inv = 1.0 / m as f64;
    let da = area_b - area_a;
    for k in 0..m {
        let (u0, u1) = (k as f64 * inv, (k + 1) as f64 * inv);
        let (a0, a1) = (area_a + da * u0, area_a + da * u1);
        let area = 0.5 * (a0 + a1) * (u1 - u0);
        if area <= 0.0 {
            continue;
        }
        // Centroid of the linear density a(u) over [u0, u1].
        let num = area_a * 0.5 * (u1 * u1 - u0 * u0) + da * (u1.powi(3) - u0.powi(3)) / 3.0;
        let uc = (num / area).clamp(u0, u1);
        let pos = la + (lb - la) * uc;
        let sigma = sna + (snb - sna) * uc;
        if sigma > 0.0 {
            sink(Emit::Gaussian(pos, sigma, area))?;
        } else {
            let w = min_width.max(1e-9);
            sink(Emit::Trapezoid(
                pos - 0.5 * w,
                pos + 0.5 * w,
                area / w,
                area / w,
            ))?;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use blueshift_spectrum::PiecewiseLinear;

    fn emitted(sa: f64, sb: f64, aa: f64, ab: f64, siga: f64, sigb: f64) -> PiecewiseLinear {
        let g = PwlGaussian::default();
        let mut s = PiecewiseLinear::new();
        emit_line(656.28, sa, sb, aa, ab, siga, sigb, 0.1, &mut |e| match e {
            Emit::Trapezoid(a, b, h0, h1) => s.add_trapezoid(a, b, h0, h1),
            Emit::Gaussian(c, sg, area) => g.add_to(&mut s, c, sg, area),
        })
        .unwrap();
        s
    }

    /// The broadened sweep keeps the segment's area and first moment, and equals the
    /// analytic convolution of the sweep with the Gaussian within the stated bound.
    #[test]
    fn broadened_sweep_matches_the_analytic_convolution() {
        let c = 656.28;
        let (sa, sb) = (1.0, 1.0 + 40e3 / SPEED_OF_LIGHT_M_PER_S); // 40 km/s sweep
        let (aa, ab) = (1.0, 3.0);
        let sig = 20e3; // 20 km/s: sweep = 2 sigma
        let s = emitted(sa, sb, aa, ab, sig, sig);
        let area = 0.5 * (aa + ab);
        assert!((s.total() - area).abs() < 1e-12 * area);
        let (la, lb) = (sa * c, sb * c);
        let sn = c * sig / SPEED_OF_LIGHT_M_PER_S;
        // Exact: integral over u of a(u) N(x; la + u (lb - la), sn) du (fine quadrature).
        let exact = |x: f64| {
            let n = 4000;
            (0..n)
                .map(|i| {
                    let u = (i as f64 + 0.5) / n as f64;
                    let a = aa + (ab - aa) * u;
                    let mu = la + (lb - la) * u;
                    let z = (x - mu) / sn;
                    a * (-0.5 * z * z).exp() / ((2.0 * std::f64::consts::PI).sqrt() * sn)
                })
                .sum::<f64>()
                / n as f64
        };
        let mut err: f64 = 0.0;
        let mut peak: f64 = 0.0;
        let mut mom = (0.0, 0.0);
        for i in -400..=400 {
            let x = 0.5 * (la + lb) + f64::from(i) * sn * 0.02;
            let e = exact(x);
            peak = peak.max(e);
            err = err.max((s.eval(x) - e).abs());
            mom.0 += e;
            mom.1 += e * x;
        }
        // Stated bound: 0.87 % (PWL Gaussian) + 0.26 % (sub-interval centroids) of the peak
        // of each Gaussian; the sum of sub-Gaussians is below the sweep's peak.
        assert!(err / peak < 0.0113, "relative sup error {}", err / peak);
        let mean_exact = mom.1 / mom.0;
        let m1: f64 = (0..20000)
            .map(|i| {
                let x = la - 6.0 * sn + f64::from(i) * (lb - la + 12.0 * sn) / 20000.0;
                s.eval(x) * x
            })
            .sum::<f64>()
            * (lb - la + 12.0 * sn)
            / 20000.0;
        assert!((m1 / area - mean_exact).abs() < 1e-3 * sn, "first moment");
    }

    #[test]
    fn without_broadening_the_box_is_unchanged() {
        let s = emitted(1.0, 1.0, 2.0, 2.0, 0.0, 0.0);
        assert!((s.total() - 2.0).abs() < 1e-9);
        assert!((s.eval(656.28) - 2.0 / 0.1).abs() < 1e-9);
    }
}
