//! MDWT paper reproductions on the CPU: Fig. 8 (render time against macrocell size),
//! Fig. 9 (render time against channel count for N-DDA, 1-DDA and the marcher) and
//! Table 1 (memory of macrocell and majorant grids against the data).
//!
//! Besides criterion's own reports, a quick single-threaded sweep is written as CSV to
//! `target/blueshift-benches/` (`fig8_macrocell.csv`, `fig9_channels.csv`,
//! `table1_memory.csv`), with each time also given as a ratio to the sweep's baseline
//! measured in the same run, and samples (pixel samples) per second per core.

use std::fmt::Write as _;
use std::hint::black_box;
use std::time::Instant;

use blueshift_benches::{Curve, channel_scene, line_plot, memory_table, out_dir};
use blueshift_tracking::{Blend, DdaMode, Integrator, RayMarcher, RenderSettings, Scene, render};
use criterion::{BenchmarkId, Criterion};

const RES: usize = 64;
const SIZE: u32 = 48;
const DENSITY: f32 = 20.0;

fn settings(scene: &Scene) -> RenderSettings {
    let mut s = RenderSettings::default_for(scene, SIZE, SIZE, true);
    s.seed = 5;
    s
}

fn methods() -> [(&'static str, Integrator); 3] {
    [
        (
            "ndda",
            Integrator::Mdwt {
                dda: DdaMode::NDda,
                blend: Blend::Density,
            },
        ),
        (
            "1dda",
            Integrator::Mdwt {
                dda: DdaMode::OneDda,
                blend: Blend::Density,
            },
        ),
        ("marcher", Integrator::Marcher(RayMarcher::default())),
    ]
}

/// Median seconds of `reps` single-threaded renders.
fn time_render(scene: &Scene, integ: &Integrator, s: &RenderSettings, reps: usize) -> f64 {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("pool");
    let mut t: Vec<f64> = (0..reps)
        .map(|_| {
            let start = Instant::now();
            pool.install(|| black_box(render(scene, integ, s).expect("render")));
            start.elapsed().as_secs_f64()
        })
        .collect();
    t.sort_by(f64::total_cmp);
    t[reps / 2]
}

fn write_tables() {
    let dir = out_dir();
    let px = f64::from(SIZE * SIZE);
    // Fig. 8: macrocell edge k = 1, 2, 4, 8 -> 1, 8, 64, 512 cells per macrocell.
    let mut csv =
        String::from("cells_per_macrocell,k,seconds,ratio_to_k1,samples_per_s_per_core\n");
    let mut base = 0.0;
    let mut fig8 = Curve {
        label: "1-DDA, 4 channels".into(),
        points: Vec::new(),
        rgb: (40, 120, 200),
    };
    for k in [1usize, 2, 4, 8] {
        let scene = channel_scene(4, RES, k, DENSITY).expect("scene");
        let s = settings(&scene);
        let t = time_render(&scene, &methods()[1].1, &s, 5);
        if k == 1 {
            base = t;
        }
        let _ = writeln!(
            csv,
            "{},{k},{t:.6},{:.3},{:.0}",
            k * k * k,
            t / base,
            px / t
        );
        fig8.points.push((k as f64, t / base));
    }
    let _ = std::fs::write(dir.join("fig8_macrocell.csv"), &csv);
    if let Err(e) = line_plot(
        &dir.join("fig8_macrocell.png"),
        "MDWT Fig. 8 (CPU, 1 thread): time vs macrocell edge k",
        "macrocell edge k (k^3 cells per macrocell)",
        "time / time with k = 1",
        &[fig8],
    ) {
        eprintln!("fig8 plot: {e}");
    }
    eprintln!("fig8 (1-DDA, 4 channels):\n{csv}");
    // Fig. 9: channel count.
    let mut csv =
        String::from("channels,method,seconds,ratio_to_1_channel,samples_per_s_per_core\n");
    let mut mem = String::from(
        "channels,data_bytes,macrocell_bytes,majorant_bytes,macrocell_ratio,majorant_ratio\n",
    );
    let mut base = [0.0f64; 3];
    let mut curves: Vec<Curve> = methods()
        .iter()
        .zip([(200, 60, 40), (40, 120, 200), (60, 160, 60)])
        .map(|((name, _), rgb)| Curve {
            label: (*name).to_string(),
            points: Vec::new(),
            rgb,
        })
        .collect();
    for n in 1..=12usize {
        let scene = channel_scene(n, RES, 4, DENSITY).expect("scene");
        let s = settings(&scene);
        for (i, (name, integ)) in methods().iter().enumerate() {
            let t = time_render(&scene, integ, &s, 3);
            if n == 1 {
                base[i] = t;
            }
            let _ = writeln!(csv, "{n},{name},{t:.6},{:.3},{:.0}", t / base[i], px / t);
            curves[i].points.push((n as f64, t / base[i]));
        }
        let (c, d, m, j) = memory_table(&scene);
        let _ = writeln!(
            mem,
            "{c},{d},{m},{j},{:.4},{:.4}",
            m as f64 / d as f64,
            j as f64 / d as f64
        );
    }
    let _ = std::fs::write(dir.join("fig9_channels.csv"), &csv);
    if let Err(e) = line_plot(
        &dir.join("fig9_channels.png"),
        "MDWT Fig. 9 (CPU, 1 thread): time vs channels",
        "channels",
        "time / time with 1 channel",
        &curves,
    ) {
        eprintln!("fig9 plot: {e}");
    }
    let _ = std::fs::write(dir.join("table1_memory.csv"), &mem);
    eprintln!("fig9:\n{csv}\ntable1:\n{mem}\nwritten to {}", dir.display());
}

fn fig8(c: &mut Criterion) {
    let mut g = c.benchmark_group("fig8_macrocell");
    g.sample_size(10);
    for k in [1usize, 2, 4, 8] {
        let scene = channel_scene(4, RES, k, DENSITY).expect("scene");
        let s = settings(&scene);
        let integ = &methods()[1].1;
        g.bench_with_input(BenchmarkId::new("1dda_cells", k * k * k), &k, |b, _| {
            b.iter(|| render(&scene, integ, &s).expect("render"));
        });
    }
    g.finish();
}

fn fig9(c: &mut Criterion) {
    let mut g = c.benchmark_group("fig9_channels");
    g.sample_size(10);
    for n in [1usize, 4, 12] {
        let scene = channel_scene(n, RES, 4, DENSITY).expect("scene");
        let s = settings(&scene);
        for (name, integ) in methods() {
            g.bench_with_input(BenchmarkId::new(name, n), &n, |b, _| {
                b.iter(|| render(&scene, &integ, &s).expect("render"));
            });
        }
    }
    g.finish();
}

fn main() {
    if std::env::var_os("BLUESHIFT_SKIP_TABLES").is_none() {
        write_tables();
    }
    let mut c = Criterion::default().configure_from_args();
    fig8(&mut c);
    fig9(&mut c);
    c.final_summary();
}
