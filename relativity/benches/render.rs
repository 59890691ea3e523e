//! Frame rendering cost per effect set from a 6 x 1024^2 cube map (the workload),
//! at 1920x1080 and, for quicker runs, 480x270 (1/16 of the pixels).

use std::hint::black_box;

use blueshift_relativity::{
    Camera, Checker, CubeMap, DopplerColourTable, Effects, Environment, Velocity, render,
};
use criterion::{Criterion, criterion_group, criterion_main};
use glam::DVec3;

fn cube(size: u32) -> Environment {
    let src = Environment::Checker(Checker::default());
    let faces: CubeMap = src.to_cube(size).expect("valid size");
    Environment::Cube(faces)
}

fn bench(c: &mut Criterion) {
    let env = cube(1024);
    let _ = DopplerColourTable::global();
    let v = Velocity::new(DVec3::new(0.2, 0.0, -0.85)).expect("|beta| < 1");
    let sets = [
        ("aberration", Effects::ABERRATION),
        (
            "aberration+doppler",
            Effects {
                doppler: true,
                ..Effects::ABERRATION
            },
        ),
        ("aberration+doppler+searchlight", Effects::ALL),
    ];
    let mut g = c.benchmark_group("frame");
    g.sample_size(10);
    for (w, h) in [(480_u32, 270_u32), (1920, 1080)] {
        let cam = Camera {
            width: w,
            height: h,
            ..Camera::default()
        };
        for (name, fx) in sets {
            g.bench_function(format!("{name}/{w}x{h}"), |b| {
                b.iter(|| render(black_box(&env), &cam, v, fx, None).expect("renders"));
            });
        }
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
