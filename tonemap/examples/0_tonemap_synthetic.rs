//! Builds a synthetic HDR image (a sky gradient with a sun five orders of magnitude
//! brighter), prints its dynamic range, and writes each operator's result as PNG plus a
//! pseudocolour picture into `target/tonemap-example/`.
//!
//! Run: `cargo run -p blueshift-tonemap --example 0_tonemap_synthetic`

use blueshift_tonemap::io::{ExrPrecision, PngDepth, write_exr, write_png, write_rgb8_png};
use blueshift_tonemap::{
    DragoParams, DurandParams, FattalParams, Operator, PseudocolourParams, ReinhardLocalParams,
    ReinhardParams, dynamic_range, pseudocolour,
};
use image::{Rgb, Rgb32FImage};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let (w, h) = (320u32, 200u32);
    let hdr = Rgb32FImage::from_fn(w, h, |x, y| {
        let (u, v) = (x as f32 / w as f32, y as f32 / h as f32);
        let sky = 0.05 + 2.0 * (1.0 - v) * (0.5 + 0.5 * (8.0 * u).sin().abs());
        let sun = if (u - 0.75).powi(2) + (v - 0.25).powi(2) < 0.002 {
            5.0e4
        } else {
            0.0
        };
        let l = sky + sun;
        Rgb([l * 1.2, l, l * 0.7])
    });
    let out = std::path::Path::new("target/tonemap-example");
    std::fs::create_dir_all(out)?;
    write_exr(out.join("input.exr"), &hdr, ExrPrecision::Half)?;
    if let Some(dr) = dynamic_range(&hdr) {
        println!(
            "dynamic range {:.2e}:1 ({:.1} orders of magnitude)",
            dr.ratio, dr.orders_of_magnitude
        );
    }
    let ops = [
        Operator::Drago(DragoParams::default()),
        Operator::Reinhard(ReinhardParams::default()),
        Operator::ReinhardLocal(ReinhardLocalParams::default()),
        Operator::Durand(DurandParams::default()),
        Operator::Fattal(FattalParams::default()),
    ];
    for op in ops {
        let display = op.apply(&hdr)?;
        let path = out.join(format!("{}.png", op.name()));
        write_png(&path, &display, PngDepth::Eight)?;
        println!("wrote {}", path.display());
    }
    let pic = pseudocolour(&hdr, &PseudocolourParams::default())?;
    write_rgb8_png(out.join("pseudocolour.png"), &pic)?;
    Ok(())
}
