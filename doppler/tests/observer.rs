//! A relativistic observer inside the volume (issue 27), against the formulas of special
//! relativity: the lines of a still medium at the observer's Doppler factor (head-on
//! `sqrt((1 + b) / (1 - b))`, transverse `1 / gamma`), a gas seen unshifted by an observer
//! moving with it (velocity composition), a bright blob at the aberrated angle, and renders
//! at rest unchanged bit for bit.

use blueshift_doppler::{DopplerScene, DopplerSettings, Species, pixel_spectrum, render_doppler};
use blueshift_relativity::{MovingObserver, Velocity};
use blueshift_spectrum::{DopplerModel, EmissionLine, SPEED_OF_LIGHT_M_PER_S};
use blueshift_volume::{AnyGrid, Geometry, Grid, synth};
use glam::{DVec3, Vec3};

const HALPHA: f64 = 656.2816;

/// Hydrogen of density `rho(i, j, k)` in a `n^3` box of unit edge, moving with `u` (m/s)
/// everywhere; H-alpha only.
fn scene(n: usize, u: Vec3, rho: impl Fn(usize, usize, usize) -> f32 + Sync) -> DopplerScene {
    let g = Geometry {
        dims: [n; 3],
        origin: Vec3::ZERO,
        spacing: Vec3::splat(1.0 / (n - 1) as f32),
    };
    let mut s = DopplerScene::new(g).unwrap();
    s.add_species(Species {
        name: "H".into(),
        density: AnyGrid::F32(Grid::from_fn(g, rho).unwrap()).into(),
        emission_lines: vec![EmissionLine::new(HALPHA, 1.0).unwrap()],
        absorption_lines: vec![],
    })
    .unwrap();
    s.set_velocity(Grid::from_fn(g, |_, _, _| u).unwrap())
        .unwrap();
    s
}

fn settings(s: &DopplerScene, w: u32) -> DopplerSettings {
    let mut st = DopplerSettings::default_for(s, w, w);
    st.model = DopplerModel::Relativistic;
    st.line_width_nm = 0.05;
    st
}

fn observer(beta: DVec3) -> Option<MovingObserver> {
    Some(MovingObserver::new(Velocity::new(beta).unwrap()))
}

/// The line's wavelength in pixel `(x, y)`'s spectrum (its centroid over 380-780 nm).
fn line_at(s: &DopplerScene, st: &DopplerSettings, x: u32, y: u32) -> f64 {
    pixel_spectrum(s, st, x, y)
        .unwrap()
        .centroid(380.0, 780.0)
        .expect("the pixel sees the line")
}

/// A still, uniform medium seen by an observer moving at beta: head-on every line is at
/// `lambda / sqrt((1 + b) / (1 - b))`, transverse (the viewing direction perpendicular to the
/// motion in the observer's frame) at `lambda gamma`; at rest at `lambda`.
#[test]
fn a_still_medium_shows_the_observer_doppler_factor() {
    let s = scene(9, Vec3::ZERO, |_, _, _| 1.0);
    let mut st = settings(&s, 9);
    // The default view looks along -z (orthographic, every ray parallel).
    let rest = line_at(&s, &st, 4, 4);
    assert!((rest - HALPHA).abs() < 1e-9 * HALPHA, "{rest}");
    let b: f64 = 0.2;
    st.observer = observer(DVec3::new(0.0, 0.0, -b));
    let head_on = line_at(&s, &st, 4, 4);
    let d = ((1.0 + b) / (1.0 - b)).sqrt();
    assert!(
        (head_on - HALPHA / d).abs() < 1e-6 * HALPHA,
        "{head_on} vs {}",
        HALPHA / d
    );
    let b: f64 = 0.3;
    st.observer = observer(DVec3::new(b, 0.0, 0.0));
    let transverse = line_at(&s, &st, 4, 4);
    let gamma = 1.0 / (1.0 - b * b).sqrt();
    assert!(
        (transverse - HALPHA * gamma).abs() < 1e-6 * HALPHA,
        "{transverse} vs {}",
        HALPHA * gamma
    );
}

