//! An observer moving through a volume at rest: what the volume renderers (Doppler,
//! Woodcock, MDWT, the ray marcher) need per ray.
//!
//! The volume's frame is the scene frame `S` of [`crate::lorentz`]; the camera's pixels are
//! viewing directions `d'` in the observer's frame. Each pixel's ray is traced through the
//! volume along the scene-frame direction `d` that aberration gives
//! ([`Velocity::observer_to_scene`]), and everything seen along it reaches the observer
//! with one Doppler factor `D = gamma (1 + beta . d)` (= `nu_obs / nu_scene`), the same for
//! every sample of the ray because the direction is. A Doppler renderer multiplies each
//! sample's own wavelength shift by `1 / D`: the observed shift of light emitted by gas
//! moving with `u` is then `1 / (D_gas(u, d) D)`, the relativistic composition of the two
//! velocities (an observer moving with the gas sees it unshifted: `D_gas D = 1` when
//! `beta = u`). An RGB renderer maps the ray's colour through the relativity crate's exact
//! colour matrix `K(D)`, times `D^4` with the searchlight effect.

use glam::{DVec3, Vec3};

use crate::Velocity;
use crate::colour::DopplerColourTable;

/// A moving observer: its velocity relative to the volume and whether its images show the
/// searchlight effect (the `I_nu / nu^3` invariant: intensity `D^4` for integrated RGB,
/// `D^5` per wavelength).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MovingObserver {
    /// Velocity relative to the volume's rest frame (`|beta| < 1`, checked by [`Velocity`]).
    pub velocity: Velocity,
    /// Scale brightness by the searchlight effect (RGB renders; Doppler renders take the
    /// invariant radiance transform of their own settings instead).
    pub searchlight: bool,
}

impl MovingObserver {
    /// An observer with velocity `velocity`, searchlight off.
    #[must_use]
    pub fn new(velocity: Velocity) -> Self {
        Self {
            velocity,
            searchlight: false,
        }
    }

    /// Whether the observer is at rest (then renders are today's, bit for bit).
    #[must_use]
    pub fn is_at_rest(&self) -> bool {
        self.velocity.speed() == 0.0
    }

    /// The scene-frame direction to trace for the observer-frame viewing direction `d_obs`
    /// (a camera ray's direction; need not be normalised). At rest: `d_obs` unchanged.
    #[must_use]
    pub fn scene_direction(&self, d_obs: Vec3) -> Vec3 {
        if self.is_at_rest() {
            return d_obs;
        }
        let d = d_obs.as_dvec3().normalize_or_zero();
        if d == DVec3::ZERO {
            return d_obs;
        }
        self.velocity.observer_to_scene(d).as_vec3()
    }

    /// The Doppler factor `D = nu_obs / nu_scene` of light reaching the observer along the
    /// scene-frame viewing direction `d_scene` (unit): `gamma (1 + beta . d)`.
    #[must_use]
    pub fn doppler_factor(&self, d_scene: Vec3) -> f64 {
        self.velocity.doppler_factor_scene(d_scene.as_dvec3())
    }

    /// The observed wavelength over the scene-frame wavelength along `d_scene`: `1 / D`.
    #[must_use]
    pub fn wavelength_shift(&self, d_scene: Vec3) -> f64 {
        1.0 / self.doppler_factor(d_scene)
    }

    /// Linear sRGB radiance seen along `d_scene` by the observer, from the scene-frame
    /// radiance `rgb`: `K(D) rgb` ([`DopplerColourTable`]), times `D^4` with the searchlight.
    /// At rest `rgb` is returned unchanged (no table lookup, so renders at rest keep their
    /// bytes).
    #[must_use]
    pub fn shift_rgb(&self, d_scene: Vec3, rgb: [f32; 3]) -> [f32; 3] {
        if self.is_at_rest() {
            return rgb;
        }
        let d = self.doppler_factor(d_scene);
        let out = DopplerColourTable::global().apply(d, rgb);
        if self.searchlight {
            let s = d.powi(4) as f32;
            out.map(|v| v * s)
        } else {
            out
        }
    }
}
