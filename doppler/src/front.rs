//! The XYZ of a ray with line absorption, front to back, in time proportional to the line
//! windows a segment touches (not to the whole optical-depth spectrum).
//!
//! Segments are taken from the eye, `k = 0, 1, ...`. Segment `k` emits `E_k` (its black body
//! on the uniform grid `lambda_i` as hat-function coefficients `r_k[i]`, plus line
//! trapezoids `e_k`) and absorbs with optical depth `a_k(lambda)` (its absorption lines).
//! The light it emits crosses everything in front and half of its own depth (the convention
//! of the back-to-front path and of the banded integrators), so it reaches the eye attenuated
//! by `P_k = a_0 + ... + a_{k-1} + a_k / 2`. Its XYZ is the closed-form XYZ of `E_k` minus
//!
//! `r_k . W(P_k) + integral e_k(lambda) cmf(lambda) (1 - exp(-P_k(lambda))) d lambda`,
//!
//! where `W_i(P) = integral hat_i cmf (1 - exp(-P))` holds, per black-body grid point, the
//! part of its hat function's XYZ that the depth `P` takes away. The march keeps `W` for
//! `A_{k-1} = a_0 + ... + a_{k-1}`, the depth in front. Segment `k` sweeps its own line
//! windows once (the supports of `a_k` and `e_k`): there it adds `integral hat_i cmf
//! (exp(-A_{k-1}) - exp(-A_k))` to `W`, and takes its own light's absorbed part, `r_k .
//! W(A_{k-1})` (one dot product of `blackbody_samples` terms) plus `r_k . integral hat cmf
//! (exp(-A_{k-1}) - exp(-P_k))` and the lines' part, from the same sub-intervals. (An
//! earlier form stepped `P_{k-1}` to `P_k` by `(a_{k-1} + a_k) / 2`, whose two shifted
//! windows cut each line into three sub-intervals and were swept twice.) `A` is a flat
//! sorted array of pieces; adding `a_k` is one pass.
//!
//! Every integral is exact in closed form: on each sub-interval (cut at the breakpoints of
//! `A`, `a_k`, `e_k`, the CMF table and the black-body grid) the hats, the CMFs and `e_k` are
//! linear, so their products are quadratics, and each depth is linear, so its transmittance
//! is an exponential of the wavelength: `integral x^n exp(-(p + s x)) dx` (n = 0, 1, 2) by the
//! recurrence of [`exp_moments`], taken from the end where the depth is smaller so nothing
//! overflows.
//!
//! Error bound (`tol = merge_tolerance`), a budget for the whole ray in four shares:
//! - merges of `A` (the `k`-th with `tol/32 * 6 / (pi k)^2`; the series sums to `tol/32`).
//!   `W` is not recomputed after a merge (that would be a pass over all of `A`): the updates
//!   after it are exact differences, so `W` keeps what the merges moved, at most `tol/32`
//!   of each hat's XYZ more. (Merges mostly keep `A` short; on the He-rich scene a larger
//!   share bought little time for much of the measured error);
//! - leaving the weakest absorption out of the sweeps: single lines of single segments,
//!   smallest peak depth first, at most `25 tol/32` in total (they are known before the
//!   march, see `choose_omissions`). A left-out line still acts, to first order and without a
//!   sweep: its depth is binned finely (`OmittedDepth`) and each later emission line's light
//!   is attenuated by the binned depth at the line's middle (times the transmittance of `A`
//!   and half its own depth there), and it adds its area times the hats and CMFs at its
//!   middle, behind `A` there, to `W` (`omitted_into_w`). Each estimate lies between zero
//!   and what the line's peak depth could take, so the bound is that of leaving the line out;
//!   the measured error is several times smaller (on the He-rich scene, leaving lines out
//!   was most of the error, from emission lines behind absorption lines of their own species);
//! - within one segment's sweep, `A` is read as chords across several of its pieces
//!   (`chord_over`), each within `eps = ln(1 + 3 tol/32)` of `A` on the chord's span, with the
//!   slope that keeps `A`'s integral where the allowed slopes include it (so the error is
//!   mostly of second order). Segment `k` moves `W` by `integral hat cmf exp(-A_{k-1}) (1 -
//!   exp(-a_k))`, here off by a factor of at most `e^eps - 1 = 3 tol/32`, and these weights
//!   summed over the segments telescope to at most `1 - exp(-A)`: the chords move `W` by at
//!   most `3 tol/32` of each hat's XYZ in all. The part behind its own half depth, used once
//!   for the segment's own light, and each line's absorbed part are off by the same factor.
//!   (Most of `A`'s breakpoints inside a line window are the edges of earlier segments'
//!   sweeps of the same lines, which the chords step over);
//! - for the faintest segments' line light (faintest first, at most `3 tol/32` of each XYZ
//!   channel's unattenuated total), each line attenuated by the transmittance at its middle
//!   instead of exactly: off by at most the line's own light.
//!
//! So `A` (and `P`) is within `tol/32 + 25 tol/32 = 13 tol/16` of the exact depth everywhere
//! and each transmittance within `13 tol/16`, the chords add `3 tol/32`: the black body's
//! absorbed part is within `29 tol/32` of its unattenuated XYZ, the lines' within `29 tol/32
//! + 3 tol/32`, and every XYZ channel within `tol` x the same channel of the unattenuated
//! emission. `tol = 0` leaves out and merges nothing and reads `A` exactly. Only the
//! piece-budget fallback (counted) can break the bound. The bound is loose: on the He-rich
//! scene `tol = 0.6` measures a mean error of 6.6e-4 of the converged image.

use blueshift_spectrum::{Piece, Xyz, merge_pieces};

use super::pwl::{PwlTables, bb_row, segment_lines, segment_lines_both, spectrum_err};
use super::render::{Context, RayOut, RaySamples};
use crate::Result;

/// The error budget's shares of `tol` (module docs): merges of `A`, left-out absorption
/// lines, chords, and line light attenuated at each line's middle.
const MERGE_SHARE: f64 = 1.0 / 32.0;
const DEPTH_SHARE: f64 = 25.0 / 32.0;
pub(crate) const CHORD_SHARE: f64 = 3.0 / 32.0;
const LIGHT_SHARE: f64 = 3.0 / 32.0;

/// A line trapezoid `(lo, hi, h_lo, h_hi)` as [`segment_lines`] gives it.
type Trap = (f64, f64, f64, f64);

/// Sums trapezoids (in any order, possibly overlapping) times `scale` into sorted, disjoint
/// pieces, appended to `out`.
fn sum_trapezoids(tr: &mut [Trap], scale: f64, out: &mut Vec<Piece>, cuts: &mut Vec<f64>) {
    if !tr.is_sorted_by(|a, b| a.0 <= b.0) {
        tr.sort_unstable_by(|a, b| a.0.total_cmp(&b.0));
    }
    let mut a = 0;
    while a < tr.len() {
        // A cluster: trapezoids that overlap (transitively) the first one.
        let mut b = a + 1;
        let mut end = tr[a].1;
        while b < tr.len() && tr[b].0 < end {
            end = end.max(tr[b].1);
            b += 1;
        }
        let cluster = &tr[a..b];
        if let [(lo, hi, h0, h1)] = *cluster {
            out.push(Piece {
                start_nm: lo,
                end_nm: hi,
                value_start: h0 * scale,
                value_end: h1 * scale,
            });
        } else {
            cuts.clear();
            cuts.extend(cluster.iter().flat_map(|t| [t.0, t.1]));
            cuts.sort_unstable_by(f64::total_cmp);
            cuts.dedup();
            for w in cuts.windows(2) {
                let (x0, x1) = (w[0], w[1]);
                let (mut v0, mut v1, mut any) = (0.0, 0.0, false);
                for &(lo, hi, h0, h1) in cluster {
                    if lo <= x0 && hi >= x1 {
                        let slope = (h1 - h0) / (hi - lo);
                        v0 += if x0 == lo { h0 } else { h0 + slope * (x0 - lo) };
                        v1 += if x1 == hi { h1 } else { h0 + slope * (x1 - lo) };
                        any = true;
                    }
                }
                if any {
                    out.push(Piece {
                        start_nm: x0,
                        end_nm: x1,
                        value_start: (v0 * scale).max(0.0),
                        value_end: (v1 * scale).max(0.0),
                    });
                }
            }
        }
        a = b;
    }
}

