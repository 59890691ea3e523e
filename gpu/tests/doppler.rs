//! The GPU Doppler integrators (piecewise linear and banded, nearest and energy-conserving
//! shift, with and without absorption, with and without line broadening) against
//! `blueshift_doppler::render_doppler` on the same scenes (16^3 and 32^3 synthetic
//! galaxy, rotating hydrogen shell, small images), the piece budget's fallback, the storage
//! and loop limits, and the settings it refuses.
//!
//! Each comparison runs in both working precisions the adapter has (`each_precision`): f32,
//! and f64 where the adapter has `SHADER_F64` (lavapipe has it).
//!
//! Tolerance, f32: the device computes in f32 what the CPU computes in f64 (the shift
//! `s = 1 + v_r / c`, Planck's law, the CMF integrals, the pieces), so per pixel and channel
//! `|gpu - cpu| <= 2e-3 |cpu| + 1e-5 max(cpu image)`; the image sums agree within 1e-4 (f32
//! has 24 bits: 6e-8 per operation, a few hundred operations per segment on rays of about 30
//! segments). f64: `1e-5 |cpu| + 1e-8 max`, the algorithms' own tolerance with absorption;
//! where both run the same sums, rounding (`f64_kernels_agree_with_the_cpu_to_rounding`).
//!
//! Every test prints `SKIP: no wgpu adapter: ...` and returns when there is no adapter,
//! unless `BLUESHIFT_REQUIRE_GPU_TESTS=1`.

use blueshift_doppler::{
    BandShift, DopplerImage, DopplerScene, DopplerSettings, SpectralIntegrator, render_doppler,
};
use blueshift_gpu::Error;
use blueshift_gpu::context::test_context;
use blueshift_gpu::doppler::{
    DEVICE_PIECE_CAP, DopplerPrecision, absorption_layout, absorption_layout_fw, check_supported,
    render_doppler_gpu, render_doppler_gpu_with,
};
use blueshift_spectrum::DopplerModel;
use blueshift_volume::synth;
use std::cell::Cell;

thread_local! {
    /// The working precision of the GPU renders of the running test (`each_precision`).
    static PRECISION: Cell<DopplerPrecision> = const { Cell::new(DopplerPrecision::F32) };
}

/// Runs `f` once per working precision the adapter has: f32, and f64 with `SHADER_F64`.
fn each_precision(ctx: &blueshift_gpu::GpuContext, f: impl Fn()) {
    let mut list = vec![DopplerPrecision::F32];
    if ctx.has_f64() {
        list.push(DopplerPrecision::F64);
    } else {
        eprintln!("NOTE: the adapter has no SHADER_F64: the f64 kernels are not run");
    }
    for p in list {
        PRECISION.set(p);
        eprintln!("-- precision {p:?}");
        f();
    }
}

fn is_f64() -> bool {
    PRECISION.get() == DopplerPrecision::F64
}

/// The GPU render in the running test's precision.
fn gpu_render(
    ctx: &blueshift_gpu::GpuContext,
    scene: &DopplerScene,
    st: &DopplerSettings,
) -> Result<DopplerImage, Error> {
    render_doppler_gpu_with(ctx, scene, st, PRECISION.get())
}

/// `(relative, of the image maximum)` per-pixel tolerance of the running precision.
fn tolerance() -> (f64, f64) {
    if is_f64() {
        (REL_F64, ABS_OF_MAX_F64)
    } else {
        (REL, ABS_OF_MAX)
    }
}

const REL: f64 = 2e-3;
const ABS_OF_MAX: f64 = 1e-5;
// f64 kernels: what is left is the algorithms' own tolerance (with absorption the device
// merges where the CPU also leaves out the weakest lines; measured worst 2.1e-6); without it
// they agree to rounding (`f64_kernels_agree_with_the_cpu_to_rounding`).
const REL_F64: f64 = 1e-5;
const ABS_OF_MAX_F64: f64 = 1e-8;

fn compare(what: &str, cpu: &DopplerImage, gpu: &DopplerImage) {
    let (rel, abs_of_max) = tolerance();
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
            let tol = rel * c[k].abs() + abs_of_max * max;
            assert!(
                d <= tol,
                "{what}: pixel {i} channel {k}: gpu {} cpu {} (diff {d}, tol {tol})",
                g[k],
                c[k]
            );
            worst = worst.max(d / (c[k].abs() + abs_of_max * max / rel));
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
    each_precision(ctx, || {
        let scene = galaxy();
        let st = DopplerSettings::default_for(&scene, 16, 16);
        let cpu = render_doppler(&scene, &st, &|| {}).unwrap();
        let gpu = gpu_render(ctx, &scene, &st).unwrap();
        compare("galaxy", &cpu, &gpu);
        assert_eq!(gpu.pieces.max, 0);
    });
}

#[test]
fn shell_matches_the_cpu_with_both_doppler_models_and_radiance_rules() {
    let Some(ctx) = test_context() else { return };
    each_precision(ctx, || {
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
            let gpu = gpu_render(ctx, &scene, &st).unwrap();
            compare(
                &format!("shell {model:?} invariant={invariant}"),
                &cpu,
                &gpu,
            );
        }
    });
}

#[test]
fn banded_integrators_match_the_cpu() {
    let Some(ctx) = test_context() else { return };
    each_precision(ctx, || {
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
                let gpu = gpu_render(ctx, sc, &st).unwrap();
                compare(&format!("{name} banded {bands} {shift:?}"), &cpu, &gpu);
            }
        }
    });
}

