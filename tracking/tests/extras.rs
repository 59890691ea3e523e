//! Tracking extras: the summed-majorant variant against N-DDA and 1-DDA, heat-map counters
//! against the theory of delta tracking, gradient shading against the analytic Lambert term,
//! the majorant-weighted blend, the timing protocol and bad settings.

mod common;

use blueshift_tracking::{
    Blend, DdaMode, DirectionalLight, HeatMap, Integrator, Material, Progressive, RayMarcher,
    RayStats, RenderSettings, Rng, Scene, Shading, render, render_progressive, render_timed,
};
use blueshift_volume::synth;
use common::*;
use glam::Vec3;

fn three_cubes(res: usize, scale: f32, k: usize) -> Scene {
    let vol = synth::three_cubes(res).unwrap();
    let cols = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    let tfs = cols
        .iter()
        .map(|&c| tf(c, &[(0.0, 0.0), (1.0, 1.0)]))
        .collect();
    Scene::from_volume(&vol, tfs, scale, k).unwrap()
}

/// Largest |z| and mean z^2 of the per-pixel difference of two independent Monte Carlo
/// images (RGBA), with both images' standard errors.
fn z_stats(a: &Progressive, b: &Progressive, w: u32, h: u32) -> (f64, f64) {
    let (mut worst, mut sum, mut count) = (0.0f64, 0.0f64, 0.0f64);
    for y in 0..h {
        for x in 0..w {
            let (ma, va, mb, vb) = (
                a.mean(x, y),
                a.variance(x, y),
                b.mean(x, y),
                b.variance(x, y),
            );
            for c in 0..4 {
                let se = (va[c] / f64::from(a.samples()) + vb[c] / f64::from(b.samples())).sqrt();
                let d = (ma[c] - mb[c]).abs();
                if se == 0.0 {
                    assert!(d < 1e-6, "pixel ({x}, {y}) differs without noise");
                    continue;
                }
                let z = d / se;
                worst = worst.max(z);
                sum += z * z;
                count += 1.0;
            }
        }
    }
    (worst, sum / count.max(1.0))
}

#[test]
fn summed_majorant_converges_to_the_same_image_as_ndda_and_1dda() {
    let mut scene = three_cubes(20, 6.0, 4);
    scene.background = [0.05, 0.05, 0.05];
    let mut s = RenderSettings::default_for(&scene, 12, 12, true);
    s.jitter_pixels = false;
    s.spp = 300;
    for blend in [
        Blend::Density,
        Blend::Max,
        Blend::Mix {
            weights: vec![1.0, 2.0, 1.0],
        },
    ] {
        s.seed = 1;
        let summed = Integrator::Mdwt {
            dda: DdaMode::Summed,
            blend: blend.clone(),
        };
        let a = render_progressive(&scene, &summed, &s, |_, _| {}).unwrap();
        for (i, dda) in [DdaMode::NDda, DdaMode::OneDda].into_iter().enumerate() {
            s.seed = 2 + i as u64;
            let integ = Integrator::Mdwt {
                dda,
                blend: blend.clone(),
            };
            let b = render_progressive(&scene, &integ, &s, |_, _| {}).unwrap();
            let (worst, mz2) = z_stats(&a, &b, 12, 12);
            assert!(
                worst < 5.0,
                "{blend:?} summed vs {dda:?}: worst z {worst:.2}"
            );
            assert!(mz2 < 1.6, "{blend:?} summed vs {dda:?}: mean z^2 {mz2:.2}");
        }
    }
}

/// Homogeneous value 0 with one voxel of value 1 in a far corner: the single macrocell's
/// majorant comes from the corner (opacity 1 x scale), the medium the ray sees is opacity
/// 0.25 x scale.
fn loose_slab(k: usize) -> Scene {
    let g = grid([8, 8, 40], |x, y, z| {
        if x == 0 && y == 0 && z == 39 {
            1.0
        } else {
            0.0
        }
    });
    let t = tf([1.0, 1.0, 1.0], &[(0.0, 0.25), (1.0, 1.0)]);
    Scene::new(vec![("slab".into(), g, t)], 0.1, k).unwrap()
}

