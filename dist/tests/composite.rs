//! Compositing schedules against a sequential reference, the cost model against counted
//! messages, the k-d split against geometry (tiling, and the visibility order against the
//! order in which rays enter the pieces), and failure agreement.

use blueshift_dist::composite::{exclusive_scan, final_region, scan_cost};
use blueshift_dist::render::agree;
use blueshift_dist::{
    Communicator, Counters, Counting, Decomposition, Error, Op, Strategy, ThreadWorld, Viewpoint,
    composite, cost,
};
use glam::Vec3;

/// A small deterministic generator.
fn lcg(state: &mut u64) -> f64 {
    *state = state
        .wrapping_mul(6_364_136_223_846_793_005)
        .wrapping_add(1_442_695_040_888_963_407);
    (*state >> 11) as f64 / (1u64 << 53) as f64
}

/// Rank `r`'s partial image: premultiplied RGBA (colour <= alpha) or any values.
fn partial(r: usize, pixels: usize, op: Op) -> Vec<f64> {
    let mut st = 1000 + r as u64;
    let mut v = Vec::with_capacity(pixels * 4);
    for _ in 0..pixels {
        let a = lcg(&mut st);
        for _ in 0..3 {
            let c = lcg(&mut st);
            v.push(if op == Op::Over { c * a } else { c });
        }
        v.push(a);
    }
    v
}

/// The sequential reference: every rank's image merged one after another in `order`.
fn reference(n: usize, pixels: usize, op: Op, order: &[usize]) -> Vec<f64> {
    let mut acc = partial(order[0], pixels, op);
    for &r in &order[1..] {
        let b = partial(r, pixels, op);
        for (o, bp) in acc.chunks_exact_mut(4).zip(b.chunks_exact(4)) {
            let t = 1.0 - o[3];
            for c in 0..4 {
                o[c] += if op == Op::Over { t * bp[c] } else { bp[c] };
            }
        }
    }
    let _ = n;
    acc
}

fn strategies(n: usize) -> Vec<Strategy> {
    let mut s = vec![Strategy::DirectSend, Strategy::auto(n)];
    if n.is_power_of_two() {
        s.push(Strategy::BinarySwap);
    }
    if n == 6 {
        s.push(Strategy::RadixK(vec![2, 3]));
        s.push(Strategy::RadixK(vec![3, 2]));
    }
    if n == 8 {
        s.push(Strategy::RadixK(vec![4, 2]));
    }
    s
}

#[test]
fn auto_strategy_by_rank_count() {
    assert_eq!(Strategy::auto(1).factors(1).unwrap(), Vec::<usize>::new());
    for n in [2, 4, 8, 64, 1024] {
        assert_eq!(Strategy::auto(n), Strategy::BinarySwap);
        assert_eq!(
            Strategy::auto(n).factors(n).unwrap(),
            vec![2; n.trailing_zeros() as usize]
        );
    }
    assert_eq!(Strategy::auto(3), Strategy::DirectSend);
    assert_eq!(Strategy::auto(7), Strategy::DirectSend);
    assert_eq!(Strategy::auto(6), Strategy::RadixK(vec![6]));
    assert_eq!(Strategy::auto(12), Strategy::RadixK(vec![6, 2]));
    assert_eq!(Strategy::auto(36), Strategy::RadixK(vec![6, 6]));
    for n in 2..200 {
        let f = Strategy::auto(n).factors(n).unwrap();
        assert_eq!(f.iter().product::<usize>(), n);
    }
    assert!(Strategy::BinarySwap.factors(6).is_err());
    assert!(Strategy::RadixK(vec![2, 2]).factors(6).is_err());
}