#[test]
fn banded_integrators_with_absorption_match_the_cpu() {
    let Some(ctx) = test_context() else { return };
    each_precision(ctx, || {
        let clear = galaxy();
        for absorption in [5.0, 1e3] {
            let mut scene = clear.clone();
            scene.factors.absorption = absorption;
            for (bands, shift) in [(60, BandShift::Nearest), (300, BandShift::EnergyConserving)] {
                let mut st = DopplerSettings::default_for(&scene, 16, 16);
                st.integrator = SpectralIntegrator::Banded { bands, shift };
                let cpu = render_doppler(&scene, &st, &|| {}).unwrap();
                let gpu = gpu_render(ctx, &scene, &st).unwrap();
                compare(
                    &format!("galaxy absorption {absorption} banded {bands} {shift:?}"),
                    &cpu,
                    &gpu,
                );
                // Absorption really acts: the image loses light, and at the strong setting some
                // pixels lose more than 5 % of their Y.
                let free = gpu_render(ctx, &clear, &st).unwrap();
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
    });
}

#[test]
fn a_tilted_perspective_view_and_cell_domain_match_the_cpu() {
    let Some(ctx) = test_context() else { return };
    each_precision(ctx, || {
        let scene = galaxy();
        let mut st = DopplerSettings::default_for(&scene, 16, 12);
        let (lo, hi) = scene.geometry().world_bounds();
        let c = 0.5 * (lo + hi);
        st.camera = blueshift_doppler::Camera {
            eye: c + glam::Vec3::new(1.5, 1.0, 2.5) * (hi - lo).length(),
            target: c,
            up: glam::Vec3::Y,
            projection: blueshift_doppler::Projection::Perspective { fov_y_deg: 30.0 },
        };
        st.cell_domain = true;
        st.blackbody_samples = 7;
        st.line_width_nm = 2.5;
        let cpu = render_doppler(&scene, &st, &|| {}).unwrap();
        let gpu = gpu_render(ctx, &scene, &st).unwrap();
        compare("galaxy perspective", &cpu, &gpu);
    });
}

#[test]
fn the_comparison_sees_the_doppler_shift_and_bad_velocities_are_errors() {
    let Some(ctx) = test_context() else { return };
    each_precision(ctx, || {
        // The tolerance is tight enough to tell the rotating shell from the still one.
        let mut moving = shell();
        moving.factors.velocity = 10.0;
        let mut still = moving.clone();
        still.factors.velocity = 0.0;
        let st = DopplerSettings::default_for(&moving, 16, 16);
        let gpu = gpu_render(ctx, &moving, &st).unwrap();
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
            let e = gpu_render(ctx, &fast, &st).unwrap_err();
            assert!(
                matches!(&e, Error::InvalidInput(m) if m.contains("Doppler shift")),
                "{e}"
            );
        }
    });
}

#[test]
fn unsupported_settings_are_refused_by_name() {
    let scene = galaxy();
    let st = DopplerSettings::default_for(&scene, 8, 8);
    assert!(check_supported(&scene, &st).is_ok());
    let mut a = scene.clone();
    a.factors.absorption = 1.0;
    assert!(
        check_supported(&a, &st).is_ok(),
        "piecewise linear with absorption runs on the GPU"
    );
    let mut b = st.clone();
    b.broadening.thermal = true;
    assert!(
        check_supported(&scene, &b).is_ok() && check_supported(&a, &b).is_ok(),
        "broadened lines run on the GPU, with and without absorption"
    );
    // More species than the kernel holds.
    let v = synth::galaxy(8, 5).unwrap();
    let many = DopplerScene::from_volume(&v, &["H"; 9]).unwrap();
    let e = check_supported(&many, &DopplerSettings::default_for(&many, 8, 8)).unwrap_err();
    assert!(
        matches!(&e, Error::Unsupported(m) if m.contains("species")),
        "{e}"
    );
    // The CPU's own refusals of broadening settings are InvalidInput, as on the CPU.
    let mut banded = b.clone();
    banded.integrator = SpectralIntegrator::Banded {
        bands: 16,
        shift: BandShift::Nearest,
    };
    assert!(render_doppler(&scene, &banded, &|| {}).is_err());
    let e = check_supported(&scene, &banded).unwrap_err();
    assert!(
        matches!(&e, Error::InvalidInput(m) if m.contains("piecewise-linear")),
        "{e}"
    );
    let no_bb = shell();
    let e = check_supported(&no_bb, &b).unwrap_err();
    assert!(
        matches!(&e, Error::InvalidInput(m) if m.contains("temperature")),
        "{e}"
    );
    let mut bad_sigma = st.clone();
    bad_sigma.broadening.sigma_m_per_s = f64::NAN;
    let e = check_supported(&scene, &bad_sigma).unwrap_err();
    assert!(
        matches!(&e, Error::InvalidInput(m) if m.contains("sigma")),
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
        let st = DopplerSettings::default_for(&many, 8, 8);
        assert!(matches!(
            render_doppler_gpu(ctx, &many, &st),
            Err(Error::Unsupported(_))
        ));
    }
}

/// Per pixel and channel, the largest `|gpu - cpu| / (cpu + clear)` where `clear` is the
/// CPU's image without absorption (the unattenuated emission, the scale of the CPU's own
/// error bound), and the largest `|gpu - cpu| / cpu` over pixels brighter than 1e-3 of the
/// image maximum.
fn absorption_errors(cpu: &DopplerImage, gpu: &DopplerImage, clear: &DopplerImage) -> (f64, f64) {
    let max = cpu
        .xyz
        .iter()
        .flat_map(|p| p.iter().copied())
        .fold(0.0f64, f64::max);
    let (mut of_clear, mut of_cpu) = (0.0f64, 0.0f64);
    for ((c, g), u) in cpu.xyz.iter().zip(&gpu.xyz).zip(&clear.xyz) {
        for k in 0..3 {
            assert!(g[k].is_finite() && g[k] >= 0.0, "gpu {}", g[k]);
            let d = (c[k] - g[k]).abs();
            of_clear = of_clear.max(d / (c[k] + u[k]).max(1e-30));
            if c[k] > 1e-3 * max {
                of_cpu = of_cpu.max(d / c[k]);
            }
        }
    }
    (of_clear, of_cpu)
}

fn absorbing_galaxy(absorption: f64) -> DopplerScene {
    let mut g = galaxy();
    g.factors.absorption = absorption;
    g
}

/// The piecewise-linear integrator with line absorption (front to back, tau_front as pieces
/// on the device) against the CPU. Measured on lavapipe: worst `|gpu - cpu| / cpu` 7.4e-4 on
/// pixels above 1e-3 of the maximum and 3.7e-4 of `cpu + clear` (`clear`: the unattenuated
/// image); asserted within 2e-3 (the emission-only kernel's tolerance: its own worst is 4.6e-4
/// on the same pixel, f32 positions and shifts). The absorbed light alone (without merges)
/// agrees within 8.7e-3 of itself (plus 1e-3 of its maximum; the worst pixel is the one where
/// the emission-only kernel errs by 1e-3 on every H I line), asserted 2e-2; the CPU's own
/// bound is `merge_tolerance` (1e-4) of the unattenuated emission.
#[test]
fn pwl_absorption_matches_the_cpu() {
    let Some(ctx) = test_context() else { return };
    each_precision(ctx, || {
        let clear_scene = galaxy();
        let scene = absorbing_galaxy(5.0);
        let st = DopplerSettings::default_for(&scene, 16, 16);
        let cpu = render_doppler(&scene, &st, &|| {}).unwrap();
        let gpu = gpu_render(ctx, &scene, &st).unwrap();
        let clear = render_doppler(&clear_scene, &st, &|| {}).unwrap();
        compare("galaxy pwl absorption 5", &cpu, &gpu);
        let (of_clear, of_cpu) = absorption_errors(&cpu, &gpu, &clear);
        eprintln!(
            "pwl absorption 5: worst |gpu - cpu| / (cpu + clear) {of_clear:.3e}, / cpu {of_cpu:.3e}; \
         pieces gpu max {} mean {:.1}, cpu max {} mean {:.1}",
            gpu.pieces.max, gpu.pieces.mean, cpu.pieces.max, cpu.pieces.mean
        );
        assert!(of_clear <= 2e-3 && of_cpu <= 2e-3);
        // The absorption acts (the test can see it) and the piece statistics are the CPU's.
        let y = |im: &DopplerImage| im.xyz.iter().map(|p| p[1]).sum::<f64>();
        assert!(y(&gpu) < 0.999 * y(&clear), "absorption darkens nothing");
        assert!(gpu.pieces.max > 0 && gpu.pieces.fallback_rays == 0);
        // The absorbed light alone (clear - absorbing, each device against its own clear image),
        // without merges (merge tolerance 0: the CPU's and the GPU's merges would differ by up to
        // the tolerance, 1e-4 in optical depth, itself about 1 % of the absorbed light here).
        let mut st = st.clone();
        st.merge_tolerance = 0.0;
        let cpu = render_doppler(&scene, &st, &|| {}).unwrap();
        let gpu = gpu_render(ctx, &scene, &st).unwrap();
        let gpu_clear = gpu_render(ctx, &clear_scene, &st).unwrap();
        // Without merges both keep every piece of the optical depth in front: the same counts.
        // (With a tolerance they may differ: the CPU also leaves out the weakest lines within
        // the budget, the device only merges.)
        let pm = |im: &DopplerImage| im.pieces.max as f64;
        assert!((pm(&gpu) - pm(&cpu)).abs() <= 0.1 * pm(&cpu) + 2.0);
        assert!((gpu.pieces.mean - cpu.pieces.mean).abs() <= 0.1 * cpu.pieces.mean + 1.0);
        let taken =
            |a: &DopplerImage, b: &DopplerImage, i: usize, k: usize| b.xyz[i][k] - a.xyz[i][k];
        let max_taken = (0..cpu.xyz.len())
            .flat_map(|i| (0..3).map(move |k| (i, k)))
            .map(|(i, k)| taken(&cpu, &clear, i, k))
            .fold(0.0f64, f64::max);
        let mut worst_taken = 0.0f64;
        for i in 0..cpu.xyz.len() {
            for k in 0..3 {
                let (tc, tg) = (taken(&cpu, &clear, i, k), taken(&gpu, &gpu_clear, i, k));
                worst_taken = worst_taken.max((tc - tg).abs() / (tc.abs() + 1e-3 * max_taken));
            }
        }
        eprintln!("pwl absorption 5: worst relative error of the absorbed light {worst_taken:.3e}");
        // f32: 1.3e-4 measured; f64: 2.1e-13 on lavapipe (the same sums as the CPU's).
        assert!(
            worst_taken
                <= if is_f64() {
                    rounding_tolerance(ctx)
                } else {
                    2e-2
                }
        );
    });
}

/// Optically thick lines (absorption x 1e4, relativistic, invariant radiance): finite, never
/// brighter than the same render without absorption, and within 2e-3 of the unattenuated
/// emission of the CPU image (the cancellation of `emitted - absorbed` in f32 is bounded by
/// the emitted light, not by the small remainder).
#[test]
fn optically_thick_pwl_absorption_is_finite_and_darker() {
    let Some(ctx) = test_context() else { return };
    each_precision(ctx, || {
        let clear_scene = galaxy();
        let scene = absorbing_galaxy(1e4);
        let mut st = DopplerSettings::default_for(&scene, 12, 12);
        st.model = DopplerModel::Relativistic;
        st.invariant = true;
        let gpu = gpu_render(ctx, &scene, &st).unwrap();
        let free = gpu_render(ctx, &clear_scene, &st).unwrap();
        let mut darker = 0;
        for (a, f) in gpu.xyz.iter().zip(&free.xyz) {
            for k in 0..3 {
                assert!(a[k].is_finite() && a[k] >= 0.0);
                assert!(
                    a[k] <= f[k] * (1.0 + 1e-5) + 1e-30,
                    "brighter: {} > {}",
                    a[k],
                    f[k]
                );
            }
            darker += usize::from(a[1] < 0.95 * f[1]);
        }
        assert!(darker > 10, "only {darker} pixels lose > 5 % of Y");
        let cpu = render_doppler(&scene, &st, &|| {}).unwrap();
        let clear = render_doppler(&clear_scene, &st, &|| {}).unwrap();
        let (of_clear, of_cpu) = absorption_errors(&cpu, &gpu, &clear);
        eprintln!("thick: worst |gpu - cpu| / (cpu + clear) {of_clear:.3e}, / cpu {of_cpu:.3e}");
        assert!(of_clear <= 2e-3);
    });
}

/// A tiny piece budget forces the fallback (coarser merges of tau_front) on both devices:
/// the GPU counts the rays that needed it, stays finite and below the unattenuated image, and
/// keeps no more than the budget.
#[test]
fn the_piece_budget_fallback_is_counted() {
    let Some(ctx) = test_context() else { return };
    each_precision(ctx, || {
        let scene = absorbing_galaxy(5.0);
        let mut st = DopplerSettings::default_for(&scene, 12, 12);
        // 40 pieces: below the ~140 the rays keep, above the number of disjoint line groups
        // (the CPU multiplies its fallback tolerance by 4 per try, without bound, when merges
        // cannot reach the budget).
        st.piece_budget = 40;
        let gpu = gpu_render(ctx, &scene, &st).unwrap();
        let cpu = render_doppler(&scene, &st, &|| {}).unwrap();
        let clear = gpu_render(ctx, &galaxy(), &st).unwrap();
        eprintln!(
            "budget 40: fallback rays gpu {} cpu {}, max pieces gpu {} cpu {}",
            gpu.pieces.fallback_rays, cpu.pieces.fallback_rays, gpu.pieces.max, cpu.pieces.max
        );
        assert!(gpu.pieces.fallback_rays > 0);
        assert!(gpu.pieces.max <= 40);
        for (a, f) in gpu.xyz.iter().zip(&clear.xyz) {
            for k in 0..3 {
                assert!(a[k].is_finite() && a[k] >= 0.0 && a[k] <= f[k] * (1.0 + 1e-5) + 1e-30);
            }
        }
        // Budget 8: fewer pieces than tau_front has disjoint line groups (max 16 here), so merges
        // cannot reach the budget (the CPU's fallback tolerance then grows without bound and
        // overflows; the device caps it) and a segment's sum may overflow the ray's region, which
        // the device answers by merging across gaps (counted too). Still finite, never brighter,
        // and the image within 5 % of budget 40's.
        let mut tiny = st.clone();
        tiny.piece_budget = 8;
        let g8 = gpu_render(ctx, &scene, &tiny).unwrap();
        eprintln!(
            "budget 8: fallback rays gpu {}, max pieces {}",
            g8.pieces.fallback_rays, g8.pieces.max
        );
        assert!(g8.pieces.fallback_rays > 0);
        let (mut y8, mut y40) = (0.0, 0.0);
        for ((a, f), b) in g8.xyz.iter().zip(&clear.xyz).zip(&gpu.xyz) {
            for k in 0..3 {
                assert!(a[k].is_finite() && a[k] >= 0.0 && a[k] <= f[k] * (1.0 + 1e-5) + 1e-30);
            }
            y8 += a[1];
            y40 += b[1];
        }
        assert!(
            (y8 - y40).abs() <= 0.05 * y40,
            "budget 8: Y {y8} vs budget 40: {y40}"
        );
        // The fallback gives up the bound, not the image: on both devices (whose fallback merges
        // differ: the CPU also leaves out the weakest lines first) the preview stays within 15 %
        // of the image a budget large enough for no fallback gives.
        let mut full = st.clone();
        full.piece_budget = 1 << 16;
        let exact = render_doppler(&scene, &full, &|| {}).unwrap();
        assert_eq!(exact.pieces.fallback_rays, 0);
        let clear_cpu = render_doppler(&galaxy(), &st, &|| {}).unwrap();
        let (gpu_off, _) = absorption_errors(&exact, &gpu, &clear_cpu);
        let (cpu_off, _) = absorption_errors(&exact, &cpu, &clear_cpu);
        eprintln!(
            "budget 40: worst |preview - full| / (full + clear): gpu {gpu_off:.3e}, cpu {cpu_off:.3e}"
        );
        assert!(gpu_off <= 0.15 && cpu_off <= 0.15);
    });
}

/// Per-ray piece storage that fits no device limit is refused by name, before anything is
/// created.
#[test]
fn absorption_storage_beyond_the_limits_is_refused_by_name() {
    let scene = absorbing_galaxy(5.0);
    let st = DopplerSettings::default_for(&scene, 8, 8);
    let limits = wgpu::Limits {
        max_storage_buffer_binding_size: 4096,
        ..wgpu::Limits::default()
    };
    let e = absorption_layout(&st, 30, &limits).unwrap_err();
    assert!(
        matches!(&e, Error::LimitExceeded { limit, .. } if *limit == "max_storage_buffer_binding_size"),
        "{e}"
    );
    let (cap, per_ray, tile) = absorption_layout(&st, 30, &wgpu::Limits::default()).unwrap();
    assert_eq!(cap, DEVICE_PIECE_CAP.min(st.piece_budget));
    assert!(tile * per_ray <= wgpu::Limits::default().max_storage_buffer_binding_size);
}

/// Broadened emission lines (thermal from the black-body temperature field and a user
/// Gaussian sigma; the CPU's `emit_line`: up to 64 sub-sweep Gaussians of 32 pieces each)
/// against the CPU, within the emission-only tolerance (measured worst 4e-6 on lavapipe). At
/// 3000 km/s (6.6 nm at H alpha) the broadening changes the image beyond that tolerance (the
/// test sees it; narrower profiles barely change XYZ, the CMFs being nearly linear over them).
#[test]
fn broadened_lines_match_the_cpu() {
    let Some(ctx) = test_context() else { return };
    each_precision(ctx, || {
        let scene = galaxy();
        let mut shell = shell();
        shell.factors.velocity = 10.0;
        for (name, sc, thermal, sigma) in [
            ("galaxy thermal", &scene, true, 0.0),
            ("galaxy thermal + 300 km/s", &scene, true, 3e5),
            ("shell 100 km/s", &shell, false, 1e5),
            ("shell 3000 km/s", &shell, false, 3e6),
        ] {
            let mut st = DopplerSettings::default_for(sc, 16, 16);
            st.broadening.thermal = thermal;
            st.broadening.sigma_m_per_s = sigma;
            let cpu = render_doppler(sc, &st, &|| {}).unwrap();
            let gpu = gpu_render(ctx, sc, &st).unwrap();
            compare(name, &cpu, &gpu);
            let mut plain = st.clone();
            plain.broadening = Default::default();
            let box_profile = render_doppler(sc, &plain, &|| {}).unwrap();
            if sigma > 1e6 {
                let r =
                    std::panic::catch_unwind(|| compare("box vs broadened", &box_profile, &gpu));
                assert!(r.is_err(), "{name}: broadening changes nothing visible");
            }
        }
    });
}

/// Long rays (32^3 galaxy: 64 segments, about 500 pieces of tau_front) need several passes of
/// the resumable kernels on lavapipe, whose loop limiter stops every loop of an invocation
/// after 65535 iterations: with and without absorption the image still matches the CPU.
#[test]
fn long_rays_resume_across_passes_and_match_the_cpu() {
    let Some(ctx) = test_context() else { return };
    each_precision(ctx, || {
        let v = synth::galaxy(32, 5).unwrap();
        let mut clear = DopplerScene::from_volume(&v, &["bb", "H", "C"]).unwrap();
        clear.factors.velocity = 30.0;
        clear.factors.blackbody = 0.1;
        let mut absorbing = clear.clone();
        absorbing.factors.absorption = 5.0;
        let mut st = DopplerSettings::default_for(&clear, 6, 6);
        // Without merges (the CPU also leaves out the weakest lines within a tolerance, the
        // device only merges): both keep every piece, so the piece counts agree too.
        st.merge_tolerance = 0.0;
        for (name, sc) in [("long clear", &clear), ("long absorbing", &absorbing)] {
            let cpu = render_doppler(sc, &st, &|| {}).unwrap();
            let gpu = gpu_render(ctx, sc, &st).unwrap();
            compare(name, &cpu, &gpu);
            let (g, c) = (gpu.pieces.max as f64, cpu.pieces.max as f64);
            eprintln!(
                "{name}: max pieces gpu {g} cpu {c}, fallback rays gpu {} cpu {}",
                gpu.pieces.fallback_rays, cpu.pieces.fallback_rays
            );
            // Rays beyond the device cap (1024 pieces, below the CPU's default budget 4096)
            // run again at the CPU's budget: no fallback where the CPU has none, and in f64
            // the CPU's own piece counts.
            assert_eq!(gpu.pieces.fallback_rays, cpu.pieces.fallback_rays, "{name}");
            if is_f64() {
                assert_eq!(gpu.pieces.max, cpu.pieces.max, "{name}");
            }
            assert!(
                (g - c).abs() <= 0.25 * c + 2.0,
                "{name}: max pieces gpu {g} cpu {c}"
            );
        }
    });
}

/// A banded render whose one invocation needs more loop iterations than a software adapter
/// runs (lavapipe stops every loop after 65535 iterations in all) is an error naming the loop
/// limit there, never a silently darker image; a hardware GPU renders it as the CPU does.
#[test]
fn banded_work_beyond_the_software_loop_limit_is_an_error_not_a_wrong_image() {
    let Some(ctx) = test_context() else { return };
    each_precision(ctx, || {
        let scene = galaxy();
        let mut st = DopplerSettings::default_for(&scene, 2, 2);
        st.integrator = SpectralIntegrator::Banded {
            bands: 100_000,
            shift: BandShift::EnergyConserving,
        };
        match gpu_render(ctx, &scene, &st) {
            Err(Error::Unsupported(m)) if !ctx.is_hardware() => {
                assert!(m.contains("loop limit"), "{m}");
            }
            Ok(gpu) if ctx.is_hardware() => {
                let cpu = render_doppler(&scene, &st, &|| {}).unwrap();
                compare("banded 100000", &cpu, &gpu);
            }
            other => panic!("hardware {}: {other:?}", ctx.is_hardware()),
        }
    });
}

/// Broadened emission and absorption lines together (rotating hydrogen shell, 50 km/s
/// Gaussian, absorption x 2; the sources of each line are added to tau_front one merge pass
/// at a time, and what tau takes from each emitted Gaussian piece is subtracted) against the
/// CPU: measured worst relative difference 9e-5 on lavapipe, piece statistics equal.
#[test]
fn broadened_lines_with_absorption_match_the_cpu() {
    let Some(ctx) = test_context() else { return };
    each_precision(ctx, || {
        let mut scene = shell();
        scene.factors.velocity = 10.0;
        scene.factors.absorption = 2.0;
        let mut st = DopplerSettings::default_for(&scene, 8, 8);
        st.broadening.sigma_m_per_s = 5e4;
        let cpu = render_doppler(&scene, &st, &|| {}).unwrap();
        let gpu = gpu_render(ctx, &scene, &st).unwrap();
        compare("shell broadened, absorption 2", &cpu, &gpu);
        eprintln!(
            "broadened absorption: pieces gpu max {} mean {:.1}, cpu max {} mean {:.1}",
            gpu.pieces.max, gpu.pieces.mean, cpu.pieces.max, cpu.pieces.mean
        );
        let pm = |im: &DopplerImage| im.pieces.max as f64;
        assert!(pm(&cpu) > 0.0 && (pm(&gpu) - pm(&cpu)).abs() <= 0.1 * pm(&cpu) + 2.0);
        // The absorption acts.
        let mut clear = scene.clone();
        clear.factors.absorption = 0.0;
        let free = gpu_render(ctx, &clear, &st).unwrap();
        let y = |im: &DopplerImage| im.xyz.iter().map(|p| p[1]).sum::<f64>();
        assert!(y(&gpu) < 0.99 * y(&free));
    });
}

/// The f64 kernels' agreement with the CPU where both run the same algorithm, per pixel and
/// channel relative to the pixel: on lavapipe they sample the volume with the CPU's own f32
/// operations (bit for bit) and do the rest in f64, so what is left is rounding. Hardware
/// compilers may fuse the f32 sampling's multiply-adds (WGSL allows it), which moves a
/// density by an ulp (about 1e-7 of it), so there the bound is that of f32 samples.
fn rounding_tolerance(ctx: &blueshift_gpu::GpuContext) -> f64 {
    if ctx.is_hardware() { 1e-5 } else { 1e-11 }
}

/// f64 kernels against the CPU where both compute the same sums: emission-only piecewise
/// linear (trapezoids and broadened lines), banded (both shifts, with absorption) and
/// piecewise linear with absorption at merge tolerance 0 (no merges, nothing left out).
/// Measured on lavapipe: worst 2e-13 (broadened lines 7e-14, the rest 2e-15).
#[test]
fn f64_kernels_agree_with_the_cpu_to_rounding() {
    let Some(ctx) = test_context() else { return };
    if !ctx.has_f64() {
        eprintln!("SKIP: the adapter has no SHADER_F64");
        return;
    }
    let tol = rounding_tolerance(ctx);
    let worst = |cpu: &DopplerImage, gpu: &DopplerImage| {
        let max = cpu.xyz.iter().flatten().fold(0.0f64, |m, &v| m.max(v));
        assert!(max > 0.0);
        cpu.xyz
            .iter()
            .zip(&gpu.xyz)
            .flat_map(|(c, g)| {
                (0..3).map(move |k| (c[k] - g[k]).abs() / (c[k].abs() + 1e-12 * max))
            })
            .fold(0.0f64, f64::max)
    };
    let galaxy = galaxy();
    let absorbing = absorbing_galaxy(5.0);
    let mut cases: Vec<(&str, DopplerScene, DopplerSettings)> = Vec::new();
    let st = DopplerSettings::default_for(&galaxy, 12, 12);
    cases.push(("pwl", galaxy.clone(), st.clone()));
    let mut b = st.clone();
    b.broadening.thermal = true;
    b.broadening.sigma_m_per_s = 3e5;
    cases.push(("pwl broadened", galaxy.clone(), b));
    for shift in [BandShift::Nearest, BandShift::EnergyConserving] {
        let mut c = DopplerSettings::default_for(&absorbing, 12, 12);
        c.integrator = SpectralIntegrator::Banded { bands: 120, shift };
        cases.push(("banded with absorption", absorbing.clone(), c));
    }
    let mut d = DopplerSettings::default_for(&absorbing, 12, 12);
    d.merge_tolerance = 0.0;
    cases.push(("pwl absorption, tolerance 0", absorbing.clone(), d));
    for (name, scene, st) in &cases {
        let cpu = render_doppler(scene, st, &|| {}).unwrap();
        let gpu = render_doppler_gpu_with(ctx, scene, st, DopplerPrecision::F64).unwrap();
        let w = worst(&cpu, &gpu);
        eprintln!("f64 {name}: worst relative difference {w:.3e} (bound {tol:.0e})");
        assert!(w <= tol, "f64 {name}: {w:e} > {tol:e}");
        assert_eq!(cpu.pieces.max, gpu.pieces.max, "{name}: piece counts");
    }
    // The same scenes in f32 are far from that (the test can tell the precisions apart).
    let (name, scene, st) = &cases[0];
    let cpu = render_doppler(scene, st, &|| {}).unwrap();
    let gpu = render_doppler_gpu_with(ctx, scene, st, DopplerPrecision::F32).unwrap();
    let w = worst(&cpu, &gpu);
    eprintln!("f32 {name}: worst relative difference {w:.3e}");
    assert!(w > 1e-9);
}

/// `auto` takes f64 exactly where the adapter has `SHADER_F64`; `f64` without it is refused
/// by name; the parser names the accepted values.
#[test]
fn the_precision_follows_the_adapter() {
    let Some(ctx) = test_context() else { return };
    assert_eq!(
        DopplerPrecision::Auto.is_double_on(ctx).unwrap(),
        ctx.has_f64()
    );
    assert!(!DopplerPrecision::F32.is_double_on(ctx).unwrap());
    match DopplerPrecision::F64.is_double_on(ctx) {
        Ok(d) => assert!(d && ctx.has_f64()),
        Err(e) => assert!(
            !ctx.has_f64() && e.to_string().contains("SHADER_F64"),
            "{e}"
        ),
    }
    assert_eq!(
        DopplerPrecision::parse("F64").unwrap(),
        DopplerPrecision::F64
    );
    assert_eq!(
        DopplerPrecision::parse("auto").unwrap(),
        DopplerPrecision::Auto
    );
    let e = DopplerPrecision::parse("f16").unwrap_err();
    assert!(e.to_string().contains("auto, f32 or f64"), "{e}");
    // f64 pieces take twice the bytes: fewer rays per tile.
    let scene = absorbing_galaxy(5.0);
    let st = DopplerSettings::default_for(&scene, 8, 8);
    let l = wgpu::Limits::default();
    let (_, b32, t32) = absorption_layout_fw(&st, 30, &l, false).unwrap();
    let (_, b64, t64) = absorption_layout_fw(&st, 30, &l, true).unwrap();
    assert_eq!(b64, 2 * b32);
    assert!(t64 < t32);
}

/// The f64 prelude's `exp_fw` and `expm1_fw` (SPIR-V has no f64 `exp`) against Rust's
/// `f64::exp` / `exp_m1` over f64's range, through the prelude the kernels use. Measured on
/// lavapipe: worst 2.2e-16 relative (exp), 5.4e-16 (expm1).
#[test]
fn the_f64_prelude_exp_matches_the_cpu() {
    let Some(ctx) = test_context() else { return };
    if !ctx.has_f64() {
        eprintln!("SKIP: the adapter has no SHADER_F64");
        return;
    }
    let src = blueshift_gpu::doppler::shader_source(true);
    let prelude = &src[..src.len() - blueshift_gpu::doppler::DOPPLER_WGSL.len()];
    let kernel = format!(
        "{prelude}
@group(0) @binding(0) var<storage, read> xs: array<f64>;
@group(0) @binding(1) var<storage, read_write> ys: array<f64>;
@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) id: vec3<u32>) {{
    let n = arrayLength(&xs);
    if (id.x >= n) {{ return; }}
    ys[id.x] = exp_fw(xs[id.x]);
    ys[n + id.x] = expm1_fw(xs[id.x]);
}}"
    );
    // Its range: [-708, 700] (above, 2e300, which the callers read as an overflow; below, 0).
    let mut xs: Vec<f64> = (0..1400).map(|i| -707.9 + 1.0056 * f64::from(i)).collect();
    xs.extend((0..600).map(|i| (f64::from(i) - 300.0) * 1.7e-3 + 1e-9));
    xs.retain(|x| *x < 700.0);
    xs.extend([705.0, 1e6, -709.0, -1e6]);
    let n = xs.len();
    let p = ctx
        .compute_pipeline("exp_fw check", &kernel, "main")
        .unwrap();
    let xb = ctx.storage_buffer("xs", &xs).unwrap();
    let yb = ctx.storage_buffer_zeroed("ys", 16 * n as u64).unwrap();
    let bg = ctx.bind_group(&p, 0, &[&xb, &yb]).unwrap();
    let groups = ctx.groups("exp", n as u32, 64).unwrap();
    ctx.dispatch(&p, &bg, [groups, 1, 1]).unwrap();
    let ys: Vec<f64> = ctx.read_buffer(&yb, 2 * n).unwrap();
    let (mut we, mut wm) = (0.0f64, 0.0f64);
    for (i, x) in xs.iter().enumerate() {
        if *x > 700.0 || *x < -708.0 {
            assert!(
                if *x > 0.0 {
                    ys[i] >= 1e300
                } else {
                    ys[i] == 0.0
                },
                "{x}: {}",
                ys[i]
            );
            continue;
        }
        let (e, m) = (x.exp(), x.exp_m1());
        if e > 1e-300 {
            we = we.max(((ys[i] - e) / e).abs());
        }
        wm = wm.max(((ys[n + i] - m) / m.abs().max(1e-300)).abs());
    }
    eprintln!("f64 prelude: worst relative error exp {we:.2e}, expm1 {wm:.2e}");
    assert!(we <= 1e-15 && wm <= 1e-15, "exp {we:e}, expm1 {wm:e}");
}

