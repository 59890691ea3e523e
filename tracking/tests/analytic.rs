//! Monte Carlo estimators against analytic solutions of the emission-absorption integral
//! `L = int_0^L T(t) sigma(t) c dt + T(L) bg`, `T = exp(-int sigma)`.

mod common;

use blueshift_tracking::{Blend, DdaMode, Integrator, RayMarcher, Scene};
use common::*;

const K: f64 = 4.5; // standard errors allowed (several tests x 4 components)

fn methods() -> Vec<(&'static str, Integrator)> {
    vec![
        ("woodcock", Integrator::Woodcock { channel: 0 }),
        (
            "mdwt-ndda",
            Integrator::Mdwt {
                dda: DdaMode::NDda,
                blend: Blend::Density,
            },
        ),
        (
            "mdwt-1dda",
            Integrator::Mdwt {
                dda: DdaMode::OneDda,
                blend: Blend::Density,
            },
        ),
    ]
}

#[test]
fn homogeneous_medium_matches_beer_lambert() {
    // 9^3 voxels, unit spacing: the box is [0, 8]^3, so rays along z cross L = 8.
    let alpha = 0.4f32;
    let scale = 0.25f32; // sigma = 0.1 per unit length, tau = 0.8
    let c = [0.9f32, 0.5, 0.2];
    let mut scene = Scene::new(
        vec![(
            "a".into(),
            grid([9, 9, 9], |_, _, _| 0.5),
            tf(c, &[(0.0, alpha)]),
        )],
        scale,
        4,
    )
    .unwrap();
    scene.background = [0.1, 0.2, 0.3];
    let t = (-0.1f64 * 8.0).exp();
    let ray = ray_z(3.3, 4.1);
    for (name, m) in methods() {
        let (mean, se) = estimate(&scene, &m, &ray, 20_000, 1);
        for i in 0..3 {
            let expected = f64::from(c[i]) * (1.0 - t) + f64::from(scene.background[i]) * t;
            assert_close(
                &format!("{name} rgb[{i}]"),
                mean[i],
                se[i],
                expected,
                K,
                0.0,
            );
        }
        assert_close(&format!("{name} alpha"), mean[3], se[3], 1.0 - t, K, 0.0);
    }
    // The marcher is a quadrature of the same integral: exact for a homogeneous medium.
    let (mean, _) = estimate(
        &scene,
        &Integrator::Marcher(RayMarcher::default()),
        &ray,
        4,
        1,
    );
    for i in 0..3 {
        let expected = f64::from(c[i]) * (1.0 - t) + f64::from(scene.background[i]) * t;
        assert!(
            (mean[i] - expected).abs() < 1e-4,
            "marcher rgb[{i}] {} vs {expected}",
            mean[i]
        );
    }
}

#[test]
fn linearly_varying_medium_matches_analytic() {
    // value = z / 8 on [0, 8]; opacity = value (knots (0,0) and (1,1)); sigma = s z / 8.
    // Optical depth through the box along z: s * 8 / 2; trilinear interpolation is exact.
    let s = 0.3f32;
    let c = [1.0f32, 0.6, 0.3];
    let scene = Scene::new(
        vec![(
            "ramp".into(),
            grid([9, 9, 9], |_, _, z| z as f32 / 8.0),
            tf(c, &[(0.0, 0.0), (1.0, 1.0)]),
        )],
        s,
        2,
    )
    .unwrap();
    let t = (-f64::from(s) * 4.0).exp();
    let ray = ray_z(2.5, 6.25);
    for (name, m) in methods() {
        let (mean, se) = estimate(&scene, &m, &ray, 20_000, 2);
        for i in 0..3 {
            assert_close(
                &format!("{name} rgb[{i}]"),
                mean[i],
                se[i],
                f64::from(c[i]) * (1.0 - t),
                K,
                0.0,
            );
        }
    }
    // Along -z the same transmittance (the medium is symmetric in what it absorbs).
    let back =
        blueshift_tracking::Ray::new(glam::Vec3::new(2.5, 6.25, 20.0), -glam::Vec3::Z).unwrap();
    let (mean, se) = estimate(
        &scene,
        &Integrator::Woodcock { channel: 0 },
        &back,
        20_000,
        3,
    );
    assert_close("woodcock -z alpha", mean[3], se[3], 1.0 - t, K, 0.0);
}

