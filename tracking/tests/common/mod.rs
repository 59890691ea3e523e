//! Shared helpers for the tracking tests.
#![allow(dead_code)]

use blueshift_tfedit::{ColorKnot, OpacityKnot, TransferFunction};
use blueshift_tracking::{Integrator, Ray, Rng, Scene};
use blueshift_volume::{AnyGrid, Geometry, Grid};
use glam::Vec3;

/// Constant-colour TF over [0, 1] with opacity knots `(x, alpha)`.
pub fn tf(rgb: [f32; 3], knots: &[(f64, f32)]) -> TransferFunction {
    TransferFunction::new(
        [0.0, 1.0],
        vec![ColorKnot { x: 0.0, rgb }, ColorKnot { x: 1.0, rgb }],
        knots.iter().map(|&(x, a)| OpacityKnot::new(x, a)).collect(),
    )
    .unwrap()
}

/// Grid with geometry unit spacing, dims `n`, values from `f(x, y, z)`.
pub fn grid(n: [usize; 3], f: impl Fn(usize, usize, usize) -> f32 + Sync) -> AnyGrid {
    AnyGrid::F32(Grid::from_fn(Geometry::unit(n), f).unwrap())
}

/// Mean and standard error of each RGBA component of `n` samples of `integrator` on `ray`.
pub fn estimate(
    scene: &Scene,
    integ: &Integrator,
    ray: &Ray,
    n: u64,
    seed: u64,
) -> ([f64; 4], [f64; 4]) {
    let integ = integ.prepared(scene).unwrap();
    let mut s = [0.0f64; 4];
    let mut s2 = [0.0f64; 4];
    for i in 0..n {
        let mut rng = Rng::new(seed, 7, i);
        let v = integ.li(scene, ray, &mut rng);
        for c in 0..4 {
            s[c] += f64::from(v[c]);
            s2[c] += f64::from(v[c]) * f64::from(v[c]);
        }
    }
    let nf = n as f64;
    let mean = s.map(|v| v / nf);
    let mut se = [0.0; 4];
    for c in 0..4 {
        let var = (s2[c] / nf - mean[c] * mean[c]).max(0.0) * nf / (nf - 1.0);
        se[c] = (var / nf).sqrt();
    }
    (mean, se)
}

/// A ray along +z through `(x, y)` starting before the volume.
pub fn ray_z(x: f32, y: f32) -> Ray {
    Ray::new(Vec3::new(x, y, -5.0), Vec3::Z).unwrap()
}

/// Asserts `|mean - expected| <= k se + abs` per component.
pub fn assert_close(what: &str, mean: f64, se: f64, expected: f64, k: f64, abs: f64) {
    let err = (mean - expected).abs();
    assert!(
        err <= k * se + abs,
        "{what}: mean {mean:.5} vs expected {expected:.5} (error {err:.2e}, standard error {se:.2e})"
    );
}
