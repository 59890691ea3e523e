//! Tests against independent truths (analytic spectra, conservation, Planck's law).

use blueshift_spectrum::{DopplerModel, EmissionLine, SPEED_OF_LIGHT_M_PER_S as C, planck};
use blueshift_volume::{AnyGrid, Geometry, Grid, synth};
use glam::Vec3;

use super::render::ray_spectrum;
use super::*;
use crate::Ray;

fn ramp_scene(line_nm: f64) -> DopplerScene {
    let geom = Geometry::unit([2, 2, 16]);
    let rho = Grid::from_fn(geom, |_, _, z| 1.0 + z as f32 / 15.0).unwrap();
    let vel = Grid::from_fn(geom, |_, _, z| {
        Vec3::new(0.0, 0.0, -3.0e6 + 6.0e6 * z as f32 / 15.0)
    })
    .unwrap();
    let mut s = DopplerScene::new(geom).unwrap();
    s.add_species(Species {
        name: "x".into(),
        density: (AnyGrid::F32(rho)).into(),
        emission_lines: vec![EmissionLine::new(line_nm, 1.0).unwrap()],
        absorption_lines: vec![],
    })
    .unwrap();
    s.set_velocity(vel).unwrap();
    s
}

#[test]
fn linear_density_and_velocity_give_the_analytic_spectrum() {
    let scene = ramp_scene(500.0);
    let mut st = DopplerSettings::default_for(&scene, 4, 4);
    st.line_width_nm = 0.05;
    let ray = Ray::new(Vec3::new(0.5, 0.5, -1.0), Vec3::Z).unwrap();
    let (_, spec) = ray_spectrum(&scene, &st, &ray).unwrap();
    // Truth: I(lambda) = S rho(z) / |d lambda / dz| at the z where 500 s(z) = lambda.
    let dsdz = 6.0e6 / 15.0 / C;
    let mut checked = 0;
    for i in 1..40 {
        let lambda = 495.0 + 10.0 * f64::from(i) / 40.0;
        let v = (lambda / 500.0 - 1.0) * C;
        let z = (v + 3.0e6) * 15.0 / 6.0e6;
        if !(0.01..14.99).contains(&z) {
            continue;
        }
        let truth = (1.0 + z / 15.0) / (500.0 * dsdz);
        let got = spec.eval(lambda);
        assert!(
            (got - truth).abs() <= 1e-6 * truth,
            "lambda {lambda}: {got} vs {truth}"
        );
        checked += 1;
    }
    assert!(checked > 30);
    // Energy: integral of rho along the ray, S = 1.
    assert!((spec.total() - 15.0 * 1.5).abs() < 1e-6 * 22.5);
}

fn shell(res: usize) -> DopplerScene {
    let v = synth::hydrogen_shell(res, 7).unwrap();
    DopplerScene::from_volume(&v, &["H"]).unwrap()
}

#[test]
fn shell_sides_shift_by_their_radial_velocity() {
    let scene = shell(32);
    let st = DopplerSettings::default_for(&scene, 32, 32);
    let ha = 656.28;
    let mut signs = [false; 2];
    for x in [4u32, 27] {
        let ray = st.camera.ray(x as f32 + 0.5, 16.5, 32, 32);
        let spec = pixel_spectrum(&scene, &st, x, 16).unwrap();
        // Centroid of H-alpha.
        let (mut m0, mut m1) = (0.0, 0.0);
        for i in 0..4000 {
            let l = 640.0 + 35.0 * (f64::from(i) + 0.5) / 4000.0;
            let v = spec.eval(l);
            m0 += v;
            m1 += v * l;
        }
        let centroid = m1 / m0;
        // Truth: v = omega x r has v_z = -omega x along the whole ray; the camera at +z looks
        // along -z, so the radial (receding) velocity v . dir is +omega x.
        let omega = f64::from(synth::SHELL_SPEED_M_PER_S / synth::SHELL_RADIUS);
        let v_r = omega * f64::from(ray.origin.x);
        let want = v_r / C;
        let got = centroid / ha - 1.0;
        assert!(
            (got - want).abs() < 0.03 * want.abs(),
            "pixel {x}: shift {got} vs {want}"
        );
        signs[usize::from(got > 0.0)] = true;
    }
    assert!(signs[0] && signs[1], "one side blue, the other red");
}

