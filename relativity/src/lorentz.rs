//! Special relativity: velocities, Lorentz boosts, aberration, Doppler factor, searchlight.
//!
//! Units: `c = 1`. Times are `c t` (same unit as lengths). Frames: the **scene frame** `S` is
//! the rest frame of the environment; the **observer frame** `S'` moves with velocity `beta`
//! (a vector, `|beta| < 1`) relative to `S`.
//!
//! Directions are **viewing directions**: unit vectors from the observer towards what is seen
//! (the opposite of the photon's direction of travel). The relativistic-visualization paper
//! writes its Eq. 2 with angles measured from the direction of motion; here both
//! directions are vectors in any orientation.

use blueshift_spectrum::DopplerFactor;
use glam::DVec3;

use crate::error::{Error, Result};

/// A velocity `beta = v / c` with `|beta| < 1`, with its speed and Lorentz factor cached.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Velocity {
    beta: DVec3,
    speed: f64,
    gamma: f64,
}

impl Velocity {
    /// At rest.
    pub const ZERO: Self = Self {
        beta: DVec3::ZERO,
        speed: 0.0,
        gamma: 1.0,
    };

    /// A velocity from `beta = v / c`. Refuses NaN/infinite components and `|beta| >= 1`.
    pub fn new(beta: DVec3) -> Result<Self> {
        let err = |reason| Error::Velocity {
            x: beta.x,
            y: beta.y,
            z: beta.z,
            reason,
        };
        if !beta.is_finite() {
            return Err(err("components must be finite numbers"));
        }
        let speed = beta.length();
        if speed >= 1.0 {
            return Err(err("the speed |beta| must be < 1 (slower than light)"));
        }
        // gamma = 1 / sqrt(1 - beta^2) (the paper's "1 / sqrt(1 - beta)" is a typo).
        let gamma = 1.0 / ((1.0 - speed) * (1.0 + speed)).sqrt();
        Ok(Self { beta, speed, gamma })
    }

    /// A velocity of speed `speed` (in units of c, may be negative: then it points along
    /// `-direction`) along `direction` (need not be normalised, must not be zero).
    pub fn along(direction: DVec3, speed: f64) -> Result<Self> {
        let dir = unit(direction, "velocity direction length")?;
        if !speed.is_finite() {
            return Err(Error::param("speed |beta|", speed, "must be finite"));
        }
        Self::new(dir * speed)
    }

    /// A velocity with the given rapidity `phi = artanh(|beta|)` along `direction`.
    pub fn from_rapidity(direction: DVec3, rapidity: f64) -> Result<Self> {
        Self::along(direction, rapidity.tanh())
    }

    /// `beta = v / c`.
    #[must_use]
    pub fn beta(self) -> DVec3 {
        self.beta
    }

    /// `|beta|`.
    #[must_use]
    pub fn speed(self) -> f64 {
        self.speed
    }

    /// The Lorentz factor `gamma = 1 / sqrt(1 - beta^2)`.
    #[must_use]
    pub fn gamma(self) -> f64 {
        self.gamma
    }

    /// The rapidity `phi = artanh(|beta|)` (rapidities of collinear boosts add).
    #[must_use]
    pub fn rapidity(self) -> f64 {
        self.speed.atanh()
    }

    /// The opposite velocity (the scene frame as seen from the observer frame).
    #[must_use]
    pub fn inverse(self) -> Self {
        Self {
            beta: -self.beta,
            ..self
        }
    }

    /// Relativistic velocity addition `self (+) other`: the velocity in `S` of a body moving
    /// with `other` relative to a frame that moves with `self` relative to `S`:
    /// `(u + v / gamma_u + gamma_u / (1 + gamma_u) (u . v) u) / (1 + u . v)`.
    /// For collinear velocities this is `(u + v) / (1 + u v)`.
    pub fn compose(self, other: Self) -> Result<Self> {
        let u = self.beta;
        let v = other.beta;
        let g = self.gamma;
        let uv = u.dot(v);
        let w = (u + v / g + (g / (1.0 + g)) * uv * u) / (1.0 + uv);
        Self::new(w)
    }

