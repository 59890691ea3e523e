//! Sort-last compositing: direct-send, binary swap and radix-k (IceT's strategies) over a
//! [`Communicator`], one implementation (radix-k; binary swap is all factors 2, direct-send
//! the one factor `n`), and the cost model of each.
//!
//! Radix-k with factors `k_1 ... k_m` (product `n`): every rank starts with a whole image
//! (`pixels` x `channels` values). In round `i` the ranks that differ only in their `i`-th
//! mixed-radix digit form a group of `k_i`; each cuts the pixel range all of them hold into
//! `k_i` parts, sends part `t` to the member of digit `t` (`k_i - 1` messages) and merges the
//! `k_i` versions of its own part in visibility order. After `m` rounds every rank holds
//! `1/n` of the composited image; rank 0 gathers them (`n - 1` messages).

use crate::comm::Communicator;
use crate::{Error, Result};

/// How two partial images combine, front to back.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Op {
    /// Sums: emission-only Doppler XYZ, sample sums. Any order gives the same value up to
    /// rounding; the schedules add in visibility order.
    Add,
    /// Premultiplied RGBA "over" (the last of the channels is alpha): `front + (1 -
    /// alpha_front) back`. Associative, not commutative.
    Over,
}

impl Op {
    /// Merges `parts` (front to back, each `channels` values per pixel) into `out`.
    pub fn merge(self, channels: usize, parts: &[&[f64]], out: &mut [f64]) {
        out.copy_from_slice(parts[0]);
        for p in &parts[1..] {
            match self {
                Op::Add => {
                    for (o, v) in out.iter_mut().zip(p.iter()) {
                        *o += v;
                    }
                }
                Op::Over => {
                    for (o, b) in out.chunks_exact_mut(channels).zip(p.chunks_exact(channels)) {
                        let t = 1.0 - o[channels - 1];
                        for c in 0..channels {
                            o[c] += t * b[c];
                        }
                    }
                }
            }
        }
    }
}

/// A compositing schedule.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Strategy {
    /// Every rank sends each other rank its part at once: one round of radix `n`.
    DirectSend,
    /// Binary swap: `log2 n` rounds of pairs (power-of-two rank counts).
    BinarySwap,
    /// Radix-k with these factors, bottom round first (product: the rank count).
    RadixK(Vec<usize>),
}

/// The largest group radix-k's automatic factors form (IceT's default target `k = 8`).
pub const RADIX_TARGET: usize = 8;

impl Strategy {
    /// The choice by rank count: binary swap for powers of two; otherwise radix-k over the
    /// prime factors of `n`, grouped greedily (largest first) into factors of at most
    /// [`RADIX_TARGET`] where they fit; a prime `n` is direct-send.
    #[must_use]
    pub fn auto(n: usize) -> Self {
        if n <= 1 {
            return Strategy::RadixK(vec![]);
        }
        if n.is_power_of_two() {
            return Strategy::BinarySwap;
        }
        let mut primes = Vec::new();
        let mut m = n;
        let mut p = 2;
        while p * p <= m {
            while m.is_multiple_of(p) {
                primes.push(p);
                m /= p;
            }
            p += 1;
        }
        if m > 1 {
            primes.push(m);
        }
        if primes.len() == 1 {
            return Strategy::DirectSend;
        }
        primes.sort_unstable_by(|a, b| b.cmp(a));
        let mut factors: Vec<usize> = Vec::new();
        for p in primes {
            match factors.iter_mut().find(|f| **f * p <= RADIX_TARGET) {
                Some(f) => *f *= p,
                None => factors.push(p),
            }
        }
        Strategy::RadixK(factors)
    }

    /// The factors for `n` ranks (bottom round first).
    ///
    /// # Errors
    /// [`Error::Parameter`] when binary swap is asked of a rank count that is not a power of
    /// two, or radix-k factors whose product is not `n`.
    pub fn factors(&self, n: usize) -> Result<Vec<usize>> {
        let f = match self {
            _ if n == 1 => vec![],
            Strategy::DirectSend => vec![n],
            Strategy::BinarySwap => {
                if !n.is_power_of_two() {
                    return Err(Error::parameter(format!(
                        "binary swap needs a power-of-two rank count, not {n}"
                    )));
                }
                vec![2; n.trailing_zeros() as usize]
            }
            Strategy::RadixK(f) => f.clone(),
        };
        if f.iter().product::<usize>() != n || f.iter().any(|&k| k < 2) {
            return Err(Error::parameter(format!(
                "radix-k factors {f:?} do not multiply to {n} ranks (each at least 2)"
            )));
        }
        Ok(f)
    }
}

