//! GPU tracking pipelines against the CPU integrators on the same scene.
//!
//! `tracking_small` runs on any adapter (lavapipe in CI): a 32x32 image of a 2-channel
//! 24^3 volume, 4 samples per pixel, for MDWT 1-DDA density (with and without shadows),
//! N-DDA max, and the f32 marcher; each as `cpu/...` (blueshift-tracking, rayon) and
//! `gpu/...` (upload excluded, readback included). The ratio gpu / cpu is the figure.
//!
//! `pool` (any adapter): the device brick pool. `upload/dense` and `upload/bsv` fill the
//! pool of a 96^3 2-channel scene from memory and from `.bsv` files through a warm brick
//! cache (the cost of out-of-core data on the GPU); `render/full` and `render/sparse` are
//! the 1-DDA render of a volume whose bricks are all resident and of one that is zero but
//! for one brick (the page table's constant bricks cost no memory reads).
//!
//! `tracking_paper` only runs on a hardware adapter: the MDWT paper's setting, 2560x1440
//! at 1 spp on a 512^3 4-channel volume, 1-DDA, density blending, with and without shadows
//! (paper, RTX 4090: 291 and 178 FPS on NYX), and frames against channel count 1..12 on
//! 256^3. On a software adapter it prints why it is skipped.

use blueshift_gpu::GpuContext;
use blueshift_gpu::tracking::GpuTracker;
use blueshift_tfedit::{ColorKnot, OpacityKnot, TransferFunction};
use blueshift_tracking::{
    Blend, DdaMode, DirectionalLight, Integrator, RayMarcher, RenderSettings, Scene, render,
};
use blueshift_volume::{AnyGrid, Geometry, Grid};
use criterion::{Criterion, criterion_group, criterion_main};
use glam::Vec3;

fn tf(c: [f32; 3], knots: &[(f64, f32)]) -> TransferFunction {
    TransferFunction::new(
        [0.0, 1.0],
        vec![
            ColorKnot { x: 0.0, rgb: c },
            ColorKnot {
                x: 1.0,
                rgb: [1.0; 3],
            },
        ],
        knots.iter().map(|&(x, a)| OpacityKnot::new(x, a)).collect(),
    )
    .unwrap()
}

/// `channels` blobs and waves on an n^3 grid.
fn scene(n: usize, channels: usize, density: f32) -> Scene {
    let c = (n - 1) as f32 * 0.5;
    let triples = (0..channels)
        .map(|i| {
            let phase = i as f32 * 0.7;
            let g = Grid::from_fn(Geometry::unit([n, n, n]), move |x, y, z| {
                let p = Vec3::new(x as f32 - c, y as f32 - c, z as f32 - c) / c;
                let blob = (-3.0 * (p + Vec3::splat(0.2 * phase.sin())).length_squared()).exp();
                (0.7 * blob + 0.3 * (0.5 + 0.5 * (4.0 * p.x + phase).sin())).clamp(0.0, 1.0)
            })
            .unwrap();
            let colour = [
                (0.3 * i as f32).sin().abs(),
                0.5,
                (0.2 * i as f32).cos().abs(),
            ];
            (
                format!("c{i}"),
                AnyGrid::F32(g),
                tf(colour, &[(0.0, 0.0), (0.4, 0.05), (1.0, 0.8)]),
            )
        })
        .collect();
    Scene::new(triples, density, 8).unwrap()
}

fn light() -> Option<DirectionalLight> {
    Some(DirectionalLight {
        direction: Vec3::new(0.5, 1.0, -0.3),
        radiance: [1.0; 3],
        ambient: 0.2,
    })
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
    let tracker = GpuTracker::new(ctx).unwrap();
    let base = scene(24, 2, 4.0 / 24.0);
    let mut lit = base.clone();
    lit.light = light();
    let cases: Vec<(&str, Scene, Integrator)> = vec![
        (
            "mdwt-1dda-density",
            base.clone(),
            Integrator::Mdwt {
                dda: DdaMode::OneDda,
                blend: Blend::Density,
            },
        ),
        (
            "mdwt-1dda-density-shadows",
            lit,
            Integrator::Mdwt {
                dda: DdaMode::OneDda,
                blend: Blend::Density,
            },
        ),
        (
            "mdwt-ndda-max",
            base.clone(),
            Integrator::Mdwt {
                dda: DdaMode::NDda,
                blend: Blend::Max,
            },
        ),
        (
            "marcher-f32",
            base,
            Integrator::Marcher(RayMarcher::default()),
        ),
    ];
    let mut g = c.benchmark_group("tracking_small");
    g.sample_size(10);
    for (name, s, integ) in cases {
        let mut set = RenderSettings::default_for(&s, 32, 32, false);
        set.spp = 4;
        let gs = tracker.upload(s.clone()).unwrap();
        g.bench_function(format!("cpu/{name}"), |b| {
            b.iter(|| render(&s, &integ, &set).unwrap());
        });
        g.bench_function(format!("gpu/{name}"), |b| {
            b.iter(|| tracker.render(&gs, &integ, &set).unwrap());
        });
    }
    g.finish();
}