    /// The Lorentz boost matrix into the frame moving with this velocity (paper Eq. 1).
    #[must_use]
    pub fn boost(self) -> LorentzMatrix {
        LorentzMatrix::boost(self)
    }

    /// Maps an observer-frame viewing direction to the scene-frame viewing direction
    /// (inverse aberration; the relativistic-visualization paper's Eq. 2 generalised to any
    /// direction of motion): with `c' = d' . u` (`u` the unit velocity),
    /// `d_par = (c' - b) / (1 - b c')`, `d_perp = d'_perp / (gamma (1 - b c'))`.
    /// The input must be a unit vector; the output is one.
    #[must_use]
    pub fn observer_to_scene(self, d_obs: DVec3) -> DVec3 {
        self.aberrate(d_obs, -1.0)
    }

    /// Maps a scene-frame viewing direction to where the observer sees it (aberration):
    /// `d'_par = (c + b) / (1 + b c)`, `d'_perp = d_perp / (gamma (1 + b c))`.
    #[must_use]
    pub fn scene_to_observer(self, d_scene: DVec3) -> DVec3 {
        self.aberrate(d_scene, 1.0)
    }

    #[inline]
    fn aberrate(self, d: DVec3, sign: f64) -> DVec3 {
        if self.speed == 0.0 {
            return d;
        }
        let b = self.speed * sign;
        let u = self.beta / self.speed;
        let c = d.dot(u);
        let perp = d - c * u;
        // One division: `1 / (1 + b c)`, then products (the renderer's lanes do the same).
        let inv = 1.0 / (1.0 + b * c);
        let par = (c + b) * inv;
        let out = par * u + perp * (inv * (1.0 / self.gamma));
        // Renormalise to stop rounding drift (the exact map preserves length).
        out.normalize()
    }

    /// The Doppler factor `D = nu_obs / nu_emit` of light seen by the observer in the
    /// observer-frame viewing direction `d_obs` (unit): `D = 1 / (gamma (1 - beta . d'))`.
    /// Head-on (`d' = beta / |beta|`) it is `sqrt((1 + b) / (1 - b))`.
    #[must_use]
    pub fn doppler_factor_observer(self, d_obs: DVec3) -> f64 {
        1.0 / (self.gamma * (1.0 - self.beta.dot(d_obs)))
    }

    /// The same factor from the scene-frame viewing direction `d_scene` of the same ray
    /// (paper Eq. 3): `D = gamma (1 + beta . d)`.
    #[must_use]
    pub fn doppler_factor_scene(self, d_scene: DVec3) -> f64 {
        self.gamma * (1.0 + self.beta.dot(d_scene))
    }

    /// [`Self::doppler_factor_observer`] as the spectrum crate's typed frequency ratio.
    pub fn doppler(self, d_obs: DVec3) -> Result<DopplerFactor> {
        let d = unit(d_obs, "viewing direction length")?;
        Ok(DopplerFactor::new(self.doppler_factor_observer(d))?)
    }
}

/// Normalises `v`, refusing zero, NaN and infinite vectors.
pub fn unit(v: DVec3, name: &'static str) -> Result<DVec3> {
    let len = v.length();
    if !(len.is_finite() && len > 0.0) {
        return Err(Error::param(name, len, "must be finite and > 0"));
    }
    Ok(v / len)
}

/// An event: time `t` (as `c t`) and position `x`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Event {
    /// Time times c.
    pub t: f64,
    /// Position.
    pub x: DVec3,
}

/// A 4x4 Lorentz transformation acting on `(c t, x, y, z)` (row-major).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LorentzMatrix(pub [[f64; 4]; 4]);

impl LorentzMatrix {
    /// The identity.
    pub const IDENTITY: Self = Self([
        [1.0, 0.0, 0.0, 0.0],
        [0.0, 1.0, 0.0, 0.0],
        [0.0, 0.0, 1.0, 0.0],
        [0.0, 0.0, 0.0, 1.0],
    ]);

