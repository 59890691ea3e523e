//! The GPU Doppler integrators (piecewise linear; banded, nearest and energy-conserving
//! shift, with and without absorption) against `blueshift_tracking::doppler::render_doppler` on the same
//! scenes (16^3 synthetic galaxy and rotating hydrogen shell, 16x16 images), and the settings
//! it refuses.
//!
//! Tolerance: the device computes in f32 what the CPU computes in f64 (positions along the
//! ray, trilinear weights, the shift `s = 1 + v_r / c`, Planck's law, the CMF integrals), so
//! per pixel and channel `|gpu - cpu| <= 2e-3 |cpu| + 1e-5 max(cpu image)`; the image sums
//! agree within 1e-4 (f32 has 24 bits: 6e-8 per operation, a few hundred operations per
//! segment on rays of about 30 segments).
//!
//! Every test prints `SKIP: no wgpu adapter: ...` and returns when there is no adapter,
//! unless `BLUESHIFT_REQUIRE_GPU_TESTS=1`.

use blueshift_gpu::doppler::{check_supported, render_doppler_gpu};
use blueshift_gpu::{Error, test_context};
use blueshift_spectrum::DopplerModel;
use blueshift_tracking::doppler::{
    BandShift, DopplerImage, DopplerScene, DopplerSettings, SpectralIntegrator, render_doppler,
};
use blueshift_volume::synth;

const REL: f64 = 2e-3;
const ABS_OF_MAX: f64 = 1e-5;

fn compare(what: &str, cpu: &DopplerImage, gpu: &DopplerImage) {
    assert_eq!((cpu.width, cpu.height), (gpu.width, gpu.height));
    let max = cpu
        .xyz
        .iter()
        .flat_map(|p| p.iter().copied())
        .fold(0.0f64, f64::max);
    assert!(max > 0.0, "{what}: the CPU image is black");
    let mut worst = 0.0f64;
    let (mut sc, mut sg) = ([0.0f64; 3], [0.0f64; 3]);
    for (i, (c, g)) in cpu.xyz.iter().zip(&gpu.xyz).enumerate() {
        for k in 0..3 {
            let d = (c[k] - g[k]).abs();
            let tol = REL * c[k].abs() + ABS_OF_MAX * max;
            assert!(
                d <= tol,
                "{what}: pixel {i} channel {k}: gpu {} cpu {} (diff {d}, tol {tol})",
                g[k],
                c[k]
            );
            worst = worst.max(d / (c[k].abs() + ABS_OF_MAX * max / REL));
            sc[k] += c[k];
            sg[k] += g[k];
        }
    }
    for k in 0..3 {
        assert!(
            (sc[k] - sg[k]).abs() <= 1e-4 * sc[k].abs(),
            "{what}: image sum channel {k}: gpu {} cpu {}",
            sg[k],
            sc[k]
        );
    }
    eprintln!("{what}: worst relative difference {worst:.3e}");
}

fn galaxy() -> DopplerScene {
    let v = synth::galaxy(16, 5).unwrap();
    let mut g = DopplerScene::from_volume(&v, &["bb", "H", "C"]).unwrap();
    g.factors.velocity = 30.0;
    g.factors.blackbody = 0.1;
    g
}

fn shell() -> DopplerScene {
    let v = synth::hydrogen_shell(16, 7).unwrap();
    DopplerScene::from_volume(&v, &["H"]).unwrap()
}

#[test]
fn galaxy_lines_and_black_body_match_the_cpu() {
    let Some(ctx) = test_context() else { return };
    let scene = galaxy();
    let st = DopplerSettings::default_for(&scene, 16, 16);
    let cpu = render_doppler(&scene, &st, &|| {}).unwrap();
    let gpu = render_doppler_gpu(ctx, &scene, &st).unwrap();
    compare("galaxy", &cpu, &gpu);
    assert_eq!(gpu.pieces.max, 0);
}

#[test]
fn shell_matches_the_cpu_with_both_doppler_models_and_radiance_rules() {
    let Some(ctx) = test_context() else { return };
    let mut scene = shell();
    // Strong rotation (3000 km/s at the equator): lines move by several nm, so the shifted
    // trapezoids span several CMF intervals and the two sides differ in colour.
    scene.factors.velocity = 10.0;
    for (model, invariant) in [
        (DopplerModel::Classical, false),
        (DopplerModel::Relativistic, true),
    ] {
        let mut st = DopplerSettings::default_for(&scene, 16, 16);
        st.model = model;
        st.invariant = invariant;
        let cpu = render_doppler(&scene, &st, &|| {}).unwrap();
        let gpu = render_doppler_gpu(ctx, &scene, &st).unwrap();
        compare(
            &format!("shell {model:?} invariant={invariant}"),
            &cpu,
            &gpu,
        );
    }
}

#[test]
fn banded_integrators_match_the_cpu() {
    let Some(ctx) = test_context() else { return };
    let scene = galaxy();
    let mut shell = shell();
    shell.factors.velocity = 10.0;
    for (name, sc) in [("galaxy", &scene), ("shell", &shell)] {
        for (bands, shift) in [
            (40, BandShift::Nearest),
            (400, BandShift::Nearest),
            (40, BandShift::EnergyConserving),
            (400, BandShift::EnergyConserving),
        ] {
            let mut st = DopplerSettings::default_for(sc, 16, 16);
            st.integrator = SpectralIntegrator::Banded { bands, shift };
            let cpu = render_doppler(sc, &st, &|| {}).unwrap();
            let gpu = render_doppler_gpu(ctx, sc, &st).unwrap();
            compare(&format!("{name} banded {bands} {shift:?}"), &cpu, &gpu);
        }
    }
}