/// The 64^3 galaxy's hydrogen, black body and velocity as `.bsv` files (bricks of 8, so 512
/// regions), in a scene whose every field takes a level per region in stripes.
fn per_brick_galaxy(dir: &std::path::Path) -> DopplerScene {
    let s = bricked_galaxy(dir);
    let g = *s.geometry();
    // Regions of 8 voxels of a grid whose world box is its own: stripes by region index.
    let (lo, hi) = g.world_bounds();
    let edge = (hi - lo) / 63.0 * 8.0;
    s.per_brick(move |a, _| {
        let r = ((a - lo) / edge + 0.5).floor();
        (r.x as usize + 2 * r.z as usize) % 3
    })
    .unwrap()
}

/// The 64^3 galaxy's hydrogen, black body and velocity as `.bsv` files (bricks of 8).
fn bricked_galaxy(dir: &std::path::Path) -> DopplerScene {
    use blueshift_volume::ooc::{self, BrickLayout, BrickedFile, GridSource};
    use blueshift_volume::{AnyGrid, BrickCache, Field, Grid, VectorField};
    let vol = synth::galaxy(64, 2).unwrap();
    let scalar = |name: &str| match &vol.channel(name).unwrap().grid {
        AnyGrid::F32(g) => g.clone(),
        _ => panic!("f32"),
    };
    let (hi, temp) = (scalar("hi_density"), scalar("temperature_k"));
    let AnyGrid::Vec3(vel) = &vol.channel("velocity_m_per_s").unwrap().grid else {
        panic!("vector")
    };
    let g = *hi.geometry();
    let comp = |a: usize| Grid::from_vec(g, vel.data().iter().map(|v| v[a]).collect()).unwrap();
    let cache = BrickCache::new(1 << 26);
    let brick = |name: &str, grid: &Grid<f32>| -> Field {
        let p = dir.join(format!("{name}.bsv"));
        ooc::convert(
            &mut GridSource(grid),
            &p,
            name,
            BrickLayout { brick: 8, apron: 1 },
            &mut |_, _| {},
        )
        .unwrap();
        BrickedFile::open_with_cache(&p, cache.clone())
            .unwrap()
            .field(0)
            .unwrap()
            .into()
    };
    let lines = blueshift_spectrum::Catalogue::HydrogenBalmer.lines();
    let density = brick("hi", &hi);
    let mut s = DopplerScene::new(g).unwrap();
    s.add_species(blueshift_doppler::Species {
        name: "H".into(),
        density: density.clone(),
        emission_lines: lines.clone(),
        absorption_lines: lines,
    })
    .unwrap();
    s.set_blackbody(density, brick("t", &temp)).unwrap();
    s.set_velocity(VectorField::Components(Box::new([
        brick("vx", &comp(0)),
        brick("vy", &comp(1)),
        brick("vz", &comp(2)),
    ])))
    .unwrap();
    s.factors.blackbody = 1e-3;
    s.factors.velocity = 20.0;
    s
}