#[test]
fn every_schedule_equals_the_sequential_composite() {
    let (w, h) = (13usize, 7usize);
    let pixels = w * h;
    for n in 1..=8 {
        for strategy in strategies(n) {
            let factors = strategy.factors(n).unwrap();
            let decomp = Decomposition::new([16, 12, 10], Vec3::ZERO, Vec3::ONE, &factors).unwrap();
            for view in [
                Viewpoint::Direction(Vec3::new(0.3, -0.5, -1.0)),
                Viewpoint::Eye(Vec3::new(5.0, 40.0, 3.0)),
                Viewpoint::Eye(Vec3::new(7.2, 5.1, 4.3)),
            ] {
                let order = decomp.visibility_order(view);
                let mut position = vec![0; n];
                for (p, &r) in order.iter().enumerate() {
                    position[r] = p;
                }
                for op in [Op::Add, Op::Over] {
                    let want = reference(n, pixels, op, &order);
                    let got = ThreadWorld::run(n, |c| {
                        composite(
                            &c,
                            partial(c.rank(), pixels, op),
                            4,
                            op,
                            &factors,
                            &position,
                        )
                        .unwrap()
                    });
                    let img = got[0].as_ref().unwrap();
                    assert!(got[1..].iter().all(Option::is_none));
                    for (a, b) in img.iter().zip(&want) {
                        assert!(
                            (a - b).abs() <= 1e-12 * b.abs().max(1.0),
                            "n {n} {strategy:?} {op:?}: {a} vs {b}"
                        );
                    }
                }
            }
        }
    }
}

#[test]
fn over_in_the_wrong_order_is_wrong() {
    // The check above is not vacuous: compositing against the visibility order changes the
    // image (over does not commute).
    let n = 4;
    let pixels = 50;
    let factors = Strategy::auto(n).factors(n).unwrap();
    let order = [0, 1, 2, 3];
    let reversed = [3usize, 2, 1, 0];
    let want = reference(n, pixels, Op::Over, &order);
    let got = ThreadWorld::run(n, |c| {
        composite(
            &c,
            partial(c.rank(), pixels, Op::Over),
            4,
            Op::Over,
            &factors,
            &reversed,
        )
        .unwrap()
    });
    let img = got[0].as_ref().unwrap();
    let diff = img
        .iter()
        .zip(&want)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    assert!(diff > 0.05, "{diff}");
}

#[test]
fn counted_messages_and_bytes_match_the_cost_model() {
    for n in 1..=8 {
        for strategy in strategies(n) {
            let factors = strategy.factors(n).unwrap();
            // A pixel count every partial product divides: the model is exact.
            let pixels = 840 * 3;
            let counters = Counters::default();
            ThreadWorld::run(n, |c| {
                let c = Counting::new(c, counters.clone());
                let pos: Vec<usize> = (0..n).collect();
                composite(
                    &c,
                    partial(c.rank(), pixels, Op::Add),
                    4,
                    Op::Add,
                    &factors,
                    &pos,
                )
                .unwrap();
            });
            let model = cost(&factors, pixels as u64, 4);
            assert_eq!(counters.messages(), model.messages, "n {n} {strategy:?}");
            assert_eq!(counters.bytes(), model.bytes, "n {n} {strategy:?}");
        }
    }
    // Independent closed forms: direct-send moves (n-1)/n of every image and gathers 1/n of
    // it from n-1 ranks; binary swap sends half, a quarter, ... of it per rank.
    let (p, ch) = (1u64 << 20, 4u64);
    for n in [4u64, 64, 1024] {
        let ds = cost(&[n as usize], p, ch);
        assert_eq!(ds.messages, n * (n - 1) + n - 1);
        assert_eq!(ds.bytes, 8 * ch * ((n - 1) * p + (n - 1) * p / n));
        let bs = cost(&vec![2; n.trailing_zeros() as usize], p, ch);
        assert_eq!(bs.messages, n * u64::from(n.trailing_zeros()) + n - 1);
        assert_eq!(bs.bytes, 8 * ch * (n * (p - p / n) + (n - 1) * p / n));
    }
}

#[test]
fn final_regions_partition_the_image() {
    for n in 1..=12 {
        let f = Strategy::auto(n).factors(n).unwrap();
        for pixels in [1usize, 7, 100, 1001] {
            let mut r: Vec<(usize, usize)> = (0..n).map(|k| final_region(pixels, &f, k)).collect();
            r.sort_unstable();
            let mut at = 0;
            for (a, b) in r {
                assert_eq!(a, at);
                at = b;
            }
            assert_eq!(at, pixels);
        }
    }
}

fn boxes_contain(decomp: &Decomposition, p: Vec3) -> usize {
    decomp
        .pieces()
        .iter()
        .filter(|q| q.clip.contains(p))
        .count()
}