/// How many pieces from the start of `a` end at or before `x` (`a` sorted): a galloping
/// search, as the answer is usually small (the cursors advance by a few pieces at a time).
#[inline]
fn count_ending_by(a: &[Piece], x: f64) -> usize {
    let mut hi = 1;
    while hi <= a.len() && a[hi - 1].end_nm <= x {
        hi *= 2;
    }
    let lo = hi / 2;
    let hi = hi.min(a.len());
    lo + a[lo..hi].partition_point(|p| p.end_nm <= x)
}

/// The part of `p` from `x` on (all of it when it starts at or after `x`).
#[inline]
fn from(p: Piece, x: f64) -> Piece {
    if p.start_nm >= x {
        p
    } else {
        Piece {
            start_nm: x,
            end_nm: p.end_nm,
            value_start: p.at(x),
            value_end: p.value_end,
        }
    }
}

/// The depth `p` (sorted, disjoint pieces) as chords, each within `eps` of it on its span
/// ([`chord_over`]'s rule, the integral kept where the allowed slopes include it): fewer
/// pieces for a depth that is sent and swept again (distributed rendering). `eps <= 0`
/// returns `p` unchanged.
#[must_use]
pub fn chord_depth(p: &[Piece], eps: f64) -> Vec<Piece> {
    let (Some(first), Some(last)) = (p.first(), p.last()) else {
        return Vec::new();
    };
    if eps <= 0.0 || p.len() < 3 {
        return p.to_vec();
    }
    let (mut u, limit) = (first.start_nm, last.end_nm);
    let mut c = Cursor::new(p);
    let mut out = Vec::new();
    // P's own pieces over [u, end) (where a chord would not do).
    let exact = |u: f64, end: f64, out: &mut Vec<Piece>| {
        for q in p.iter().filter(|q| q.end_nm > u && q.start_nm < end) {
            let mut q = *q;
            if q.start_nm < u {
                q.value_start = value_at(&q, u);
                q.start_nm = u;
            }
            if q.end_nm > end {
                q.value_end = value_at(&q, end);
                q.end_nm = end;
            }
            out.push(q);
        }
    };
    while u < limit {
        let cur = c.at(u);
        let (end, a, b) = chord_over(&c, cur, u, limit, eps);
        if end <= u {
            // Rounding left no room: keep the rest exact.
            exact(u, limit, &mut out);
            break;
        }
        if a < 0.0 || b < 0.0 {
            // A depth is never negative: keep P itself here.
            exact(u, end, &mut out);
        } else if a != 0.0 || b != 0.0 {
            out.push(Piece {
                start_nm: u,
                end_nm: end,
                value_start: a,
                value_end: b,
            });
        }
        u = end;
    }
    out
}

/// `a + b` for sorted, disjoint piece lists, into `out` (cleared first). Runs of `a` that `b`
/// does not touch are copied as they are; `b` is expected to be the short one.
pub(crate) fn add_sorted(a: &[Piece], b: &[Piece], out: &mut Vec<Piece>) {
    out.clear();
    // Invariant: a[..i] is out, and a[i] is out up to x.
    let mut i = 0;
    let mut x = f64::NEG_INFINITY;
    for q in b {
        let n = count_ending_by(&a[i..], q.start_nm);
        if n > 0 {
            out.push(from(a[i], x));
            out.extend_from_slice(&a[i + 1..i + n]);
            i += n;
        }
        if let Some(&p) = a.get(i).filter(|p| p.start_nm < q.start_nm) {
            let lo = p.start_nm.max(x);
            if lo < q.start_nm {
                out.push(Piece {
                    start_nm: lo,
                    end_nm: q.start_nm,
                    value_start: p.at(lo),
                    value_end: p.at(q.start_nm),
                });
            }
        }
        x = q.start_nm;
        while x < q.end_nm {
            let p = a.get(i).copied().filter(|p| p.start_nm <= x);
            let next = match p {
                Some(p) => p.end_nm.min(q.end_nm),
                None => a.get(i).map_or(q.end_nm, |p| p.start_nm.min(q.end_nm)),
            };
            let (pu, pw) = p.map_or((0.0, 0.0), |p| (p.at(x), p.at(next)));
            out.push(Piece {
                start_nm: x,
                end_nm: next,
                value_start: pu + q.at(x),
                value_end: pw + q.at(next),
            });
            x = next;
            if p.is_some_and(|p| p.end_nm <= x) {
                i += 1;
            }
        }
    }
    if i < a.len() {
        out.push(from(a[i], x));
        out.extend_from_slice(&a[i + 1..]);
    }
}

/// A piece's values at `u` and `w` (inside it or at its end; zero for none).
#[inline]
pub(crate) fn ends(q: Option<Piece>, u: f64, w: f64) -> (f64, f64) {
    q.map_or((0.0, 0.0), |q| {
        let slope = (q.value_end - q.value_start) / (q.end_nm - q.start_nm);
        let at = |x: f64| {
            if x >= q.end_nm {
                q.value_end
            } else {
                q.value_start + slope * (x - q.start_nm)
            }
        };
        (at(u), at(w))
    })
}

/// A cursor over sorted, disjoint pieces, advanced monotonically.
pub(crate) struct Cursor<'a> {
    pieces: &'a [Piece],
    i: usize,
}

impl<'a> Cursor<'a> {
    pub(crate) fn new(pieces: &'a [Piece]) -> Self {
        Self { pieces, i: 0 }
    }

    /// The piece holding `x` (`start <= x < end`), if any; skips pieces ending at or before `x`.
    #[inline]
    pub(crate) fn at(&mut self, x: f64) -> Option<Piece> {
        if self.pieces.get(self.i).is_some_and(|p| p.end_nm <= x) {
            self.i += count_ending_by(&self.pieces[self.i..], x);
        }
        self.pieces.get(self.i).copied().filter(|p| p.start_nm <= x)
    }

    /// The next breakpoint after `x` given the piece `at(x)` returned.
    #[inline]
    pub(crate) fn next_break(&self, current: Option<Piece>) -> f64 {
        match current {
            Some(p) => p.end_nm,
            None => self
                .pieces
                .get(self.i)
                .map_or(f64::INFINITY, |p| p.start_nm),
        }
    }
}

/// `1 / (k! (n + k + 1))` for `n = 0, 1, 2` and `k = 0..8`: the series of [`exp_moments`].
const SERIES: [[f64; 8]; 3] = {
    let mut c = [[0.0; 8]; 3];
    let mut n = 0;
    while n < 3 {
        let mut k = 0;
        let mut fact = 1.0;
        while k < 8 {
            c[n][k] = 1.0 / (fact * (n + k + 1) as f64);
            k += 1;
            fact *= k as f64;
        }
        n += 1;
    }
    c
};

/// `[int_0^h x^n exp(-s x) dx for n = 0, 1, 2]` for `s >= 0`, given `e = exp(-s h)`; the
/// series where `s h` is small (the recurrence cancels there).
#[inline]
fn exp_moments(s: f64, h: f64, e: f64) -> [f64; 3] {
    let z = s * h;
    if z < 0.05 {
        // h^(n+1) sum_k (-z)^k / (k! (n + k + 1)); 8 terms: error < 0.05^8 / 8! ~ 1e-15.
        let mz = -z;
        let horner = |c: &[f64; 8]| c.iter().rev().fold(0.0, |acc, &ck| acc * mz + ck);
        let h2 = h * h;
        [
            horner(&SERIES[0]) * h,
            horner(&SERIES[1]) * h2,
            horner(&SERIES[2]) * h2 * h,
        ]
    } else {
        let r = 1.0 / s;
        let i0 = (1.0 - e) * r;
        let i1 = (i0 - h * e) * r;
        let i2 = (2.0 * i1 - h * h * e) * r;
        [i0, i1, i2]
    }
}

