//! Whole images: thread-count determinism, N-DDA vs 1-DDA vs the converged marcher on the
//! three cubes of MDWT Fig. 3, progressive statistics, the HDR VolVis Fig. 3 precision
//! experiment, the default cameras and error cases.

mod common;

use blueshift_tfedit::TransferFunction;
use blueshift_tracking::{
    Blend, Camera, DdaMode, DirectionalLight, Error, Integrator, Precision, Progressive,
    RayMarcher, RenderSettings, Scene, render,
};
use blueshift_volume::synth;
use common::*;
use glam::Vec3;

fn three_cubes(res: usize, scale: f32) -> Scene {
    let vol = synth::three_cubes(res).unwrap();
    let cols = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    let tfs: Vec<TransferFunction> = cols
        .iter()
        .map(|&c| tf(c, &[(0.0, 0.0), (1.0, 1.0)]))
        .collect();
    Scene::from_volume(&vol, tfs, scale, 4).unwrap()
}

#[test]
fn image_is_identical_for_any_thread_count() {
    let scene = three_cubes(24, 8.0);
    let mut s = RenderSettings::default_for(&scene, 24, 16, false);
    s.spp = 3;
    s.seed = 99;
    let m = Integrator::Mdwt {
        dda: DdaMode::OneDda,
        blend: Blend::Density,
    };
    let run = |threads| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| render(&scene, &m, &s).unwrap())
    };
    let a = run(1);
    let b = run(3);
    assert_eq!(a.as_raw(), b.as_raw());
    // A different seed gives a different image.
    s.seed = 100;
    let c = rayon::ThreadPoolBuilder::new()
        .num_threads(2)
        .build()
        .unwrap()
        .install(|| render(&scene, &m, &s).unwrap());
    assert_ne!(a.as_raw(), c.as_raw());
}

/// Per-pixel comparison of a Monte Carlo image (with its standard errors) to a reference.
fn compare(p: &Progressive, reference: &image::Rgba32FImage, what: &str) {
    let (w, h) = reference.dimensions();
    let mut worst = 0.0f64;
    let mut sum_z2 = 0.0;
    let mut count = 0.0;
    for y in 0..h {
        for x in 0..w {
            let m = p.mean(x, y);
            let v = p.variance(x, y);
            let r = reference.get_pixel(x, y).0;
            for c in 0..4 {
                let se = (v[c] / f64::from(p.samples())).sqrt();
                let d = (m[c] - f64::from(r[c])).abs();
                // 0.01 absorbs the marcher's quadrature error and pixels with zero variance.
                let z = d / (se + 0.01);
                worst = worst.max(z);
                sum_z2 += (d / (se + 1e-3)).powi(2).min(100.0);
                count += 1.0;
            }
        }
    }
    assert!(
        worst < 5.5,
        "{what}: worst pixel {worst:.2} standard errors off"
    );
    assert!(
        sum_z2 / count < 3.0,
        "{what}: mean squared z {:.2}",
        sum_z2 / count
    );
}

#[test]
fn three_cubes_mdwt_converges_to_the_marcher_for_every_blend() {
    // The marcher with steps of 1/10 voxel is an independent quadrature of the same integral
    // (module docs of `integrator`); N-DDA and 1-DDA must both agree with it.
    let mut scene = three_cubes(20, 6.0);
    scene.background = [0.05, 0.05, 0.05];
    let blends = [
        Blend::Density,
        Blend::Max,
        Blend::Mix {
            weights: vec![1.0, 1.0, 1.0],
        },
        Blend::Composite {
            weights: vec![1.0, 1.0, 1.0],
        },
        Blend::Weighted {
            weights: vec![1.0, 0.3, 0.6],
        },
    ];
    let mut s = RenderSettings::default_for(&scene, 12, 12, true);
    s.jitter_pixels = false;
    for blend in blends {
        let marcher = RayMarcher {
            step: Some(0.005),
            blend: blend.clone(),
            ..RayMarcher::default()
        };
        s.spp = 2;
        let reference = render(&scene, &Integrator::Marcher(marcher), &s).unwrap();
        // The reference is not empty: the cubes absorb in the middle of the image.
        assert!(
            reference.get_pixel(6, 6).0[3] > 0.3,
            "{blend:?}: {:?}",
            reference.get_pixel(6, 6)
        );
        s.spp = 400;
        for dda in [DdaMode::NDda, DdaMode::OneDda, DdaMode::Summed] {
            let integ = Integrator::Mdwt {
                dda,
                blend: blend.clone(),
            };
            let p = blueshift_tracking::render_progressive(&scene, &integ, &s, |_, _| {}).unwrap();
            compare(&p, &reference, &format!("{blend:?} {dda:?}"));
        }
    }
}