#[test]
fn pieces_tile_the_grid_and_space() {
    let dims = [17, 9, 30];
    for n in 1..=12 {
        let f = Strategy::auto(n).factors(n).unwrap();
        let d = Decomposition::new(
            dims,
            Vec3::new(-1.0, 2.0, 0.5),
            Vec3::new(0.5, 1.0, 0.25),
            &f,
        )
        .unwrap();
        // Voxels: every voxel in exactly one piece.
        let mut count = vec![0u8; dims.iter().product()];
        for p in d.pieces() {
            for z in p.lo[2]..p.hi[2] {
                for y in p.lo[1]..p.hi[1] {
                    for x in p.lo[0]..p.hi[0] {
                        count[(z * dims[1] + y) * dims[0] + x] += 1;
                    }
                }
            }
        }
        assert!(count.iter().all(|&c| c == 1), "n {n}");
        // Space: random points (inside and far outside) in exactly one box; a voxel centre
        // in the box of the piece that owns the voxel.
        let mut st = 7;
        for _ in 0..2000 {
            let p = Vec3::new(
                (lcg(&mut st) * 40.0 - 20.0) as f32,
                (lcg(&mut st) * 40.0 - 20.0) as f32,
                (lcg(&mut st) * 40.0 - 20.0) as f32,
            );
            assert_eq!(boxes_contain(&d, p), 1, "{p}");
        }
        for p in d.pieces() {
            let c = Vec3::new(
                -1.0 + 0.5 * p.lo[0] as f32,
                2.0 + p.lo[1] as f32,
                0.5 + 0.25 * p.lo[2] as f32,
            );
            assert!(p.clip.contains(c), "n {n} {p:?}");
        }
    }
    assert!(Decomposition::new([3, 3, 3], Vec3::ZERO, Vec3::ONE, &[2, 2, 2, 2]).is_err());
}

/// The pieces a ray crosses, by entry parameter (the geometric truth).
fn crossing_order(d: &Decomposition, origin: Vec3, dir: Vec3) -> Vec<usize> {
    let ray = blueshift_camera::Ray::new(origin, dir).unwrap();
    let big = Vec3::splat(1e4);
    let mut hits: Vec<(f32, usize)> = d
        .pieces()
        .iter()
        .filter_map(|p| {
            let lo = p.clip.lo.max(-big);
            let hi = p.clip.hi.min(big);
            let (t0, t1) = ray.clip_box(lo, hi)?;
            (t1 - t0 > 1e-4).then_some((t0, p.rank))
        })
        .collect();
    hits.sort_by(|a, b| a.0.total_cmp(&b.0));
    hits.into_iter().map(|h| h.1).collect()
}

fn is_subsequence(sub: &[usize], of: &[usize]) -> bool {
    let mut it = of.iter();
    sub.iter().all(|s| it.any(|o| o == s))
}

#[test]
fn visibility_order_follows_every_ray() {
    let dims = [16, 12, 10];
    let mut st = 3;
    for n in 1..=8 {
        let f = Strategy::auto(n).factors(n).unwrap();
        let d = Decomposition::new(dims, Vec3::ZERO, Vec3::ONE, &f).unwrap();
        // Orthographic: along each axis both ways, and oblique.
        let dirs = [
            Vec3::X,
            -Vec3::X,
            Vec3::Y,
            -Vec3::Y,
            Vec3::Z,
            -Vec3::Z,
            Vec3::new(0.4, -0.7, 0.6),
            Vec3::new(-1.0, -0.2, -0.3),
        ];
        for dir in dirs {
            let order = d.visibility_order(Viewpoint::Direction(dir));
            for _ in 0..200 {
                let o = Vec3::new(
                    (lcg(&mut st) * 16.0) as f32,
                    (lcg(&mut st) * 12.0) as f32,
                    (lcg(&mut st) * 10.0) as f32,
                ) - 50.0 * dir.normalize();
                let seen = crossing_order(&d, o, dir);
                assert!(
                    is_subsequence(&seen, &order),
                    "n {n} dir {dir}: {seen:?} in {order:?}"
                );
            }
        }
        // Perspective: eyes outside and inside the volume.
        for eye in [
            Vec3::new(8.0, 6.0, 40.0),
            Vec3::new(-30.0, 20.0, -5.0),
            Vec3::new(3.3, 7.7, 2.2),
            Vec3::new(12.1, 1.4, 8.9),
        ] {
            let order = d.visibility_order(Viewpoint::Eye(eye));
            for _ in 0..300 {
                let target = Vec3::new(
                    (lcg(&mut st) * 16.0) as f32,
                    (lcg(&mut st) * 12.0) as f32,
                    (lcg(&mut st) * 10.0) as f32,
                );
                if (target - eye).length() < 1e-3 {
                    continue;
                }
                let seen = crossing_order(&d, eye, target - eye);
                assert!(
                    is_subsequence(&seen, &order),
                    "n {n} eye {eye}: {seen:?} in {order:?}"
                );
            }
        }
    }
}