/// `[int_0^h x^n exp(-p(x)) dx]` for the linear depth `p` going from `pu` to `pw` over
/// `[0, h]`, given the transmittances `tu = exp(-pu)`, `tw = exp(-pw)`; computed from the end
/// where the depth is smaller, so nothing overflows.
#[inline]
pub(crate) fn depth_moments(pu: f64, pw: f64, tu: f64, tw: f64, h: f64) -> [f64; 3] {
    if pw >= pu {
        if tu <= 0.0 {
            return [0.0; 3];
        }
        let m = exp_moments((pw - pu) / h, h, tw / tu);
        [tu * m[0], tu * m[1], tu * m[2]]
    } else {
        if tw <= 0.0 {
            return [0.0; 3];
        }
        // From the right end: x = h - y.
        let m = exp_moments((pu - pw) / h, h, tu / tw);
        [
            tw * m[0],
            tw * (h * m[0] - m[1]),
            tw * (h * h * m[0] - 2.0 * h * m[1] + m[2]),
        ]
    }
}

/// `integral_0^h f(x) g(x) J(x) dx` for linear `f = fu + df x`, `g = gu + dg x` against the
/// moments `j` of `J`.
#[inline]
fn quad_dot(fu: f64, df: f64, gu: f64, dg: f64, j: &[f64; 3]) -> f64 {
    fu * gu * j[0] + (fu * dg + df * gu) * j[1] + df * dg * j[2]
}

/// A depth function's transmittance at the last point asked, reused by the next sub-interval.
#[derive(Clone, Copy)]
pub(crate) struct Carry {
    x: f64,
    depth: f64,
    trans: f64,
}

impl Carry {
    pub(crate) const NONE: Self = Self {
        x: f64::NAN,
        depth: f64::NAN,
        trans: 1.0,
    };

    #[inline]
    pub(crate) fn trans(&mut self, x: f64, depth: f64) -> f64 {
        if x != self.x || depth != self.depth {
            self.x = x;
            self.depth = depth;
            self.trans = (-depth).exp();
        }
        self.trans
    }
}

/// `1 - exp(-x)` for `x >= 0`, within 2e-14 of it relatively: a series below 0.01, where the
/// difference would cancel, and `exp` (several times cheaper than `exp_m1` here) above.
#[inline]
fn absorbed_by(x: f64) -> f64 {
    if x < 1e-2 {
        // Six terms; the next, x^7 / 5040, is below 2e-16 x.
        let tail = 1.0 / 24.0 - x * (1.0 / 120.0 - x * (1.0 / 720.0));
        x * (1.0 - x * (0.5 - x * (1.0 / 6.0 - x * tail)))
    } else {
        1.0 - (-x).exp()
    }
}

/// `q` at `x` in `[start, end]`, computed the same way wherever it is asked (so a
/// sub-interval that ends where the next begins sees the same depth from both sides).
#[inline]
fn value_at(q: &Piece, x: f64) -> f64 {
    if x >= q.end_nm {
        q.value_end
    } else {
        let slope = (q.value_end - q.value_start) / (q.end_nm - q.start_nm);
        q.value_start + slope * (x - q.start_nm)
    }
}

/// The longest chord of the depth `P` (the pieces under `pc`) from `u` towards `limit` that
/// stays within `eps` of `P` on both sides of every breakpoint it crosses: returns its end
/// (one of P's breakpoints, or `limit`) and its values at `u` (`P(u)` from the right) and at
/// the end. `current` is P's piece at `u` (`None` in a gap). As `P` and the chord are both
/// linear between P's breakpoints, checking the breakpoints bounds every point.
///
/// The set of slopes from `(u, P(u))` within `eps` of every point seen so far is an
/// interval (the cone) that each point narrows; the chord ends before the first point that
/// would empty it. At least the first breakpoint is always reached (from its left the chord
/// is `P`'s own piece).
fn chord_over(
    pc: &Cursor<'_>,
    current: Option<Piece>,
    u: f64,
    limit: f64,
    eps: f64,
) -> (f64, f64, f64) {
    let a = current.map_or(0.0, |q| value_at(&q, u));
    let (mut lo, mut hi) = (f64::NEG_INFINITY, f64::INFINITY);
    // The piece P is in on the left of the next breakpoint (`None`: a gap), the index of
    // the piece after it, and the last point passed with P's value on its right.
    let mut inside = current;
    let mut i = pc.i;
    let pieces = pc.pieces;
    let (mut last_x, mut last_value) = (u, a);
    // The integral of P from u to the chord's end so far.
    let (mut area, mut end) = (0.0, u);
    loop {
        // The next breakpoint: the end of the piece P is in, or the start of the next piece.
        let x = match inside {
            Some(q) => q.end_nm,
            None => pieces.get(i).map_or(f64::INFINITY, |q| q.start_nm),
        };
        let x = x.min(limit);
        let left = inside.map_or(0.0, |q| value_at(&q, x));
        let inv = 1.0 / (x - u);
        let (l1, h1) = ((left - eps - a) * inv, (left + eps - a) * inv);
        if l1.max(lo) > h1.min(hi) {
            break;
        }
        lo = lo.max(l1);
        hi = hi.min(h1);
        area += 0.5 * (last_value + left) * (x - last_x);
        end = x;
        if x >= limit {
            break;
        }
        // The right side of x: the next piece if it starts here, else a gap.
        let next = match inside {
            Some(_) => {
                i += 1;
                pieces.get(i).copied().filter(|q| q.start_nm <= x)
            }
            None => pieces.get(i).copied(),
        };
        let right = next.map_or(0.0, |q| q.value_start);
        let (l2, h2) = ((right - eps - a) * inv, (right + eps - a) * inv);
        if l2.max(lo) > h2.min(hi) {
            break;
        }
        lo = lo.max(l2);
        hi = hi.min(h2);
        (last_x, last_value) = (x, right);
        inside = next;
    }
    if end <= u {
        // Nothing reached (rounding): P's own piece to its first breakpoint.
        let x = pc.next_break(current).min(limit);
        return (x, a, current.map_or(0.0, |q| value_at(&q, x)));
    }
    // Of the slopes in the cone, the one that keeps P's integral (the transmittance's error
    // is then of second order where the weights are flat).
    let len = end - u;
    let s = (2.0 * (area / len - a) / len).clamp(lo, hi);
    (end, a, a + s * len)
}

/// Per-ray state of the sweep.
struct Sweep<'a> {
    t: &'a PwlTables,
    /// How far (optical depth) the sweep's chords may stray from `P` (0: no chords).
    eps: f64,
    /// `W_i`, per black-body grid point and XYZ channel.
    w: Vec<[f64; 3]>,
}