#[test]
fn tentative_collisions_per_ray_follow_delta_tracking_theory() {
    let scene = loose_slab(64);
    let (sigma, m, len) = (0.025f64, 0.1f64, 39.0f64);
    let p_real = 1.0 - (-sigma * len).exp();
    let expect_tent = m / sigma * p_real;
    let expect_rej = expect_tent - p_real;
    let ray = ray_z(6.0, 6.0);
    let n = 20_000u64;
    for integ in [
        Integrator::Woodcock { channel: 0 },
        Integrator::Mdwt {
            dda: DdaMode::NDda,
            blend: Blend::Density,
        },
        Integrator::Mdwt {
            dda: DdaMode::OneDda,
            blend: Blend::Density,
        },
        Integrator::Mdwt {
            dda: DdaMode::Summed,
            blend: Blend::Density,
        },
    ] {
        let integ = integ.prepared(&scene).unwrap();
        let (mut s, mut s2, mut r, mut r2) = (0.0f64, 0.0, 0.0, 0.0);
        for i in 0..n {
            let mut rng = Rng::new(3, 0, i);
            let mut st = RayStats::default();
            let _ = integ.li_with_stats(&scene, &ray, &mut rng, &mut st);
            assert_eq!(st.cells, 1, "one macrocell");
            let (t, j) = (f64::from(st.tentative), f64::from(st.rejections));
            s += t;
            s2 += t * t;
            r += j;
            r2 += j * j;
        }
        let nf = n as f64;
        let (mt, mr) = (s / nf, r / nf);
        let se_t = ((s2 / nf - mt * mt) / nf).sqrt();
        let se_r = ((r2 / nf - mr * mr) / nf).sqrt();
        assert_close(
            &format!("{integ:?} tentative"),
            mt,
            se_t,
            expect_tent,
            4.0,
            0.0,
        );
        assert_close(
            &format!("{integ:?} rejections"),
            mr,
            se_r,
            expect_rej,
            4.0,
            0.0,
        );
    }
}

#[test]
fn heat_maps_of_a_tight_homogeneous_slab_and_tighter_grids_reject_less() {
    // Homogeneous slab with a tight majorant: no rejections, collisions 1 - exp(-sigma L).
    let g = grid([8, 8, 40], |_, _, _| 0.5);
    let t = tf([1.0, 1.0, 1.0], &[(0.0, 0.5), (1.0, 0.5)]);
    let scene = Scene::new(vec![("slab".into(), g, t)], 0.1, 4).unwrap();
    let mut s = RenderSettings::default_for(&scene, 16, 16, true);
    s.spp = 1;
    let integ = Integrator::Mdwt {
        dda: DdaMode::OneDda,
        blend: Blend::Density,
    };
    let mut p = Progressive::new(16, 16).unwrap();
    assert!(p.heatmap(HeatMap::Steps).is_none());
    p.enable_heatmaps();
    for _ in 0..40 {
        p.add_pass(&scene, &integ, &s).unwrap();
    }
    let rej = p.heatmap(HeatMap::Rejections).unwrap();
    assert!(
        rej.iter().all(|&v| v == 0.0),
        "tight majorant rejects nothing"
    );
    let col = p.heatmap(HeatMap::Collisions).unwrap();
    let mean = col.iter().map(|&v| f64::from(v)).sum::<f64>() / col.len() as f64;
    let expect = 1.0 - (-0.05f64 * 39.0).exp();
    // Bernoulli count: se = sqrt(p (1 - p) / samples).
    let se = (expect * (1.0 - expect) / (256.0 * 40.0)).sqrt();
    assert_close("collisions", mean, se, expect, 4.0, 0.0);
    let steps = p.heatmap(HeatMap::Steps).unwrap();
    assert!(steps.iter().all(|&v| v >= 1.0), "every ray visits a cell");
    assert!(p.heatmap(HeatMap::Time).unwrap().iter().all(|&v| v > 0.0));

    // Heterogeneous volume: a macrocell grid rejects fewer tentative collisions than one
    // global majorant, for the same image.
    let mean_rej = |k: usize, dda: DdaMode| {
        let scene = three_cubes(32, 4.0, k);
        let mut s = RenderSettings::default_for(&scene, 16, 16, true);
        s.spp = 4;
        let mut p = Progressive::new(16, 16).unwrap();
        p.enable_heatmaps();
        let integ = Integrator::Mdwt {
            dda,
            blend: Blend::Density,
        };
        for _ in 0..4 {
            p.add_pass(&scene, &integ, &s).unwrap();
        }
        let r = p.heatmap(HeatMap::Rejections).unwrap();
        r.iter().map(|&v| f64::from(v)).sum::<f64>() / r.len() as f64
    };
    for dda in [DdaMode::OneDda, DdaMode::Summed] {
        let tight = mean_rej(4, dda);
        let global = mean_rej(64, dda);
        assert!(
            tight < 0.5 * global,
            "{dda:?}: rejections per ray {tight} (k = 4) vs {global} (global)"
        );
    }
}

/// Distance to the centre of a 48^3 grid, normalised by 48.
fn sphere_scene() -> Scene {
    let c = 23.5f32;
    let g = grid([48, 48, 48], |x, y, z| {
        Vec3::new(x as f32 - c, y as f32 - c, z as f32 - c).length() / 48.0
    });
    let r = 16.0 / 48.0;
    let t = tf(
        [1.0, 1.0, 1.0],
        &[(0.0, 1.0), (r - 0.5 / 48.0, 1.0), (r, 0.0), (1.0, 0.0)],
    );
    Scene::new(vec![("sphere".into(), g, t)], 200.0, 4).unwrap()
}

