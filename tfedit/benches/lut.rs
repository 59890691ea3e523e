//! Lookup-table generation at 2^16 and 2^24 entries, and max-opacity queries per second.
//!
//! Baselines measured in the same run:
//! - `lut/*/per_entry_scalar`: the table built by a plain loop of `eval` on one thread, the
//!   obvious implementation, against `lut/*/lut` (chunked, rayon when enabled).
//! - `max_opacity/sampled_256`: the majorant by sampling the interval at 256 points (the
//!   loop of MDWT section 4.3, which can underestimate), against the exact knot query.

use std::hint::black_box;

use blueshift_tfedit::{ColorKnot, ColorSpace, OpacityKnot, TransferFunction, builtin_over};
use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};

/// PCG32 (O'Neill), fixed seed: deterministic inputs.
struct Pcg32(u64);
impl Pcg32 {
    fn next_u32(&mut self) -> u32 {
        let old = self.0;
        self.0 = old
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        let xorshifted = (((old >> 18) ^ old) >> 27) as u32;
        let rot = (old >> 59) as u32;
        xorshifted.rotate_right(rot)
    }
    fn next_f64(&mut self) -> f64 {
        f64::from(self.next_u32()) / 4_294_967_296.0
    }
}

/// A transfer function with 64 opacity knots and HSV colour over [0, 65535].
fn busy_tf() -> TransferFunction {
    let mut rng = Pcg32(0x853c_49e6_748f_ea9b);
    let opacity = (0..64)
        .map(|i| {
            OpacityKnot::new(
                f64::from(i) * 65_535.0 / 63.0,
                (rng.next_f64() * 0.2) as f32,
            )
        })
        .collect();
    let color = (0..8)
        .map(|i| ColorKnot {
            x: f64::from(i) * 65_535.0 / 7.0,
            rgb: [
                rng.next_f64() as f32,
                rng.next_f64() as f32,
                rng.next_f64() as f32,
            ],
        })
        .collect();
    TransferFunction::new([0.0, 65_535.0], color, opacity)
        .unwrap()
        .with_color_space(ColorSpace::Hsv)
        .with_alpha_g(0.05)
        .unwrap()
}

fn lut_generation(c: &mut Criterion) {
    let tfs = [
        (
            "viridis_rgb",
            builtin_over("viridis", [0.0, 65_535.0]).unwrap(),
        ),
        ("busy_hsv", busy_tf()),
    ];
    for (name, tf) in &tfs {
        let mut g = c.benchmark_group(format!("lut/{name}"));
        g.sample_size(10);
        for n in [1usize << 16, 1 << 24] {
            g.throughput(Throughput::Elements(n as u64));
            g.bench_with_input(BenchmarkId::new("lut", n), &n, |b, &n| {
                b.iter(|| tf.lut(black_box(n)).unwrap())
            });
            g.bench_with_input(BenchmarkId::new("per_entry_scalar", n), &n, |b, &n| {
                b.iter(|| {
                    let [lo, hi] = tf.domain();
                    let step = (hi - lo) / (n - 1) as f64;
                    let mut v = Vec::with_capacity(n * 4);
                    for i in 0..n {
                        v.extend_from_slice(&tf.eval(lo + i as f64 * step));
                    }
                    black_box(v)
                });
            });
        }
        g.finish();
    }
}

fn max_opacity(c: &mut Criterion) {
    let tf = busy_tf();
    let mut rng = Pcg32(42);
    // Macrocell-like value ranges: a random start and a width of up to 5 % of the domain.
    let queries: Vec<(f64, f64)> = (0..4096)
        .map(|_| {
            let a = rng.next_f64() * 65_535.0;
            (a, a + rng.next_f64() * 3_300.0)
        })
        .collect();
    let mut g = c.benchmark_group("max_opacity");
    g.throughput(Throughput::Elements(queries.len() as u64));
    g.bench_function("exact", |b| {
        b.iter(|| {
            queries
                .iter()
                .map(|&(lo, hi)| tf.max_opacity(black_box(lo)..=black_box(hi)))
                .fold(0f32, f32::max)
        });
    });
    g.bench_function("sampled_256", |b| {
        b.iter(|| {
            queries
                .iter()
                .map(|&(lo, hi)| {
                    (0..256)
                        .map(|i| tf.opacity(lo + (hi - lo) * f64::from(i) / 255.0))
                        .fold(0f32, f32::max)
                })
                .fold(0f32, f32::max)
        });
    });
    g.finish();
}

criterion_group!(benches, lut_generation, max_opacity);
criterion_main!(benches);
