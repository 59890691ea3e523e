//! The engine API: a session equals the one-call render and a fresh session after an edit,
//! observes passes, stops on a noise target or a cancel, and keeps heat maps and the timing
//! protocol in its settings.

mod common;

use std::sync::Mutex;
use std::sync::atomic::{AtomicU32, Ordering};

use blueshift_camera::{CancelToken, Observer, OnProgress, Progress, Session, Silent};
use blueshift_tfedit::TransferFunction;
use blueshift_tracking::{
    Blend, DdaMode, Error, HeatMap, Integrator, Progressive, RenderSettings, Scene,
    TrackingSession, render, render_timed,
};
use blueshift_volume::synth;
use common::*;

fn tfs(k: f32) -> Vec<TransferFunction> {
    [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
        .iter()
        .map(|&c| tf(c, &[(0.0, 0.0), (1.0, k)]))
        .collect()
}

fn scene(k: f32) -> Scene {
    Scene::from_volume(&synth::three_cubes(20).unwrap(), tfs(k), 6.0, 4).unwrap()
}

fn mdwt() -> Integrator {
    Integrator::Mdwt {
        dda: DdaMode::OneDda,
        blend: Blend::Density,
    }
}

fn settings(s: &Scene) -> RenderSettings {
    let mut st = RenderSettings::default_for(s, 20, 14, false);
    st.spp = 3;
    st.seed = 11;
    st
}

#[test]
fn a_session_renders_the_same_bytes_as_render() {
    let sc = scene(1.0);
    let st = settings(&sc);
    let expected = render(&sc, &mdwt(), &st).unwrap();
    let mut session = TrackingSession::new(sc, mdwt(), st).unwrap();
    let out = session.run(&Silent).unwrap();
    assert_eq!(out.image.mean_image().as_raw(), expected.as_raw());
    assert!(out.frame_times.is_none());
    // Running again gives the same image (the session keeps no state between runs).
    assert_eq!(
        session.run(&Silent).unwrap().image.mean_image().as_raw(),
        expected.as_raw()
    );
}

#[test]
fn a_transfer_function_edit_equals_a_fresh_session_with_that_function() {
    let sc = scene(1.0);
    let st = settings(&sc);
    let mut edited = TrackingSession::new(sc, mdwt(), st.clone()).unwrap();
    let new_tf = tf([0.9, 0.9, 0.2], &[(0.0, 0.0), (0.5, 0.2), (1.0, 0.9)]);
    edited.set_transfer_function(1, new_tf.clone()).unwrap();
    let mut fresh_tfs = tfs(1.0);
    fresh_tfs[1] = new_tf;
    let fresh_scene =
        Scene::from_volume(&synth::three_cubes(20).unwrap(), fresh_tfs, 6.0, 4).unwrap();
    // The edit rebuilt exactly the fresh scene's majorants.
    for (a, b) in edited.scene().channels().iter().zip(fresh_scene.channels()) {
        assert_eq!(a.majorant().values(), b.majorant().values());
    }
    let fresh = TrackingSession::new(fresh_scene, mdwt(), st).unwrap();
    assert_eq!(
        edited.render(&Silent).unwrap().image.mean_image().as_raw(),
        fresh.render(&Silent).unwrap().image.mean_image().as_raw()
    );
    // A bad channel is refused and leaves the session as it was.
    assert!(matches!(
        edited.set_transfer_function(7, tf([1.0; 3], &[(0.0, 0.0), (1.0, 1.0)])),
        Err(Error::Parameter(_))
    ));
}

#[test]
fn a_camera_edit_equals_a_fresh_session_with_that_camera() {
    let sc = scene(1.0);
    let st = settings(&sc);
    let mut cam = st.camera;
    cam.eye += glam::Vec3::new(0.3, -0.2, 0.0);
    let mut moved = st.clone();
    moved.camera = cam;
    let expected = render(&sc, &mdwt(), &moved).unwrap();
    let mut session = TrackingSession::new(sc, mdwt(), st).unwrap();
    session.set_camera(cam).unwrap();
    assert_eq!(
        session.render(&Silent).unwrap().image.mean_image().as_raw(),
        expected.as_raw()
    );
    let mut bad = cam;
    bad.target = bad.eye;
    assert!(session.set_camera(bad).is_err());
    assert_eq!(session.settings().camera, cam);
}

/// Records every event.
#[derive(Default)]
struct Recorder {
    progress: Mutex<Vec<Progress>>,
    passes: Mutex<Vec<(u32, u32, Option<f64>)>>,
    cancel_after: Option<u32>,
    seen: AtomicU32,
}

impl Observer<Progressive> for Recorder {
    fn progress(&self, p: Progress) {
        self.progress.lock().unwrap().push(p);
    }
    fn pass(&self, pass: u32, image: &Progressive, noise: Option<f64>) {
        self.seen.fetch_add(1, Ordering::Relaxed);
        self.passes
            .lock()
            .unwrap()
            .push((pass, image.samples(), noise));
    }
    fn cancelled(&self) -> bool {
        self.cancel_after
            .is_some_and(|n| self.seen.load(Ordering::Relaxed) >= n)
    }
}

#[test]
fn the_observer_sees_every_pass_and_can_cancel() {
    let sc = scene(1.0);
    let mut st = settings(&sc);
    st.spp = 4;
    let session = TrackingSession::new(sc, mdwt(), st).unwrap();
    let rec = Recorder::default();
    let out = session.render(&rec).unwrap();
    let passes = rec.passes.lock().unwrap().clone();
    assert_eq!(
        passes.iter().map(|p| (p.0, p.1)).collect::<Vec<_>>(),
        vec![(1, 1), (2, 2), (3, 3), (4, 4)]
    );
    // No noise estimate from one sample; the last one is the result's.
    assert_eq!(passes[0].2, None);
    assert_eq!(passes[3].2, Some(out.image.noise()));
    let prog = rec.progress.lock().unwrap().clone();
    assert_eq!(prog.last().map(|p| (p.done, p.total)), Some((4, 4)));

    let stop = Recorder {
        cancel_after: Some(2),
        ..Recorder::default()
    };
    assert!(matches!(session.render(&stop), Err(Error::Cancelled)));
    assert_eq!(stop.passes.lock().unwrap().len(), 2);

    // A cancel token stops a run before its first pass.
    let token = CancelToken::new();
    token.cancel();
    let obs = OnProgress::new(|_| {}).with_cancel(token);
    assert!(matches!(session.render(&obs), Err(Error::Cancelled)));
}

#[test]
fn a_noise_target_in_the_settings_stops_early() {
    let sc = scene(1.0);
    let mut st = settings(&sc);
    st.spp = 64;
    let all = TrackingSession::new(scene(1.0), mdwt(), st.clone())
        .unwrap()
        .render(&Silent)
        .unwrap();
    // A target between the 4-sample and the 64-sample noise stops in between, at the first
    // pass whose noise is below it.
    st.noise_target = Some(all.image.noise() * 2.0);
    let rec = Recorder::default();
    let early = TrackingSession::new(sc, mdwt(), st.clone())
        .unwrap()
        .render(&rec)
        .unwrap();
    let n = early.image.samples();
    assert!((2..64).contains(&n), "stopped after {n} samples");
    assert!(early.image.noise() <= st.noise_target.unwrap());
    let passes = rec.passes.lock().unwrap();
    assert!(
        passes[..passes.len() - 1]
            .iter()
            .all(|p| p.2.is_none_or(|e| e > st.noise_target.unwrap()))
    );
}

#[test]
fn heat_maps_and_the_timing_protocol_are_settings() {
    let sc = scene(1.0);
    let mut st = settings(&sc);
    st.heatmaps = true;
    st.timed_frames = Some(3);
    st.warmup = 2;
    let (expected, times) = render_timed(&sc, &mdwt(), &settings(&sc), 2, 3, true).unwrap();
    let out = TrackingSession::new(sc, mdwt(), st.clone())
        .unwrap()
        .render(&Silent)
        .unwrap();
    assert_eq!(out.image.samples(), 3);
    assert_eq!(
        out.image.mean_image().as_raw(),
        expected.mean_image().as_raw()
    );
    assert_eq!(
        out.image.heatmap(HeatMap::Steps),
        expected.heatmap(HeatMap::Steps)
    );
    let ft = out.frame_times.unwrap();
    assert_eq!((ft.warmup, ft.frames.len()), (2, 3));
    assert_eq!(times.frames.len(), 3);
    // Zero timed frames are refused when the session is built.
    st.timed_frames = Some(0);
    assert!(TrackingSession::new(scene(1.0), mdwt(), st).is_err());
}

#[test]
fn progressive_from_moments_reproduces_the_noise_formula() {
    // Two pixels, 4 samples: noise = sqrt(mean over pixels and RGB of var / n).
    let mean = vec![[0.5; 4], [0.25; 4]];
    let m2 = vec![[0.3, 0.6, 0.9, 0.0], [0.0, 0.0, 0.3, 0.0]];
    let p = Progressive::from_moments(2, 1, 4, mean, m2).unwrap();
    let expected = ((0.3 + 0.6 + 0.9 + 0.3) / 3.0 / 4.0 / 6.0_f64).sqrt();
    assert!((p.noise() - expected).abs() < 1e-15);
    assert!((p.variance(0, 0)[1] - 0.2).abs() < 1e-15);
    assert!(Progressive::from_moments(2, 2, 4, vec![[0.0; 4]], vec![[0.0; 4]]).is_err());
}

#[test]
fn a_session_equals_the_add_pass_loop_with_unevenly_rounding_weights() {
    // 12 equal mix weights do not normalise to the same f32s once and twice; a session must
    // give the bytes of the add_pass loop over a prepared integrator (the CLI's old loop).
    let vol = synth::channels12(12, 7).unwrap();
    let tfs: Vec<TransferFunction> = (0..12)
        .map(|i| tf([1.0, i as f32 / 12.0, 0.5], &[(0.0, 0.0), (1.0, 0.8)]))
        .collect();
    let sc = Scene::from_volume(&vol, tfs, 4.0, 4).unwrap();
    let mdwt_mix = Integrator::Mdwt {
        dda: DdaMode::NDda,
        blend: Blend::Mix {
            weights: vec![1.0; 12],
        },
    };
    let mut st = RenderSettings::default_for(&sc, 10, 8, true);
    st.spp = 2;
    let prepared = mdwt_mix.prepared(&sc).unwrap();
    let mut acc = Progressive::new(10, 8).unwrap();
    for _ in 0..2 {
        acc.add_pass(&sc, &prepared, &st).unwrap();
    }
    let out = TrackingSession::new(sc, mdwt_mix, st)
        .unwrap()
        .render(&Silent)
        .unwrap();
    assert_eq!(out.image.mean_image().as_raw(), acc.mean_image().as_raw());
}

/// Sees only sweeps: a progress bar's observer ([`Observer::every_pass`] `false`).
#[derive(Default)]
struct SweepRecorder {
    passes: Mutex<Vec<u32>>,
}

impl Observer<Progressive> for SweepRecorder {
    fn pass(&self, pass: u32, image: &Progressive, _noise: Option<f64>) {
        assert_eq!(pass, image.samples());
        self.passes.lock().unwrap().push(pass);
    }
    fn every_pass(&self) -> bool {
        false
    }
}

/// Passes run in sweeps for an observer that does not need every pass: the mean, the
/// variance and the heat-map counts are those of one pass at a time, bit for bit (each
/// pixel takes its samples in the same order), on 1 and 3 threads, and the observer hears
/// fewer, growing sweeps ending at the sample count. With a noise target every pass is
/// still seen (the target is checked after each).
#[test]
fn sweeps_of_passes_give_the_bytes_of_single_passes() {
    let sc = scene(1.0);
    let mut st = settings(&sc);
    st.spp = 40;
    st.heatmaps = true;
    let session = TrackingSession::new(sc, mdwt(), st.clone()).unwrap();
    let one = Recorder::default();
    let single = session.render(&one).unwrap().image;
    assert_eq!(one.passes.lock().unwrap().len(), 40);
    for threads in [1, 3] {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        let rec = SweepRecorder::default();
        let swept = pool.install(|| session.render(&rec).unwrap().image);
        let passes = rec.passes.lock().unwrap().clone();
        assert!(passes.len() < 40, "{threads} threads: {passes:?}");
        assert_eq!(passes.last(), Some(&40));
        assert_eq!(swept.samples(), 40);
        assert_eq!(swept.mean_image().as_raw(), single.mean_image().as_raw());
        for (x, y) in [(0, 0), (7, 5), (19, 13), (10, 7)] {
            assert_eq!(swept.variance(x, y), single.variance(x, y));
        }
        for map in [HeatMap::Steps, HeatMap::Collisions, HeatMap::Rejections] {
            assert_eq!(swept.heatmap(map), single.heatmap(map), "{map:?}");
        }
    }
    // The one-call render sweeps too, with the same bytes.
    let mut plain = st.clone();
    plain.heatmaps = false;
    assert_eq!(
        render(&scene(1.0), &mdwt(), &plain).unwrap().as_raw(),
        single.mean_image().as_raw()
    );
    // A noise target keeps one pass per step.
    st.noise_target = Some(1e-9);
    st.spp = 6;
    let session = TrackingSession::new(scene(1.0), mdwt(), st).unwrap();
    let rec = SweepRecorder::default();
    session.render(&rec).unwrap();
    assert_eq!(*rec.passes.lock().unwrap(), vec![1, 2, 3, 4, 5, 6]);
}