impl Sweep<'_> {
    /// Over the supports of `d` (a segment's whole optical depth) and `e` (its line light):
    /// adds `integral hat_i cmf (exp(-p) - exp(-(p + d)))` to `W_i` and returns the light
    /// that the depth `p + d/2` (in front plus half its own) takes: `integral e cmf (1 -
    /// exp(-(p + d/2)))` plus, given the segment's black-body row `row`, `sum_i row_i
    /// integral hat_i cmf (exp(-p) - exp(-(p + d/2)))` (XYZ).
    fn run(&mut self, p: &[Piece], d: &[Piece], e: &[Piece], row: Option<&[f64]>) -> [f64; 3] {
        let t = self.t;
        let c_lo = t.cmf_lo;
        let c_step = t.cmf_step;
        let c_hi = c_lo + c_step * (t.cmf.len() - 1) as f64;
        let k = t.lambdas.len();
        let (g0, g1) = (t.lambdas[0], t.lambdas[k - 1]);
        let gstep = (g1 - g0) / (k - 1) as f64;
        let inv_gstep = 1.0 / gstep;
        let inv_cstep = 1.0 / c_step;
        let mut taken = [0.0f64; 3];
        let (mut pc, mut dc, mut ec) = (Cursor::new(p), Cursor::new(d), Cursor::new(e));
        let (mut before, mut half, mut after) = (Carry::NONE, Carry::NONE, Carry::NONE);
        let start = |d: &[Piece], e: &[Piece]| {
            d.first()
                .map_or(f64::INFINITY, |q| q.start_nm)
                .min(e.first().map_or(f64::INFINITY, |q| q.start_nm))
        };
        let mut u = start(d, e).max(c_lo);
        // The CMFs at the end of the previous sub-interval (reused when the next starts there).
        let mut c_prev = (f64::NAN, [0.0; 3]);
        while u < c_hi {
            let dp = dc.at(u);
            let ep = ec.at(u);
            if dp.is_none() && ep.is_none() {
                // A gap in both: jump to the next piece.
                u = dc.next_break(None).min(ec.next_break(None));
                continue;
            }
            let pp = pc.at(u);
            let mut w = c_hi.min(dc.next_break(dp)).min(ec.next_break(ep));
            w = w.min(super::pwl::cell_of(c_lo, c_step, inv_cstep, u).1);
            let in_grid = u >= g0 && u < g1;
            let cell = if in_grid {
                let (i, next) = super::pwl::cell_of(g0, gstep, inv_gstep, u);
                let i = i.min(k - 2);
                w = w.min(if i == k - 2 { g1 } else { next });
                Some(i)
            } else {
                if u < g0 {
                    w = w.min(g0);
                }
                None
            };
            // P on [u, w]: its own piece up to its next breakpoint, or a chord over several
            // of P's pieces that stays within `eps` of P (module docs).
            let p_break = pc.next_break(pp);
            let mut chord = None;
            if p_break < w {
                if self.eps > 0.0 && p_break > u {
                    let (end, pu, pw) = chord_over(&pc, pp, u, w, self.eps);
                    w = end;
                    chord = Some((pu, pw));
                } else {
                    w = p_break;
                }
            }
            if w <= u {
                // A breakpoint that rounding put at u.
                w = c_hi.min(u + 1e-9 * u.abs().max(1.0));
                if w <= u {
                    break;
                }
            }
            let h = w - u;
            let (pu, pw) = chord.unwrap_or_else(|| ends(pp, u, w));
            let (du, dw) = ends(dp, u, w);
            let (eu, ew) = ends(ep, u, w);
            let has_d = du > 0.0 || dw > 0.0;
            let has_e = (eu > 0.0 || ew > 0.0) && (has_d || pu > 0.0 || pw > 0.0);
            let bb = row.filter(|_| has_d).zip(cell);
            if !(has_d || has_e) {
                u = w;
                continue;
            }
            let inv_h = 1.0 / h;
            let j_before = depth_moments(pu, pw, before.trans(u, pu), before.trans(w, pw), h);
            // Behind half the segment's own depth (its light), and behind all of it (W).
            let j_half = if has_d && (has_e || bb.is_some()) {
                let (hu, hw) = (pu + 0.5 * du, pw + 0.5 * dw);
                depth_moments(hu, hw, half.trans(u, hu), half.trans(w, hw), h)
            } else {
                j_before
            };
            let cu = if c_prev.0 == u { c_prev.1 } else { t.cmf_at(u) };
            let cw = t.cmf_at(w);
            c_prev = (w, cw);
            let dc = [
                (cw[0] - cu[0]) * inv_h,
                (cw[1] - cu[1]) * inv_h,
                (cw[2] - cu[2]) * inv_h,
            ];
            if has_e {
                let de = (ew - eu) * inv_h;
                let h6 = h * (1.0 / 6.0);
                for c in 0..3 {
                    let full = h6 * (eu * (2.0 * cu[c] + cw[c]) + ew * (cu[c] + 2.0 * cw[c]));
                    taken[c] += full - quad_dot(eu, de, cu[c], dc[c], &j_half);
                }
            }
            if let (true, Some(i)) = (has_d, cell) {
                let (au, aw) = (pu + du, pw + dw);
                let j_after = depth_moments(au, aw, after.trans(u, au), after.trans(w, aw), h);
                let dj = [
                    j_before[0] - j_after[0],
                    j_before[1] - j_after[1],
                    j_before[2] - j_after[2],
                ];
                let hu = (u - (g0 + i as f64 * gstep)) * inv_gstep;
                for c in 0..3 {
                    let up = quad_dot(hu, inv_gstep, cu[c], dc[c], &dj);
                    let all = cu[c] * dj[0] + dc[c] * dj[1];
                    self.w[i + 1][c] += up;
                    self.w[i][c] += all - up;
                }
                if let Some((r, _)) = bb {
                    // This segment's own black body behind half its depth.
                    let dh = [
                        j_before[0] - j_half[0],
                        j_before[1] - j_half[1],
                        j_before[2] - j_half[2],
                    ];
                    let (r0, r1) = (r[i], r[i + 1]);
                    for c in 0..3 {
                        let up = quad_dot(hu, inv_gstep, cu[c], dc[c], &dh);
                        let all = cu[c] * dh[0] + dc[c] * dh[1];
                        taken[c] += r1 * up + r0 * (all - up);
                    }
                }
            }
            u = w;
        }
        taken
    }
}

/// Chooses what to leave out within the error budget (module docs): single absorption line
/// sweeps (one line of one segment), smallest depth first, up to `depth_budget` in total
/// (marked in `omit`); then, among the segments from the first one that still absorbs, the
/// absorption of their line light, faintest first (relative to each channel's unattenuated
/// total `total`), up to `light_share` of each channel. Smallest first leaves out the most
/// that a budget allows.
fn choose_omissions(
    segs: &mut [Segment],
    abs: &[Trap],
    omit: &mut Vec<bool>,
    depth_budget: f64,
    light_share: f64,
    total: [f64; 3],
) {
    omit.clear();
    omit.resize(abs.len(), false);
    let depth = |t: &Trap| t.2.max(t.3);
    // Smallest first, without a sort: depths binned by their binary exponent; whole bins are
    // left out while their running sum fits, then the next bin's lines in order while they
    // fit. (Any set whose depths sum within the budget keeps the bound.)
    const BINS: usize = 96;
    let bin = |d: f64| -> usize {
        let e = ((d.to_bits() >> 52) & 0x7ff) as i64 - 1023;
        (e + 80).clamp(0, BINS as i64 - 1) as usize
    };
    let mut sums = [0.0f64; BINS];
    for t in abs {
        let d = depth(t);
        if d > 0.0 && d <= depth_budget {
            sums[bin(d)] += d;
        }
    }
    let mut left = depth_budget;
    let mut full = 0;
    while full < BINS && sums[full] <= left {
        left -= sums[full];
        full += 1;
    }
    for (i, t) in abs.iter().enumerate() {
        let d = depth(t);
        if d > 0.0 && d <= depth_budget {
            let b = bin(d);
            if b < full {
                omit[i] = true;
            } else if b == full && d <= left {
                left -= d;
                omit[i] = true;
            }
        }
    }
    let Some(first) = segs.iter().position(|g| g.abs.clone().any(|i| !omit[i])) else {
        return;
    };
    let score = |g: &Segment| {
        (0..3)
            .map(|c| {
                if total[c] > 0.0 {
                    g.line_xyz[c] / total[c]
                } else {
                    0.0
                }
            })
            .fold(0.0, f64::max)
    };
    let mut idx: Vec<usize> = (first..segs.len())
        .filter(|&i| !segs[i].emit.is_empty())
        .collect();
    idx.sort_by(|&a, &b| score(&segs[a]).total_cmp(&score(&segs[b])));
    let mut left = total.map(|v| light_share * v);
    for i in idx {
        let x = segs[i].line_xyz;
        if (0..3).any(|c| x[c] > left[c]) {
            break;
        }
        for c in 0..3 {
            left[c] -= x[c];
        }
        segs[i].omit_light = true;
    }
}

/// One segment's emission and absorption, gathered before the march.
struct Segment {
    /// Its absorption line trapezoids (full depth) in `abs_all` (a range).
    abs: std::ops::Range<usize>,
    /// Its absorption `a_k` without the left-out lines, in `own_all` (a range).
    own: std::ops::Range<usize>,
    /// Half the depth of its left-out lines, in `own_all` (a range).
    left_half: std::ops::Range<usize>,
    /// Its emission line trapezoids in `emit` (a range) and their XYZ.
    emit: std::ops::Range<usize>,
    line_xyz: [f64; 3],
    /// Whether its black-body row (in `rows`) is non-zero.
    has_bb: bool,
    /// The absorption of its line light is left out (negligible, within the budget).
    omit_light: bool,
}