fn three_homogeneous(sigmas: [f32; 3]) -> Scene {
    let cols = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    let ch = (0..3)
        .map(|n| {
            (
                format!("c{n}"),
                grid([9, 9, 9], |_, _, _| 0.5),
                tf(cols[n], &[(0.0, sigmas[n])]),
            )
        })
        .collect();
    Scene::new(ch, 1.0, 4).unwrap()
}

#[test]
fn overlapping_channels_take_collisions_in_proportion_to_their_density() {
    // Channel n is pure red/green/blue, so the pixel's component n is the fraction of
    // samples whose first real collision was channel n: sigma_n / sum sigma (1 - T).
    let sig = [0.05f32, 0.1, 0.2];
    let scene = three_homogeneous(sig);
    let sum: f32 = sig.iter().sum();
    let t = (-f64::from(sum) * 8.0).exp();
    let ray = ray_z(1.7, 5.5);
    for (name, dda) in [("ndda", DdaMode::NDda), ("1dda", DdaMode::OneDda)] {
        let m = Integrator::Mdwt {
            dda,
            blend: Blend::Density,
        };
        let (mean, se) = estimate(&scene, &m, &ray, 30_000, 4);
        for n in 0..3 {
            let expected = f64::from(sig[n] / sum) * (1.0 - t);
            assert_close(
                &format!("{name} channel {n}"),
                mean[n],
                se[n],
                expected,
                K,
                0.0,
            );
        }
        assert_close(&format!("{name} alpha"), mean[3], se[3], 1.0 - t, K, 0.0);
    }
}

#[test]
fn max_and_mix_blends_match_their_definitions() {
    // Max: only the densest channel (blue, 0.2) absorbs and emits. Mix with weights w:
    // extinction max sigma = 0.2, colour sum_n c_n sigma_n w_n / 0.2.
    let sig = [0.05f32, 0.1, 0.2];
    let scene = three_homogeneous(sig);
    let t = (-0.2f64 * 8.0).exp();
    let ray = ray_z(4.0, 4.0);
    let w = [0.2f32, 0.3, 0.5];
    let mix_col: Vec<f64> = (0..3).map(|n| f64::from(sig[n] * w[n] / 0.2)).collect();
    for dda in [DdaMode::NDda, DdaMode::OneDda] {
        let (mean, se) = estimate(
            &scene,
            &Integrator::Mdwt {
                dda,
                blend: Blend::Max,
            },
            &ray,
            20_000,
            5,
        );
        assert_close("max red", mean[0], se[0], 0.0, K, 0.0);
        assert_close("max green", mean[1], se[1], 0.0, K, 0.0);
        assert_close("max blue", mean[2], se[2], 1.0 - t, K, 0.0);
        let blend = Blend::Mix {
            weights: w.to_vec(),
        };
        let (mean, se) = estimate(&scene, &Integrator::Mdwt { dda, blend }, &ray, 20_000, 6);
        for n in 0..3 {
            assert_close(
                &format!("mix {n}"),
                mean[n],
                se[n],
                mix_col[n] * (1.0 - t),
                K,
                0.0,
            );
        }
    }
    // The marcher uses the same model: deterministic and exact here.
    let m = RayMarcher {
        blend: Blend::Mix {
            weights: w.to_vec(),
        },
        ..RayMarcher::default()
    };
    let (mean, _) = estimate(&scene, &Integrator::Marcher(m), &ray, 2, 1);
    for n in 0..3 {
        assert!(
            (mean[n] - mix_col[n] * (1.0 - t)).abs() < 1e-4,
            "marcher mix {n}"
        );
    }
    // Composite: channel images (each alone) summed with weights.
    let blend = Blend::Composite {
        weights: w.to_vec(),
    };
    let (mean, se) = estimate(
        &scene,
        &Integrator::Mdwt {
            dda: DdaMode::OneDda,
            blend,
        },
        &ray,
        20_000,
        7,
    );
    for n in 0..3 {
        let expected = f64::from(w[n]) * (1.0 - (-f64::from(sig[n]) * 8.0).exp());
        assert_close(&format!("composite {n}"), mean[n], se[n], expected, K, 0.0);
    }
}
