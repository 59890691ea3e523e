//! The renderer: pixels land on the analytically expected scene directions.

use blueshift_relativity::{
    Camera, Checker, Effects, Environment, Velocity, out_of_map_fraction, parse_ramp, render,
    scene_direction,
};
use glam::DVec3;

/// Camera looking along the motion (+Z): the pixel at angle theta' off-axis in the
/// horizontal plane sees the scene at cos(theta) = (cos(theta') - b) / (1 - b cos(theta'))
/// (Eq. 2), in the same azimuth.
#[test]
fn pixels_land_on_eq2_directions_looking_forward() {
    let cam = Camera {
        look: DVec3::Z,
        up: DVec3::Y,
        fov_y_deg: 90.0,
        width: 201,
        height: 101,
    };
    let b = 0.8;
    let v = Velocity::along(DVec3::Z, b).unwrap();
    let half_w = 45_f64.to_radians().tan() * 201.0 / 101.0;
    for x in [100_u32, 130, 170, 200] {
        // The pixel's observer direction from the pinhole geometry, written out here.
        let sx = (2.0 * (f64::from(x) + 0.5) / 201.0 - 1.0) * half_w;
        let cos_p = 1.0 / (1.0 + sx * sx).sqrt();
        let cos_s = (cos_p - b) / (1.0 - b * cos_p);
        let d = scene_direction(&cam, v, Effects::ALL, x, 50).unwrap();
        assert!((d.z - cos_s).abs() < 1e-12, "x {x}: {d} vs cos {cos_s}");
        assert!(d.y.abs() < 1e-12);
        // Right of the image: f x up = Z x Y = -X.
        assert!(x == 100 || d.x < 0.0);
    }
}

/// Looking sideways (+X) while moving along +Z: the centre pixel (cos(theta') = 0) sees the
/// scene direction (1/gamma, 0, -b), i.e. things that are behind in the scene frame.
#[test]
fn sideways_view_sees_behind() {
    let cam = Camera {
        look: DVec3::X,
        width: 101,
        height: 101,
        ..Camera::default()
    };
    for b in [0.3, 0.9, 0.99] {
        let v = Velocity::along(DVec3::Z, b).unwrap();
        let d = scene_direction(&cam, v, Effects::ALL, 50, 50).unwrap();
        let g = 1.0 / (1.0 - b * b).sqrt();
        assert!((d - DVec3::new(1.0 / g, 0.0, -b)).length() < 1e-12, "{d}");
        // Without aberration the pixel direction is the look direction.
        let d0 = scene_direction(&cam, v, Effects::default(), 50, 50).unwrap();
        assert!((d0 - DVec3::X).length() < 1e-12);
    }
}

/// Rendering the checkerboard: chosen pixels show the colour of the checker cell at the
/// analytically expected scene direction.
#[test]
fn checker_render_shows_expected_cells() {
    let checker = Checker {
        grid_deg: 0.0,
        ..Checker::default()
    };
    let env = Environment::Checker(checker.clone());
    let cam = Camera {
        look: DVec3::X,
        width: 64,
        height: 64,
        fov_y_deg: 60.0,
        ..Camera::default()
    };
    let b = 0.9;
    let v = Velocity::along(DVec3::Z, b).unwrap();
    let img = render(&env, &cam, v, Effects::ABERRATION, None).unwrap();
    let mut checked = 0;
    let half = 30_f64.to_radians().tan();
    let fwd = DVec3::X;
    let right = fwd.cross(DVec3::Y).normalize();
    let up = right.cross(fwd);
    for y in (0..64).step_by(7) {
        for x in (0..64).step_by(7) {
            let sx = (2.0 * (f64::from(x) + 0.5) / 64.0 - 1.0) * half;
            let sy = (1.0 - 2.0 * (f64::from(y) + 0.5) / 64.0) * half;
            let d_obs = (fwd + sx * right + sy * up).normalize();
            // Eq. 2 in vector form, written out independently of the crate.
            let g = 1.0 / (1.0 - b * b).sqrt();
            let c = d_obs.z;
            let par = (c - b) / (1.0 - b * c);
            let perp = DVec3::new(d_obs.x, d_obs.y, 0.0) / (g * (1.0 - b * c));
            let d = DVec3::new(perp.x, perp.y, par);
            // Skip pixels within 1 degree of a cell border.
            let (lon, polar) = blueshift_relativity::lon_polar(d);
            let near = |a: f64| {
                let r = a.to_degrees().rem_euclid(10.0);
                r.min(10.0 - r) < 1.0
            };
            if near(lon) || near(polar) {
                continue;
            }
            assert_eq!(img.get_pixel(x, y).0, checker.sample(d), "pixel {x},{y}");
            checked += 1;
        }
    }
    assert!(checked > 20, "{checked}");
}

