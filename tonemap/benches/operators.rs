//! Each operator at 1 and 8 megapixels on a seeded synthetic HDR image.

use blueshift_tonemap::{
    DragoParams, DurandParams, FattalParams, Operator, ReinhardLocalParams, ReinhardParams,
};
use criterion::{Criterion, criterion_group, criterion_main};
use image::{Rgb, Rgb32FImage};

fn hash01(i: u64) -> f32 {
    let mut z = i.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    ((z ^ (z >> 31)) >> 40) as f32 / (1u64 << 24) as f32
}

fn scene(w: u32, h: u32) -> Rgb32FImage {
    Rgb32FImage::from_fn(w, h, |x, y| {
        let (u, v) = (x as f32 / w as f32, y as f32 / h as f32);
        let mut l = 0.01 + 2.0 * u * v + 0.2 * (20.0 * u).sin().abs();
        if (u - 0.7).powi(2) + (v - 0.3).powi(2) < 0.004 {
            l += 500.0;
        }
        l *= 1.0 + 0.1 * hash01(u64::from(y * w + x));
        Rgb([l * 1.1, l, l * 0.8])
    })
}

fn operators(c: &mut Criterion) {
    for (label, w, h) in [("1MP", 1024u32, 1024u32), ("8MP", 3464, 2309)] {
        let img = scene(w, h);
        let mut g = c.benchmark_group(format!("tonemap_{label}"));
        g.sample_size(10);
        for op in [
            Operator::Drago(DragoParams::default()),
            Operator::Reinhard(ReinhardParams::default()),
            Operator::ReinhardLocal(ReinhardLocalParams::default()),
            Operator::Durand(DurandParams::default()),
            Operator::Fattal(FattalParams::default()),
        ] {
            g.bench_function(op.name(), |b| b.iter(|| op.apply(&img).unwrap()));
        }
        g.finish();
    }
}

criterion_group!(benches, operators);
criterion_main!(benches);
