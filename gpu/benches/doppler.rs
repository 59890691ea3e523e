//! The GPU Doppler integrator against the CPU's on the same scene.
//!
//! `doppler_small` runs on any adapter (lavapipe in CI): the synthetic galaxy at 32^3 with a
//! black body, H I and C I lines and its rotation x 30, a 32x32 image, the emission-only
//! piecewise-linear integrator and the banded one (200 bands, energy-conserving shift, without
//! and with absorption x 50), and the piecewise-linear integrator with absorption x 5
//! (`pwl_absorption`: front to back, the optical depth in front as pieces); `cpu` is `blueshift_doppler::render_doppler`
//! (rayon), `gpu` is `blueshift_gpu::doppler::render_doppler_gpu_with` in f32 and `gpu_f64`
//! the same in f64 (where the adapter has `SHADER_F64`), each as a whole call (upload,
//! dispatch and readback; the pipeline is compiled once per context, on the first call). The
//! ratio gpu / cpu is the figure, and gpu_f64 / gpu the cost of double precision.
//!
//! `doppler_table1` runs on hardware adapters only: the Doppler paper's Table 1
//! configurations (the CPU's `benches/benches/doppler.rs` table1: synthetic shell H I, and the
//! 128^3 galaxy at 60 degrees with black body / H I / black body + H I + C I / H I + C I +
//! He I, Doppler off (velocity x 0) and on (x 30)) at 512x512, f32 and f64 (paper, Titan RTX:
//! 91 ms black body with Doppler ... 78,933 ms H I + C I + He I with Doppler).

use blueshift_doppler::Projection;
use blueshift_doppler::{
    BandShift, DopplerImage, DopplerScene, DopplerSettings, SpectralIntegrator, render_doppler,
};
use blueshift_gpu::GpuContext;
use blueshift_gpu::doppler::{DopplerPrecision, render_doppler_gpu_with};
use blueshift_volume::{Volume, synth};
use criterion::{BenchmarkGroup, Criterion, criterion_group, criterion_main};

/// The GPU variants of one case: `gpu` (f32) and `gpu_f64` where the adapter has SHADER_F64.
///
/// A case's first call compiles its pipeline (once per context). Each variant therefore
/// renders the case once at 8x8 before its timing, when criterion first selects it: criterion's
/// `--quick` (which `benches/scripts/gpu_bench.sh` uses for `doppler_table1`, whose calls can
/// take seconds) has no warm-up and times a call longer than its measurement time once.
fn bench_gpu(
    g: &mut BenchmarkGroup<'_, criterion::measurement::WallTime>,
    ctx: &GpuContext,
    name: &str,
    scene: &DopplerScene,
    st: &DopplerSettings,
) {
    let render = |st: &DopplerSettings, p: DopplerPrecision| -> DopplerImage {
        render_doppler_gpu_with(ctx, scene, st, p).expect("gpu")
    };
    let mut tiny = st.clone();
    (tiny.width, tiny.height) = (8, 8);
    let mut variants = vec![("gpu", DopplerPrecision::F32)];
    if ctx.has_f64() {
        variants.push(("gpu_f64", DopplerPrecision::F64));
    }
    for (prefix, p) in variants {
        let mut compiled = false;
        g.bench_function(format!("{prefix}/{name}"), |b| {
            if !compiled {
                render(&tiny, p);
                compiled = true;
            }
            b.iter(|| render(st, p));
        });
    }
}

fn small(c: &mut Criterion) {
    let ctx = match GpuContext::shared() {
        Ok(c) => c,
        Err(e) => {
            eprintln!("SKIP: no wgpu adapter: {e}");
            return;
        }
    };
    // Read by benches/scripts/gpu_bench.sh (the adapter column of its CSV).
    let r = ctx.report();
    eprintln!("adapter: {} ({}, {})", r.name, r.backend, r.device_type);
    let v = synth::galaxy(32, 5).expect("galaxy");
    let mut scene = DopplerScene::from_volume(&v, &["bb", "H", "C"]).expect("scene");
    scene.factors.velocity = 30.0;
    scene.factors.blackbody = 0.1;
    let st = DopplerSettings::default_for(&scene, 32, 32);
    let mut g = c.benchmark_group("doppler_small");
    g.sample_size(10);
    g.bench_function("cpu/pwl_emission", |b| {
        b.iter(|| render_doppler(&scene, &st, &|| {}).expect("cpu"));
    });
    bench_gpu(&mut g, ctx, "pwl_emission", &scene, &st);
    let mut banded = st.clone();
    banded.integrator = SpectralIntegrator::Banded {
        bands: 200,
        shift: BandShift::EnergyConserving,
    };
    g.bench_function("cpu/banded_ec_200", |b| {
        b.iter(|| render_doppler(&scene, &banded, &|| {}).expect("cpu"));
    });
    bench_gpu(&mut g, ctx, "banded_ec_200", &scene, &banded);
    let mut absorbing = scene.clone();
    absorbing.factors.absorption = 50.0;
    g.bench_function("cpu/banded_ec_200_absorption", |b| {
        b.iter(|| render_doppler(&absorbing, &banded, &|| {}).expect("cpu"));
    });
    bench_gpu(&mut g, ctx, "banded_ec_200_absorption", &absorbing, &banded);
    // The piecewise-linear integrator with absorption (front to back, tau_front as pieces).
    let mut lines_absorb = scene.clone();
    lines_absorb.factors.absorption = 5.0;
    g.bench_function("cpu/pwl_absorption", |b| {
        b.iter(|| render_doppler(&lines_absorb, &st, &|| {}).expect("cpu"));
    });
    bench_gpu(&mut g, ctx, "pwl_absorption", &lines_absorb, &st);
    g.finish();
}

fn table1(c: &mut Criterion) {
    let Ok(ctx) = GpuContext::shared() else {
        eprintln!("SKIP doppler_table1: no wgpu adapter");
        return;
    };
    if !ctx.is_hardware() {
        eprintln!(
            "SKIP doppler_table1: {} is a software adapter; the 512x512 Table 1 group runs on \
             hardware GPUs (doppler_small gives lavapipe's GPU / CPU ratios)",
            ctx.info().name
        );
        return;
    }
    let galaxy = synth::galaxy(128, 1).expect("galaxy");
    let shell = synth::hydrogen_shell(64, 1).expect("shell");
    let configs: [(&str, &Volume, &[&str]); 5] = [
        ("shell_H", &shell, &["H"]),
        ("galaxy_bb", &galaxy, &["bb"]),
        ("galaxy_H", &galaxy, &["H"]),
        ("galaxy_bb_H_C", &galaxy, &["bb", "H", "C"]),
        ("galaxy_H_C_He", &galaxy, &["H", "C", "He"]),
    ];
    let mut g = c.benchmark_group(format!("doppler_table1 ({})", ctx.info().name));
    g.sample_size(10);
    for (name, vol, species) in configs {
        for (doppler, vf) in [("off", 0.0), ("on", 30.0)] {
            let mut s = DopplerScene::from_volume(vol, species).expect("scene");
            s.factors.velocity = vf;
            s.factors.blackbody = 0.1;
            let mut st = DopplerSettings::default_for(&s, 512, 512);
            if name != "shell_H" {
                // As the CPU's Table 1 bench: 60 degrees, zoomed to the disc.
                st.incline(&s, 60.0).expect("inclination");
                st.camera.projection = Projection::Orthographic { height: 30.0 };
            }
            bench_gpu(&mut g, ctx, &format!("{name}_doppler_{doppler}"), &s, &st);
        }
    }
    g.finish();
}

criterion_group!(benches, small, table1);
criterion_main!(benches);