#[test]
fn per_brick_levels_of_detail_match_the_cpu() {
    let Some(ctx) = test_context() else { return };
    let dir = tempfile::tempdir().unwrap();
    let scene = per_brick_galaxy(dir.path());
    let map = scene.species()[0]
        .density
        .as_bricked()
        .unwrap()
        .level_map()
        .unwrap();
    assert!(
        map.histogram().iter().all(|&n| n > 0),
        "{:?}",
        map.histogram()
    );
    let mut st = DopplerSettings::default_for(&scene, 20, 20);
    assert!(check_supported(&scene, &st).is_ok());
    each_precision(ctx, || {
        for absorption in [0.0, 0.5] {
            let mut s = scene.clone();
            s.factors.absorption = absorption;
            let cpu = render_doppler(&s, &st, &|| {}).unwrap();
            let gpu = gpu_render(ctx, &s, &st).unwrap();
            compare(
                &format!("per-brick galaxy, absorption {absorption}"),
                &cpu,
                &gpu,
            );
        }
    });
    // And banded, in f32.
    st.integrator = "banded:16".parse().unwrap();
    let cpu = render_doppler(&scene, &st, &|| {}).unwrap();
    PRECISION.set(DopplerPrecision::F32);
    compare(
        "per-brick galaxy, banded",
        &cpu,
        &gpu_render(ctx, &scene, &st).unwrap(),
    );
}