/// Most black-body row values (grid points x segments) kept from the pre-pass to the march
/// (16 MiB); longer rays evaluate their rows twice instead.
const MAX_KEPT_ROWS: usize = 1 << 21;

/// Buffers reused from ray to ray (per thread).
#[derive(Default)]
struct Scratch {
    segs: Vec<Segment>,
    rows: Vec<f64>,
    abs_all: Vec<Trap>,
    abs_omit: Vec<bool>,
    own_all: Vec<Piece>,
    emit_all: Vec<Trap>,
    emit_xyz: Vec<[f64; 3]>,
    acc: Vec<f64>,
    f_near: Vec<f64>,
    f_far: Vec<f64>,
    lines: Vec<Trap>,
    abs_lines: Vec<Trap>,
    cuts: Vec<f64>,
    w: Vec<[f64; 3]>,
    p: Vec<Piece>,
    p_next: Vec<Piece>,
    e: Vec<Piece>,
    o: OmittedDepth,
}

thread_local! {
    static SCRATCH: std::cell::RefCell<Scratch> = std::cell::RefCell::new(Scratch::default());
}

/// The XYZ of a ray with absorption (see the module docs).
pub(crate) fn front_to_back(ctx: &Context<'_>, t: &PwlTables, s: &RaySamples) -> Result<RayOut> {
    front_to_back_behind(ctx, t, s, &[])
}

/// [`front_to_back`] for samples that lie behind an optical depth `front` (sorted, disjoint
/// pieces: everything in front of the first segment, as distributed rendering's exclusive
/// scan gives it): each segment's light is attenuated by `front` plus the depth in front of
/// it here, exactly as in the ray's single-process march, where `front` is the sum of the
/// depths of the segments before.
pub(crate) fn front_to_back_behind(
    ctx: &Context<'_>,
    t: &PwlTables,
    s: &RaySamples,
    front: &[Piece],
) -> Result<RayOut> {
    SCRATCH.with(|cell| match cell.try_borrow_mut() {
        Ok(mut scratch) => march(ctx, t, s, front, &mut scratch),
        // Re-entered on this thread (not done today): fresh buffers.
        Err(_) => march(ctx, t, s, front, &mut Scratch::default()),
    })
}

/// The optical depth of all the segments of `s` (sorted, disjoint pieces), each segment's
/// absorption lines as the march takes them (no line left out, no merge).
pub(crate) fn total_depth(ctx: &Context<'_>, s: &RaySamples) -> Result<Vec<Piece>> {
    // Each segment's lines summed on their own (small clusters), then the segments' sums
    // added pairwise, as a balanced tree: O(P log n) for P pieces over n segments (one sum
    // of all the lines at once is quadratic in an overlapping cluster).
    let (mut lines, mut cuts) = (Vec::new(), Vec::new());
    let mut level: Vec<Vec<Piece>> = Vec::new();
    for j in 0..s.len().saturating_sub(1) {
        segment_lines(ctx, s, j, false, 1.0, &mut lines)?;
        if lines.is_empty() {
            continue;
        }
        let mut one = Vec::new();
        sum_trapezoids(&mut lines, 1.0, &mut one, &mut cuts);
        level.push(one);
    }
    while level.len() > 1 {
        level = level
            .chunks(2)
            .map(|c| match c {
                [a, b] => add_depths(a, b),
                [a] => a.clone(),
                _ => unreachable!("chunks of at most two"),
            })
            .collect();
    }
    Ok(level.pop().unwrap_or_default())
}

/// `a + b` for sorted, disjoint piece lists (exact: the sum of two piecewise-linear
/// functions, cut at both lists' breakpoints).
#[must_use]
pub fn add_depths(a: &[Piece], b: &[Piece]) -> Vec<Piece> {
    let mut out = Vec::with_capacity(a.len() + 2 * b.len());
    if a.len() >= b.len() {
        add_sorted(a, b, &mut out);
    } else {
        add_sorted(b, a, &mut out);
    }
    out
}