#[test]
fn broadening_conserves_line_energy() {
    let mut scene = shell(24);
    let mut st = DopplerSettings::default_for(&scene, 24, 24);
    st.range_nm = (300.0, 900.0);
    for vf in [1.0, 30.0] {
        let max_vr = f64::from(synth::SHELL_SPEED_M_PER_S) * vf * 1.2;
        for x in [3u32, 8, 12, 20] {
            scene.factors.velocity = vf;
            let moving = pixel_spectrum(&scene, &st, x, 12).unwrap().total();
            scene.factors.velocity = 0.0;
            let rest = pixel_spectrum(&scene, &st, x, 12).unwrap().total();
            if rest > 0.0 {
                assert!(
                    ((moving - rest) / rest).abs() <= max_vr / C,
                    "x {x} factor {vf}: {moving} vs {rest}"
                );
            }
        }
    }
}

fn uniform_bb(v: Vec3) -> DopplerScene {
    let geom = Geometry::unit([2, 2, 4]);
    let mut s = DopplerScene::new(geom).unwrap();
    let one = Grid::from_fn(geom, |_, _, _| 1.0f32).unwrap();
    let t = Grid::from_fn(geom, |_, _, _| 6000.0f32).unwrap();
    s.set_blackbody(AnyGrid::F32(one), AnyGrid::F32(t)).unwrap();
    s.set_velocity(Grid::from_fn(geom, |_, _, _| v).unwrap())
        .unwrap();
    s
}

#[test]
fn shifted_black_body_is_the_black_body_at_t_over_s() {
    let beta = 0.1;
    let gamma = 1.0 / (1.0f64 - beta * beta).sqrt();
    for (v, s) in [
        (Vec3::Z, ((1.0 + beta) / (1.0 - beta)).sqrt()),
        (-Vec3::Z, ((1.0 - beta) / (1.0 + beta)).sqrt()),
        (Vec3::X, gamma),
    ] {
        let scene = uniform_bb(v * (beta * C) as f32);
        let mut st = DopplerSettings::default_for(&scene, 2, 2);
        st.model = DopplerModel::Relativistic;
        st.invariant = true;
        let ray = Ray::new(Vec3::new(0.5, 0.5, -1.0), Vec3::Z).unwrap();
        let (_, spec) = ray_spectrum(&scene, &st, &ray).unwrap();
        // Grid points (the last piece is half-open, so its end is left out).
        for i in 0..31 {
            let l = 380.0 + 400.0 * f64::from(i) / 31.0;
            let truth = 3.0 * BB_UNIT * planck(l, 6000.0 / s).unwrap();
            let got = spec.eval(l);
            assert!((got - truth).abs() <= 1e-6 * truth, "{l}: {got} vs {truth}");
        }
    }
}

fn rel_err(a: [f64; 3], b: [f64; 3]) -> f64 {
    let n = b.iter().map(|x| x * x).sum::<f64>().sqrt();
    (0..3).map(|i| (a[i] - b[i]).powi(2)).sum::<f64>().sqrt() / n
}

#[test]
fn banded_converges_to_piecewise_linear() {
    let scene = shell(24);
    let mut st = DopplerSettings::default_for(&scene, 12, 12);
    let pwl = render_doppler(&scene, &st, &|| {}).unwrap();
    let mut errs = Vec::new();
    for n in [40, 400, 4000] {
        st.integrator = SpectralIntegrator::Banded {
            bands: n,
            shift: BandShift::EnergyConserving,
        };
        let b = render_doppler(&scene, &st, &|| {}).unwrap();
        let e: f64 = (0..pwl.xyz.len())
            .filter(|&i| pwl.xyz[i][1] > 1e-3 * 1.0)
            .map(|i| rel_err(b.xyz[i], pwl.xyz[i]))
            .fold(0.0, f64::max);
        errs.push(e);
    }
    assert!(errs[2] < errs[0] && errs[2] < 0.01, "{errs:?}");
}