/// The levels an observer hears, in order.
#[derive(Default)]
struct Levels(std::sync::Mutex<Vec<usize>>);

impl blueshift_camera::Observer<DopplerImage> for Levels {
    fn level(&self, _step: u32, level: usize) {
        self.0.lock().unwrap().push(level);
    }
}

#[test]
fn progressive_renders_through_one_pool_end_with_the_target_level() {
    let Some(ctx) = test_context() else { return };
    let dir = tempfile::tempdir().unwrap();
    let scene = bricked_galaxy(dir.path());
    let count = scene.levels().unwrap().len();
    let st = DopplerSettings::default_for(&scene, 20, 20);
    PRECISION.set(DopplerPrecision::F32);
    for target in [0, 1] {
        let want = gpu_render(ctx, &scene.at_level(target).unwrap(), &st).unwrap();
        for bricks in [false, true] {
            let heard = Levels::default();
            let (img, stats) = blueshift_gpu::doppler::render_doppler_gpu_progressive(
                ctx,
                &scene,
                &st,
                target,
                bricks,
                &heard,
                &mut |_, _, _| {},
                DopplerPrecision::F32,
            )
            .unwrap();
            assert_eq!(img.xyz, want.xyz, "target {target}, bricks {bricks}");
            let got = heard.0.lock().unwrap().clone();
            assert_eq!(got.first(), Some(&(count - 1)), "{got:?}");
            assert_eq!(got.last(), Some(&target), "{got:?}");
            if !bricks {
                assert_eq!(got, (target..count).rev().collect::<Vec<_>>());
            }
            assert!(stats.resident > 0, "{stats}");
        }
    }
}

