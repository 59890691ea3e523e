//! Compositing time against image size and rank count, in process (threads over channels:
//! the schedules' arithmetic and copying, not a network), per strategy; and the cost
//! model's projection to 64 and 1,024 ranks (printed once).

use blueshift_dist::{Communicator, Op, Strategy, ThreadWorld, composite, cost};
use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};

fn image(rank: usize, pixels: usize) -> Vec<f64> {
    (0..pixels * 4)
        .map(|i| ((i * 31 + rank * 17) % 101) as f64 / 202.0)
        .collect()
}

fn bench(c: &mut Criterion) {
    let mut g = c.benchmark_group("composite");
    g.sample_size(10);
    for side in [128usize, 512] {
        let pixels = side * side;
        for n in [1usize, 2, 3, 4] {
            let mut strategies = vec![("direct", Strategy::DirectSend)];
            if n.is_power_of_two() && n > 1 {
                strategies.push(("binary-swap", Strategy::BinarySwap));
            }
            for (name, s) in strategies {
                let f = s.factors(n).unwrap();
                let pos: Vec<usize> = (0..n).collect();
                g.bench_with_input(
                    BenchmarkId::new(format!("{name}/{side}x{side}"), n),
                    &n,
                    |b, &n| {
                        b.iter(|| {
                            ThreadWorld::run(n, |comm| {
                                composite(&comm, image(comm.rank(), pixels), 4, Op::Over, &f, &pos)
                                    .unwrap()
                                    .map(|v| v.len())
                            })
                        });
                    },
                );
            }
        }
    }
    g.finish();
    // The cost model at scale (1920x1080 RGBA f64): messages and bytes per strategy.
    let pixels = 1920 * 1080;
    for n in [4usize, 64, 1024] {
        for (name, s) in [
            ("direct-send", Strategy::DirectSend),
            ("binary-swap", Strategy::BinarySwap),
            ("radix-k(8)", Strategy::RadixK(radix8(n))),
        ] {
            let f = s.factors(n).unwrap();
            let m = cost(&f, pixels, 4);
            println!(
                "cost n={n:5} {name:12} messages {:9} bytes {:12.3e} steps {:5}",
                m.messages, m.bytes as f64, m.steps
            );
        }
    }
}

/// Factors of a power of two grouped by 8 (IceT's radix-k target).
fn radix8(n: usize) -> Vec<usize> {
    let mut f = Vec::new();
    let mut m = n;
    while m > 1 {
        let k = if m.is_multiple_of(8) { 8 } else { m };
        f.push(k);
        m /= k;
    }
    f
}

criterion_group!(benches, bench);
criterion_main!(benches);