#[test]
fn absorption_never_brightens_and_render_is_thread_independent() {
    let mut scene = shell(16);
    let st = DopplerSettings::default_for(&scene, 8, 8);
    let clear = render_doppler(&scene, &st, &|| {}).unwrap();
    scene.factors.absorption = 50.0;
    let absorbed = render_doppler(&scene, &st, &|| {}).unwrap();
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap()
        .install(|| render_doppler(&scene, &st, &|| {}).unwrap());
    assert_eq!(one.xyz, absorbed.xyz);
    let mut darker = 0;
    for (a, c) in absorbed.xyz.iter().zip(&clear.xyz) {
        assert!(a[1] <= c[1] * (1.0 + 1e-9));
        darker += usize::from(a[1] < 0.99 * c[1]);
    }
    assert!(darker > 0);
    assert!(absorbed.pieces.max > 0);
}

/// The preview fallback on the image path with absorption: a tiny piece budget still gives
/// a finite image no brighter than the unattenuated one, and the rays that needed it are
/// counted.
#[test]
fn tiny_piece_budget_falls_back_and_stays_bounded() {
    // He I adds lines: more separate line groups than the budget, so merges cannot reach it
    // (the fallback's tolerance must stop growing instead of overflowing).
    let v = synth::galaxy(16, 5).unwrap();
    let mut scene = DopplerScene::from_volume(&v, &["bb", "H", "C", "He"]).unwrap();
    scene.factors.velocity = 30.0;
    let mut st = DopplerSettings::default_for(&scene, 8, 8);
    st.piece_budget = 8;
    let clear = render_doppler(&scene, &st, &|| {}).unwrap();
    scene.factors.absorption = 5.0;
    let img = render_doppler(&scene, &st, &|| {}).unwrap();
    assert!(img.pieces.fallback_rays > 0, "{:?}", img.pieces);
    // The kept-spectrum path too: more separate lines than the budget, still a spectrum.
    let spec = pixel_spectrum(&scene, &st, 4, 4).unwrap();
    assert!(spec.max_value().is_finite());
    let mut darker = 0;
    for (a, c) in img.xyz.iter().zip(&clear.xyz) {
        for ch in 0..3 {
            assert!(a[ch].is_finite() && a[ch] >= 0.0 && a[ch] <= c[ch] * (1.0 + 1e-9));
        }
        darker += usize::from(a[1] < 0.99 * c[1]);
    }
    assert!(darker > 0);
}

/// A constant medium along the z axis: density 1, one line at 500 nm emitting `e` and
/// absorbing `k` (optical depth per unit length over the line's 1 nm box), no velocity.
fn slab(e: f64, k: f64) -> DopplerScene {
    let geom = Geometry::unit([2, 2, 16]);
    let mut s = DopplerScene::new(geom).unwrap();
    let one = Grid::from_fn(geom, |_, _, _| 1.0f32).unwrap();
    s.add_species(Species {
        name: "slab".into(),
        density: (AnyGrid::F32(one)).into(),
        emission_lines: vec![EmissionLine::new(500.0, e).unwrap()],
        absorption_lines: vec![EmissionLine::new(500.0, k).unwrap()],
    })
    .unwrap();
    s.factors.absorption = 1.0;
    s
}