fn march(
    ctx: &Context<'_>,
    t: &PwlTables,
    s: &RaySamples,
    front: &[Piece],
    sc: &mut Scratch,
) -> Result<RayOut> {
    let st = ctx.settings;
    let n = s.len();
    let k = t.lambdas.len();
    let tol = st.merge_tolerance;
    let mut out = RayOut::default();
    let Scratch {
        segs,
        rows,
        abs_all,
        abs_omit,
        own_all,
        emit_all,
        emit_xyz,
        acc,
        f_near,
        f_far,
        lines,
        abs_lines,
        cuts,
        w,
        p,
        p_next,
        e,
        o,
    } = sc;
    // Gather every segment (from the eye), the unattenuated XYZ per segment and in total.
    segs.clear();
    // The segments' black-body rows are kept for the march unless they would take more than
    // MAX_KEPT_ROWS values (then the march evaluates them again).
    let keep_rows = k.saturating_mul(n - 1) <= MAX_KEPT_ROWS;
    rows.clear();
    rows.resize(if keep_rows { k * (n - 1) } else { k }, 0.0);
    abs_all.clear();
    own_all.clear();
    emit_all.clear();
    emit_xyz.clear();
    for v in [&mut *acc, &mut *f_near, &mut *f_far] {
        v.clear();
        v.resize(k, 0.0);
    }
    let mut has_near = bb_row(ctx, t, s, n - 1, f_near)?;
    let mut total_lines = [0.0f64; 3];
    for (m, j) in (0..n - 1).rev().enumerate() {
        let dt = f64::from(s.t[j] - s.t[j + 1]).abs();
        segment_lines_both(ctx, s, j, abs_lines, lines)?;
        let abs_start = abs_all.len();
        abs_all.extend_from_slice(abs_lines);
        if !lines.is_sorted_by(|a, b| a.0 + a.1 <= b.0 + b.1) {
            lines.sort_unstable_by(|a, b| (a.0 + a.1).total_cmp(&(b.0 + b.1)));
        }
        let emit_start = emit_all.len();
        emit_all.extend_from_slice(lines);
        let mut seg_xyz = [0.0f64; 3];
        for &tr in lines.iter() {
            let x = t.line_xyz(tr);
            for c in 0..3 {
                seg_xyz[c] += x[c];
            }
            emit_xyz.push(x);
        }
        for c in 0..3 {
            total_lines[c] += seg_xyz[c];
        }
        let has_far = bb_row(ctx, t, s, j, f_far)?;
        let has_bb = has_near || has_far;
        if has_bb {
            let at = if keep_rows { m * k } else { 0 };
            let row = &mut rows[at..at + k];
            for i in 0..k {
                row[i] = 0.5 * dt * (f_near[i] + f_far[i]);
                acc[i] += row[i];
            }
        }
        segs.push(Segment {
            abs: abs_start..abs_all.len(),
            own: 0..0,
            left_half: 0..0,
            emit: emit_start..emit_all.len(),
            line_xyz: seg_xyz,
            has_bb,
            omit_light: false,
        });
        std::mem::swap(f_near, f_far);
        has_near = has_far;
    }
    let mut total = Xyz::from_array(total_lines);
    for i in 0..k {
        total += t.hat_xyz[i].scaled(acc[i]);
    }
    let total = total.to_array();
    if tol > 0.0 {
        choose_omissions(
            segs,
            abs_all,
            abs_omit,
            DEPTH_SHARE * tol,
            LIGHT_SHARE * tol,
            total,
        );
    } else {
        abs_omit.clear();
        abs_omit.resize(abs_all.len(), false);
    }
    // Each segment's depth, without the left-out lines.
    for seg in segs.iter_mut() {
        lines.clear();
        lines.extend(
            seg.abs
                .clone()
                .filter(|&i| !abs_omit[i])
                .map(|i| abs_all[i]),
        );
        let start = own_all.len();
        sum_trapezoids(lines, 1.0, own_all, cuts);
        seg.own = start..own_all.len();
        // Half its left-out depth, which lies in front of its own light.
        lines.clear();
        lines.extend(seg.abs.clone().filter(|&i| abs_omit[i]).map(|i| abs_all[i]));
        let start = own_all.len();
        sum_trapezoids(lines, 0.5, own_all, cuts);
        seg.left_half = start..own_all.len();
    }

    // March from the eye. Error budget (module docs): merges tol/32, left-out depth 25 tol/32,
    // chords 3 tol/32, line light at line middles 3 tol/32 of each channel of the unattenuated
    // emission.
    w.clear();
    w.resize(k, [0.0; 3]);
    let mut sweep = Sweep {
        t,
        // The chords' budget, less what the depth in front already took (distributed).
        eps: ((CHORD_SHARE * tol).ln_1p() - ctx.front_eps).max(0.0),
        w: std::mem::take(w),
    };
    p.clear();
    o.reset(st.range_nm, st.line_width_nm);
    if !front.is_empty() {
        // W_i = integral hat_i cmf (1 - exp(-front)): the depth in front, taken in one step
        // from nothing (no emission of its own here).
        sweep.run(p, front, &[], None);
        p.extend_from_slice(front);
    }
    let mut taken = [0.0f64; 3];
    let mut merges = 0u32;
    let mut merge_at = 64usize;
    let segments = segs.len().max(1) as f64;
    if !keep_rows {
        bb_row(ctx, t, s, n - 1, f_near)?;
    }
    for (m, seg) in segs.iter().enumerate() {
        if !keep_rows {
            // This segment's row again (the pre-pass did not keep it).
            let j = n - 2 - m;
            let dt = f64::from(s.t[j] - s.t[j + 1]).abs();
            bb_row(ctx, t, s, j, f_far)?;
            for i in 0..k {
                rows[i] = 0.5 * dt * (f_near[i] + f_far[i]);
            }
            std::mem::swap(f_near, f_far);
        }
        // P holds the depth of the segments in front; this one's light crosses half of
        // its own depth `d` as well.
        let d = &own_all[seg.own.clone()];
        // Half of this segment's left-out depth lies in front of its own light; all of it
        // is binned after, for the segments behind.
        let left_half = &own_all[seg.left_half.clone()];
        let left_out = !o.is_empty() || !left_half.is_empty();
        let lit = !(p.is_empty() && d.is_empty());
        e.clear();
        if !seg.omit_light && lit && !seg.emit.is_empty() {
            lines.clear();
            lines.extend_from_slice(&emit_all[seg.emit.clone()]);
            sum_trapezoids(lines, 1.0, e, cuts);
        }
        // Light read at each line's middle (the lines are sorted by their middles, so the
        // cursors only advance): the faintest segments' lines attenuated by the whole depth
        // there (off by at most the line's own light, as the budget assumes, and dark behind
        // a thick medium); the others' swept exactly above, and here only the left-out lines
        // in front taken to first order.
        if !seg.emit.is_empty() && (left_out || (seg.omit_light && lit)) {
            let (mut pc, mut dc, mut hc) = (Cursor::new(p), Cursor::new(d), Cursor::new(left_half));
            for (&(lo, hi, _, _), x) in emit_all[seg.emit.clone()]
                .iter()
                .zip(&emit_xyz[seg.emit.clone()])
            {
                let mid = 0.5 * (lo + hi);
                let om = o.at(mid) + hc.at(mid).map_or(0.0, |q| q.at(mid));
                if !seg.omit_light && om <= 0.0 {
                    continue;
                }
                let depth = pc.at(mid).map_or(0.0, |q| q.at(mid))
                    + 0.5 * dc.at(mid).map_or(0.0, |q| q.at(mid));
                let f = if seg.omit_light {
                    absorbed_by(depth + om)
                } else {
                    let absorbed = absorbed_by(om);
                    if depth > 0.0 {
                        (-depth).exp() * absorbed
                    } else {
                        absorbed
                    }
                };
                if f > 0.0 {
                    for c in 0..3 {
                        taken[c] += f * x[c];
                    }
                }
            }
        }
        // The black body behind P (W before this segment's sweep), and behind half its own
        // depth in the sweep.
        let row = (seg.has_bb && (lit || left_out)).then(|| {
            let at = if keep_rows { m * k } else { 0 };
            &rows[at..at + k]
        });
        if let Some(row) = row {
            for (r, wi) in row.iter().zip(&sweep.w) {
                for c in 0..3 {
                    taken[c] += r * wi[c];
                }
            }
        }
        if !d.is_empty() || !e.is_empty() {
            let x = sweep.run(p, d, e, row);
            for c in 0..3 {
                taken[c] += x[c];
            }
        }
        if !d.is_empty() {
            add_sorted(p, d, p_next);
            std::mem::swap(p, p_next);
        }
        // This segment's left-out lines, to first order: into the depth that later lines'
        // light reads, and into W for the black bodies behind (and half for its own).
        // (Their middles mostly increase, so one cursor serves; it restarts where not.)
        let (mut pc, mut last_mid) = (Cursor::new(p), f64::NEG_INFINITY);
        for i in seg.abs.clone().filter(|&i| abs_omit[i]) {
            let tr = abs_all[i];
            o.add(tr);
            let mid = 0.5 * (tr.0 + tr.1);
            if mid < last_mid {
                pc = Cursor::new(p);
            }
            last_mid = mid;
            let depth = pc.at(mid).map_or(0.0, |q| value_at(&q, mid));
            let x = omitted_into_w(&mut sweep.w, t, depth, tr, row);
            for c in 0..3 {
                taken[c] += x[c];
            }
        }
        // W is not recomputed after a merge (a pass over all of P): it keeps what the merge
        // moved, at most the merge's tolerance (module docs).
        if p.len() > merge_at {
            merges += 1;
            let share = 6.0 / (std::f64::consts::PI.powi(2) * f64::from(merges).powi(2));
            merge_pieces(p, MERGE_SHARE * tol * share, p_next).map_err(spectrum_err)?;
            std::mem::swap(p, p_next);
            merge_at = (2 * p.len()).max(64);
        }
        // Budget fallback: coarser merges until P fits (the preview strategy; this breaks
        // the error bound above and is counted), from 4x this segment's share of the
        // tolerance up, for this segment only (a scale kept for the rest of the ray
        // compounded: a galaxy at budget 16 was 31 % off in a pixel).
        // Stops when a merge gains nothing (more separate line groups than the budget) and
        // never lets the scale overflow.
        let mut budget_scale = 1.0f64;
        while p.len() > st.piece_budget {
            budget_scale = (budget_scale * 4.0).min(1e30);
            merge_pieces(
                p,
                (tol.max(1e-6) * budget_scale / segments).min(f64::MAX),
                p_next,
            )
            .map_err(spectrum_err)?;
            let gained = p_next.len() < p.len();
            std::mem::swap(p, p_next);
            out.fallback = true;
            if !gained && budget_scale >= 1e30 {
                break;
            }
            if !gained && p.windows(2).all(|w| w[0].end_nm < w[1].start_nm) {
                // Nothing left to join: only gaps separate the pieces.
                break;
            }
        }
        out.max_pieces = out.max_pieces.max(p.len());
    }
    *w = sweep.w;
    // Do not hold on to the buffers of an exceptionally long ray.
    if abs_all.capacity() + emit_all.capacity() + own_all.capacity() > MAX_KEPT_ROWS {
        *sc = Scratch::default();
    }
    out.xyz = Xyz::from_array([
        (total[0] - taken[0]).max(0.0),
        (total[1] - taken[1]).max(0.0),
        (total[2] - taken[2]).max(0.0),
    ]);
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn eval(pieces: &[Piece], x: f64) -> f64 {
        pieces
            .iter()
            .find(|p| p.start_nm <= x && x < p.end_nm)
            .map_or(0.0, |p| p.at(x))
    }

    fn sorted_disjoint(pieces: &[Piece]) -> bool {
        pieces
            .windows(2)
            .all(|w| w[0].end_nm <= w[1].start_nm && w[0].start_nm < w[0].end_nm)
    }

    /// A small deterministic generator (no dependency needed for a unit test).
    fn lcg(state: &mut u64) -> f64 {
        *state = state
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        (*state >> 11) as f64 / (1u64 << 53) as f64
    }

    fn random_traps(seed: u64, n: usize) -> Vec<Trap> {
        let mut st = seed;
        (0..n)
            .map(|_| {
                let lo = 400.0 + 50.0 * lcg(&mut st);
                let w = 0.1 + 5.0 * lcg(&mut st);
                (lo, lo + w, lcg(&mut st), lcg(&mut st))
            })
            .collect()
    }

    #[test]
    fn absorbed_by_is_one_minus_exp_across_its_switch() {
        // libm's exp_m1 is the independent truth, from 1e-12 to 40 (each decade 50 times).
        for i in 0..=700 {
            let x = 10f64.powf(-12.0 + f64::from(i) * (13.6 / 700.0));
            let want = -(-x).exp_m1();
            let got = absorbed_by(x);
            assert!((got - want).abs() <= 2e-14 * want, "x {x}: {got} vs {want}");
        }
        assert_eq!(absorbed_by(0.0), 0.0);
    }

    #[test]
    fn binned_omitted_depth_keeps_each_line_area_and_its_values_at_bin_middles() {
        let mut st = 11u64;
        for case in 0..200 {
            let mut o = OmittedDepth::default();
            o.reset((400.0, 500.0), 0.05 + lcg(&mut st));
            let lo = 390.0 + 115.0 * lcg(&mut st);
            let w = if case % 3 == 0 {
                1e-3
            } else {
                0.01 + 8.0 * lcg(&mut st)
            };
            let (h0, h1) = (lcg(&mut st), lcg(&mut st));
            o.add((lo, lo + w, h0, h1));
            // The area inside the range is kept (a linear function's mean over a bin is
            // its value at the bin's middle).
            let (a, b) = (lo.max(400.0), (lo + w).min(500.0));
            let slope = (h1 - h0) / w;
            let area = if b > a {
                (b - a) * (h0 + slope * (0.5 * (a + b) - lo))
            } else {
                0.0
            };
            let binned: f64 = o.bins.iter().sum::<f64>() * o.bin;
            assert!(
                (binned - area).abs() <= 1e-9 * area.max(1e-3),
                "case {case}: binned {binned} vs {area}"
            );
            // A bin wholly inside the line holds the line's value at its middle.
            for (i, &v) in o.bins.iter().enumerate() {
                let (b0, b1) = (400.0 + i as f64 * o.bin, 400.0 + (i + 1) as f64 * o.bin);
                if b0 > lo + 1e-9 && b1 < lo + w - 1e-9 {
                    let want = h0 + slope * (0.5 * (b0 + b1) - lo);
                    assert!(
                        (v - want).abs() <= 1e-9,
                        "case {case} bin {i}: {v} vs {want}"
                    );
                }
            }
        }
    }

    #[test]
    fn summed_and_added_pieces_equal_the_pointwise_sums() {
        let mut cuts = Vec::new();
        for seed in 0..50 {
            let mut ta = random_traps(seed, 1 + (seed as usize % 12));
            let mut tb = random_traps(seed + 1000, 1 + (seed as usize % 5));
            let (mut a, mut b, mut sum) = (Vec::new(), Vec::new(), Vec::new());
            sum_trapezoids(&mut ta.clone(), 0.5, &mut a, &mut cuts);
            sum_trapezoids(&mut tb.clone(), 2.0, &mut b, &mut cuts);
            assert!(sorted_disjoint(&a) && sorted_disjoint(&b));
            add_sorted(&a, &b, &mut sum);
            assert!(sorted_disjoint(&sum), "seed {seed}: {sum:?}");
            let tr = |t: &[Trap], x: f64| -> f64 {
                t.iter()
                    .filter(|t| t.0 <= x && x < t.1)
                    .map(|t| t.2 + (t.3 - t.2) * (x - t.0) / (t.1 - t.0))
                    .sum()
            };
            ta.sort_by(|a, b| a.0.total_cmp(&b.0));
            tb.sort_by(|a, b| a.0.total_cmp(&b.0));
            for i in 0..2000 {
                let x = 395.0 + 65.0 * i as f64 / 2000.0 + 1e-7;
                let want_a = 0.5 * tr(&ta, x);
                let want = want_a + 2.0 * tr(&tb, x);
                assert!((eval(&a, x) - want_a).abs() < 1e-12, "seed {seed} x {x}");
                assert!(
                    (eval(&sum, x) - want).abs() < 1e-12,
                    "seed {seed} x {x}: {} vs {want}",
                    eval(&sum, x)
                );
            }
        }
    }

    /// P(x) from the right (the piece starting at a breakpoint wins), 0 in gaps.
    fn eval_right(pieces: &[Piece], x: f64) -> f64 {
        eval(pieces, x)
    }

    /// P(x) from the left.
    fn eval_left(pieces: &[Piece], x: f64) -> f64 {
        pieces
            .iter()
            .find(|p| p.start_nm < x && x <= p.end_nm)
            .map_or(0.0, |p| p.at(x))
    }

    #[test]
    fn a_chorded_depth_stays_within_eps_and_is_smaller() {
        let mut cuts = Vec::new();
        let (mut before, mut after) = (0usize, 0usize);
        for seed in 0..60 {
            // Jumps (random trapezoids) and continuous line profiles (tents of depth up to
            // 0.02, as weak lines' are): chords can cross only the latter's breakpoints.
            let mut tr = random_traps(seed, 5 + (seed as usize % 40));
            let mut st = seed + 99;
            for _ in 0..60 {
                let (c, w, h) = (
                    400.0 + 50.0 * lcg(&mut st),
                    0.05 + 2.0 * lcg(&mut st),
                    0.02 * lcg(&mut st),
                );
                tr.push((c - w, c, 0.0, h));
                tr.push((c, c + w, h, 0.0));
            }
            if seed % 2 == 0 {
                tr.retain(|t| t.2 == 0.0 || t.3 == 0.0);
            }
            let mut p = Vec::new();
            sum_trapezoids(&mut tr, 0.3, &mut p, &mut cuts);
            let eps = [1e-4, 1e-3, 1e-2][seed as usize % 3];
            let c = chord_depth(&p, eps);
            assert!(sorted_disjoint(&c), "seed {seed}: {c:?}");
            assert!(c.iter().all(|q| q.value_start >= 0.0 && q.value_end >= 0.0));
            // Everywhere, from both sides, including the gaps and past the ends.
            for i in 0..=6000 {
                let x = 395.0 + 65.0 * f64::from(i) / 6000.0;
                for (got, want) in [
                    (eval_right(&c, x), eval_right(&p, x)),
                    (eval_left(&c, x), eval_left(&p, x)),
                ] {
                    assert!(
                        (got - want).abs() <= eps * (1.0 + 1e-9) + 1e-12,
                        "seed {seed} x {x}: {got} vs {want} (eps {eps})"
                    );
                }
            }
            assert_eq!(chord_depth(&p, 0.0), p, "eps 0 is the depth itself");
            before += p.len();
            after += c.len();
        }
        // Half the cases are continuous profiles: the chords take many of their breakpoints.
        assert!(2 * after < before, "{after} pieces of {before}");
    }

    #[test]
    fn chords_stay_within_eps_of_the_depth_and_keep_its_integral_when_free() {
        let mut cuts = Vec::new();
        let mut checked = 0;
        for seed in 0..60 {
            let mut tr = random_traps(seed, 2 + (seed as usize % 20));
            let mut p = Vec::new();
            sum_trapezoids(&mut tr, 0.05, &mut p, &mut cuts);
            let eps = [1e-3, 1e-2, 0.05][seed as usize % 3];
            let mut st = seed + 7;
            let u0 = 400.0 + 50.0 * lcg(&mut st);
            let limit = u0 + 0.5 + 10.0 * lcg(&mut st);
            let mut c = Cursor::new(&p);
            // Chords one after another from u0 to the limit, as the sweep takes them.
            let mut u = u0;
            let mut steps = 0;
            while u < limit && steps < 10_000 {
                let cur = c.at(u);
                let (end, a, b) = chord_over(&c, cur, u, limit, eps);
                assert!(end > u && end <= limit, "seed {seed}: {u} .. {end}");
                assert!(
                    (a - eval_right(&p, u)).abs() <= 1e-12,
                    "seed {seed}: the chord starts at {a}, P at {}",
                    eval_right(&p, u)
                );
                // Every point strictly inside, and the ends from the inside.
                for j in 0..=400 {
                    let x = u + (end - u) * f64::from(j) / 400.0;
                    let chord = a + (b - a) * (x - u) / (end - u);
                    let mut want = vec![eval_right(&p, x), eval_left(&p, x)];
                    if j == 0 {
                        want.pop();
                    } else if j == 400 {
                        want.remove(0);
                    }
                    for v in want {
                        assert!(
                            (chord - v).abs() <= eps * (1.0 + 1e-9) + 1e-12,
                            "seed {seed} x {x}: chord {chord} vs P {v} (eps {eps})"
                        );
                    }
                    checked += 1;
                }
                u = end;
                steps += 1;
            }
            assert!(u >= limit, "seed {seed}: stuck at {u}");
        }
        assert!(checked > 10_000);
        // A peak the cone allows to flatten: the chord keeps its area (the integral of a
        // tent of height h over [0, 2] is h, the chord from 0 with that area ends at h).
        let h = 0.01;
        let tent = [
            Piece {
                start_nm: 500.0,
                end_nm: 501.0,
                value_start: 0.0,
                value_end: h,
            },
            Piece {
                start_nm: 501.0,
                end_nm: 502.0,
                value_start: h,
                value_end: 0.0,
            },
        ];
        let c = Cursor::new(&tent);
        let (end, a, b) = chord_over(&c, Some(tent[0]), 500.0, 502.0, 0.02);
        assert_eq!((end, a), (502.0, 0.0));
        assert!((0.5 * (a + b) * 2.0 - h).abs() < 1e-15, "chord end {b}");
        // One the cone does not allow: the chord stops at the peak.
        let (end, _, b) = chord_over(&c, Some(tent[0]), 500.0, 502.0, 0.004);
        assert_eq!(end, 501.0);
        assert!((b - h).abs() <= 0.004);
    }

    #[test]
    fn depth_moments_match_quadrature() {
        // integral_0^h x^n exp(-(pu + (pw - pu) x / h)) dx by composite Simpson.
        for &(pu, pw, h) in &[
            (0.0, 0.0, 1.0),
            (0.3, 0.31, 0.5),
            (2.0, 40.0, 1.3),
            (40.0, 2.0, 1.3),
            (700.0, 760.0, 0.2),
            (0.0, 1e-9, 2.0),
        ] {
            let j = depth_moments(pu, pw, (-pu).exp(), (-pw).exp(), h);
            for (nn, &jn) in j.iter().enumerate() {
                let m = 20_000;
                let f = |x: f64| x.powi(nn as i32) * (-(pu + (pw - pu) * x / h)).exp();
                let mut q = f(0.0) + f(h);
                for i in 1..m {
                    q += f(h * i as f64 / m as f64) * if i % 2 == 1 { 4.0 } else { 2.0 };
                }
                q *= h / (3.0 * m as f64);
                assert!(
                    (jn - q).abs() <= 1e-10 * q.abs().max(1e-300) + 1e-300,
                    "({pu}, {pw}, {h}) n={nn}: {jn} vs {q}"
                );
            }
        }
    }
}