#[test]
fn progressive_variance_is_bernoulli_and_noise_target_stops_early() {
    // Homogeneous slab, colour 1: each Woodcock sample is 1 (collision) or 0, so the pixel
    // variance is p (1 - p) with p = 1 - T.
    let scene = Scene::new(
        vec![(
            "a".into(),
            grid([9, 9, 9], |_, _, _| 0.5),
            tf([1.0; 3], &[(0.0, 0.1)]),
        )],
        1.0,
        4,
    )
    .unwrap();
    let mut s = RenderSettings::default_for(&scene, 8, 8, true);
    s.spp = 300;
    s.jitter_pixels = false;
    let p = blueshift_tracking::render_progressive(
        &scene,
        &Integrator::Woodcock { channel: 0 },
        &s,
        |_, _| {},
    )
    .unwrap();
    let q = 1.0 - (-0.8f64).exp();
    let mut var = 0.0;
    for y in 0..8 {
        for x in 0..8 {
            var += p.variance(x, y)[0];
        }
    }
    var /= 64.0;
    // 64 x 300 Bernoulli samples: the variance estimate is good to about 1 %.
    assert!(
        (var - q * (1.0 - q)).abs() < 0.02,
        "variance {var} vs {}",
        q * (1.0 - q)
    );
    // Standard error of the mean ~ sqrt(p(1-p)/n): a target of 0.1 is met after ~25 passes.
    s.noise_target = Some(0.1);
    let mut passes = 0;
    let p = blueshift_tracking::render_progressive(
        &scene,
        &Integrator::Woodcock { channel: 0 },
        &s,
        |n, _| passes = n,
    )
    .unwrap();
    assert!(
        p.noise() <= 0.1 && (15..60).contains(&passes),
        "passes {passes}, noise {}",
        p.noise()
    );
}

#[test]
fn hdr_fig3_eight_bit_compositing_loses_what_f32_keeps() {
    // A deep homogeneous volume with alpha_g = 0.005: each step's contribution is far below
    // 1/255, so 8-bit compositing rounds it away; f32 keeps the analytic result.
    let alpha_g = 0.005f32;
    let t = tf([1.0, 0.8, 0.6], &[(0.0, 1.0)])
        .with_alpha_g(alpha_g)
        .unwrap();
    let scene = Scene::new(
        vec![("d".into(), grid([4, 4, 257], |_, _, _| 0.5), t)],
        1.0,
        4,
    )
    .unwrap();
    let ray = ray_z(1.5, 1.5);
    let expected = 1.0 - (-f64::from(alpha_g) * 256.0).exp(); // about 0.72
    let get = |precision| {
        let m = RayMarcher {
            precision,
            ..RayMarcher::default()
        };
        estimate(&scene, &Integrator::Marcher(m), &ray, 1, 0).0
    };
    let f32v = get(Precision::F32);
    let f16v = get(Precision::F16);
    let u8v = get(Precision::U8);
    assert!(
        (f32v[0] - expected).abs() < 1e-3,
        "f32 {} vs {expected}",
        f32v[0]
    );
    // Each step adds about 0.64/255 while the remaining transparency is high (rounded up to
    // 1/255), then less than half a level (rounded to nothing): 8-bit stalls near 0.22.
    assert!(
        u8v[0] < 0.4 * expected,
        "8-bit keeps {} of {expected}",
        u8v[0]
    );
    assert!(
        (f16v[0] - expected).abs() < (u8v[0] - expected).abs(),
        "f16 {}",
        f16v[0]
    );
    // The Woodcock estimate agrees with f32 compositing.
    let (m, se) = estimate(
        &scene,
        &Integrator::Woodcock { channel: 0 },
        &ray,
        10_000,
        3,
    );
    assert_close("woodcock", m[0], se[0], expected, 4.5, 0.0);
}