#[test]
fn constant_medium_follows_beer_lambert_on_both_paths() {
    // Emission e and absorption k per unit length over a 1 nm box (line areas e and k).
    let (e, k) = (2.0, 0.2);
    let scene = slab(e, k);
    let mut st = DopplerSettings::default_for(&scene, 2, 2);
    st.merge_tolerance = 1e-5;
    st.max_depth_step = 0.01;
    let len = 15.0f64;
    let dt = 0.5f64;
    // Analytic Beer-Lambert: I = (e / k) (1 - exp(-k L)) over the box.
    let exact = e / k * (1.0 - (-k * len).exp());
    // The half-depth convention over segments of length dt: the discrete sum
    // e dt (1 - exp(-k L)) / (2 sinh(k dt / 2)), within (k dt)^2 / 24 of the exact value.
    let discrete = e * dt * (1.0 - (-k * len).exp()) / (2.0 * (0.5 * k * dt).sinh());
    assert!(((discrete - exact) / exact).abs() <= (k * dt).powi(2) / 24.0);
    let ray = Ray::new(Vec3::new(0.5, 0.5, -1.0), Vec3::Z).unwrap();
    // Back to front (the kept spectrum): the box value.
    let (_, spec) = ray_spectrum(&scene, &st, &ray).unwrap();
    for l in [499.6, 500.0, 500.4] {
        let got = spec.eval(l);
        assert!(
            (got - discrete).abs() <= 1e-4 * discrete,
            "{l}: {got} vs {discrete}"
        );
    }
    // Front to back (image path): the XYZ of that box, within the stated 2 tol bound.
    let img = render_doppler(&scene, &st, &|| {}).unwrap();
    let cmf = blueshift_spectrum::Cmf::cie1931_2deg();
    let want = cmf
        .trapezoid_xyz(499.5, 500.5, discrete, discrete)
        .to_array();
    for px in &img.xyz {
        for c in 0..3 {
            assert!(
                (px[c] - want[c]).abs() <= 2.0 * st.merge_tolerance * want[c] + 1e-12,
                "{px:?} vs {want:?}"
            );
        }
    }
    // Banded (energy-conserving, bands 0.1 nm wide): the same convention per sample, within
    // the trapezoid rule's error along the ray.
    st.integrator = SpectralIntegrator::Banded {
        bands: 4000,
        shift: BandShift::EnergyConserving,
    };
    let (bx, _) = ray_spectrum(&scene, &st, &ray).unwrap();
    let bx = bx.to_array();
    assert!(
        (bx[1] - want[1]).abs() <= 0.01 * want[1],
        "{bx:?} vs {want:?}"
    );
}

#[test]
fn front_to_back_xyz_equals_the_kept_spectrum_xyz() {
    check_paths_agree(&Broadening::default());
}

/// Thermal and Gaussian profiles reach both paths (emission and absorption lines alike): the
/// image path still equals the kept spectrum's XYZ, and differs from the box-profile image.
#[test]
fn broadened_lines_reach_the_front_to_back_path() {
    let b = Broadening {
        thermal: true,
        sigma_m_per_s: 3e5,
        ..Broadening::default()
    };
    let broad = check_paths_agree(&b);
    let boxed = check_paths_agree(&Broadening::default());
    let diff = broad
        .iter()
        .zip(&boxed)
        .map(|(a, b)| (a[1] - b[1]).abs())
        .fold(0.0, f64::max);
    let peak = boxed.iter().map(|x| x[1]).fold(0.0, f64::max);
    assert!(
        diff > 1e-3 * peak,
        "broadening changed nothing: {diff} vs peak {peak}"
    );
}

/// The galaxy (24^3) with black body, H I and C I, velocity x30 and absorption x5, and the
/// same without absorption.
fn absorbing_galaxy() -> (DopplerScene, DopplerScene) {
    let v = synth::galaxy(24, 3).unwrap();
    let mut scene = DopplerScene::from_volume(&v, &["bb", "H", "C"]).unwrap();
    scene.factors.velocity = 30.0;
    scene.factors.absorption = 5.0;
    scene.factors.blackbody = 0.1;
    let mut clear = scene.clone();
    clear.factors.absorption = 0.0;
    (scene, clear)
}

