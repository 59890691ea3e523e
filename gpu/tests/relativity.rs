//! The GPU relativity renderer against blueshift_relativity::render on the same scene.
//! Smooth maps: every channel within 2e-3 of the pixel's brightest channel + 1e-5 (f32 vs
//! f64). Checker
//! (discontinuous): at least 99.5% of pixels equal within the same tolerance.

use blueshift_gpu::context::test_context;
use blueshift_gpu::relativity::GpuRelativity;
use blueshift_relativity::{
    Camera, Checker, CubeMap, Effects, Environment, EquirectMap, Velocity, cube_dir,
};
use glam::DVec3;
use image::{Rgb, Rgb32FImage};

fn smooth(d: DVec3) -> [f32; 3] {
    let d = d.normalize();
    [
        (1.0 + 0.8 * d.x) as f32,
        (1.0 + 0.6 * d.y * d.z) as f32,
        (0.5 + 0.4 * (2.0 * d.z).sin() + 0.3 * d.y) as f32,
    ]
}

fn equirect() -> Environment {
    let (w, h) = (64, 32);
    let img = Rgb32FImage::from_fn(w, h, |x, y| {
        let lon = ((x as f64 + 0.5) / w as f64 - 0.5) * std::f64::consts::TAU;
        let polar = (y as f64 + 0.5) / h as f64 * std::f64::consts::PI;
        Rgb(smooth(blueshift_relativity::from_lon_polar(lon, polar)))
    });
    Environment::Equirect(EquirectMap::new(img).unwrap())
}

fn cube() -> Environment {
    let n = 16;
    let faces: [Rgb32FImage; 6] = std::array::from_fn(|f| {
        Rgb32FImage::from_fn(n, n, |x, y| {
            let d = cube_dir(f, (x as f64 + 0.5) / n as f64, (y as f64 + 0.5) / n as f64);
            Rgb(smooth(d))
        })
    });
    Environment::Cube(CubeMap::new(faces).unwrap())
}

fn camera() -> Camera {
    Camera {
        look: DVec3::new(0.3, -0.2, -1.0),
        up: DVec3::Y,
        fov_y_deg: 100.0,
        width: 40,
        height: 30,
    }
}

fn compare(env: &Environment, v: Velocity, fx: Effects, min_frac: f64) {
    let Some(ctx) = test_context() else { return };
    let cam = camera();
    let cpu = blueshift_relativity::render(env, &cam, v, fx, None).unwrap();
    let gpu = GpuRelativity::new(ctx, None)
        .unwrap()
        .render(env, &cam, v, fx)
        .unwrap();
    assert_eq!(cpu.dimensions(), gpu.dimensions());
    let mut good = 0usize;
    let mut worst = 0.0f32;
    for (c, g) in cpu.pixels().zip(gpu.pixels()) {
        // Relative to the pixel's brightest channel: the f32 direction error moves the
        // lookup by ~1e-4 texel, which shifts every channel by the same small amount.
        let peak = c.0.iter().fold(0.0f32, |m, v| m.max(v.abs()));
        let ok = (0..3).all(|i| {
            let tol = 1e-5 + 2e-3 * peak;
            let e = (c.0[i] - g.0[i]).abs();
            worst = worst.max(e / tol);
            e <= tol
        });
        good += usize::from(ok);
    }
    let frac = good as f64 / (cpu.width() * cpu.height()) as f64;
    assert!(
        frac >= min_frac,
        "{fx:?}: only {frac} of pixels agree (worst {worst} x tolerance)"
    );
}

fn velocities() -> [Velocity; 2] {
    [
        Velocity::along(DVec3::new(0.2, 0.1, -1.0), 0.6).unwrap(),
        Velocity::along(DVec3::new(-0.5, 0.3, -0.4), 0.9).unwrap(),
    ]
}

const SETS: [Effects; 4] = [
    Effects {
        aberration: false,
        doppler: false,
        searchlight: false,
    },
    Effects::ABERRATION,
    Effects {
        aberration: true,
        doppler: true,
        searchlight: false,
    },
    Effects::ALL,
];

#[test]
fn equirect_matches_cpu_for_every_effect_set() {
    let env = equirect();
    for v in velocities() {
        for fx in SETS {
            compare(&env, v, fx, 1.0);
        }
    }
}

#[test]
fn cube_map_matches_cpu_for_every_effect_set() {
    let env = cube();
    for v in velocities() {
        for fx in SETS {
            compare(&env, v, fx, 1.0);
        }
    }
}

/// A 1024 x 512 map whose texels jump independently over two decades (like the lamps and
/// stars of real HDR photos): texel-sized detail shows any error in the lookup position.
fn detailed_equirect() -> Environment {
    let img = Rgb32FImage::from_fn(1024, 512, |x, y| {
        let mut h = u64::from(x).wrapping_mul(0x9E37_79B9_7F4A_7C15)
            ^ u64::from(y).wrapping_mul(0xC2B2_AE3D_27D4_EB4F);
        Rgb(std::array::from_fn(|_| {
            h ^= h >> 29;
            h = h.wrapping_mul(0xBF58_476D_1CE4_E5B9);
            h ^= h >> 32;
            10f32.powf(2.0 * (h >> 40) as f32 / (1u64 << 24) as f32 - 1.0)
        }))
    });
    Environment::Equirect(EquirectMap::new(img).unwrap())
}