/// `[start, end)` of part `j` of `k` of the pixel range `[s, e)`.
#[must_use]
pub fn part(s: usize, e: usize, k: usize, j: usize) -> (usize, usize) {
    (s + (e - s) * j / k, s + (e - s) * (j + 1) / k)
}

/// The pixel range rank `rank` holds after all rounds of `factors`.
#[must_use]
pub fn final_region(pixels: usize, factors: &[usize], rank: usize) -> (usize, usize) {
    let (mut s, mut e) = (0, pixels);
    let mut stride = 1;
    for &k in factors {
        let d = (rank / stride) % k;
        (s, e) = part(s, e, k, d);
        stride *= k;
    }
    (s, e)
}

/// Composites every rank's `image` (`channels` values per pixel) with radix-k over
/// `factors` (see the module docs), merging each group in `position` order (`position[r]`:
/// rank `r`'s place in the visibility order; for [`Op::Over`] the decomposition must have
/// been built for the same factors, or `factors == [n]`). Rank 0 returns the whole image,
/// the others `None`.
///
/// # Errors
/// [`Error::Comm`] from the communicator or a message of the wrong size; [`Error::Parameter`]
/// for factors that do not multiply to the rank count or an image of the wrong length.
pub fn composite(
    comm: &dyn Communicator,
    mut image: Vec<f64>,
    channels: usize,
    op: Op,
    factors: &[usize],
    position: &[usize],
) -> Result<Option<Vec<f64>>> {
    let n = comm.size();
    let me = comm.rank();
    if factors.iter().product::<usize>() != n || position.len() != n {
        return Err(Error::parameter(format!(
            "compositing: factors {factors:?} and {} positions for {n} ranks",
            position.len()
        )));
    }
    if channels == 0 || !image.len().is_multiple_of(channels) {
        return Err(Error::parameter(
            "compositing: image length not a pixel multiple",
        ));
    }
    let pixels = image.len() / channels;
    let (mut s, mut e) = (0, pixels);
    let mut stride = 1;
    let mut merged = Vec::new();
    for &k in factors {
        let d = (me / stride) % k;
        let member = |t: usize| me - d * stride + t * stride;
        let mine = part(s, e, k, d);
        let mut pieces: Vec<(usize, Vec<f64>)> = Vec::with_capacity(k);
        for shift in 1..k {
            let to = (d + shift) % k;
            let from = (d + k - shift) % k;
            let (a, b) = part(s, e, k, to);
            let got =
                comm.send_recv(&image[a * channels..b * channels], member(to), member(from))?;
            if got.len() != (mine.1 - mine.0) * channels {
                return Err(Error::comm(format!(
                    "rank {me}: {} values from rank {}, expected {}",
                    got.len(),
                    member(from),
                    (mine.1 - mine.0) * channels
                )));
            }
            pieces.push((position[member(from)], got));
        }
        let own = image[mine.0 * channels..mine.1 * channels].to_vec();
        pieces.push((position[me], own));
        pieces.sort_by_key(|p| p.0);
        let parts: Vec<&[f64]> = pieces.iter().map(|p| &p.1[..]).collect();
        merged.resize(own_len(mine, channels), 0.0);
        op.merge(channels, &parts, &mut merged);
        image[mine.0 * channels..mine.1 * channels].copy_from_slice(&merged);
        (s, e) = mine;
        stride *= k;
    }
    gather(comm, image, channels, factors, (s, e))
}

fn own_len(r: (usize, usize), channels: usize) -> usize {
    (r.1 - r.0) * channels
}

/// Rank 0 collects every rank's final region into its image.
fn gather(
    comm: &dyn Communicator,
    mut image: Vec<f64>,
    channels: usize,
    factors: &[usize],
    mine: (usize, usize),
) -> Result<Option<Vec<f64>>> {
    let pixels = image.len() / channels;
    if comm.rank() != 0 {
        comm.send(0, &image[mine.0 * channels..mine.1 * channels])?;
        return Ok(None);
    }
    for r in 1..comm.size() {
        let (a, b) = final_region(pixels, factors, r);
        let got = comm.recv(r)?;
        if got.len() != (b - a) * channels {
            return Err(Error::comm(format!(
                "gather: {} values from rank {r}, expected {}",
                got.len(),
                (b - a) * channels
            )));
        }
        image[a * channels..b * channels].copy_from_slice(&got);
    }
    Ok(Some(image))
}