/// The merge tolerance is an error budget for the whole ray: with loose tolerances (merges,
/// left-out absorption and line light all in play) every pixel's XYZ stays within `tol` x the
/// unattenuated emission of the exact (`tol = 0`) image, per channel; and the budget is used.
#[test]
fn loose_tolerances_stay_within_their_error_budget() {
    let (scene, clear) = absorbing_galaxy();
    let mut st = DopplerSettings::default_for(&scene, 10, 10);
    st.merge_tolerance = 0.0;
    st.piece_budget = 1 << 20;
    let exact = render_doppler(&scene, &st, &|| {}).unwrap();
    let emitted = render_doppler(&clear, &st, &|| {}).unwrap();
    for tol in [1e-2, 5e-2, 0.2] {
        st.merge_tolerance = tol;
        let img = render_doppler(&scene, &st, &|| {}).unwrap();
        let mut worst = 0.0f64;
        for ((a, b), e) in img.xyz.iter().zip(&exact.xyz).zip(&emitted.xyz) {
            for c in 0..3 {
                let err = (a[c] - b[c]).abs();
                assert!(
                    err <= tol * e[c] * (1.0 + 1e-9) + 1e-300,
                    "tol {tol} channel {c}: {a:?} vs exact {b:?} (emitted {e:?})"
                );
                if e[c] > 0.0 {
                    worst = worst.max(err / (tol * e[c]));
                }
            }
        }
        // Not vacuous: the loose settings do change the image, by a visible part of the budget.
        assert!(worst > 1e-3, "tol {tol}: worst error {worst} of the budget");
    }
}

fn check_paths_agree(broadening: &Broadening) -> Vec<[f64; 3]> {
    let (scene, clear) = absorbing_galaxy();
    let tol = 1e-4;
    let mut st = DopplerSettings::default_for(&scene, 10, 10);
    st.merge_tolerance = tol;
    st.broadening = broadening.clone();
    let img = render_doppler(&scene, &st, &|| {}).unwrap();
    // The kept spectrum, back to front, converged: merges within 1e-6 of the maximum in
    // total, attenuation chords within dtau^2 / 8 = 1.25e-7 per sub-piece.
    let mut fine = st.clone();
    fine.merge_tolerance = 1e-6;
    fine.max_depth_step = 1e-3;
    fine.piece_budget = 1 << 20;
    let cmf = blueshift_spectrum::Cmf::cie1931_2deg();
    let peak = img.xyz.iter().map(|x| x[1]).fold(0.0, f64::max);
    let (mut checked, mut absorbed) = (0, 0);
    for y in [2u32, 5, 7] {
        for x in [2u32, 4, 5, 8] {
            let f2b = img.xyz[(y * 10 + x) as usize];
            if f2b[1] < 1e-3 * peak {
                continue;
            }
            let b2f = cmf
                .xyz_of(&pixel_spectrum(&scene, &fine, x, y).unwrap())
                .to_array();
            let emitted = cmf
                .xyz_of(&pixel_spectrum(&clear, &fine, x, y).unwrap())
                .to_array();
            // The front-to-back bound: 2 tol x the unattenuated emission, per channel (plus
            // 1e-5 of it for the converged reference's own error).
            for c in 0..3 {
                assert!(
                    (f2b[c] - b2f[c]).abs() <= (2.0 * tol + 1e-5) * emitted[c],
                    "pixel {x},{y} channel {c}: {f2b:?} vs {b2f:?} (emitted {emitted:?})"
                );
            }
            checked += 1;
            absorbed += usize::from(emitted[1] > 1.01 * b2f[1]);
        }
    }
    assert!(checked >= 4 && absorbed >= 2, "{checked} {absorbed}");
    img.xyz
}

