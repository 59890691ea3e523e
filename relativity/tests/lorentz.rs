//! Special relativity as physics statements: aberration, Doppler, boosts, errors.

use blueshift_relativity::{Error, LorentzMatrix, Velocity};
use glam::DVec3;
use proptest::prelude::*;
use std::f64::consts::{PI, TAU};

fn dir(theta: f64, phi: f64) -> DVec3 {
    DVec3::new(
        theta.sin() * phi.cos(),
        theta.sin() * phi.sin(),
        theta.cos(),
    )
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]
    /// Aberration and its inverse are inverse functions, for any velocity and direction.
    #[test]
    fn aberration_and_inverse_are_inverse(
        b in -0.999f64..0.999, vt in 0.0f64..PI, vp in 0.0f64..TAU,
        t in 0.0f64..PI, p in 0.0f64..TAU,
    ) {
        let v = Velocity::along(dir(vt, vp), b).unwrap();
        let d = dir(t, p);
        let back = v.scene_to_observer(v.observer_to_scene(d));
        prop_assert!((back - d).length() < 1e-9, "{back} vs {d}");
        let back2 = v.observer_to_scene(v.scene_to_observer(d));
        prop_assert!((back2 - d).length() < 1e-9);
    }

    /// D for a ray and D for the inverse boost of the same ray multiply to one.
    #[test]
    fn doppler_of_ray_and_inverse_boost_multiply_to_one(
        b in 0.0f64..0.99, vt in 0.0f64..PI, vp in 0.0f64..TAU,
        t in 0.0f64..PI, p in 0.0f64..TAU,
    ) {
        let v = Velocity::along(dir(vt, vp), b).unwrap();
        let d_obs = dir(t, p);
        let d_scene = v.observer_to_scene(d_obs);
        let forward = v.doppler_factor_observer(d_obs);
        // The scene seen from the observer frame moves with -beta; the same ray there has
        // the observer-frame direction d_obs as its "scene" direction.
        let inverse = v.inverse().doppler_factor_observer(d_scene);
        prop_assert!((forward * inverse - 1.0).abs() < 1e-9, "{forward} * {inverse}");
        // And the two closed forms of D (observer Eq. 3 form and scene form) agree.
        prop_assert!((forward / v.doppler_factor_scene(d_scene) - 1.0).abs() < 1e-9);
    }

    /// The aberration formula agrees with boosting the photon four-momentum with the
    /// Lorentz matrix (an independent route through Eq. 1), and D is its energy ratio.
    #[test]
    fn aberration_matches_four_momentum_boost(
        b in 0.0f64..0.99, vt in 0.0f64..PI, vp in 0.0f64..TAU,
        t in 0.0f64..PI, p in 0.0f64..TAU,
    ) {
        let v = Velocity::along(dir(vt, vp), b).unwrap();
        let d = dir(t, p);
        // Photon travels along -d: k = (1, -d).
        let k = LorentzMatrix::boost(v).apply4([1.0, -d.x, -d.y, -d.z]);
        let d_obs = -DVec3::new(k[1], k[2], k[3]) / k[0];
        prop_assert!((d_obs - v.scene_to_observer(d)).length() < 1e-9);
        prop_assert!((k[0] - v.doppler_factor_scene(d)).abs() < 1e-9 * k[0]);
    }
}

#[test]
fn beta_zero_is_the_identity() {
    let v = Velocity::new(DVec3::ZERO).unwrap();
    assert_eq!(v.gamma(), 1.0);
    for d in [DVec3::X, DVec3::NEG_Y, dir(1.0, 2.0)] {
        assert_eq!(v.observer_to_scene(d), d);
        assert_eq!(v.scene_to_observer(d), d);
        assert_eq!(v.doppler_factor_observer(d), 1.0);
    }
    let m = LorentzMatrix::boost(v);
    assert_eq!(m, LorentzMatrix::IDENTITY);
}

#[test]
fn forward_and_backward_directions_are_fixed() {
    let u = DVec3::new(1.0, 2.0, -0.5).normalize();
    let v = Velocity::along(u, 0.9).unwrap();
    assert!((v.observer_to_scene(u) - u).length() < 1e-12);
    assert!((v.observer_to_scene(-u) + u).length() < 1e-12);
}