fn paper(c: &mut Criterion) {
    let Ok(ctx) = GpuContext::shared() else {
        return;
    };
    if !ctx.is_hardware() {
        eprintln!(
            "SKIP tracking_paper: {} is a software adapter; the 2560x1440, 512^3 x 4 group \
             needs a hardware GPU",
            ctx.info().name
        );
        return;
    }
    let tracker = GpuTracker::new(ctx).unwrap();
    let mut g = c.benchmark_group("tracking_paper");
    g.sample_size(10);
    let integ = Integrator::Mdwt {
        dda: DdaMode::OneDda,
        blend: Blend::Density,
    };
    let s = scene(512, 4, 2.0 / 512.0);
    let mut set = RenderSettings::default_for(&s, 2560, 1440, false);
    set.spp = 1;
    for (name, l) in [("no-shadows", None), ("shadows", light())] {
        let mut s2 = s.clone();
        s2.light = l;
        match tracker.upload(s2) {
            Ok(gs) => {
                g.bench_function(format!("mdwt-1dda-512x4-2560x1440/{name}"), |b| {
                    b.iter(|| tracker.render(&gs, &integ, &set).unwrap());
                });
            }
            Err(e) => eprintln!("SKIP {name}: {e}"),
        }
    }
    for channels in 1..=12 {
        let s = scene(256, channels, 2.0 / 256.0);
        let mut set = RenderSettings::default_for(&s, 2560, 1440, false);
        set.spp = 1;
        if let Ok(gs) = tracker.upload(s) {
            g.bench_function(format!("mdwt-1dda-256-channels/{channels}"), |b| {
                b.iter(|| tracker.render(&gs, &integ, &set).unwrap());
            });
        }
    }
    g.finish();
}

fn pool(c: &mut Criterion) {
    use blueshift_volume::ooc::{self, BrickLayout, BrickedFile, GridSource};
    use blueshift_volume::{BrickCache, Field};
    let ctx = match GpuContext::shared() {
        Ok(c) => c,
        Err(e) => {
            eprintln!("SKIP: no wgpu adapter: {e}");
            return;
        }
    };
    let tracker = GpuTracker::new(ctx).unwrap();
    let n = 96;
    let full = scene(n, 2, 4.0 / n as f32);
    let dir = tempfile::tempdir().unwrap();
    let cache = BrickCache::new(1 << 28);
    let mut triples = Vec::new();
    for (i, ch) in full.channels().iter().enumerate() {
        let Some(AnyGrid::F32(g)) = ch.grid().as_dense() else {
            unreachable!("f32 channels")
        };
        let p = dir.path().join(format!("c{i}.bsv"));
        ooc::convert(
            &mut GridSource(g),
            &p,
            "c",
            BrickLayout::default(),
            &mut |_, _| {},
        )
        .unwrap();
        let f = BrickedFile::open_with_cache(&p, cache.clone()).unwrap();
        triples.push((
            format!("c{i}"),
            Field::from(f.field(0).unwrap()),
            ch.transfer_function().clone(),
        ));
    }
    let bsv = Scene::new(triples, 4.0 / n as f32, 4).unwrap();
    // Zero but for a blob inside one pool brick.
    let sparse_grid = Grid::from_fn(Geometry::unit([n, n, n]), |x, y, z| {
        let d = Vec3::new(x as f32 - 48.0, y as f32 - 48.0, z as f32 - 48.0).length();
        if d < 12.0 { 1.0 - d / 12.0 } else { 0.0 }
    })
    .unwrap();
    let sparse = Scene::new(
        vec![(
            "blob".to_owned(),
            AnyGrid::F32(sparse_grid),
            tf([1.0, 0.5, 0.2], &[(0.0, 0.0), (1.0, 0.8)]),
        )],
        4.0 / n as f32,
        4,
    )
    .unwrap();
    let one = Scene::new(
        vec![(
            "c0".to_owned(),
            full.channels()[0].grid().clone(),
            full.channels()[0].transfer_function().clone(),
        )],
        4.0 / n as f32,
        4,
    )
    .unwrap();
    let mut g = c.benchmark_group("pool");
    g.sample_size(10);
    tracker.upload(bsv.clone()).unwrap(); // warms the brick cache
    g.bench_function("upload/dense", |b| {
        b.iter(|| tracker.upload(full.clone()).unwrap());
    });
    g.bench_function("upload/bsv", |b| {
        b.iter(|| tracker.upload(bsv.clone()).unwrap());
    });
    let integ = Integrator::Mdwt {
        dda: DdaMode::OneDda,
        blend: Blend::Density,
    };
    for (name, s) in [("full", one), ("sparse", sparse)] {
        let mut set = RenderSettings::default_for(&s, 64, 64, false);
        set.spp = 4;
        let gs = tracker.upload(s).unwrap();
        g.bench_function(format!("render/{name}"), |b| {
            b.iter(|| tracker.render(&gs, &integ, &set).unwrap());
        });
    }
    g.finish();
}

criterion_group!(benches, small, pool, paper);
criterion_main!(benches);