    /// The pure boost into the frame moving with `v` (relativistic-visualization Eq. 1, with
    /// `gamma = 1 / sqrt(1 - beta^2)` and the sign for a frame moving with `+beta`):
    /// `t' = gamma (t - beta . x)`, `x' = x + ((gamma - 1) / beta^2 (beta . x) - gamma t) beta`.
    #[must_use]
    pub fn boost(v: Velocity) -> Self {
        let b = v.beta.to_array();
        let g = v.gamma;
        let b2 = v.speed * v.speed;
        let k = if b2 > 0.0 { (g - 1.0) / b2 } else { 0.0 };
        let mut m = [[0.0; 4]; 4];
        m[0][0] = g;
        for i in 0..3 {
            m[0][i + 1] = -g * b[i];
            m[i + 1][0] = -g * b[i];
            for j in 0..3 {
                m[i + 1][j + 1] = f64::from(u8::from(i == j)) + k * b[i] * b[j];
            }
        }
        Self(m)
    }

    /// The product `self * rhs` (apply `rhs` first).
    #[must_use]
    pub fn mul(&self, rhs: &Self) -> Self {
        let mut m = [[0.0; 4]; 4];
        for i in 0..4 {
            for j in 0..4 {
                m[i][j] = (0..4).map(|k| self.0[i][k] * rhs.0[k][j]).sum();
            }
        }
        Self(m)
    }

    /// Applies the transformation to a four-vector `(c t, x, y, z)`.
    #[must_use]
    pub fn apply4(&self, v: [f64; 4]) -> [f64; 4] {
        let mut out = [0.0; 4];
        for i in 0..4 {
            out[i] = (0..4).map(|k| self.0[i][k] * v[k]).sum();
        }
        out
    }

    /// Applies the transformation to an event.
    #[must_use]
    pub fn apply(&self, e: Event) -> Event {
        let o = self.apply4([e.t, e.x.x, e.x.y, e.x.z]);
        Event {
            t: o[0],
            x: DVec3::new(o[1], o[2], o[3]),
        }
    }

    /// The largest absolute difference of entries (for comparisons).
    #[must_use]
    pub fn max_abs_diff(&self, other: &Self) -> f64 {
        let mut m = 0.0_f64;
        for i in 0..4 {
            for j in 0..4 {
                m = m.max((self.0[i][j] - other.0[i][j]).abs());
            }
        }
        m
    }
}

// The searchlight effect (Weiskopf, Kraus and Ruder 1999, "Searchlight and Doppler effects
// in the visualization of special relativity: a corrected derivation of the transformation
// of radiance", ACM TOG 18(3)).
//
// Derivation in brief: the photon phase-space density `f = I_nu / nu^3` is a Lorentz
// invariant (Liouville: the number of photons in a phase-space cell is frame independent).
// So `I'_nu'(nu') = (nu' / nu)^3 I_nu(nu) = D^3 I_nu(nu)` with `nu' = D nu`. Per wavelength,
// `I_lambda = I_nu nu^2 / c`, so `I'_lambda'(lambda') = D^5 I_lambda(lambda' D)`. Integrating
// over frequency, `d nu' = D d nu`, gives the total radiance `L' = D^4 L`. (Earlier
// literature used other exponents for the total; the corrected one is 4.)

/// Searchlight factor on spectral radiance per unit frequency at corresponding frequencies,
/// `D^3` (`I_nu / nu^3` is invariant; Weiskopf, Kraus and Ruder 1999).
#[must_use]
pub fn searchlight_per_frequency(doppler_factor: f64) -> f64 {
    doppler_factor.powi(3)
}

/// Searchlight factor on spectral radiance per unit wavelength at corresponding wavelengths,
/// `D^5` (`I_lambda lambda^5` is invariant).
#[must_use]
pub fn searchlight_per_wavelength(doppler_factor: f64) -> f64 {
    doppler_factor.powi(5)
}

/// Searchlight factor on frequency-integrated radiance, `D^4`.
#[must_use]
pub fn searchlight_integrated(doppler_factor: f64) -> f64 {
    doppler_factor.powi(4)
}
