//! The GPU sessions: the same images as the one-call GPU functions, a transfer-function edit
//! on the device equals a fresh upload, and `auto` falls back through `run_with_fallback`.
//! Skipped (with a note) without a wgpu adapter.

use blueshift_camera::{Session, Silent};
use blueshift_doppler::{DopplerScene, DopplerSession, DopplerSettings};
use blueshift_gpu::context::test_context;
use blueshift_gpu::doppler::{DopplerPrecision, GpuDopplerSession, render_doppler_gpu_with};
use blueshift_gpu::tracking::{GpuTracker, GpuTrackingSession};
use blueshift_gpu::{DeviceChoice, Error, Unsupported, run_with_fallback};
use blueshift_tfedit::{ColorKnot, OpacityKnot, TransferFunction};
use blueshift_tracking::{Blend, DdaMode, Integrator, RenderSettings, Scene, Shading};
use blueshift_volume::synth;

fn tf(rgb: [f32; 3], top: f32) -> TransferFunction {
    TransferFunction::new(
        [0.0, 1.0],
        vec![ColorKnot { x: 0.0, rgb }, ColorKnot { x: 1.0, rgb }],
        vec![OpacityKnot::new(0.0, 0.0), OpacityKnot::new(1.0, top)],
    )
    .unwrap()
}

fn scene(tfs: Vec<TransferFunction>) -> Scene {
    Scene::from_volume(&synth::three_cubes(16).unwrap(), tfs, 5.0, 4).unwrap()
}

fn tfs() -> Vec<TransferFunction> {
    vec![
        tf([1.0, 0.0, 0.0], 1.0),
        tf([0.0, 1.0, 0.0], 1.0),
        tf([0.0, 0.0, 1.0], 1.0),
    ]
}

fn mdwt() -> Integrator {
    Integrator::Mdwt {
        dda: DdaMode::OneDda,
        blend: Blend::Density,
    }
}

#[test]
fn gpu_tracking_session_edits_equal_fresh_uploads() {
    let Some(ctx) = test_context() else {
        eprintln!("SKIP: no wgpu adapter");
        return;
    };
    let sc = scene(tfs());
    let mut st = RenderSettings::default_for(&sc, 16, 12, false);
    st.spp = 2;
    st.seed = 4;
    let tracker = GpuTracker::new(ctx).unwrap();
    let direct = tracker
        .render(&tracker.upload(sc.clone()).unwrap(), &mdwt(), &st)
        .unwrap();
    let mut session = GpuTrackingSession::new(ctx, sc, mdwt(), st.clone()).unwrap();
    assert_eq!(session.device(), blueshift_camera::DeviceKind::Gpu);
    assert_eq!(
        session.run(&Silent).unwrap().image.mean_image().as_raw(),
        direct.as_raw()
    );
    // A transfer-function edit on the device equals uploading the edited scene.
    let new_tf = tf([0.8, 0.7, 0.1], 0.4);
    session.set_transfer_function(2, new_tf.clone()).unwrap();
    let mut edited = tfs();
    edited[2] = new_tf;
    let fresh = GpuTrackingSession::new(ctx, scene(edited), mdwt(), st).unwrap();
    assert_eq!(
        session.render(&Silent).unwrap().image.mean_image().as_raw(),
        fresh.render(&Silent).unwrap().image.mean_image().as_raw()
    );
    // What the GPU does not do is refused as Unsupported when the session is built.
    let mut shaded = scene(tfs());
    shaded.shading = Some(Shading::default());
    let s = RenderSettings::default_for(&shaded, 8, 8, false);
    assert!(matches!(
        GpuTrackingSession::new(ctx, shaded, mdwt(), s),
        Err(Error::Unsupported(_))
    ));
}

#[test]
fn gpu_doppler_session_equals_the_one_call_render() {
    let Some(ctx) = test_context() else {
        eprintln!("SKIP: no wgpu adapter");
        return;
    };
    let vol = synth::galaxy(12, 1).unwrap();
    let sc = DopplerScene::from_volume(&vol, &["bb", "H"]).unwrap();
    let st = DopplerSettings::default_for(&sc, 10, 8);
    let direct = render_doppler_gpu_with(ctx, &sc, &st, DopplerPrecision::F32).unwrap();
    let cpu = DopplerSession::new(sc.clone(), st.clone()).unwrap();
    let mut session = GpuDopplerSession::new(ctx, sc, st, DopplerPrecision::F32).unwrap();
    let img = session.run(&Silent).unwrap();
    assert_eq!(img.xyz, direct.xyz);
    // Within the f32 kernels' stated 2e-3 of the CPU's image per pixel (of its peak).
    let reference = cpu.render(&Silent).unwrap();
    let peak = reference
        .xyz
        .iter()
        .flatten()
        .fold(0.0f64, |m, v| m.max(v.abs()));
    for (a, b) in img.xyz.iter().zip(&reference.xyz) {
        for c in 0..3 {
            assert!((a[c] - b[c]).abs() <= 2e-3 * peak, "{a:?} vs {b:?}");
        }
    }
}

#[test]
fn auto_runs_unsupported_jobs_on_the_cpu_and_gpu_refuses_them() {
    let run = |choice| {
        run_with_fallback::<u8, Error>(
            choice,
            || Err(Unsupported("heat maps are CPU-only".into())),
            |_| Ok(1),
            || Ok(2),
        )
    };
    let cpu = run(DeviceChoice::Cpu).unwrap();
    assert_eq!((cpu.value, cpu.fallback), (2, None));
    if test_context().is_none() {
        eprintln!("SKIP: no wgpu adapter");
        return;
    }
    assert!(matches!(run(DeviceChoice::Gpu), Err(Error::Unsupported(_))));
    // auto uses a software adapter only when BLUESHIFT_GPU forces it; either way it runs
    // this job on the CPU.
    assert_eq!(run(DeviceChoice::Auto).unwrap().value, 2);
}
