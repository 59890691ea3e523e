//! Picks an adapter (honouring `BLUESHIFT_GPU`), prints what it got, and tone-maps a small
//! HDR ramp on the GPU and on the CPU to show they agree.
//!
//! `cargo run -p blueshift-gpu --example gpu_info`

use blueshift_gpu::{GpuContext, GpuOptions};
use blueshift_tonemap::{DragoParams, Operator};
use image::{Rgb, Rgb32FImage};

fn main() {
    let ctx = match GpuContext::new(GpuOptions::default()) {
        Ok(ctx) => ctx,
        Err(e) => {
            eprintln!("{e}");
            std::process::exit(1);
        }
    };
    let r = ctx.report();
    println!(
        "adapter {} ({}, {}), f16 {}, f64 {}, timestamps {}",
        r.name, r.backend, r.device_type, r.shader_f16, r.shader_f64, r.timestamp_query
    );
    let hdr = Rgb32FImage::from_fn(64, 4, |x, _| {
        let v = 10f32.powf(x as f32 / 16.0 - 2.0);
        Rgb([v, v * 0.8, v * 0.6])
    });
    let op = Operator::Drago(DragoParams::default());
    let cpu = op.apply(&hdr).expect("cpu tone mapping");
    match blueshift_gpu::tonemap::tonemap(&ctx, &op, &hdr) {
        Ok(gpu) => {
            let worst = cpu
                .as_raw()
                .iter()
                .zip(gpu.as_raw())
                .map(|(a, b)| (a - b).abs())
                .fold(0.0f32, f32::max);
            println!("Drago on 64x4: largest GPU - CPU difference {worst:.2e}");
        }
        Err(e) => eprintln!("GPU tone mapping failed: {e}"),
    }
}
