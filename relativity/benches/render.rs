//! Frame rendering cost per effect set from a 6 x 1024^2 cube map and from a 4096 x 2048
//! equirectangular map (the workloads), at 1920x1080 and, for quicker runs, 480x270
//! (1/16 of the pixels).
//!
//! Group `equirect_vs_exact`: [`render`] against `exact_render` below, the same loop with
//! the exact per-pixel formulas it replaced (libm `atan2`/`acos` through
//! [`EquirectMap::sample`], `K(D)` through the `ln D` table, [`DopplerColourTable::apply`]),
//! measured in the same run: the ratio of the two is the speed-up of the table,
//! polynomial and vectorised-lanes path. `render` runs for each effect set (none,
//! aberration, + Doppler, + searchlight), `exact` for the first and the last; the issue's
//! goal is 30 frames per second (33 ms) for all effects at 1920x1080 on 2 cores.

use std::hint::black_box;

use blueshift_relativity::{
    Camera, CameraFrame, Checker, CubeMap, DopplerColourTable, Effects, Environment, Velocity,
    render, searchlight_integrated,
};
use criterion::{Criterion, criterion_group, criterion_main};
use glam::DVec3;
use image::Rgb32FImage;
use rayon::prelude::*;

fn cube(size: u32) -> Environment {
    let src = Environment::Checker(Checker::default());
    let faces: CubeMap = src.to_cube(size).expect("valid size");
    Environment::Cube(faces)
}

/// The renderer before the tables: exact `atan2`/`acos` lookups and the `ln D` colour table.
fn exact_render(env: &Environment, cam: &Camera, v: Velocity, fx: Effects) -> Rgb32FImage {
    let frame = CameraFrame::new(cam).expect("camera");
    let table = DopplerColourTable::global();
    let (w, h) = (cam.width, cam.height);
    let mut buf = vec![0.0_f32; w as usize * h as usize * 3];
    buf.par_chunks_mut(w as usize * 3)
        .enumerate()
        .for_each(|(y, row)| {
            for x in 0..w as usize {
                let d_obs = frame.pixel_direction(x as f64, y as f64);
                let d_scene = if fx.aberration {
                    v.observer_to_scene(d_obs)
                } else {
                    d_obs
                };
                let mut rgb = env.sample(d_scene);
                if fx.doppler || fx.searchlight {
                    let dop = v.doppler_factor_observer(d_obs);
                    if fx.doppler {
                        rgb = table.apply(dop, rgb);
                    }
                    if fx.searchlight {
                        let f = searchlight_integrated(dop) as f32;
                        rgb = rgb.map(|c| c * f);
                    }
                }
                row[3 * x..3 * x + 3].copy_from_slice(&rgb);
            }
        });
    Rgb32FImage::from_raw(w, h, buf).expect("size")
}

fn bench(c: &mut Criterion) {
    let _ = DopplerColourTable::global();
    let v = Velocity::new(DVec3::new(0.2, 0.0, -0.85)).expect("|beta| < 1");
    let none = Effects::default();
    let sets = [
        ("none", none),
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
    let equirect = Environment::Equirect(
        Environment::Checker(Checker::default())
            .to_equirect(4096, 2048)
            .expect("valid size"),
    );
    let mut g = c.benchmark_group("equirect_vs_exact");
    g.sample_size(10);
    for (w, h) in [(480_u32, 270_u32), (1920, 1080)] {
        let cam = Camera {
            width: w,
            height: h,
            ..Camera::default()
        };
        for (name, fx) in sets {
            if name == "none" || name.ends_with("searchlight") {
                g.bench_function(format!("exact/{name}/{w}x{h}"), |b| {
                    b.iter(|| exact_render(black_box(&equirect), &cam, v, fx));
                });
            }
            g.bench_function(format!("render/{name}/{w}x{h}"), |b| {
                b.iter(|| render(black_box(&equirect), &cam, v, fx, None).expect("renders"));
            });
        }
    }
    g.finish();

    let env = cube(1024);
    let mut g = c.benchmark_group("frame");
    g.sample_size(10);
    for (w, h) in [(480_u32, 270_u32), (1920, 1080)] {
        let cam = Camera {
            width: w,
            height: h,
            ..Camera::default()
        };
        for (name, fx) in &sets[1..] {
            g.bench_function(format!("{name}/{w}x{h}"), |b| {
                b.iter(|| render(black_box(&env), &cam, v, *fx, None).expect("renders"));
            });
        }
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