/// A left-out line's absorption of the black body light behind it (`depth` in front), to
/// first order at the line's middle: added to `W` for the segments behind; returns the half
/// its own black body `row` loses (XYZ; weighted behind the same depth, which already holds
/// the segment's kept depth, so a little less than behind half of it: within the bound).
/// Lines outside the black-body grid or the CMF table take nothing.
fn omitted_into_w(
    w: &mut [[f64; 3]],
    t: &PwlTables,
    depth: f64,
    (lo, hi, h0, h1): Trap,
    row: Option<&[f64]>,
) -> [f64; 3] {
    let k = t.lambdas.len();
    let (g0, g1) = (t.lambdas[0], t.lambdas[k - 1]);
    let mid = 0.5 * (lo + hi);
    let mut taken = [0.0; 3];
    let c_hi = t.cmf_lo + t.cmf_step * (t.cmf.len() - 1) as f64;
    if !(mid > g0 && mid < g1 && mid >= t.cmf_lo && mid <= c_hi) {
        return taken;
    }
    let area = 0.5 * (h0 + h1) * (hi - lo);
    let f = if depth > 0.0 {
        (-depth).exp() * area
    } else {
        area
    };
    let x = (mid - g0) / (g1 - g0) * (k - 1) as f64;
    let i = (x as usize).min(k - 2);
    let fr = x - i as f64;
    let c = t.cmf_at(mid);
    for ch in 0..3 {
        let v = f * c[ch];
        w[i][ch] += v * (1.0 - fr);
        w[i + 1][ch] += v * fr;
        if let Some(r) = row {
            taken[ch] += 0.5 * v * ((1.0 - fr) * r[i] + fr * r[i + 1]);
        }
    }
    taken
}

