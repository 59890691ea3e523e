//! Tracking extras: frame time of the summed-majorant MDWT variant against 1-DDA and N-DDA
//! over channel counts (MDWT Fig. 9 with the third method added) and macrocell sizes
//! (Fig. 8), and the cost of gradient shading on and off.
//!
//! Before criterion runs, a quick single-threaded sweep prints each time as a ratio to the
//! 1-DDA time measured in the same run (set `BLUESHIFT_SKIP_TABLES` to skip it).
//!
//! Group `woodcock_threads`: Woodcock on one channel of `channels12(64)` (the Mitsuba
//! comparison's density, 48 x 48, 256 spp) on pools of 1 and 2 threads, with an observer
//! that needs every pass (`every_pass`: one parallel loop and one noise estimate per pass,
//! the loop before sweeps) and with a progress-bar observer (`sweeps`: up to 64 passes per
//! parallel loop). The 1 / 2 thread ratio of each is its scaling.

use std::hint::black_box;
use std::time::Instant;

use blueshift_benches::channel_scene;
use blueshift_camera::Observer;
use blueshift_tracking::{
    Blend, DdaMode, DirectionalLight, Integrator, Progressive, RenderSettings, Scene, Shading,
    TrackingSession, render,
};
use criterion::{BenchmarkId, Criterion};
use glam::Vec3;

const RES: usize = 48;
const SIZE: u32 = 40;
const DENSITY: f32 = 20.0;

fn settings(scene: &Scene) -> RenderSettings {
    let mut s = RenderSettings::default_for(scene, SIZE, SIZE, true);
    s.seed = 5;
    s
}

fn mdwt(dda: DdaMode) -> Integrator {
    Integrator::Mdwt {
        dda,
        blend: Blend::Density,
    }
}

const MODES: [(&str, DdaMode); 3] = [
    ("1dda", DdaMode::OneDda),
    ("ndda", DdaMode::NDda),
    ("summed", DdaMode::Summed),
];

fn shaded(mut scene: Scene) -> Scene {
    scene.light = Some(DirectionalLight {
        direction: Vec3::new(1.0, 1.0, -1.0),
        radiance: [1.0; 3],
        ambient: 0.2,
    });
    scene.shading = Some(Shading {
        materials: Vec::new(),
        shadows: false,
    });
    scene
}

/// Fastest of `reps` single-threaded renders, seconds (the least disturbed by other load).
fn time_render(scene: &Scene, integ: &Integrator, reps: usize) -> f64 {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("pool");
    let s = settings(scene);
    let mut t: Vec<f64> = (0..reps)
        .map(|_| {
            let start = Instant::now();
            pool.install(|| black_box(render(scene, integ, &s).expect("render")));
            start.elapsed().as_secs_f64()
        })
        .collect();
    t.sort_by(f64::total_cmp);
    t[0]
}

fn sweep() {
    println!("channels,k,ndda/1dda,summed/1dda");
    for n in [1usize, 2, 4, 8, 12] {
        for k in [2usize, 4, 8] {
            let scene = channel_scene(n, RES, k, DENSITY).expect("scene");
            let t: Vec<f64> = MODES
                .iter()
                .map(|(_, m)| time_render(&scene, &mdwt(*m), 7))
                .collect();
            println!("{n},{k},{:.3},{:.3}", t[1] / t[0], t[2] / t[0]);
        }
    }
    println!("channels,method,shaded/unshaded");
    for n in [1usize, 4] {
        let scene = channel_scene(n, RES, 4, DENSITY).expect("scene");
        let lit = shaded(scene.clone());
        for (name, m) in MODES {
            let a = time_render(&scene, &mdwt(m), 7);
            let b = time_render(&lit, &mdwt(m), 7);
            println!("{n},{name},{:.3}", b / a);
        }
    }
}

fn main() {
    if std::env::var_os("BLUESHIFT_SKIP_TABLES").is_none() {
        sweep();
    }
    let mut c = Criterion::default().configure_from_args();
    let mut g = c.benchmark_group("traversal_by_channels");
    g.sample_size(10);
    for n in [1usize, 4, 12] {
        let scene = channel_scene(n, RES, 4, DENSITY).expect("scene");
        let s = settings(&scene);
        for (name, m) in MODES {
            g.bench_with_input(BenchmarkId::new(name, n), &n, |b, _| {
                b.iter(|| render(&scene, &mdwt(m), &s).expect("render"));
            });
        }
    }
    g.finish();
    let mut g = c.benchmark_group("shading");
    g.sample_size(10);
    let scene = channel_scene(4, RES, 4, DENSITY).expect("scene");
    let lit = shaded(scene.clone());
    let s = settings(&scene);
    for (label, sc) in [("off", &scene), ("on", &lit)] {
        g.bench_function(label, |b| {
            b.iter(|| render(sc, &mdwt(DdaMode::OneDda), &s).expect("render"));
        });
    }
    g.finish();
    woodcock_threads(&mut c);
    c.final_summary();
}

/// Needs every pass (the default).
struct EveryPass;
impl Observer<Progressive> for EveryPass {}

/// A progress bar: passes may run in sweeps.
struct Sweeps;
impl Observer<Progressive> for Sweeps {
    fn every_pass(&self) -> bool {
        false
    }
}

fn woodcock_threads(c: &mut Criterion) {
    let scene = channel_scene(1, 64, 4, DENSITY).expect("scene");
    let mut s = RenderSettings::default_for(&scene, 48, 48, true);
    s.spp = 256;
    s.seed = 5;
    let session =
        TrackingSession::new(scene, Integrator::Woodcock { channel: 0 }, s).expect("session");
    let mut g = c.benchmark_group("woodcock_threads");
    g.sample_size(10);
    for threads in [1, 2] {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("pool");
        g.bench_function(format!("every_pass/threads_{threads}"), |b| {
            b.iter(|| pool.install(|| session.render(&EveryPass).expect("render")));
        });
        g.bench_function(format!("sweeps/threads_{threads}"), |b| {
            b.iter(|| pool.install(|| session.render(&Sweeps).expect("render")));
        });
    }
    g.finish();
}
