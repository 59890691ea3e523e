//! Re-rendering after an edit against building a fresh session (the engine API's promise:
//! a session rebuilds only what an edit touches).
//!
//! - `tracking_tf_edit`: 4 channels of `synth::channels12(128)` with 1-DDA MDWT, a 48 x 48
//!   one-sample preview (the viewer's first frame after an edit). `fresh` builds the scene
//!   from the loaded channels (macrocells and majorant grids of every channel) and the
//!   session, then renders;
//!   `tf_edit` changes one channel's transfer function on a kept session (only that
//!   channel's majorant grid is rebuilt), then renders.
//! - `doppler_factor_edit`: the galaxy (`synth::galaxy(64)`, black body + H I, absorption
//!   on), piecewise-linear, a 32 x 32 preview. `fresh` builds the Doppler scene from the
//!   volume and the session (validation, CMF and black-body tables, broadening tables),
//!   then renders; `factor_edit` changes the velocity factor on a kept session (which
//!   reuses its last render's samples before the factors), then renders. The table also
//!   has the emission-only case (absorption factor 0: the closed-form image path).
//!
//! Besides criterion's groups, a single-threaded comparison is written to
//! `target/blueshift-benches/sessions.csv` with each edit's median time as a ratio to the
//! fresh session's measured in the same run, both with the render and for the building /
//! rebuilding alone (`BLUESHIFT_SKIP_TABLES=1` skips it).

use std::fmt::Write as _;
use std::hint::black_box;
use std::time::Instant;

use blueshift_benches::{channel_scene, out_dir, ramp_tf};
use blueshift_camera::Silent;
use blueshift_doppler::{DopplerScene, DopplerSession, DopplerSettings};
use blueshift_tfedit::TransferFunction;
use blueshift_tracking::{Blend, DdaMode, Integrator, RenderSettings, Scene, TrackingSession};
use blueshift_volume::{Field, Volume, synth};
use criterion::Criterion;

const RES: usize = 128;
const SIZE: u32 = 48;
const DOPPLER_RES: usize = 64;
const DOPPLER_SIZE: u32 = 32;

fn integrator() -> Integrator {
    Integrator::Mdwt {
        dda: DdaMode::OneDda,
        blend: Blend::Density,
    }
}

/// The channels of the tracking scene (made once: the data a session is built from).
fn tracking_channels() -> Vec<(String, Field, TransferFunction)> {
    channel_scene(4, RES, 8, 20.0)
        .expect("scene")
        .channels()
        .iter()
        .map(|c| {
            (
                c.name().to_owned(),
                c.grid().clone(),
                c.transfer_function().clone(),
            )
        })
        .collect()
}

/// A fresh session: macrocells and majorant grids of every channel, then the session.
fn fresh_tracking(channels: &[(String, Field, TransferFunction)]) -> TrackingSession {
    let scene = Scene::new(channels.to_vec(), 20.0, 8).expect("scene");
    let mut s = RenderSettings::default_for(&scene, SIZE, SIZE, true);
    s.seed = 3;
    TrackingSession::new(scene, integrator(), s).expect("session")
}

fn doppler_scene(vol: &Volume, absorption: f64) -> DopplerScene {
    let mut scene = DopplerScene::from_volume(vol, &["bb", "H"]).expect("doppler scene");
    scene.factors.absorption = absorption;
    scene
}

fn fresh_doppler(vol: &Volume) -> DopplerSession {
    fresh_doppler_with(vol, 1.0)
}

fn fresh_doppler_with(vol: &Volume, absorption: f64) -> DopplerSession {
    let scene = doppler_scene(vol, absorption);
    let st = DopplerSettings::default_for(&scene, DOPPLER_SIZE, DOPPLER_SIZE);
    DopplerSession::new(scene, st).expect("doppler session")
}

