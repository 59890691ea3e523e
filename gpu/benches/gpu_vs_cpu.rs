//! GPU pipeline time against the CPU function on the same input, per tone-mapping operator
//! and for the relativity renderer.
//!
//! Groups `*_small` run on any adapter (lavapipe in CI: the ratio makes a regression
//! visible without a GPU). Groups `tonemap_8MP` and `relativity_1080p` (the sizes:
//! an 8-megapixel image; 1920x1080 from a 6 x 1024^2 cube map) run only when the adapter is
//! a hardware GPU. The GPU time includes upload, all passes and readback; the shaders are
//! compiled once outside the timing.

use blueshift_gpu::relativity::GpuRelativity;
use blueshift_gpu::tonemap::GpuTonemapper;
use blueshift_gpu::{GpuContext, GpuOptions};
use blueshift_relativity::{Camera, CubeMap, Effects, Environment, Velocity, cube_dir};
use blueshift_tonemap::{
    DragoParams, DurandParams, FattalParams, LinearParams, Operator, ReinhardLocalParams,
    ReinhardParams,
};
use criterion::{Bencher, Criterion, criterion_group, criterion_main};
use glam::DVec3;
use image::{Rgb, Rgb32FImage};

fn scene(w: u32, h: u32) -> Rgb32FImage {
    Rgb32FImage::from_fn(w, h, |x, y| {
        let (u, v) = (x as f32 / w as f32, y as f32 / h as f32);
        let mut l = 0.01 + 2.0 * u * v + 0.2 * (20.0 * u).sin().abs();
        if (u - 0.7).powi(2) + (v - 0.3).powi(2) < 0.004 {
            l += 500.0;
        }
        Rgb([l * 1.1, l, l * 0.8])
    })
}

fn cube(n: u32) -> Environment {
    let faces: [Rgb32FImage; 6] = std::array::from_fn(|f| {
        Rgb32FImage::from_fn(n, n, |x, y| {
            let d = cube_dir(
                f,
                (f64::from(x) + 0.5) / f64::from(n),
                (f64::from(y) + 0.5) / f64::from(n),
            );
            Rgb([(1.0 + d.x) as f32, (1.0 + d.y) as f32, (1.0 + d.z) as f32])
        })
    });
    Environment::Cube(CubeMap::new(faces).expect("valid cube"))
}

/// Times `f` after one untimed call on the bench's first run. `benches/scripts/gpu_bench.sh`
/// runs `tonemap_8MP` with criterion's `--quick`, which has no warm-up and times a call slower
/// than its measurement time once, so a first call's one-off costs (allocations, page faults,
/// the driver's first dispatch) would otherwise be the figure.
fn warm_then_time<O>(mut f: impl FnMut() -> O) -> impl FnMut(&mut Bencher<'_>) {
    let mut warmed = false;
    move |b| {
        if !warmed {
            std::hint::black_box(f());
            warmed = true;
        }
        b.iter(&mut f);
    }
}

fn operators() -> [Operator; 6] {
    [
        Operator::Linear(LinearParams::default()),
        Operator::Drago(DragoParams::default()),
        Operator::Reinhard(ReinhardParams::default()),
        Operator::ReinhardLocal(ReinhardLocalParams::default()),
        Operator::Durand(DurandParams::default()),
        Operator::Fattal(FattalParams::default()),
    ]
}

fn tonemap_group(c: &mut Criterion, ctx: &GpuContext, label: &str, w: u32, h: u32) {
    let img = scene(w, h);
    let tm = GpuTonemapper::new(ctx).expect("tone-mapping pipelines");
    let mut g = c.benchmark_group(format!("tonemap_{label}"));
    g.sample_size(10);
    for op in operators() {
        g.bench_function(
            format!("{}_cpu", op.name()),
            warm_then_time(|| op.apply(&img).expect("cpu")),
        );
        g.bench_function(
            format!("{}_gpu", op.name()),
            warm_then_time(|| tm.apply(&op, &img).expect("gpu")),
        );
    }
    g.finish();
}

fn relativity_group(c: &mut Criterion, ctx: &GpuContext, label: &str, face: u32, w: u32, h: u32) {
    let env = cube(face);
    let cam = Camera {
        look: DVec3::NEG_Z,
        width: w,
        height: h,
        ..Camera::default()
    };
    let v = Velocity::along(DVec3::new(0.3, 0.0, -1.0), 0.9).expect("velocity");
    let gpu = GpuRelativity::new(ctx, None).expect("relativity pipeline");
    let mut g = c.benchmark_group(format!("relativity_{label}"));
    g.sample_size(10);
    let sets = [
        ("aberration", Effects::ABERRATION),
        (
            "aberration_doppler",
            Effects {
                aberration: true,
                doppler: true,
                searchlight: false,
            },
        ),
        ("all", Effects::ALL),
    ];
    for (name, fx) in sets {
        g.bench_function(
            format!("{name}_cpu"),
            warm_then_time(|| blueshift_relativity::render(&env, &cam, v, fx, None).expect("cpu")),
        );
        g.bench_function(
            format!("{name}_gpu"),
            warm_then_time(|| gpu.render(&env, &cam, v, fx).expect("gpu")),
        );
    }
    g.finish();
}

fn benches(c: &mut Criterion) {
    let ctx = match GpuContext::new(GpuOptions::default()) {
        Ok(ctx) => ctx,
        Err(e) => {
            eprintln!("SKIP: no wgpu adapter: {e}");
            return;
        }
    };
    // Read by benches/scripts/gpu_bench.sh (the adapter column of its CSV).
    eprintln!(
        "adapter: {} ({}, {})",
        ctx.report().name,
        ctx.report().backend,
        ctx.report().device_type
    );
    tonemap_group(c, &ctx, "small", 256, 256);
    relativity_group(c, &ctx, "small", 64, 256, 144);
    if ctx.is_hardware() {
        tonemap_group(c, &ctx, "8MP", 3464, 2309);
        relativity_group(c, &ctx, "1080p", 1024, 1920, 1080);
    } else {
        eprintln!("software adapter: the 8 MP and 1920x1080 groups need a hardware GPU");
    }
}

criterion_group!(gpu, benches);
criterion_main!(gpu);