#[test]
fn optically_thick_medium_stays_finite_and_dark() {
    // Optical depth 100 per segment, 3000 along the ray: exp(+tau) would overflow.
    let scene = slab(2.0, 200.0);
    let st = DopplerSettings::default_for(&scene, 2, 2);
    let img = render_doppler(&scene, &st, &|| {}).unwrap();
    let cmf = blueshift_spectrum::Cmf::cie1931_2deg();
    // Only the nearest half segment shines: e dt exp(-k dt / 2) ~ 2e-22 of the box.
    let clear = cmf
        .trapezoid_xyz(499.5, 500.5, 2.0 * 15.0, 2.0 * 15.0)
        .to_array();
    for px in &img.xyz {
        for c in 0..3 {
            assert!(
                px[c].is_finite() && px[c] >= 0.0 && px[c] <= 1e-12 * clear[c],
                "{px:?}"
            );
        }
    }
    // Moving gas with depths in the thousands, rising and falling across the lines.
    let v = synth::galaxy(16, 5).unwrap();
    let mut g = DopplerScene::from_volume(&v, &["bb", "H", "C"]).unwrap();
    g.factors.velocity = 30.0;
    let st = DopplerSettings::default_for(&g, 8, 8);
    let clear = render_doppler(&g, &st, &|| {}).unwrap();
    g.factors.absorption = 1e5;
    let thick = render_doppler(&g, &st, &|| {}).unwrap();
    let mut darker = 0;
    for (a, c) in thick.xyz.iter().zip(&clear.xyz) {
        for k in 0..3 {
            assert!(
                a[k].is_finite() && a[k] >= 0.0 && a[k] <= c[k] * (1.0 + 1e-9),
                "{a:?}"
            );
        }
        darker += usize::from(a[1] < 0.9 * c[1]);
    }
    assert!(darker > 0);
}

/// Broadening is a piecewise-linear feature: the banded integrators refuse it instead of
/// silently rendering box profiles.
#[test]
fn banded_refuses_broadening() {
    let scene = ramp_scene(656.3);
    let mut st = DopplerSettings::default_for(&scene, 2, 2);
    st.broadening = Broadening {
        sigma_m_per_s: 1e4,
        ..Broadening::default()
    };
    st.integrator = "banded:400".parse().unwrap();
    let e = render_doppler(&scene, &st, &|| {}).unwrap_err().to_string();
    assert!(e.contains("piecewise-linear integrator only"), "{e}");
    st.integrator = SpectralIntegrator::PiecewiseLinear;
    assert!(render_doppler(&scene, &st, &|| {}).is_ok());
}

