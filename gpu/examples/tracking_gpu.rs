//! Renders the MDWT paper's three cubes (MDWT Fig. 3) with multi-density Woodcock tracking
//! on the GPU and on the CPU, and prints how far apart the two images are.
//!
//! `cargo run -p blueshift-gpu --example tracking_gpu` (any wgpu adapter; lavapipe works).

use blueshift_gpu::GpuContext;
use blueshift_gpu::tracking::GpuTracker;
use blueshift_tfedit::{ColorKnot, OpacityKnot, TransferFunction};
use blueshift_tracking::{Blend, DdaMode, Integrator, RenderSettings, Scene, render};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let ctx = match GpuContext::shared() {
        Ok(c) => c,
        Err(e) => {
            eprintln!("SKIP: no wgpu adapter: {e}");
            return Ok(());
        }
    };
    let volume = blueshift_volume::synth::by_name("three-cubes", 24, 0)?;
    let tfs = volume
        .channels()
        .iter()
        .enumerate()
        .map(|(i, _)| {
            let mut rgb = [0.2f32; 3];
            rgb[i % 3] = 1.0;
            TransferFunction::new(
                [0.0, 1.0],
                vec![ColorKnot { x: 0.0, rgb }],
                vec![OpacityKnot::new(0.0, 0.0), OpacityKnot::new(1.0, 1.0)],
            )
        })
        .collect::<Result<Vec<_>, _>>()?;
    let scene = Scene::from_volume(&volume, tfs, 0.3, 4)?;
    let integrator = Integrator::Mdwt {
        dda: DdaMode::OneDda,
        blend: Blend::Density,
    };
    let mut settings = RenderSettings::default_for(&scene, 48, 48, false);
    settings.spp = 16;

    let tracker = GpuTracker::new(ctx)?;
    let gpu_scene = tracker.upload(scene.clone())?;
    let t = std::time::Instant::now();
    let gpu = tracker.render(&gpu_scene, &integrator, &settings)?;
    let gpu_s = t.elapsed().as_secs_f64();
    let t = std::time::Instant::now();
    let cpu = render(&scene, &integrator, &settings)?;
    let cpu_s = t.elapsed().as_secs_f64();
    let mean = |i: &image::Rgba32FImage| {
        i.as_raw().iter().map(|v| f64::from(*v)).sum::<f64>() / i.as_raw().len() as f64
    };
    println!(
        "{}: image mean gpu {:.5} cpu {:.5}; {gpu_s:.3} s on the GPU, {cpu_s:.3} s on the CPU",
        ctx.info().name,
        mean(&gpu),
        mean(&cpu)
    );
    Ok(())
}