#[test]
fn shaded_sphere_matches_the_lambert_term() {
    let mut scene = sphere_scene();
    let l = Vec3::new(1.0, 1.0, -1.5).normalize();
    scene.light = Some(DirectionalLight {
        direction: l,
        radiance: [1.0; 3],
        ambient: 0.0,
    });
    scene.shading = Some(Shading {
        materials: vec![Material::lambert()],
        shadows: false,
    });
    let c = Vec3::splat(23.5);
    let integ = Integrator::Mdwt {
        dda: DdaMode::OneDda,
        blend: Blend::Density,
    };
    for (dx, dy) in [
        (0.0f32, 0.0f32),
        (6.0, 0.0),
        (0.0, -8.0),
        (5.0, 5.0),
        (-9.0, 3.0),
    ] {
        // The opaque shell sits between radius 15.5 and 16: collisions happen at its outside.
        let r = 15.9f32;
        let z = -(r * r - dx * dx - dy * dy).sqrt();
        let n = Vec3::new(dx, dy, z) / r;
        let expect = f64::from(n.dot(l).max(0.0));
        let (mean, se) = estimate(&scene, &integ, &ray_z(c.x + dx, c.y + dy), 400, 5);
        for ch in 0..3 {
            assert_close(
                &format!("({dx}, {dy})"),
                mean[ch],
                se[ch],
                expect,
                4.0,
                0.02,
            );
        }
        assert!((mean[3] - 1.0).abs() < 1e-9, "opaque");
    }
    // Lit from behind, the visible hemisphere keeps only the ambient part.
    scene.light = Some(DirectionalLight {
        direction: Vec3::Z,
        radiance: [1.0; 3],
        ambient: 0.5,
    });
    scene.shading = Some(Shading {
        materials: vec![Material {
            ambient: 0.6,
            diffuse: 0.7,
            specular: 0.3,
            shininess: 16.0,
        }],
        shadows: true,
    });
    let (mean, _) = estimate(&scene, &integ, &ray_z(c.x + 3.0, c.y - 2.0), 50, 6);
    assert!((mean[0] - 0.3).abs() < 1e-5, "ambient only: {mean:?}");
    // Shading is off by default: the emission model returns the albedo.
    scene.shading = None;
    scene.light = None;
    let (mean, _) = estimate(&scene, &integ, &ray_z(c.x, c.y), 50, 6);
    assert!((mean[0] - 1.0).abs() < 1e-6);
}

#[test]
fn shadowed_shaded_hits_keep_only_their_ambient_part() {
    // Two channels: a thin opaque wall (channel 1) between the light and a lit plane
    // (channel 0) facing the camera. Behind the wall's shadow only ambient remains.
    let g0 = grid([32, 32, 32], |_, _, z| if z >= 20 { 1.0 } else { 0.0 });
    let g1 = grid([32, 32, 32], |x, _, z| {
        if x < 16 && (8..=10).contains(&z) {
            1.0
        } else {
            0.0
        }
    });
    let t = tf([1.0, 1.0, 1.0], &[(0.0, 0.0), (0.5, 0.0), (1.0, 1.0)]);
    let mut scene = Scene::new(
        vec![("plane".into(), g0, t.clone()), ("wall".into(), g1, t)],
        100.0,
        4,
    )
    .unwrap();
    // Light from the camera's side, 45 degrees towards -x: seen from -z, the plane's front
    // at x = 20 is in the wall's shadow (the path to the light crosses x < 16 at z 8..10),
    // at x = 28 it is not.
    let l = Vec3::new(-1.0, 0.0, -1.0).normalize();
    scene.light = Some(DirectionalLight {
        direction: l,
        radiance: [1.0; 3],
        ambient: 0.25,
    });
    let mat = Material {
        ambient: 0.5,
        ..Material::lambert()
    };
    scene.shading = Some(Shading {
        materials: vec![mat; 2],
        shadows: true,
    });
    let integ = Integrator::Mdwt {
        dda: DdaMode::Summed,
        blend: Blend::Density,
    };
    let ambient = 0.25 * 0.5;
    let (shadowed, se) = estimate(&scene, &integ, &ray_z(20.0, 16.0), 1000, 1);
    assert_close("shadowed", shadowed[0], se[0], ambient, 4.0, 0.005);
    // Unshadowed: the collision lies at an optical depth tau ~ Exp(1) below the plane's
    // surface along the (vertical) view ray; the shadow ray leaves the plane-parallel layer
    // along l through optical depth tau / cos 45: E[exp(-sqrt2 tau)] = 1 / (1 + sqrt2).
    let cos = std::f64::consts::FRAC_1_SQRT_2;
    let expect = ambient + cos / (1.0 + std::f64::consts::SQRT_2);
    let (lit, se) = estimate(&scene, &integ, &ray_z(28.0, 16.0), 1000, 2);
    assert_close("lit", lit[0], se[0], expect, 4.0, 0.01);
}