/// The integrators' per-interval line XYZ equals the spectrum crate's prefix-sum form
/// (`Cmf::trapezoid_xyz`, an independent implementation) for narrow and wide lines, inside,
/// across and outside the CMF table's range.
#[test]
fn line_xyz_equals_the_prefix_sum_form() {
    let scene = slab(1.0, 1.0);
    let st = DopplerSettings::default_for(&scene, 2, 2);
    let t = super::pwl::PwlTables::new(&st);
    let cmf = blueshift_spectrum::Cmf::cie1931_2deg();
    let mut state = 12345u64;
    let mut next = || {
        state = state
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    let mut cases = vec![
        (499.5, 500.5, 1.0, 1.0),
        (500.0, 501.0, 2.0, 0.5),
        (355.0, 362.3, 1.0, 3.0),
        (828.2, 840.0, 1.0, 1.0),
        (300.0, 350.0, 1.0, 1.0),
        (400.0, 460.0, 0.0, 5.0),
    ];
    for _ in 0..500 {
        let lo = 350.0 + 500.0 * next();
        let w = 1e-3 + 12.0 * next() * next();
        cases.push((lo, lo + w, 10.0 * next(), 10.0 * next()));
    }
    for (lo, hi, h0, h1) in cases {
        let a = t.line_xyz((lo, hi, h0, h1));
        let b = cmf.trapezoid_xyz(lo, hi, h0, h1).to_array();
        // The prefix-sum form differences moments accumulated from 360 nm (~1e5 at the red
        // end), so it carries ~1e-10 absolute error per unit height and nm; the per-interval
        // form has no such cancellation.
        let tol = 1e-9 * h0.max(h1) * (hi - lo).max(1.0);
        for c in 0..3 {
            assert!(
                (a[c] - b[c]).abs() <= tol + 1e-12 * b[c].abs(),
                "({lo}, {hi}, {h0}, {h1}) channel {c}: {} vs {}",
                a[c],
                b[c]
            );
        }
    }
}

/// Continuity in the velocity: a tiny velocity factor changes the image by about the
/// largest |v_r| / c it implies, not by a jump (the shift is exactly 1 without velocity).
#[test]
fn a_tiny_velocity_changes_the_image_continuously() {
    let v = synth::galaxy(16, 5).unwrap();
    let mut scene = DopplerScene::from_volume(&v, &["bb", "H", "C"]).unwrap();
    let st = DopplerSettings::default_for(&scene, 12, 12);
    scene.factors.velocity = 0.0;
    let still = render_doppler(&scene, &st, &|| {}).unwrap();
    scene.factors.velocity = 1e-3;
    let slow = render_doppler(&scene, &st, &|| {}).unwrap();
    let peak = still.xyz.iter().map(|x| x[1]).fold(0.0, f64::max);
    let mut worst = 0.0f64;
    for (a, b) in slow.xyz.iter().zip(&still.xyz) {
        for c in 0..3 {
            worst = worst.max((a[c] - b[c]).abs() / peak);
        }
    }
    assert!(
        worst < 1e-5,
        "velocity x1e-3 moved the image by {worst:e} of its peak"
    );
}

/// A ray whose black-body rows would not fit the kept-rows cap (100,000 grid points x 30
/// segments) evaluates them again in the march: the same image as a grid below the cap, to
/// the black-body sampling's convergence.
#[test]
fn very_fine_black_body_grids_give_the_same_absorbed_image() {
    let mut scene = slab(2.0, 0.4);
    let geom = scene.geometry;
    let one = || AnyGrid::F32(Grid::from_fn(geom, |_, _, _| 1.0f32).unwrap());
    let t = AnyGrid::F32(Grid::from_fn(geom, |_, _, z| 3000.0 + 100.0 * z as f32).unwrap());
    scene.set_blackbody(one(), t).unwrap();
    scene.factors.blackbody = 1e-6;
    let ray = Ray::new(Vec3::new(0.5, 0.5, -1.0), Vec3::Z).unwrap();
    let mut st = DopplerSettings::default_for(&scene, 2, 2);
    st.merge_tolerance = 0.0;
    let xyz = |k: usize, st: &mut DopplerSettings| {
        st.blackbody_samples = k;
        let ctx = super::render::Context::new(&scene, st).unwrap();
        super::render::integrate(&ctx, &ray, super::render::Want::Xyz)
            .unwrap()
            .xyz
            .to_array()
    };
    let kept = xyz(60_000, &mut st);
    let again = xyz(100_000, &mut st);
    for c in 0..3 {
        assert!(
            (kept[c] - again[c]).abs() <= 1e-8 * kept[c],
            "channel {c}: {kept:?} vs {again:?}"
        );
    }
}

#[test]
fn incline_tilts_the_line_of_sight_about_x_and_refuses_bad_angles() {
    let v = synth::galaxy(8, 1).unwrap();
    let scene = DopplerScene::from_volume(&v, &["H"]).unwrap();
    let mut st = DopplerSettings::default_for(&scene, 4, 4);
    // The observer starts at +z (yt's default view) and tilts towards +y; x stays right.
    for (deg, want) in [
        (0.0f32, -Vec3::Z),
        (90.0, -Vec3::Y),
        (-90.0, Vec3::Y),
        (60.0, -Vec3::new(0.0, 0.75f32.sqrt(), 0.5)),
    ] {
        st.incline(&scene, deg).unwrap();
        let dir = (st.camera.target - st.camera.eye).normalize();
        assert!((dir - want).length() < 1e-5, "{deg}: {dir} vs {want}");
        assert!(
            st.camera.basis().1.abs_diff_eq(Vec3::X, 1e-5),
            "{deg}: x not right"
        );
        // The up vector is perpendicular to the line of sight.
        assert!(st.camera.up.dot(dir).abs() < 1e-5);
    }
    for bad in [90.5f32, -100.0, f32::NAN, f32::INFINITY] {
        let e = st.incline(&scene, bad).unwrap_err();
        assert!(e.to_string().contains("[-90, 90]"), "{e}");
    }
}