#[test]
fn exclusive_scan_gives_the_sum_in_front() {
    for n in 1..=6 {
        let order: Vec<usize> = (0..n).rev().collect();
        let got = ThreadWorld::run(n, |c| {
            let me = c.rank() as f64;
            exclusive_scan(
                &c,
                &order,
                &vec![me, 1.0],
                vec![0.0, 0.0],
                |a, b| vec![a[0] + b[0], a[1] + b[1]],
                |v| v.clone(),
                |d| Ok(d.to_vec()),
            )
            .unwrap()
        });
        for (r, v) in got.iter().enumerate() {
            // In front of rank r (order n-1, ..., 0): the ranks above it.
            let want: f64 = (r + 1..n).map(|k| k as f64).sum();
            assert_eq!(v, &vec![want, (n - 1 - r) as f64]);
        }
    }
}

/// The tree scan against the sequential definition for an associative operation that does
/// not commute (concatenation): every rank gets exactly the values of the ranks in front of
/// it, in visibility order, for 1 to 9 ranks and shuffled orders; and the messages counted
/// equal [`scan_cost`] (`sum_d (n - d)`, in `ceil(log2 n)` rounds).
#[test]
fn tree_scan_concatenates_in_visibility_order() {
    for n in 1..=9usize {
        // A fixed shuffle of 0..n (multiplication by a unit mod a prime above n).
        let order: Vec<usize> = (0..11)
            .map(|i| (i * 7 + 3) % 11)
            .filter(|&r| r < n)
            .collect();
        assert_eq!(order.len(), n);
        let counters = Counters::default();
        let got = ThreadWorld::run(n, |c| {
            let c = Counting::new(c, counters.clone());
            let me = c.rank() as f64;
            exclusive_scan(
                &c,
                &order,
                &vec![me, me + 0.5],
                Vec::new(),
                |a, b| [a.as_slice(), b.as_slice()].concat(),
                |v| v.clone(),
                |d| Ok(d.to_vec()),
            )
            .unwrap()
        });
        for (p, &r) in order.iter().enumerate() {
            let want: Vec<f64> = order[..p]
                .iter()
                .flat_map(|&q| [q as f64, q as f64 + 0.5])
                .collect();
            assert_eq!(got[r], want, "n {n} rank {r} at position {p}");
        }
        let (messages, rounds) = scan_cost(n);
        assert_eq!(counters.messages(), messages, "n {n}");
        assert_eq!(
            rounds,
            n.next_power_of_two().trailing_zeros() as u64,
            "n {n}"
        );
    }
}

#[test]
fn a_failing_rank_stops_every_rank_at_the_same_phase() {
    for n in 1..=5 {
        for bad in 0..n {
            let got = ThreadWorld::run(n, |c| {
                let r = if c.rank() == bad {
                    Err(Error::Parameter("cannot read brick 3".into()))
                } else {
                    Ok(c.rank())
                };
                agree(&c, "reading", r)
            });
            for (r, g) in got.iter().enumerate() {
                match g {
                    Err(Error::Parameter(m)) if r == bad => assert!(m.contains("brick")),
                    Err(Error::PeerFailed("reading")) if r != bad => {}
                    other => panic!("rank {r}: {other:?}"),
                }
            }
        }
    }
    // Several failing: only the lowest reports its error.
    let got = ThreadWorld::run(4, |c| {
        let r = if c.rank() % 2 == 1 {
            Err(Error::Parameter(format!("rank {} broke", c.rank())))
        } else {
            Ok(())
        };
        agree(&c, "x", r)
    });
    assert!(matches!(&got[1], Err(Error::Parameter(m)) if m == "rank 1 broke"));
    for r in [0, 2, 3] {
        assert!(
            matches!(got[r], Err(Error::PeerFailed("x"))),
            "{r}: {:?}",
            got[r]
        );
    }
    // And all succeed together.
    let got = ThreadWorld::run(3, |c| agree(&c, "x", Ok::<_, Error>(c.rank())).unwrap());
    assert_eq!(got, vec![0, 1, 2]);
}