#[test]
fn shadows_darken_by_the_ratio_tracked_transmittance() {
    // A homogeneous slab lit from +x with no ambient: the collision at depth z, lateral x
    // sees the light through (8 - x) of medium. Ratio tracking is unbiased for T.
    let sigma = 0.1f32;
    let mut scene = Scene::new(
        vec![(
            "a".into(),
            grid([9, 9, 9], |_, _, _| 0.5),
            tf([1.0; 3], &[(0.0, sigma)]),
        )],
        1.0,
        4,
    )
    .unwrap();
    scene.light = Some(DirectionalLight {
        direction: Vec3::X,
        radiance: [1.0; 3],
        ambient: 0.0,
    });
    let x = 2.0f64;
    let ray = ray_z(x as f32, 4.0);
    let expected = (1.0 - (-0.8f64).exp()) * (-0.1 * (8.0 - x)).exp();
    for m in [
        Integrator::Woodcock { channel: 0 },
        Integrator::Mdwt {
            dda: DdaMode::OneDda,
            blend: Blend::Density,
        },
    ] {
        let (mean, se) = estimate(&scene, &m, &ray, 20_000, 8);
        assert_close(&format!("{m:?}"), mean[0], se[0], expected, 4.5, 0.0);
    }
    // The marcher refuses a light instead of ignoring it.
    assert!(matches!(
        Integrator::Marcher(RayMarcher::default()).prepared(&scene),
        Err(Error::Parameter(_))
    ));
}

#[test]
fn default_cameras_frame_the_volume() {
    let lo = Vec3::new(-1.0, 2.0, 0.0);
    let hi = Vec3::new(3.0, 4.0, 5.0);
    // Orthographic, 2:1 image: the x-y extent 4 x 2 fills it; corner rays graze the box.
    let cam = Camera::default_view(lo, hi, 2.0, true);
    let r = cam.ray(0.0, 0.0, 200, 100);
    // yt's convention: the observer on the +z side looking towards -z, +x right, +y up.
    assert!(r.dir.abs_diff_eq(-Vec3::Z, 1e-6));
    let c = cam.ray(100.0, 50.0, 200, 100);
    assert!((c.origin.x - 1.0).abs() < 1e-5 && (c.origin.y - 3.0).abs() < 1e-5);
    assert!((r.origin.y - 4.0).abs() < 1e-4, "{r:?}");
    // The top-left pixel corner sees the (-x, +y) edge.
    assert!((r.origin.x - lo.x).abs() < 1e-4, "{r:?}");
    assert!(r.origin.z > hi.z);
    // Perspective: the centre ray goes through the box centre along -z.
    let cam = Camera::default_view(lo, hi, 1.0, false);
    let c = cam.ray(50.0, 50.0, 100, 100);
    assert!(c.dir.abs_diff_eq(-Vec3::Z, 1e-5));
    assert!(c.clip_box(lo, hi).is_some());
}

#[test]
fn bad_input_gets_typed_errors() {
    let a = grid([5, 5, 5], |_, _, _| 0.0);
    let b = grid([5, 5, 6], |_, _, _| 0.0);
    let t = tf([1.0; 3], &[(0.0, 1.0)]);
    let e = Scene::new(
        vec![
            ("a".into(), a.clone(), t.clone()),
            ("b".into(), b, t.clone()),
        ],
        1.0,
        4,
    )
    .unwrap_err();
    assert!(
        matches!(e, Error::Scene(_)) && e.to_string().contains("channels[1]"),
        "{e}"
    );
    assert!(Scene::new::<blueshift_volume::AnyGrid>(vec![], 1.0, 4).is_err());
    assert!(Scene::new(vec![("a".into(), a.clone(), t.clone())], f32::NAN, 4).is_err());
    assert!(matches!(
        Scene::new(vec![("a".into(), a.clone(), t.clone())], 1.0, 0),
        Err(Error::Volume(_))
    ));
    // An absurd density scale would make tracking crawl: refused with the field named.
    let e = Scene::new(vec![("a".into(), a.clone(), t.clone())], 1e30, 4).unwrap_err();
    assert!(e.to_string().contains("density_scale"), "{e}");
    let scene = Scene::new(vec![("a".into(), a, t)], 1.0, 4).unwrap();
    let mut s = RenderSettings::default_for(&scene, 4, 4, true);
    s.spp = 0;
    let e = render(&scene, &Integrator::Woodcock { channel: 0 }, &s).unwrap_err();
    assert!(e.to_string().contains("spp"), "{e}");
    s.spp = 1;
    assert!(render(&scene, &Integrator::Woodcock { channel: 1 }, &s).is_err());
    let mix = Integrator::Mdwt {
        dda: DdaMode::NDda,
        blend: Blend::Mix {
            weights: vec![0.5, 0.5],
        },
    };
    assert!(render(&scene, &mix, &s).is_err());
    s.width = 0;
    assert!(render(&scene, &Integrator::Woodcock { channel: 0 }, &s).is_err());
    s.width = 100_000;
    assert!(render(&scene, &Integrator::Woodcock { channel: 0 }, &s).is_err());
    let m = RayMarcher {
        step: Some(0.0),
        ..RayMarcher::default()
    };
    s.width = 4;
    assert!(render(&scene, &Integrator::Marcher(m), &s).is_err());
    let m = RayMarcher {
        step: Some(1e-9),
        ..RayMarcher::default()
    };
    assert!(render(&scene, &Integrator::Marcher(m), &s).is_err());
}