#[test]
fn a_session_keeps_its_pool_across_renders() {
    let Some(ctx) = test_context() else { return };
    let dir = tempfile::tempdir().unwrap();
    let scene = bricked_galaxy(dir.path());
    let st = DopplerSettings::default_for(&scene, 16, 16);
    let mut sess = blueshift_gpu::doppler::GpuDopplerSession::new(
        ctx,
        scene.clone(),
        st.clone(),
        DopplerPrecision::F32,
    )
    .unwrap();
    let first = sess.render(&blueshift_camera::Silent).unwrap();
    let st1 = sess.pool_stats().unwrap();
    assert_eq!(st1.kept, 0, "{st1}");
    // Another camera: the same bricks, none uploaded again; the image a fresh render's.
    let mut cam = st.camera;
    cam.eye += (cam.eye - cam.target) * 0.3;
    sess.cpu_mut().set_camera(cam).unwrap();
    let second = sess.render(&blueshift_camera::Silent).unwrap();
    let st2 = sess.pool_stats().unwrap();
    assert_eq!(
        (st2.kept, st2.resident),
        (st1.resident, st1.resident),
        "{st2}"
    );
    let mut moved = st.clone();
    moved.camera = cam;
    PRECISION.set(DopplerPrecision::F32);
    assert_eq!(second.xyz, gpu_render(ctx, &scene, &moved).unwrap().xyz);
    assert_ne!(first.xyz, second.xyz);
}
