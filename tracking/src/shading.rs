//! Gradient shading at real collisions: per-channel Blinn-Phong materials, energy-normalised,
//! lit by the scene's directional light (or a headlight) plus an ambient term.
//!
//! At a real collision with channel n at point p the normal is the normalised gradient of
//! channel n's raw scalar field (central differences of the trilinear field, one voxel
//! spacing per axis, in world units), turned towards the viewer (two-sided). With albedo `c`
//! (the transfer function's colour), light direction `l`, view direction `v`, half vector
//! `h = normalize(l + v)`, light radiance `E` (per RGB) and ambient light `A`:
//!
//! `L = A ka c + T E (kd c max(n.l, 0) + ks (s + 8) / 8 max(n.h, 0)^s max(n.l, 0))`
//!
//! where `T` is the ratio-tracked transmittance towards the light when shadows are on (1
//! otherwise): a hit in full shadow keeps only its ambient part. `(s + 8) / 8` is the usual
//! energy normalisation of the Blinn-Phong lobe (the `1/pi` of both lobes is folded into the
//! light's radiance, so a white Lambertian material facing a light of radiance 1 returns 1),
//! and `kd + ks` is scaled down to 1 when larger, so a material never reflects more than it
//! receives.

use glam::Vec3;

use crate::scene::Scene;
use crate::{Error, Result};

/// A Blinn-Phong material of one channel.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Material {
    /// Reflectance of the ambient light, in [0, 1].
    pub ambient: f32,
    /// Diffuse (Lambertian) reflectance, >= 0.
    pub diffuse: f32,
    /// Specular reflectance, >= 0 (`diffuse + specular` is normalised to at most 1).
    pub specular: f32,
    /// Blinn-Phong exponent, >= 0.
    pub shininess: f32,
}

impl Default for Material {
    /// Mostly diffuse with a little specular: ambient 1, diffuse 0.8, specular 0.2, shininess 32.
    fn default() -> Self {
        Material {
            ambient: 1.0,
            diffuse: 0.8,
            specular: 0.2,
            shininess: 32.0,
        }
    }
}

impl Material {
    /// An opaque-looking purely diffuse material (no ambient, no specular).
    #[must_use]
    pub fn lambert() -> Self {
        Material {
            ambient: 0.0,
            diffuse: 1.0,
            specular: 0.0,
            shininess: 0.0,
        }
    }

    /// Checks the ranges; `what` names the material in the message.
    pub fn validate(&self, what: &str) -> Result<()> {
        let ok = |v: f32| v.is_finite() && v >= 0.0;
        if !ok(self.shininess) {
            return Err(Error::parameter(format!(
                "{what}.shininess: {} must be finite and >= 0",
                self.shininess
            )));
        }
        if !(ok(self.ambient) && self.ambient <= 1.0) {
            return Err(Error::parameter(format!(
                "{what}.ambient: {} must be in [0, 1]",
                self.ambient
            )));
        }
        if !ok(self.diffuse) || !ok(self.specular) {
            return Err(Error::parameter(format!(
                "{what}: diffuse {} and specular {} must be finite and >= 0",
                self.diffuse, self.specular
            )));
        }
        Ok(())
    }

    /// `(kd, ks)` scaled so that `kd + ks <= 1`.
    #[must_use]
    pub fn normalised_lobes(&self) -> (f32, f32) {
        let sum = self.diffuse + self.specular;
        if sum > 1.0 {
            (self.diffuse / sum, self.specular / sum)
        } else {
            (self.diffuse, self.specular)
        }
    }
}

/// Gradient shading settings of a scene ([`Scene::shading`]); `None` there keeps the
/// emission-absorption model.
#[derive(Clone, Debug, PartialEq)]
pub struct Shading {
    /// One material per channel (a shorter list repeats its last entry; empty = default).
    pub materials: Vec<Material>,
    /// Trace ratio-tracked shadow rays towards the scene's light.
    pub shadows: bool,
}

impl Default for Shading {
    fn default() -> Self {
        Shading {
            materials: Vec::new(),
            shadows: true,
        }
    }
}

impl Shading {
    /// The material of channel `n`.
    #[must_use]
    pub fn material(&self, n: usize) -> Material {
        self.materials
            .get(n)
            .or(self.materials.last())
            .copied()
            .unwrap_or_default()
    }

    /// Checks every material.
    pub fn validate(&self) -> Result<()> {
        for (i, m) in self.materials.iter().enumerate() {
            m.validate(&format!("materials[{i}]"))?;
        }
        Ok(())
    }
}

/// World-space gradient of channel `n`'s raw scalar field at `p`: central differences of the
/// trilinear field with one voxel spacing per axis.
#[must_use]
pub fn gradient(scene: &Scene, n: usize, p: Vec3) -> Vec3 {
    let g = scene.geometry();
    let grid = scene.channels()[n].grid();
    let f = |q: Vec3| grid.sample_scalar_index(g.world_to_index(q));
    let mut out = Vec3::ZERO;
    for a in 0..3 {
        let mut e = Vec3::ZERO;
        e[a] = g.spacing[a];
        out[a] = (f(p + e) - f(p - e)) / (2.0 * g.spacing[a]);
    }
    out
}

/// The direction of [`gradient`] (any length; zero where the gradient is), from differences
/// scaled by the smallest spacing over each axis's: free of the units of lengths and values,
/// where the gradient itself underflows for data in cgs units (1e-27 g/cm^3 over 1e21 cm)
/// and overflows for tiny spacings.
#[must_use]
pub fn normal_direction(scene: &Scene, n: usize, p: Vec3) -> Vec3 {
    let g = scene.geometry();
    let grid = scene.channels()[n].grid();
    let f = |q: Vec3| grid.sample_scalar_index(g.world_to_index(q));
    let smallest = g.spacing.min_element();
    let mut out = Vec3::ZERO;
    for a in 0..3 {
        let mut e = Vec3::ZERO;
        e[a] = g.spacing[a];
        out[a] = (f(p + e) - f(p - e)) * (smallest / g.spacing[a]);
    }
    out
}

/// Blinn-Phong reflection of `light_radiance` from `light_dir` towards `view` (unit vectors)
/// for a surface of `normal` (any length; a zero or NaN normal faces the viewer), albedo `c`
/// and material `m`; two-sided. Returns `(ambient reflectance x c, direct RGB per unit T)`.
#[must_use]
pub(crate) fn blinn_phong(
    m: &Material,
    c: [f32; 3],
    normal: Vec3,
    light_dir: Vec3,
    view: Vec3,
) -> ([f32; 3], [f32; 3]) {
    let mut n = blueshift_camera::unit(normal).unwrap_or(view);
    if n.dot(view) < 0.0 {
        n = -n;
    }
    let nl = n.dot(light_dir).max(0.0);
    let (kd, ks) = m.normalised_lobes();
    let spec = if ks > 0.0 && nl > 0.0 {
        let h = blueshift_camera::unit(light_dir + view).unwrap_or(n);
        ks * (m.shininess + 8.0) / 8.0 * n.dot(h).max(0.0).powf(m.shininess) * nl
    } else {
        0.0
    };
    (c.map(|v| v * m.ambient), c.map(|v| kd * v * nl + spec))
}