/// Eq. 2: cos(theta_scene) = (cos(theta') - beta) / (1 - beta cos(theta')), so the observer
/// direction at cos(theta') = beta comes from 90 degrees in the scene frame.
#[test]
fn cos_theta_prime_beta_maps_to_ninety_degrees() {
    for b in [0.1, 0.5, 0.9, 0.99] {
        let v = Velocity::along(DVec3::Z, b).unwrap();
        let d_obs = DVec3::new((1.0 - b * b).sqrt(), 0.0, b);
        let d_scene = v.observer_to_scene(d_obs);
        assert!(d_scene.z.abs() < 1e-12, "beta {b}: {d_scene}");
        // And the same formula in closed form for another angle (Eq. 2 literally).
        let c = 0.3_f64;
        let d = v.observer_to_scene(DVec3::new((1.0 - c * c).sqrt(), 0.0, c));
        assert!((d.z - (c - b) / (1.0 - b * c)).abs() < 1e-12);
    }
}

/// Two boosts along one axis equal one boost with the relativistic velocity sum, and
/// rapidities add.
#[test]
fn collinear_boosts_compose_with_velocity_addition() {
    let (b1, b2) = (0.6, 0.7);
    let v1 = Velocity::along(DVec3::X, b1).unwrap();
    let v2 = Velocity::along(DVec3::X, b2).unwrap();
    let sum = (b1 + b2) / (1.0 + b1 * b2);
    let product = LorentzMatrix::boost(v2).mul(&LorentzMatrix::boost(v1));
    let single = LorentzMatrix::boost(Velocity::along(DVec3::X, sum).unwrap());
    assert!(product.max_abs_diff(&single) < 1e-12);
    let composed = v1.compose(v2).unwrap();
    assert!((composed.speed() - sum).abs() < 1e-15);
    assert!((composed.rapidity() - (v1.rapidity() + v2.rapidity())).abs() < 1e-12);
    // The aberration maps compose too.
    let d = dir(1.1, 0.3);
    let two = v2.observer_to_scene(d);
    let two = v1.observer_to_scene(two);
    assert!((two - composed.observer_to_scene(d)).length() < 1e-12);
}

/// Boosts preserve the interval t^2 - x^2.
#[test]
fn boost_preserves_the_interval() {
    let v = Velocity::new(DVec3::new(0.3, -0.5, 0.6)).unwrap();
    let e = [2.0, 0.5, -1.0, 3.0];
    let o = LorentzMatrix::boost(v).apply4(e);
    let s = |a: [f64; 4]| a[0] * a[0] - a[1] * a[1] - a[2] * a[2] - a[3] * a[3];
    assert!((s(e) - s(o)).abs() < 1e-12);
}

/// Head-on D = sqrt((1+b)/(1-b)); from straight behind, its inverse.
#[test]
fn doppler_head_on_and_from_behind() {
    for b in [0.1, 0.5, 0.9, 0.99] {
        let u = DVec3::new(-2.0, 1.0, 0.5).normalize();
        let v = Velocity::along(u, b).unwrap();
        let expected = ((1.0 + b) / (1.0 - b)).sqrt();
        assert!((v.doppler_factor_observer(u) / expected - 1.0).abs() < 1e-12);
        assert!((v.doppler_factor_observer(-u) * expected - 1.0).abs() < 1e-12);
        assert!((v.doppler(u).unwrap().value() / expected - 1.0).abs() < 1e-12);
    }
}

#[test]
fn invalid_velocities_are_errors() {
    for b in [
        DVec3::new(1.0, 0.0, 0.0),
        DVec3::new(0.8, 0.8, 0.0),
        DVec3::new(f64::NAN, 0.0, 0.0),
        DVec3::new(0.0, f64::INFINITY, 0.0),
    ] {
        assert!(
            matches!(Velocity::new(b), Err(Error::Velocity { .. })),
            "{b}"
        );
    }
    assert!(Velocity::along(DVec3::ZERO, 0.5).is_err());
    assert!(Velocity::along(DVec3::X, -1.0).is_err());
    assert!(Velocity::along(DVec3::X, f64::NAN).is_err());
    // A composition that would reach c is impossible; a fast one stays below 1.
    let v = Velocity::along(DVec3::X, 0.999_999).unwrap();
    assert!(v.compose(v).unwrap().speed() < 1.0);
}