#[test]
fn banded_integrators_with_absorption_match_the_cpu() {
    let Some(ctx) = test_context() else { return };
    let clear = galaxy();
    for absorption in [5.0, 1e3] {
        let mut scene = clear.clone();
        scene.factors.absorption = absorption;
        for (bands, shift) in [(60, BandShift::Nearest), (300, BandShift::EnergyConserving)] {
            let mut st = DopplerSettings::default_for(&scene, 16, 16);
            st.integrator = SpectralIntegrator::Banded { bands, shift };
            let cpu = render_doppler(&scene, &st, &|| {}).unwrap();
            let gpu = render_doppler_gpu(ctx, &scene, &st).unwrap();
            compare(
                &format!("galaxy absorption {absorption} banded {bands} {shift:?}"),
                &cpu,
                &gpu,
            );
            // Absorption really acts: the image loses light, and at the strong setting some
            // pixels lose more than 5 % of their Y.
            let free = render_doppler_gpu(ctx, &clear, &st).unwrap();
            let y = |im: &DopplerImage| im.xyz.iter().map(|p| p[1]).sum::<f64>();
            assert!(
                y(&gpu) < y(&free),
                "absorption {absorption} darkens nothing"
            );
            let darker = gpu
                .xyz
                .iter()
                .zip(&free.xyz)
                .filter(|(a, c)| a[1] < 0.95 * c[1])
                .count();
            eprintln!("absorption {absorption}: {darker} pixels lose > 5 % of Y");
            assert!(absorption < 1e3 || darker > 0, "absorption {absorption}");
        }
    }
}

#[test]
fn a_tilted_perspective_view_and_cell_domain_match_the_cpu() {
    let Some(ctx) = test_context() else { return };
    let scene = galaxy();
    let mut st = DopplerSettings::default_for(&scene, 16, 12);
    let (lo, hi) = scene.geometry().world_bounds();
    let c = 0.5 * (lo + hi);
    st.camera = blueshift_tracking::Camera {
        eye: c + glam::Vec3::new(1.5, 1.0, 2.5) * (hi - lo).length(),
        target: c,
        up: glam::Vec3::Y,
        projection: blueshift_tracking::Projection::Perspective { fov_y_deg: 30.0 },
    };
    st.cell_domain = true;
    st.blackbody_samples = 7;
    st.line_width_nm = 2.5;
    let cpu = render_doppler(&scene, &st, &|| {}).unwrap();
    let gpu = render_doppler_gpu(ctx, &scene, &st).unwrap();
    compare("galaxy perspective", &cpu, &gpu);
}

#[test]
fn the_comparison_sees_the_doppler_shift_and_bad_velocities_are_errors() {
    let Some(ctx) = test_context() else { return };
    // The tolerance is tight enough to tell the rotating shell from the still one.
    let mut moving = shell();
    moving.factors.velocity = 10.0;
    let mut still = moving.clone();
    still.factors.velocity = 0.0;
    let st = DopplerSettings::default_for(&moving, 16, 16);
    let gpu = render_doppler_gpu(ctx, &moving, &st).unwrap();
    let cpu_still = render_doppler(&still, &st, &|| {}).unwrap();
    let result = std::panic::catch_unwind(|| compare("moving vs still", &cpu_still, &gpu));
    assert!(
        result.is_err(),
        "the comparison cannot see a 3000 km/s rotation"
    );
    // Faster than light (300 km/s x 2000): the CPU refuses the shift, so does the GPU.
    let mut fast = shell();
    fast.factors.velocity = 2000.0;
    for model in [DopplerModel::Classical, DopplerModel::Relativistic] {
        let mut st = DopplerSettings::default_for(&fast, 16, 16);
        st.model = model;
        assert!(render_doppler(&fast, &st, &|| {}).is_err());
        let e = render_doppler_gpu(ctx, &fast, &st).unwrap_err();
        assert!(
            matches!(&e, Error::InvalidInput(m) if m.contains("Doppler shift")),
            "{e}"
        );
    }
}

#[test]
fn unsupported_settings_are_refused_by_name() {
    let scene = galaxy();
    let st = DopplerSettings::default_for(&scene, 8, 8);
    assert!(check_supported(&scene, &st).is_ok());
    let mut a = scene.clone();
    a.factors.absorption = 1.0;
    let e = check_supported(&a, &st).unwrap_err();
    assert!(
        matches!(&e, Error::Unsupported(m) if m.contains("absorption")),
        "{e}"
    );
    let mut b = st.clone();
    b.broadening.thermal = true;
    let e = check_supported(&scene, &b).unwrap_err();
    assert!(
        matches!(&e, Error::Unsupported(m) if m.contains("broadening")),
        "{e}"
    );
    let mut c = st.clone();
    c.integrator = SpectralIntegrator::Banded {
        bands: 16,
        shift: BandShift::Nearest,
    };
    assert!(check_supported(&scene, &c).is_ok());
    assert!(
        check_supported(&a, &c).is_ok(),
        "banded with absorption runs on the GPU"
    );
    // Invalid settings are the CPU's errors, before anything reaches a device.
    let mut d = st.clone();
    d.line_width_nm = f64::NAN;
    let e = check_supported(&scene, &d).unwrap_err();
    assert!(matches!(e, Error::InvalidInput(_)), "{e}");
    // And the renderer itself refuses them too.
    if let Some(ctx) = test_context() {
        assert!(matches!(
            render_doppler_gpu(ctx, &a, &st),
            Err(Error::Unsupported(_))
        ));
    }
}