#[test]
fn weighted_blend_equals_density_with_scaled_opacities() {
    let g = |flip: bool| {
        grid([16, 16, 16], move |x, _, _| {
            let v = x as f32 / 15.0;
            if flip { 1.0 - v } else { v }
        })
    };
    let ta = tf([1.0, 0.0, 0.0], &[(0.0, 0.0), (1.0, 0.4)]);
    let tb = tf([0.0, 0.0, 1.0], &[(0.0, 0.0), (1.0, 0.8)]);
    let tb_half = tf([0.0, 0.0, 1.0], &[(0.0, 0.0), (1.0, 0.4)]);
    let two = Scene::new(
        vec![
            ("a".into(), g(false), ta.clone()),
            ("b".into(), g(true), tb),
        ],
        0.2,
        4,
    )
    .unwrap();
    let w = Blend::majorant_weights(&two);
    assert!(
        (w[0] - 1.0).abs() < 1e-6 && (w[1] - 0.5).abs() < 1e-6,
        "{w:?}"
    );
    let halved = Scene::new(
        vec![("a".into(), g(false), ta), ("b".into(), g(true), tb_half)],
        0.2,
        4,
    )
    .unwrap();
    let mut s = RenderSettings::default_for(&two, 10, 10, true);
    s.spp = 2;
    let m = |blend| {
        Integrator::Marcher(RayMarcher {
            step: Some(0.25),
            blend,
            ..RayMarcher::default()
        })
    };
    let a = render(&two, &m(Blend::Weighted { weights: w }), &s).unwrap();
    let b = render(&halved, &m(Blend::Density), &s).unwrap();
    for (x, y) in a.as_raw().iter().zip(b.as_raw()) {
        assert!((x - y).abs() < 1e-5, "{x} vs {y}");
    }
    assert!(a.as_raw().iter().any(|&v| v > 0.1));
}

#[test]
fn timing_protocol_accumulates_the_timed_frames_only() {
    let scene = three_cubes(16, 4.0, 4);
    let mut s = RenderSettings::default_for(&scene, 8, 8, false);
    s.spp = 5;
    let integ = Integrator::Mdwt {
        dda: DdaMode::Summed,
        blend: Blend::Density,
    };
    let (acc, times) = render_timed(&scene, &integ, &s, 2, 5, true).unwrap();
    assert_eq!(acc.samples(), 5);
    assert_eq!(times.frames.len(), 5);
    assert_eq!(times.warmup, 2);
    assert!(times.mean() > 0.0 && times.median() > 0.0);
    // Same image as a plain 5 spp render.
    let plain = render(&scene, &integ, &s).unwrap();
    assert_eq!(acc.mean_image().as_raw(), plain.as_raw());
    assert!(acc.heatmap(HeatMap::Collisions).is_some());
    assert!(render_timed(&scene, &integ, &s, 0, 0, false).is_err());
}

#[test]
fn bad_settings_get_clear_errors() {
    let mut scene = sphere_scene();
    let integ = Integrator::Mdwt {
        dda: DdaMode::OneDda,
        blend: Blend::Density,
    };
    for dir in [Vec3::ZERO, Vec3::new(f32::NAN, 0.0, 1.0)] {
        scene.light = Some(DirectionalLight {
            direction: dir,
            radiance: [1.0; 3],
            ambient: 0.1,
        });
        let e = integ.prepared(&scene).unwrap_err().to_string();
        assert!(e.contains("light.direction"), "{e}");
    }
    scene.light = None;
    scene.shading = Some(Shading {
        materials: vec![Material {
            shininess: -1.0,
            ..Material::default()
        }],
        shadows: false,
    });
    let e = integ.prepared(&scene).unwrap_err().to_string();
    assert!(e.contains("shininess"), "{e}");
    let e = "heat".parse::<HeatMap>().unwrap_err().to_string();
    assert!(
        e.contains("unknown 'heat'") && e.contains("rejections"),
        "{e}"
    );
    assert_eq!("time".parse::<HeatMap>().unwrap(), HeatMap::Time);
    // Shading is for the trackers; the marcher refuses it.
    scene.shading = Some(Shading::default());
    assert!(
        Integrator::Marcher(RayMarcher::default())
            .prepared(&scene)
            .is_err()
    );
}