/// Real maps, and the polar angle near the poles: the device once took the polar angle as
/// `acos(y)`, which in f32 loses up to 3e-4 rad near the poles (and lavapipe's `acos` is an
/// approximation), so 15-27 % of the pixels of the real maps in `shared/data` missed the
/// tolerance; `atan2(|xz|, y)` is well conditioned everywhere (measured on those maps: at
/// most 1 pixel in 1500 outside the tolerance, none on most).
#[test]
fn detailed_equirect_matches_cpu_including_near_the_poles() {
    let env = detailed_equirect();
    for look in [DVec3::new(0.3, -0.2, -1.0), DVec3::new(0.2, 0.9, -0.3)] {
        let Some(ctx) = test_context() else { return };
        let cam = Camera {
            look,
            up: DVec3::Y,
            fov_y_deg: 60.0,
            width: 48,
            height: 32,
        };
        for fx in [SETS[0], Effects::ALL] {
            let v = velocities()[0];
            let cpu = blueshift_relativity::render(&env, &cam, v, fx, None).unwrap();
            let gpu = GpuRelativity::new(ctx, None)
                .unwrap()
                .render(&env, &cam, v, fx)
                .unwrap();
            let good = cpu
                .pixels()
                .zip(gpu.pixels())
                .filter(|(c, g)| {
                    let peak = c.0.iter().fold(0.0f32, |m, v| m.max(v.abs()));
                    (0..3).all(|i| (c.0[i] - g.0[i]).abs() <= 1e-5 + 2e-3 * peak)
                })
                .count();
            let frac = good as f64 / f64::from(cam.width * cam.height);
            assert!(
                frac >= 0.995,
                "look {look}, {fx:?}: only {frac} of pixels agree"
            );
        }
    }
}

/// Near the speed of light, looking along the motion through a narrow field of view: the
/// device once took the aberration and the Doppler factor as the CPU's formulas in f32,
/// where `1 - 0.999999` keeps 6 % precision and `c - beta` cancels (on a real 1k map 70 %
/// of the pixels were wrong at beta 0.999999, fov 1; here the searchlight case failed); it
/// now gets `1 - |beta|` from the host and `1 - c` from the perpendicular part. Smooth map:
/// every pixel within the tolerance.
#[test]
fn ultra_relativistic_forward_view_matches_cpu() {
    let Some(ctx) = test_context() else { return };
    let env = equirect();
    let gpu_r = GpuRelativity::new(ctx, None).unwrap();
    let dir = DVec3::new(0.2, 0.1, -1.0);
    for (beta, fov) in [(0.9999, 1.0), (0.999999, 1.0), (0.999999, 10.0)] {
        let cam = Camera {
            look: dir,
            up: DVec3::Y,
            fov_y_deg: fov,
            width: 48,
            height: 32,
        };
        let v = Velocity::along(dir, beta).unwrap();
        let searchlight = Effects {
            aberration: true,
            doppler: false,
            searchlight: true,
        };
        for fx in [Effects::ABERRATION, searchlight] {
            let cpu = blueshift_relativity::render(&env, &cam, v, fx, None).unwrap();
            let gpu = gpu_r.render(&env, &cam, v, fx).unwrap();
            let good = cpu
                .pixels()
                .zip(gpu.pixels())
                .filter(|(c, g)| {
                    let peak = c.0.iter().fold(0.0f32, |m, v| m.max(v.abs()));
                    (0..3).all(|i| (c.0[i] - g.0[i]).abs() <= 1e-5 + 2e-3 * peak)
                })
                .count();
            let frac = good as f64 / f64::from(cam.width * cam.height);
            assert!(
                frac >= 1.0,
                "beta {beta}, fov {fov}, {fx:?}: only {frac} of pixels agree"
            );
        }
    }
}

#[test]
fn checker_matches_cpu_except_on_edges() {
    let env = Environment::Checker(Checker::default());
    for v in velocities() {
        compare(&env, v, Effects::ALL, 0.995);
        compare(&env, v, Effects::ABERRATION, 0.995);
    }
}

#[test]
fn searchlight_brightens_ahead_as_d_to_the_fourth() {
    // Independent truth: with only the searchlight on, the pixel straight ahead of an
    // observer moving along the view axis is multiplied by D^4, D = sqrt((1+b)/(1-b)).
    let Some(ctx) = test_context() else { return };
    let env = Environment::Checker(Checker {
        grid_deg: 0.0,
        light: [1.0, 1.0, 1.0],
        dark: [1.0, 1.0, 1.0],
        ..Checker::default()
    });
    let cam = Camera {
        look: DVec3::NEG_Z,
        width: 9,
        height: 9,
        fov_y_deg: 1.0,
        ..Camera::default()
    };
    let b = 0.5;
    let v = Velocity::along(DVec3::NEG_Z, b).unwrap();
    let fx = Effects {
        aberration: false,
        doppler: false,
        searchlight: true,
    };
    let img = GpuRelativity::new(ctx, None)
        .unwrap()
        .render(&env, &cam, v, fx)
        .unwrap();
    let d = ((1.0 + b) / (1.0 - b)).sqrt();
    let expect = d.powi(4) as f32;
    let got = img.get_pixel(4, 4).0[0];
    assert!((got - expect).abs() < 1e-3 * expect, "{got} vs {expect}");
}

#[test]
fn bad_camera_is_an_error() {
    let Some(ctx) = test_context() else { return };
    let r = GpuRelativity::new(ctx, None).unwrap();
    let cam = Camera {
        fov_y_deg: 0.0,
        ..camera()
    };
    let v = Velocity::along(DVec3::Z, 0.5).unwrap();
    assert!(matches!(
        r.render(
            &Environment::Checker(Checker::default()),
            &cam,
            v,
            Effects::ALL
        ),
        Err(blueshift_gpu::Error::Relativity(_))
    ));
}