/// Gas moving at u seen by an observer moving with the same velocity: every line in every
/// direction is at its rest wavelength (the two Doppler factors compose to 1), where the
/// observer at rest sees it shifted by up to `sqrt((1 + u) / (1 - u))`.
#[test]
fn an_observer_moving_with_the_gas_sees_its_lines_unshifted() {
    let beta = DVec3::new(0.12, -0.05, 0.15);
    let u = (beta * SPEED_OF_LIGHT_M_PER_S).as_vec3();
    let s = scene(9, u, |_, _, _| 1.0);
    let mut st = settings(&s, 7);
    // A perspective view from outside the box: every pixel a different direction.
    st.camera = blueshift_camera::Camera {
        eye: Vec3::new(0.5, 0.4, 3.0),
        target: Vec3::splat(0.5),
        up: Vec3::Y,
        projection: blueshift_camera::Projection::Perspective { fov_y_deg: 20.0 },
    };
    let mut widest = 0.0f64;
    for (x, y) in [(0, 0), (3, 3), (6, 1), (2, 6)] {
        st.observer = None;
        widest = widest.max((line_at(&s, &st, x, y) - HALPHA).abs());
        st.observer = observer(beta);
        let seen = line_at(&s, &st, x, y);
        assert!(
            (seen - HALPHA).abs() < 1e-5 * HALPHA,
            "pixel {x},{y}: {seen}"
        );
    }
    // The test can fail: at rest the gas's motion shifts the line by tens of nanometres.
    assert!(widest > 40.0, "{widest}");
}

/// A bright blob 25 degrees off the direction of motion appears where aberration puts it:
/// `cos t' = (cos t + b) / (1 + b cos t)` (about 18.5 degrees at b = 0.3), not where it is at
/// rest.
#[test]
fn aberration_moves_a_bright_blob_to_the_aberrated_angle() {
    let n = 41;
    let c = 0.5f32;
    // The blob inside the box, 25 degrees off the view axis (-z) in the x-z plane.
    let t = 25f32.to_radians();
    let blob = Vec3::new(c + 0.75 * t.tan(), c, c);
    let eye = Vec3::new(c, c, c + 0.75);
    let h = 1.0 / (n - 1) as f32;
    let s = scene(n, Vec3::ZERO, |i, j, k| {
        let p = Vec3::new(i as f32, j as f32, k as f32) * h;
        (-(p - blob).length_squared() / (2.0 * (1.2 * h) * (1.2 * h))).exp()
    });
    let w = 121u32;
    let mut st = settings(&s, w);
    st.camera = blueshift_camera::Camera {
        eye,
        target: Vec3::new(c, c, 0.0),
        up: Vec3::Y,
        projection: blueshift_camera::Projection::Perspective { fov_y_deg: 70.0 },
    };
    let b = 0.3;
    let v = Velocity::new(DVec3::new(0.0, 0.0, -b)).unwrap();
    st.observer = Some(MovingObserver::new(v));
    let img = render_doppler(&s, &st, &|| {}).unwrap();
    let lum = |x: u32, y: u32| img.xyz[(y * w + x) as usize][1];
    let (mut bx, mut by) = (0, 0);
    for y in 0..w {
        for x in 0..w {
            if lum(x, y) > lum(bx, by) {
                (bx, by) = (x, y);
            }
        }
    }
    // Luminance-weighted centre of the 7x7 pixels around the brightest.
    let (mut sx, mut sy, mut sw) = (0.0, 0.0, 0.0);
    for y in by.saturating_sub(3)..(by + 4).min(w) {
        for x in bx.saturating_sub(3)..(bx + 4).min(w) {
            let l = lum(x, y);
            sx += l * (f64::from(x) + 0.5);
            sy += l * (f64::from(y) + 0.5);
            sw += l;
        }
    }
    let seen = st
        .camera
        .ray((sx / sw) as f32, (sy / sw) as f32, w, w)
        .dir
        .as_dvec3()
        .normalize();
    let angle = |a: DVec3, b: DVec3| a.dot(b).clamp(-1.0, 1.0).acos().to_degrees();
    let scene_dir = (blob - eye).as_dvec3().normalize();
    let expected = v.scene_to_observer(scene_dir);
    let forward = DVec3::NEG_Z;
    // The formula's angle, independently: cos t' = (cos t + b) / (1 + b cos t).
    let ct = scene_dir.dot(forward);
    let t_prime = ((ct + b) / (1.0 + b * ct)).acos().to_degrees();
    assert!((angle(expected, forward) - t_prime).abs() < 1e-9);
    let pixel = 70.0 / f64::from(w);
    assert!(
        angle(seen, expected) < 0.6 * pixel,
        "seen {:.3} deg off axis, expected {t_prime:.3}",
        angle(seen, forward)
    );
    // ... and not at rest's 25 degrees.
    assert!(angle(seen, scene_dir) > 5.0);
}