/// Two transfer functions to alternate between (so every edit changes the majorants).
fn tfs() -> [TransferFunction; 2] {
    [
        ramp_tf([1.0, 0.5, 0.2]).expect("tf"),
        ramp_tf([0.2, 0.5, 1.0])
            .expect("tf")
            .with_alpha_g(0.5)
            .expect("alpha_g"),
    ]
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Threads of the comparison table (`BLUESHIFT_BENCH_THREADS`, default 1).
fn pool() -> rayon::ThreadPool {
    let n = std::env::var("BLUESHIFT_BENCH_THREADS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(1);
    rayon::ThreadPoolBuilder::new()
        .num_threads(n)
        .build()
        .expect("pool")
}

fn seconds(f: &mut dyn FnMut()) -> f64 {
    let t = Instant::now();
    f();
    t.elapsed().as_secs_f64()
}

/// Median seconds of `reps` runs of `a` and of `b`, run alternately (so a drift in the
/// machine's speed hits both alike).
fn pair(reps: usize, a: &mut dyn FnMut(), b: &mut dyn FnMut()) -> (f64, f64) {
    let (mut ta, mut tb) = (Vec::new(), Vec::new());
    for _ in 0..reps {
        ta.push(seconds(a));
        tb.push(seconds(b));
    }
    (median(ta), median(tb))
}

fn table() {
    if std::env::var_os("BLUESHIFT_SKIP_TABLES").is_some() {
        return;
    }
    let pool = pool();
    let tf = tfs();
    let chans = tracking_channels();
    let vol = synth::galaxy(DOPPLER_RES, 1).expect("galaxy");
    let rows = pool.install(|| {
        let mut session = fresh_tracking(&chans);
        let mut k = 0;
        let mut tf_edit = |s: &mut TrackingSession| {
            k += 1;
            s.set_transfer_function(0, tf[k % 2].clone())
                .expect("tf edit");
        };
        let (t_fresh, t_edit) = pair(
            7,
            &mut || {
                black_box(fresh_tracking(&chans).render(&Silent).expect("render"));
            },
            &mut || {
                tf_edit(&mut session);
                black_box(session.render(&Silent).expect("render"));
            },
        );
        let (t_build, t_rebuild) = pair(
            7,
            &mut || {
                black_box(fresh_tracking(&chans));
            },
            &mut || tf_edit(&mut session),
        );
        let doppler = |absorption: f64| {
            let mut ds = fresh_doppler_with(&vol, absorption);
            ds.render(&Silent).expect("render");
            let mut j = 0;
            let mut factor_edit = |ds: &mut DopplerSession| {
                j += 1;
                let mut f = ds.scene().factors;
                f.velocity = if j % 2 == 0 { 1.0 } else { 2.0 };
                ds.set_factors(f).expect("factor edit");
            };
            let (fresh, edit) = pair(
                7,
                &mut || {
                    black_box(
                        fresh_doppler_with(&vol, absorption)
                            .render(&Silent)
                            .expect("render"),
                    );
                },
                &mut || {
                    factor_edit(&mut ds);
                    black_box(ds.render(&Silent).expect("render"));
                },
            );
            let (build, rebuild) = pair(
                7,
                &mut || {
                    black_box(fresh_doppler_with(&vol, absorption));
                },
                &mut || factor_edit(&mut ds),
            );
            (fresh, edit, build, rebuild)
        };
        let (d_fresh, d_edit, d_build, d_rebuild) = doppler(1.0);
        let (e_fresh, e_edit, e_build, e_rebuild) = doppler(0.0);
        [
            ("tracking_tf_edit", t_fresh, t_edit, t_build, t_rebuild),
            ("doppler_factor_edit", d_fresh, d_edit, d_build, d_rebuild),
            (
                "doppler_factor_edit_emission_only",
                e_fresh,
                e_edit,
                e_build,
                e_rebuild,
            ),
        ]
    });
    let mut csv =
        String::from("case,fresh_s,edit_s,speedup,fresh_build_s,edit_rebuild_s,rebuild_speedup\n");
    for (name, a, b, c, d) in rows {
        let _ = writeln!(
            csv,
            "{name},{a:.6},{b:.6},{:.2},{c:.6},{d:.3e},{:.1}",
            a / b,
            c / d
        );
        eprintln!(
            "{name}: fresh {a:.4} s, after edit {b:.4} s ({:.2}x); building {c:.5} s, \
             rebuilding after the edit {d:.3e} s ({:.1}x)",
            a / b,
            c / d
        );
    }
    let path = out_dir().join("sessions.csv");
    if let Err(e) = std::fs::write(&path, csv) {
        eprintln!("cannot write {}: {e}", path.display());
    }
}

fn criterion_groups(c: &mut Criterion) {
    let tf = tfs();
    let chans = tracking_channels();
    let mut g = c.benchmark_group("tracking_tf_edit");
    g.sample_size(10);
    g.bench_function("fresh", |b| {
        b.iter(|| black_box(fresh_tracking(&chans).render(&Silent).expect("render")));
    });
    let mut session = fresh_tracking(&chans);
    let mut k = 0;
    g.bench_function("tf_edit", |b| {
        b.iter(|| {
            k += 1;
            session
                .set_transfer_function(0, tf[k % 2].clone())
                .expect("tf edit");
            black_box(session.render(&Silent).expect("render"))
        });
    });
    g.finish();

    let vol = synth::galaxy(DOPPLER_RES, 1).expect("galaxy");
    let mut g = c.benchmark_group("doppler_factor_edit");
    g.sample_size(10);
    g.bench_function("fresh", |b| {
        b.iter(|| black_box(fresh_doppler(&vol).render(&Silent).expect("render")));
    });
    let mut ds = fresh_doppler(&vol);
    let mut j = 0;
    g.bench_function("factor_edit", |b| {
        b.iter(|| {
            j += 1;
            let mut f = ds.scene().factors;
            f.velocity = if j % 2 == 0 { 1.0 } else { 2.0 };
            ds.set_factors(f).expect("factor edit");
            black_box(ds.render(&Silent).expect("render"))
        });
    });
    g.finish();
}

fn main() {
    table();
    let mut c = Criterion::default().configure_from_args();
    criterion_groups(&mut c);
    c.final_summary();
}