/// Radiative transfer depends on lengths only through optical depths: a volume whose spacing
/// is multiplied by s with its extinction divided by s is the same image, from the default
/// cameras, in any units. Volumes in centimetres (1e21 cm per voxel for a galaxy) once failed:
/// squared lengths overflowed f32 ("eye and target coincide", an infinite diagonal), and a
/// fixed 1e-6 minimum view size blanked volumes smaller than that.
#[test]
fn images_do_not_depend_on_the_unit_of_length() {
    let vol = synth::three_cubes(12).unwrap();
    let image = |s: f32, orthographic: bool, m: &Integrator, seed: u64, shaded: bool| {
        let mut v = vol.clone();
        let g = *v.geometry();
        v.set_geometry(blueshift_volume::Geometry {
            origin: g.origin * s,
            spacing: g.spacing * s,
            ..g
        })
        .unwrap();
        let tfs: Vec<TransferFunction> = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
            .iter()
            .map(|&c| tf(c, &[(0.0, 0.0), (1.0, 1.0)]))
            .collect();
        let mut scene = Scene::from_volume(&v, tfs, 8.0 / s, 4).unwrap();
        if shaded {
            scene.shading = Some(blueshift_tracking::Shading {
                shadows: false,
                ..Default::default()
            });
        }
        let mut st = RenderSettings::default_for(&scene, 16, 12, orthographic);
        st.spp = 32;
        st.seed = seed;
        render(&scene, m, &st).unwrap()
    };
    let methods = [
        (Integrator::Marcher(RayMarcher::default()), false),
        (
            Integrator::Mdwt {
                dda: DdaMode::OneDda,
                blend: Blend::Density,
            },
            false,
        ),
        // Gradient shading: its normals' directions do not depend on the units either.
        (
            Integrator::Mdwt {
                dda: DdaMode::OneDda,
                blend: Blend::Density,
            },
            true,
        ),
    ];
    for (m, shaded) in &methods {
        let shaded = *shaded;
        for orthographic in [false, true] {
            let reference = image(1.0, orthographic, m, 5, shaded);
            let mean_diff = |a: &image::Rgba32FImage| {
                a.as_raw()
                    .iter()
                    .zip(reference.as_raw())
                    .map(|(x, y)| f64::from((x - y).abs()))
                    .sum::<f64>()
                    / a.as_raw().len() as f64
            };
            // How far another seed's image is: the Monte Carlo noise.
            let noise = mean_diff(&image(1.0, orthographic, m, 6, shaded));
            let lit = reference.as_raw().iter().filter(|&&v| v > 0.05).count();
            assert!(
                lit > 100,
                "the reference shows the cubes ({lit} lit values)"
            );
            for s in [1e-30f32, 1e-9, 1e21, 1e30] {
                let got = image(s, orthographic, m, 5, shaded);
                let worst = got
                    .as_raw()
                    .iter()
                    .zip(reference.as_raw())
                    .map(|(a, b)| (a - b).abs())
                    .fold(0.0f32, f32::max);
                // A Monte Carlo path takes another branch where a comparison rounds the other
                // way, and then draws other numbers: a few pixels differ as another seed's
                // would, never more than the noise (a blank or shifted image is ten times it).
                let diff = mean_diff(&got);
                let what = format!(
                    "{m:?} shaded {shaded} orthographic {orthographic} at {s} units per unit: \
                     worst {worst}, \
                     mean difference {diff} (another seed: {noise})"
                );
                if matches!(m, Integrator::Marcher(_)) {
                    assert!(worst < 1e-3, "{what}");
                } else {
                    assert!(diff <= noise, "{what}");
                }
            }
        }
    }
}