/// The depth of the lines left out in front (`choose_omissions`), binned finely on the
/// wavelength range: read at emission lines' middles to attenuate their light to first order.
#[derive(Default)]
struct OmittedDepth {
    lo: f64,
    inv_bin: f64,
    bin: f64,
    bins: Vec<f64>,
    /// The bins written since the last reset (`touched.0..touched.1`).
    touched: (usize, usize),
}

impl OmittedDepth {
    /// Most bins (32 KiB): a line covers at most `4096 x` its share of the range in bins.
    const MAX_BINS: usize = 1 << 12;

    fn reset(&mut self, (a, b): (f64, f64), line_width: f64) {
        let (t0, t1) = self.touched;
        if t0 < t1 {
            self.bins[t0..t1].fill(0.0);
        }
        self.touched = (usize::MAX, 0);
        let span = (b - a).max(f64::MIN_POSITIVE);
        // Bins of half the narrowest line's width (a quarter measured a larger error on
        // the He-rich scene, a whole width a much larger one).
        let want = (span / (0.5 * line_width).max(1e-3)).ceil();
        let n = if want.is_finite() {
            (want as usize).clamp(16, Self::MAX_BINS)
        } else {
            Self::MAX_BINS
        };
        if self.bins.len() != n || self.lo != a || self.bin != span / n as f64 {
            self.bins.clear();
            self.bins.resize(n, 0.0);
        }
        self.lo = a;
        self.bin = span / n as f64;
        self.inv_bin = 1.0 / self.bin;
    }

    fn is_empty(&self) -> bool {
        self.touched.0 >= self.touched.1
    }

    /// Adds a line trapezoid's depth: each bin gets its mean over the bin.
    fn add(&mut self, (lo, hi, h0, h1): Trap) {
        let n = self.bins.len();
        if n == 0 || hi.is_nan() || lo.is_nan() || hi <= lo {
            return;
        }
        let first = ((lo - self.lo) * self.inv_bin).max(0.0);
        let last = ((hi - self.lo) * self.inv_bin).max(0.0);
        if first >= n as f64 {
            return;
        }
        let (first, last) = (first as usize, (last as usize).min(n - 1));
        let slope = (h1 - h0) / (hi - lo);
        let k = self.inv_bin;
        // The mean over the part of bin `b` inside the line, times that part's share of
        // the bin.
        let edge = |b: usize| {
            let b0 = self.lo + b as f64 * self.bin;
            let (x0, x1) = (lo.max(b0), hi.min(b0 + self.bin));
            if x1 > x0 {
                (x1 - x0) * (h0 + slope * (0.5 * (x0 + x1) - lo)) * k
            } else {
                0.0
            }
        };
        self.bins[first] += edge(first);
        if last > first {
            // The bins in between lie wholly inside: the line's value at their middles.
            let c0 = self.lo + 0.5 * self.bin - lo;
            for (b, v) in self.bins[first + 1..last].iter_mut().enumerate() {
                *v += h0 + slope * (c0 + (first + 1 + b) as f64 * self.bin);
            }
            self.bins[last] += edge(last);
        }
        self.touched = (self.touched.0.min(first), self.touched.1.max(last + 1));
    }

    /// The binned depth at `x` (0 outside the range).
    fn at(&self, x: f64) -> f64 {
        if self.is_empty() {
            return 0.0;
        }
        let u = (x - self.lo) * self.inv_bin;
        if u >= 0.0 && u < self.bins.len() as f64 {
            self.bins[u as usize]
        } else {
            0.0
        }
    }
}
