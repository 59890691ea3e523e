//! Criterion benchmarks of blueshift-spectrum.
//!
//! - `insertion/*/N`: adding 64 trapezoids to a spectrum of N pieces (10, 100, 1,000,
//!   10,000), either overlapping about two pieces each (the data structure's own cost) or
//!   0.5 nm wide (overlapping more pieces as N grows). This is the paper's bottleneck
//!   (Fig. 17/18, Table 1). The clone of the input is not timed.
//! - `xyz/*`: inner product with the CIE functions (exact piecewise-linear convolution).
//! - `banded/*`: add, nearest and energy-conserving shifts, XYZ at N = 40, 400, 4,000.
//! - `shift/*`: Doppler-scaling a piecewise-linear spectrum.
//! - `line_list/{one_by_one,sweep}/N`: N 1 nm box lines spread over 300 nm (N = 1,000,
//!   10,000, 100,000; one-by-one up to 10,000): `EmissionLine::add_to` in a loop costs the
//!   pieces each line overlaps (quadratic), `add_lines` one sorted sweep (n log n).

use std::hint::black_box;

use blueshift_spectrum::*;
use criterion::{BatchSize, BenchmarkId, Criterion, criterion_group, criterion_main};

/// A tiny fixed-seed generator (xorshift64*), so inputs are the same every run.
struct Rng(u64);
impl Rng {
    fn next_f64(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        (self.0.wrapping_mul(0x2545_f491_4f6c_dd1d) >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// A spectrum of `n` disjoint pieces over 360-830 nm.
fn spectrum_with_pieces(n: usize) -> PiecewiseLinear {
    let w = 470.0 / n as f64;
    let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
    let pieces = (0..n).map(|i| Piece {
        start_nm: 360.0 + i as f64 * w,
        end_nm: 360.0 + (i as f64 + 0.9) * w,
        value_start: rng.next_f64(),
        value_end: rng.next_f64(),
    });
    PiecewiseLinear::from_pieces(pieces).unwrap()
}

fn insertion(c: &mut Criterion) {
    let mut g = c.benchmark_group("insertion");
    for n in [10usize, 100, 1_000, 10_000] {
        let base = spectrum_with_pieces(n);
        let spacing = 470.0 / n as f64;
        let mut rng = Rng(42);
        let starts: Vec<(f64, f64)> = (0..64)
            .map(|_| (360.0 + 460.0 * rng.next_f64(), rng.next_f64()))
            .collect();
        // Each trapezoid overlaps about two existing pieces whatever N is: the cost of the data
        // structure itself (the paper's list grows linearly here, the tree logarithmically).
        g.bench_with_input(
            BenchmarkId::new("64_traps_overlapping_2_pieces", n),
            &n,
            |b, _| {
                b.iter_batched_ref(
                    || base.clone(),
                    |s| {
                        for &(a, v) in &starts {
                            s.add_trapezoid(a, a + 1.5 * spacing, v, 0.5 * v).unwrap();
                        }
                    },
                    BatchSize::LargeInput,
                )
            },
        );
        // A fixed 0.5 nm line: it overlaps more pieces as they get denser, and every
        // overlapped piece must change, so this grows with N by necessity.
        g.bench_with_input(BenchmarkId::new("64_lines_of_0.5nm", n), &n, |b, _| {
            b.iter_batched_ref(
                || base.clone(),
                |s| {
                    for &(a, v) in &starts {
                        s.add_trapezoid(a, a + 0.5, v, 0.5 * v).unwrap();
                    }
                },
                BatchSize::LargeInput,
            )
        });
    }
    g.finish();
}

fn xyz(c: &mut Criterion) {
    let cmf = Cmf::cie1931_2deg();
    let mut g = c.benchmark_group("xyz");
    for n in [21usize, 1_000, 10_000] {
        let s = spectrum_with_pieces(n);
        g.bench_with_input(BenchmarkId::new("prefix_closed_form", n), &s, |b, s| {
            b.iter(|| black_box(cmf.xyz_of(s)))
        });
    }
    let s = spectrum_with_pieces(1_000);
    let chans = [cmf.channel(0), cmf.channel(1), cmf.channel(2)];
    g.bench_function("merge_walk_dot/1000", |b| {
        b.iter(|| black_box([s.dot(&chans[0]), s.dot(&chans[1]), s.dot(&chans[2])]))
    });
    g.finish();
}

fn banded(c: &mut Criterion) {
    let cmf = Cmf::cie1931_2deg();
    let bb = Blackbody::new(6000.0).unwrap();
    let mut g = c.benchmark_group("banded");
    for n in [40usize, 400, 4_000] {
        let layout = BandLayout::new(360.0, 830.0, n).unwrap();
        let a = Banded::sampled(layout, |w| bb.eval(w)).unwrap();
        let b2 = a.clone();
        let shift = WavelengthShift::new(1.01).unwrap();
        let weights = BandWeights::new(layout, cmf);
        g.bench_with_input(BenchmarkId::new("add", n), &n, |b, _| {
            b.iter_batched_ref(|| a.clone(), |x| x.add(&b2).unwrap(), BatchSize::SmallInput)
        });
        g.bench_with_input(BenchmarkId::new("shift_nearest", n), &n, |b, _| {
            b.iter(|| black_box(a.shift_nearest(shift)))
        });
        g.bench_with_input(
            BenchmarkId::new("shift_energy_conserving", n),
            &n,
            |b, _| {
                b.iter(|| black_box(a.shift_energy_conserving(shift, RadiometricTransform::None)))
            },
        );
        g.bench_with_input(BenchmarkId::new("xyz", n), &n, |b, _| {
            b.iter(|| black_box(weights.xyz(&a).unwrap()))
        });
    }
    g.finish();
}

fn shift(c: &mut Criterion) {
    let mut g = c.benchmark_group("shift");
    for n in [21usize, 1_000] {
        let s = spectrum_with_pieces(n);
        let sh = WavelengthShift::classical(3.0e5).unwrap();
        g.bench_with_input(BenchmarkId::new("pwl_shifted", n), &s, |b, s| {
            b.iter(|| black_box(s.shifted(sh, RadiometricTransform::Invariant)))
        });
    }
    g.bench_function("relativistic_factor", |b| {
        b.iter(|| {
            black_box(WavelengthShift::from_velocity(
                DopplerModel::Relativistic,
                black_box([1.0e5, 2.0e5, -3.0e5]),
                black_box([0.0, 0.0, 1.0]),
            ))
        })
    });
    g.finish();
}

fn line_list(c: &mut Criterion) {
    let mut g = c.benchmark_group("line_list");
    let profile = LineProfile::Box { width_nm: 1.0 };
    for n in [1_000usize, 10_000, 100_000] {
        let lines: Vec<EmissionLine> = (0..n)
            .map(|i| EmissionLine::new(400.0 + 300.0 * i as f64 / n as f64, 1.0).unwrap())
            .collect();
        if n <= 10_000 {
            g.bench_with_input(BenchmarkId::new("one_by_one", n), &lines, |b, lines| {
                b.iter(|| {
                    let mut s = PiecewiseLinear::new();
                    for l in lines {
                        l.add_to(&mut s, profile, 1.0).unwrap();
                    }
                    black_box(s)
                });
            });
        }
        g.bench_with_input(BenchmarkId::new("sweep", n), &lines, |b, lines| {
            b.iter(|| {
                let mut s = PiecewiseLinear::new();
                add_lines(&mut s, lines, profile, 1.0).unwrap();
                black_box(s)
            });
        });
    }
    g.finish();
}

criterion_group!(benches, insertion, xyz, banded, shift, line_list);
criterion_main!(benches);