/// An exclusive scan in visibility order: the rank at position `p` of `order` gets the sum
/// (by `add`, front operand first) of the `local` values of the ranks at positions `0..p`
/// (`empty` for the first). Recursive doubling (Hillis and Steele): in round `d = 1, 2, 4,
/// ...` the rank at `p` sends the sum it holds of positions `p - 2d + 1 ..= p` (clipped at
/// 0) to position `p + d` and adds the one from `p - d` in front of its own. `ceil(log2 n)`
/// rounds of latency instead of a chain's `n - 1`; `sum_d (n - d)` messages. `add` must be
/// associative (the sums group differently from a chain's; the optical depths are, up to
/// rounding). Values travel encoded by `encode` / `decode`.
///
/// # Errors
/// [`Error::Comm`] from the communicator or `decode`.
pub fn exclusive_scan<T>(
    comm: &dyn Communicator,
    order: &[usize],
    local: &T,
    empty: T,
    add: impl Fn(&T, &T) -> T,
    encode: impl Fn(&T) -> Vec<f64>,
    decode: impl Fn(&[f64]) -> Result<T>,
) -> Result<T> {
    let me = comm.rank();
    let n = order.len();
    let p = order
        .iter()
        .position(|&r| r == me)
        .ok_or_else(|| Error::parameter(format!("scan: rank {me} not in the order")))?;
    // `front`: the sum of the positions in front of p received so far (exclusive);
    // `held`: that plus the local value (what p passes on).
    let mut front: Option<T> = None;
    let mut held: Option<T> = None;
    let mut d = 1;
    while d < n {
        let to = (p + d < n).then(|| order[p + d]);
        let from = (p >= d).then(|| order[p - d]);
        let out = to.map(|_| encode(held.as_ref().unwrap_or(local)));
        let got = match (to, from, out) {
            (Some(t), Some(f), Some(o)) => Some(comm.send_recv(&o, t, f)?),
            (Some(t), None, Some(o)) => {
                comm.send(t, &o)?;
                None
            }
            (None, Some(f), _) => Some(comm.recv(f)?),
            _ => None,
        };
        if let Some(g) = got {
            let g = decode(&g)?;
            held = Some(add(&g, held.as_ref().unwrap_or(local)));
            front = Some(match &front {
                Some(f) => add(&g, f),
                None => g,
            });
        }
        d *= 2;
    }
    Ok(front.unwrap_or(empty))
}

/// Messages and rounds of [`exclusive_scan`] over `n` ranks: `sum_d (n - d)` messages for
/// `d = 1, 2, 4, ... < n`, in `ceil(log2 n)` rounds.
#[must_use]
pub fn scan_cost(n: usize) -> (u64, u64) {
    let (mut messages, mut rounds, mut d) = (0u64, 0u64, 1usize);
    while d < n {
        messages += (n - d) as u64;
        rounds += 1;
        d *= 2;
    }
    (messages, rounds)
}

/// Messages and bytes of a compositing run, all ranks together.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Cost {
    /// Point-to-point messages.
    pub messages: u64,
    /// Payload bytes.
    pub bytes: u64,
    /// Message steps on the critical path: `sum (k_i - 1)` exchanges, then the gather's
    /// `n - 1` receives at rank 0.
    pub steps: u64,
}

/// The cost of radix-k over `factors` for an image of `pixels` x `channels` f64 values,
/// gather included, in closed form: `messages = n sum_i (k_i - 1) + n - 1`, `bytes = 8 C
/// (n sum_i (k_i - 1) P / (k_1 ... k_i) + (n - 1) P / n)`. Exact when `pixels` divides
/// evenly at every round (a multiple of `n`); otherwise within a few pixels per message.
#[must_use]
pub fn cost(factors: &[usize], pixels: u64, channels: u64) -> Cost {
    let n: u64 = factors.iter().map(|&k| k as u64).product();
    let mut messages = 0u64;
    let mut values = 0.0f64;
    let mut prod = 1.0f64;
    let mut steps = 0u64;
    for &k in factors {
        let k = k as u64;
        messages += n * (k - 1);
        steps += k - 1;
        prod *= k as f64;
        values += (n * (k - 1)) as f64 * pixels as f64 / prod;
    }
    messages += n - 1;
    steps += n - 1;
    values += (n - 1) as f64 * pixels as f64 / n as f64;
    Cost {
        messages,
        bytes: (8.0 * channels as f64 * values).round() as u64,
        steps,
    }
}
