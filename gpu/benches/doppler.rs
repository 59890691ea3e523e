//! The GPU Doppler integrator against the CPU's on the same scene.
//!
//! `doppler_small` runs on any adapter (lavapipe in CI): the synthetic galaxy at 32^3 with a
//! black body, H I and C I lines and its rotation x 30, a 32x32 image, the emission-only
//! piecewise-linear integrator and the banded one (200 bands, energy-conserving shift, without
//! and with absorption x 50), and the piecewise-linear integrator with absorption x 5
//! (`pwl_absorption`: front to back, the optical depth in front as pieces); `cpu` is `blueshift_tracking::doppler::render_doppler`
//! (rayon), `gpu` is `blueshift_gpu::doppler::render_doppler_gpu` as a whole call (pipeline
//! creation, upload, dispatch and readback included). The ratio gpu / cpu is the figure.

use blueshift_gpu::GpuContext;
use blueshift_gpu::doppler::render_doppler_gpu;
use blueshift_tracking::doppler::{
    BandShift, DopplerScene, DopplerSettings, SpectralIntegrator, render_doppler,
};
use blueshift_volume::synth;
use criterion::{Criterion, criterion_group, criterion_main};

fn small(c: &mut Criterion) {
    let ctx = match GpuContext::shared() {
        Ok(c) => c,
        Err(e) => {
            eprintln!("SKIP: no wgpu adapter: {e}");
            return;
        }
    };
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
    g.bench_function("gpu/pwl_emission", |b| {
        b.iter(|| render_doppler_gpu(ctx, &scene, &st).expect("gpu"));
    });
    let mut banded = st.clone();
    banded.integrator = SpectralIntegrator::Banded {
        bands: 200,
        shift: BandShift::EnergyConserving,
    };
    g.bench_function("cpu/banded_ec_200", |b| {
        b.iter(|| render_doppler(&scene, &banded, &|| {}).expect("cpu"));
    });
    g.bench_function("gpu/banded_ec_200", |b| {
        b.iter(|| render_doppler_gpu(ctx, &scene, &banded).expect("gpu"));
    });
    let mut absorbing = scene.clone();
    absorbing.factors.absorption = 50.0;
    g.bench_function("cpu/banded_ec_200_absorption", |b| {
        b.iter(|| render_doppler(&absorbing, &banded, &|| {}).expect("cpu"));
    });
    g.bench_function("gpu/banded_ec_200_absorption", |b| {
        b.iter(|| render_doppler_gpu(ctx, &absorbing, &banded).expect("gpu"));
    });
    // The piecewise-linear integrator with absorption (front to back, tau_front as pieces).
    let mut lines_absorb = scene.clone();
    lines_absorb.factors.absorption = 5.0;
    g.bench_function("cpu/pwl_absorption", |b| {
        b.iter(|| render_doppler(&lines_absorb, &st, &|| {}).expect("cpu"));
    });
    g.bench_function("gpu/pwl_absorption", |b| {
        b.iter(|| render_doppler_gpu(ctx, &lines_absorb, &st).expect("gpu"));
    });
    g.finish();
}

criterion_group!(benches, small);
criterion_main!(benches);