/// An observer at rest (speed 0, in any direction) changes no bit of the image or spectra.
#[test]
fn at_rest_renders_are_unchanged_bit_for_bit() {
    let vol = synth::galaxy(24, 3).unwrap();
    let s = DopplerScene::from_volume(&vol, &["bb", "H"]).unwrap();
    let mut st = DopplerSettings::default_for(&s, 20, 16);
    let a = render_doppler(&s, &st, &|| {}).unwrap();
    let pa = pixel_spectrum(&s, &st, 10, 8).unwrap();
    st.observer = Some(MovingObserver::new(Velocity::ZERO));
    let b = render_doppler(&s, &st, &|| {}).unwrap();
    let pb = pixel_spectrum(&s, &st, 10, 8).unwrap();
    assert_eq!(a.xyz, b.xyz);
    assert_eq!(
        pa.pieces().collect::<Vec<_>>(),
        pb.pieces().collect::<Vec<_>>()
    );
    // A moving observer does change it.
    st.observer = observer(DVec3::new(0.0, 0.0, -0.1));
    let c = render_doppler(&s, &st, &|| {}).unwrap();
    assert_ne!(a.xyz, c.xyz);
}

/// Spectral cubes see the observer too: a still, uniform medium seen head-on at beta has
/// moment 1 (optical velocity) `c (1 / D - 1)` in every pixel, `D = sqrt((1 + b) / (1 - b))`.
#[test]
fn a_cube_of_a_still_medium_has_the_observer_velocity() {
    use blueshift_doppler::{CubeLineWidth, CubeSpec, SpectralAxis, render_cube};
    let s = scene(9, Vec3::ZERO, |_, _, _| 1.0);
    let mut st = settings(&s, 5);
    let b: f64 = 5e-4;
    st.observer = observer(DVec3::new(0.0, 0.0, -b));
    let spec = CubeSpec {
        rest_nm: HALPHA,
        axis: SpectralAxis::OpticalVelocity,
        min: -300e3,
        max: 300e3,
        channels: 60,
        line_width: CubeLineWidth::OneChannel,
    };
    let cube = render_cube(&s, &st, &spec, &|| {}).unwrap();
    let m = cube.moments();
    let d = ((1.0 + b) / (1.0 - b)).sqrt();
    let expected = SPEED_OF_LIGHT_M_PER_S * (1.0 / d - 1.0);
    assert!(expected < -140e3, "{expected}");
    for (p, &m1) in m.m1.iter().enumerate() {
        assert!(
            (f64::from(m1) - expected).abs() < 0.1 * spec.width(),
            "pixel {p}: moment 1 {m1} m/s, expected {expected}"
        );
    }
}

/// The rotating hydrogen shell (`v = (omega z, 0, -omega x)`) seen along -z by an observer
/// moving with the shell's gas at one point `(x0, 0, z0)` of the pixel's line of sight: that
/// gas, and every parcel on the line of sight (the same `v_z`, the same speed up to the
/// shell's thickness), is seen at its rest wavelength, where at rest the line is shifted by
/// `lambda omega x0 / c` (about 0.27 nm).
#[test]
fn an_observer_moving_with_the_shell_at_one_point_sees_its_line_unshifted() {
    let vol = synth::hydrogen_shell(40, 1).unwrap();
    let s = DopplerScene::from_volume(&vol, &["H"]).unwrap();
    let mut st = DopplerSettings::default_for(&s, 20, 20);
    st.model = DopplerModel::Relativistic;
    st.line_width_nm = 0.05;
    // Pixel (12, 10): x = 0.25, y = -0.05 on the [-1, 1] square.
    let (x0, z0) = (0.25f64, (0.6f64 * 0.6 - 0.25 * 0.25).sqrt());
    let omega = f64::from(synth::SHELL_SPEED_M_PER_S) / f64::from(synth::SHELL_RADIUS);
    let halpha = |st: &DopplerSettings| {
        pixel_spectrum(&s, st, 12, 10)
            .unwrap()
            .centroid(HALPHA - 5.0, HALPHA + 5.0)
            .expect("the pixel sees H-alpha")
    };
    let rest = halpha(&st);
    let shift = HALPHA * omega * x0 / SPEED_OF_LIGHT_M_PER_S;
    assert!(
        (rest - HALPHA - shift).abs() < 0.1 * shift,
        "at rest the receding side is red-shifted by {shift} nm: {rest}"
    );
    let beta = DVec3::new(omega * z0, 0.0, -omega * x0) / SPEED_OF_LIGHT_M_PER_S;
    st.observer = observer(beta);
    let seen = halpha(&st);
    assert!((seen - HALPHA).abs() < 1e-5 * HALPHA, "{seen}");
}