/// Searchlight on a uniform white sky: the head-on pixel is D^4 brighter, the pixel straight
/// behind D^-4, with D = sqrt((1 + b) / (1 - b)); Doppler on white at D = 1 (the pixel at
/// cos(theta') = ... where D = 1) stays white.
#[test]
fn searchlight_scales_radiance_by_d_to_the_fourth() {
    let white = Checker {
        light: [1.0; 3],
        dark: [1.0; 3],
        grid_deg: 0.0,
        ..Checker::default()
    };
    let env = Environment::Checker(white);
    let b: f64 = 0.5;
    let dd = ((1.0 + b) / (1.0 - b)).sqrt();
    let v = Velocity::along(DVec3::Z, b).unwrap();
    let searchlight_only = Effects {
        aberration: true,
        doppler: false,
        searchlight: true,
    };
    for (look, expected) in [(DVec3::Z, dd.powi(4)), (DVec3::NEG_Z, dd.powi(-4))] {
        let cam = Camera {
            look,
            width: 3,
            height: 3,
            ..Camera::default()
        };
        let img = render(&env, &cam, v, searchlight_only, None).unwrap();
        let p = img.get_pixel(1, 1).0;
        assert!(
            (f64::from(p[1]) / expected - 1.0).abs() < 1e-5,
            "{p:?} vs {expected}"
        );
    }
    // At the observer direction where D = 1, cos(theta') = (1 - 1/gamma) / b, the full
    // effect set leaves white unchanged (K(1) = identity).
    let g = 1.0 / (1.0 - b * b).sqrt();
    let c = (1.0 - 1.0 / g) / b;
    let look = DVec3::new((1.0 - c * c).sqrt(), 0.0, c);
    let cam = Camera {
        look,
        width: 1,
        height: 1,
        ..Camera::default()
    };
    let p = render(&env, &cam, v, Effects::ALL, None)
        .unwrap()
        .get_pixel(0, 0)
        .0;
    for ch in p {
        assert!((ch - 1.0).abs() < 1e-4, "{p:?}");
    }
}

#[test]
fn rendering_is_identical_on_any_thread_count() {
    let env = Environment::Checker(Checker::default());
    let cam = Camera {
        width: 97,
        height: 41,
        ..Camera::default()
    };
    let v = Velocity::new(DVec3::new(0.3, 0.2, -0.6)).unwrap();
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    let three = rayon::ThreadPoolBuilder::new()
        .num_threads(3)
        .build()
        .unwrap();
    let a = one.install(|| render(&env, &cam, v, Effects::ALL, None).unwrap());
    let b = three.install(|| render(&env, &cam, v, Effects::ALL, None).unwrap());
    assert_eq!(a.as_raw(), b.as_raw());
}

#[test]
fn bad_camera_and_ramp_are_errors() {
    let env = Environment::Checker(Checker::default());
    let v = Velocity::ZERO;
    for cam in [
        Camera {
            fov_y_deg: 0.0,
            ..Camera::default()
        },
        Camera {
            fov_y_deg: f64::NAN,
            ..Camera::default()
        },
        Camera {
            width: 0,
            ..Camera::default()
        },
        Camera {
            height: 1_000_000,
            ..Camera::default()
        },
        Camera {
            look: DVec3::ZERO,
            ..Camera::default()
        },
    ] {
        assert!(
            render(&env, &cam, v, Effects::ALL, None).is_err(),
            "{cam:?}"
        );
    }
    assert_eq!(parse_ramp("0:0.99:4").unwrap(), vec![0.0, 0.33, 0.66, 0.99]);
    for bad in [
        "0:1:10",
        "0:0.5",
        "a:0.5:3",
        "0:0.5:0",
        "-0.1:0.5:3",
        "0:NaN:3",
    ] {
        assert!(parse_ramp(bad).is_err(), "{bad}");
    }
}

/// At beta 0.9 the view ahead has Doppler factors above the RGB map's reach: exactly the
/// pixels `out_of_map_fraction` counts render black from a white sky (the black disc), and
/// the fraction is the share of the view inside the analytic cone D > 780 / 360 (360 nm
/// observed came from beyond the RGB spectrum's 780 nm),
/// D = 1 / (gamma (1 - beta cos theta')) for the observer-frame angle theta' to the motion.
#[test]
fn out_of_map_fraction_counts_the_black_disc() {
    let white = Checker {
        light: [1.0; 3],
        dark: [1.0; 3],
        grid_deg: 0.0,
        ..Checker::default()
    };
    let env = Environment::Checker(white);
    let b: f64 = 0.9;
    let v = Velocity::along(DVec3::Z, b).unwrap();
    let cam = Camera {
        look: DVec3::Z,
        width: 64,
        height: 48,
        fov_y_deg: 90.0,
        ..Camera::default()
    };
    let fx = Effects::ALL;
    let f = out_of_map_fraction(&cam, v, fx, None).unwrap();
    let img = render(&env, &cam, v, fx, None).unwrap();
    let black = img.pixels().filter(|p| p.0 == [0.0; 3]).count();
    assert!(black > 0, "no black disc at beta 0.9");
    assert_eq!(black as f64 / (64.0 * 48.0), f);
    // The analytic cone: cos theta' > (1 - 1 / (gamma D_max)) / beta.
    let g = 1.0 / (1.0 - b * b).sqrt();
    let cos_max = (1.0 - 1.0 / (g * (780.0 / 360.0))) / b;
    let frame = blueshift_relativity::CameraFrame::new(&cam).unwrap();
    let mut inside = 0;
    for y in 0..48 {
        for x in 0..64 {
            let d = frame.pixel_direction(f64::from(x), f64::from(y));
            if d.normalize().z > cos_max {
                inside += 1;
            }
        }
    }
    assert!(
        (f - f64::from(inside) / (64.0 * 48.0)).abs() < 0.01,
        "{f} vs cone {inside}"
    );
    // Without the Doppler colour shift nothing is out of the map; at rest neither.
    let no_doppler = Effects {
        doppler: false,
        ..Effects::ALL
    };
    assert_eq!(out_of_map_fraction(&cam, v, no_doppler, None).unwrap(), 0.0);
    let rest = Velocity::along(DVec3::Z, 0.0).unwrap();
    assert_eq!(out_of_map_fraction(&cam, rest, fx, None).unwrap(), 0.0);
}

/// A misspelt effect is named in the error, with the words that are effects.
#[test]
fn an_unknown_effect_is_named() {
    let e = blueshift_relativity::Effects::parse("aberration, abberation").unwrap_err();
    let m = e.to_string();
    assert!(
        m.contains("'abberation'") && m.contains("searchlight"),
        "{m}"
    );
    assert!(!m.contains("NaN"), "{m}");
}
