//! Piecewise-linear spectra (Doppler paper section 4.2, Eq. 12-14).

use std::collections::BTreeMap;
use std::ops::Bound;

use crate::doppler::{RadiometricTransform, WavelengthShift};
use crate::error::{Error, Result, non_negative, range};

/// One linear piece of a [`PiecewiseLinear`] spectrum: the value goes linearly from
/// `value_start` at `start_nm` to `value_end` at `end_nm`. Values are spectral radiance per nm
/// (whatever unit the caller uses, W sr^-1 m^-2 nm^-1 for black bodies). The piece covers the
/// half-open interval `[start_nm, end_nm)`.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct Piece {
    /// Start wavelength, nm.
    pub start_nm: f64,
    /// End wavelength, nm (`> start_nm`).
    pub end_nm: f64,
    /// Value at `start_nm` (>= 0).
    pub value_start: f64,
    /// Value at `end_nm` (>= 0, the limit from the left).
    pub value_end: f64,
}

impl Piece {
    /// Value at `wavelength_nm` on the piece's line (no range check).
    #[inline]
    #[must_use]
    pub fn at(&self, wavelength_nm: f64) -> f64 {
        lerp(
            self.start_nm,
            self.end_nm,
            self.value_start,
            self.value_end,
            wavelength_nm,
        )
    }

    /// Integral of the piece over its own interval (trapezoid area).
    #[inline]
    #[must_use]
    pub fn integral(&self) -> f64 {
        0.5 * (self.end_nm - self.start_nm) * (self.value_start + self.value_end)
    }
}

/// Value at `x` of the line through `(a, va)` and `(b, vb)`; exact at both ends.
#[inline]
pub(crate) fn lerp(a: f64, b: f64, va: f64, vb: f64, x: f64) -> f64 {
    if x <= a {
        return va;
    }
    if x >= b {
        return vb;
    }
    let t = (x - a) / (b - a);
    va + (vb - va) * t
}

/// Exact integral over `[u, w]` of the product of two linear functions given by their values
/// at the ends (`f0, f1` and `g0, g1`). Simpson's rule is exact for the quadratic product.
#[inline]
pub(crate) fn product_integral(u: f64, w: f64, f0: f64, f1: f64, g0: f64, g1: f64) -> f64 {
    (w - u) * (2.0 * f0 * g0 + f0 * g1 + f1 * g0 + 2.0 * f1 * g1) / 6.0
}

/// Key of the piece map: the start wavelength, totally ordered (keys are always finite).
#[derive(Clone, Copy, Debug, PartialEq)]
struct Key(f64);
impl Eq for Key {}
impl PartialOrd for Key {
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(other))
    }
}
impl Ord for Key {
    fn cmp(&self, other: &Self) -> std::cmp::Ordering {
        self.0.total_cmp(&other.0)
    }
}

#[derive(Clone, Copy, Debug, PartialEq)]
struct Seg {
    end: f64,
    v0: f64,
    v1: f64,
}

/// The most pieces [`PiecewiseLinear::add_trapezoids`] (and so a line list, through
/// [`crate::add_lines`]) may produce: 4,194,304 (about 2 million lines), about 200 MB.
pub const MAX_PIECES: usize = 1 << 22;

/// A spectrum made of sorted, non-overlapping, non-negative linear pieces over wavelength
/// (Doppler paper Eq. 12-14); zero outside its pieces.
///
/// Adding a trapezoid splits the pieces it overlaps (every case of the paper's Fig. 8 falls
/// out of one rule: split at the trapezoid's ends, add on the overlapped pieces, fill the gaps).
/// The pieces live in a balanced tree keyed by start wavelength, so adding a trapezoid costs
/// `O(log n + k)` for `n` pieces of which it overlaps `k`, not `O(n)` as in the paper's list
/// (its Fig. 17/18 bottleneck).
///
/// All operations are exact in real arithmetic except [`merged`](Self::merged) (which adds at
/// most its stated tolerance) and [`attenuated`](Self::attenuated) (which states its bound).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PiecewiseLinear {
    map: BTreeMap<Key, Seg>,
}

impl PiecewiseLinear {
    /// The zero spectrum (no pieces).
    #[must_use]
    pub fn new() -> Self {
        Self::default()
    }

    /// Builds a spectrum from pieces in any order. Refuses NaN/infinite values, negative
    /// values, empty or reversed pieces and overlapping pieces, naming the offending piece.
    pub fn from_pieces(pieces: impl IntoIterator<Item = Piece>) -> Result<Self> {
        let mut v: Vec<Piece> = pieces.into_iter().collect();
        for p in &v {
            check_piece(p)?;
        }
        v.sort_by(|a, b| a.start_nm.total_cmp(&b.start_nm));
        for w in v.windows(2) {
            if w[1].start_nm < w[0].end_nm {
                return Err(Error::Range {
                    name: "piece overlapping its predecessor",
                    min_nm: w[1].start_nm,
                    max_nm: w[1].end_nm,
                    reason: "pieces must not overlap",
                });
            }
        }
        Ok(Self::from_sorted_unchecked(v))
    }

    /// Builds a spectrum from samples `(wavelength_nm, value)` joined by straight lines
    /// (a tabulated spectrum). Wavelengths must be strictly increasing.
    pub fn from_samples(samples: &[(f64, f64)]) -> Result<Self> {
        let mut pieces = Vec::with_capacity(samples.len().saturating_sub(1));
        for w in samples.windows(2) {
            let (a, va) = w[0];
            let (b, vb) = w[1];
            range("sample wavelengths (must increase)", a, b)?;
            pieces.push(Piece {
                start_nm: a,
                end_nm: b,
                value_start: va,
                value_end: vb,
            });
        }
        for p in &pieces {
            check_piece(p)?;
        }
        Ok(Self::from_sorted_unchecked(pieces))
    }

    /// Parses blueshift's spectrum CSV (header `wavelength_nm,value`; `#` lines are
    /// comments): consecutive rows are joined by straight lines and a repeated wavelength
    /// marks a jump, which is how `blueshift spectrum --csv` writes spectra. Refuses
    /// decreasing wavelengths, negative or non-finite values, naming the line.
    pub fn parse_csv(text: &str, source_name: &str) -> Result<Self> {
        let rows = crate::cie::parse_csv_rows(text, source_name, 2)?;
        let mut pieces = Vec::with_capacity(rows.len());
        for w in rows.windows(2) {
            let ((_, a), (line, b)) = (&w[0], &w[1]);
            let bad = |message: &str| Error::Parse {
                source_name: source_name.to_owned(),
                line: *line,
                message: message.to_owned(),
            };
            if b[0] < a[0] {
                return Err(bad("wavelengths must not decrease"));
            }
            if a[1] < 0.0 || b[1] < 0.0 {
                return Err(bad("spectral values must be >= 0"));
            }
            if b[0] > a[0] {
                pieces.push(Piece {
                    start_nm: a[0],
                    end_nm: b[0],
                    value_start: a[1],
                    value_end: b[1],
                });
            }
        }
        Ok(Self::from_sorted_unchecked(pieces))
    }

    /// Reads a spectrum CSV file (see [`parse_csv`](Self::parse_csv)).
    pub fn read_csv(path: &std::path::Path) -> Result<Self> {
        let text = std::fs::read_to_string(path).map_err(|source| Error::Io {
            path: path.display().to_string(),
            source,
        })?;
        Self::parse_csv(&text, &path.display().to_string())
    }

    fn from_sorted_unchecked(pieces: Vec<Piece>) -> Self {
        let map = pieces
            .into_iter()
            .filter(|p| p.value_start != 0.0 || p.value_end != 0.0)
            .map(|p| {
                (
                    Key(p.start_nm),
                    Seg {
                        end: p.end_nm,
                        v0: p.value_start,
                        v1: p.value_end,
                    },
                )
            })
            .collect();
        Self { map }
    }

    /// A box: `value` on `[start_nm, end_nm)`, zero elsewhere.
    pub fn boxed(start_nm: f64, end_nm: f64, value: f64) -> Result<Self> {
        let mut s = Self::new();
        s.add_box(start_nm, end_nm, value)?;
        Ok(s)
    }

    /// Number of pieces.
    #[must_use]
    pub fn piece_count(&self) -> usize {
        self.map.len()
    }

    /// True when the spectrum has no pieces (is zero everywhere).
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.map.is_empty()
    }

    /// The pieces in increasing wavelength order.
    pub fn pieces(&self) -> impl DoubleEndedIterator<Item = Piece> + ExactSizeIterator + '_ {
        self.map.iter().map(|(k, s)| Piece {
            start_nm: k.0,
            end_nm: s.end,
            value_start: s.v0,
            value_end: s.v1,
        })
    }

    /// The wavelength interval covered by pieces, or `None` when empty.
    #[must_use]
    pub fn support_nm(&self) -> Option<(f64, f64)> {
        let first = self.map.first_key_value()?;
        let last = self.map.last_key_value()?;
        Some((first.0.0, last.1.end))
    }

    /// The flux-weighted centroid over `[min_nm, max_nm]`: the exact first moment over the
    /// zeroth (each piece's `∫ λ f dλ` and `∫ f dλ` in closed form); `None` where the
    /// spectrum has no flux there. A line's centroid over a window around it is where its
    /// Doppler shift puts it.
    #[must_use]
    pub fn centroid(&self, min_nm: f64, max_nm: f64) -> Option<f64> {
        let (mut m0, mut m1) = (0.0, 0.0);
        for p in self.pieces() {
            let (l0, l1) = (p.start_nm.max(min_nm), p.end_nm.min(max_nm));
            if l1 <= l0 {
                continue;
            }
            let (f0, f1) = (p.at(l0), p.at(l1));
            let d = l1 - l0;
            m0 += 0.5 * (f0 + f1) * d;
            // The first moment of the line from (l0, f0) to (l1, f1).
            m1 += d * (f0 * (2.0 * l0 + l1) + f1 * (l0 + 2.0 * l1)) / 6.0;
        }
        (m0 > 0.0).then(|| m1 / m0)
    }

    /// Value at `wavelength_nm` (zero outside the pieces; pieces are half-open `[start, end)`).
    #[must_use]
    pub fn eval(&self, wavelength_nm: f64) -> f64 {
        if !wavelength_nm.is_finite() {
            return 0.0;
        }
        match self.map.range(..=Key(wavelength_nm)).next_back() {
            Some((k, s)) if wavelength_nm < s.end => lerp(k.0, s.end, s.v0, s.v1, wavelength_nm),
            _ => 0.0,
        }
    }

    /// Largest value (0 for the empty spectrum).
    #[must_use]
    pub fn max_value(&self) -> f64 {
        self.map.values().fold(0.0, |m, s| m.max(s.v0).max(s.v1))
    }

    /// Integral over all wavelengths (units of value x nm).
    #[must_use]
    pub fn total(&self) -> f64 {
        self.map
            .iter()
            .map(|(k, s)| 0.5 * (s.end - k.0) * (s.v0 + s.v1))
            .sum()
    }

    /// Exact integral over `[min_nm, max_nm]`. Refuses a reversed or non-finite interval.
    pub fn integrate(&self, min_nm: f64, max_nm: f64) -> Result<f64> {
        let (lo, hi) = range("integration interval", min_nm, max_nm)?;
        Ok(self
            .pieces_overlapping(lo, hi)
            .map(|p| {
                let a = p.start_nm.max(lo);
                let b = p.end_nm.min(hi);
                if b > a {
                    0.5 * (b - a) * (p.at(a) + p.at(b))
                } else {
                    0.0
                }
            })
            .sum())
    }

    /// The pieces that intersect `(lo, hi)`, in order.
    fn pieces_overlapping(&self, lo: f64, hi: f64) -> impl Iterator<Item = Piece> + '_ {
        let first = self
            .map
            .range(..Key(lo))
            .next_back()
            .filter(|(_, s)| s.end > lo);
        first
            .into_iter()
            .chain(
                self.map
                    .range((Bound::Included(Key(lo)), Bound::Excluded(Key(hi)))),
            )
            .map(|(k, s)| Piece {
                start_nm: k.0,
                end_nm: s.end,
                value_start: s.v0,
                value_end: s.v1,
            })
    }

    /// Adds a trapezoid going linearly from `value_start` at `start_nm` to `value_end` at
    /// `end_nm` (paper Eq. 12), splitting overlapped pieces (all cases of the paper's Fig. 8).
    /// Refuses non-finite input, negative values and `start_nm >= end_nm`.
    pub fn add_trapezoid(
        &mut self,
        start_nm: f64,
        end_nm: f64,
        value_start: f64,
        value_end: f64,
    ) -> Result<()> {
        range("trapezoid", start_nm, end_nm)?;
        non_negative("trapezoid start value", value_start)?;
        non_negative("trapezoid end value", value_end)?;
        self.add_trapezoid_unchecked(start_nm, end_nm, value_start, value_end);
        Ok(())
    }

    /// Adds many trapezoids `(start_nm, end_nm, value_start, value_end)` (already validated:
    /// `start < end`, values finite and >= 0) in one sweep over their sorted ends: O(n log n)
    /// however much they overlap, where adding them one by one costs the number of pieces
    /// each overlaps (quadratic for dense line lists). The spectrum's own pieces take part.
    ///
    /// # Errors
    /// More than [`MAX_PIECES`] / 2 trapezoids, own pieces included (the spectrum is left
    /// unchanged).
    pub fn add_trapezoids(&mut self, trapezoids: &[(f64, f64, f64, f64)]) -> Result<()> {
        let list: Vec<(f64, f64, f64, f64)> = self
            .pieces()
            .map(|p| (p.start_nm, p.end_nm, p.value_start, p.value_end))
            .chain(trapezoids.iter().copied())
            .collect();
        // n trapezoids make at most 2n - 1 pieces.
        if list.len() > MAX_PIECES / 2 {
            return Err(Error::param(
                "piece count",
                list.len() as f64,
                "too many trapezoids: more than MAX_PIECES / 2 (2,097,152)",
            ));
        }
        let mut map = BTreeMap::new();
        sum_trapezoids(&list, &mut Vec::new(), |x, end, v0, v1| {
            map.insert(Key(x), Seg { end, v0, v1 });
        });
        self.map = map;
        Ok(())
    }

    /// Adds a box of height `value` over `[start_nm, end_nm)`.
    pub fn add_box(&mut self, start_nm: f64, end_nm: f64, value: f64) -> Result<()> {
        self.add_trapezoid(start_nm, end_nm, value, value)
    }

    /// Adds a piece that the caller has already validated.
    pub(crate) fn add_trapezoid_unchecked(&mut self, a: f64, b: f64, va: f64, vb: f64) {
        debug_assert!(a < b && va >= 0.0 && vb >= 0.0);
        if va == 0.0 && vb == 0.0 {
            return;
        }
        self.split_at(a);
        self.split_at(b);
        // Pieces now lie either inside [a, b) or outside it.
        let inside: Vec<(f64, Seg)> = self
            .map
            .range((Bound::Included(Key(a)), Bound::Excluded(Key(b))))
            .map(|(k, s)| (k.0, *s))
            .collect();
        let mut cursor = a;
        for (start, seg) in inside {
            if start > cursor {
                // A gap in the spectrum: the trapezoid alone fills it.
                self.map.insert(
                    Key(cursor),
                    Seg {
                        end: start,
                        v0: lerp(a, b, va, vb, cursor),
                        v1: lerp(a, b, va, vb, start),
                    },
                );
            }
            self.map.insert(
                Key(start),
                Seg {
                    end: seg.end,
                    v0: seg.v0 + lerp(a, b, va, vb, start),
                    v1: seg.v1 + lerp(a, b, va, vb, seg.end),
                },
            );
            cursor = seg.end;
        }
        if cursor < b {
            self.map.insert(
                Key(cursor),
                Seg {
                    end: b,
                    v0: lerp(a, b, va, vb, cursor),
                    v1: vb,
                },
            );
        }
    }

    /// Splits the piece that strictly contains `x` (if any) into two at `x`.
    fn split_at(&mut self, x: f64) {
        let Some((k, s)) = self.map.range(..Key(x)).next_back() else {
            return;
        };
        let (k, s) = (k.0, *s);
        if x < s.end {
            let vx = lerp(k, s.end, s.v0, s.v1, x);
            self.map.insert(
                Key(k),
                Seg {
                    end: x,
                    v0: s.v0,
                    v1: vx,
                },
            );
            self.map.insert(
                Key(x),
                Seg {
                    end: s.end,
                    v0: vx,
                    v1: s.v1,
                },
            );
        }
    }

    /// Adds another spectrum (piece by piece).
    pub fn add(&mut self, other: &PiecewiseLinear) {
        for p in other.pieces() {
            self.add_trapezoid_unchecked(p.start_nm, p.end_nm, p.value_start, p.value_end);
        }
    }

    /// Multiplies all values by `factor` (finite, >= 0).
    pub fn scale(&mut self, factor: f64) -> Result<()> {
        non_negative("scale factor", factor)?;
        if factor == 0.0 {
            self.map.clear();
        } else {
            for s in self.map.values_mut() {
                s.v0 *= factor;
                s.v1 *= factor;
            }
        }
        Ok(())
    }

    /// A copy multiplied by `factor` (finite, >= 0).
    pub fn scaled(&self, factor: f64) -> Result<Self> {
        let mut s = self.clone();
        s.scale(factor)?;
        Ok(s)
    }

    /// Exact inner product `integral f(lambda) g(lambda) d lambda` with another
    /// piecewise-linear function (paper section 4.2 "Convolution", closed form per overlap).
    #[must_use]
    pub fn dot(&self, other: &PiecewiseLinear) -> f64 {
        let mut total = 0.0;
        let mut a = self.pieces().peekable();
        let mut b = other.pieces().peekable();
        while let (Some(p), Some(q)) = (a.peek().copied(), b.peek().copied()) {
            let u = p.start_nm.max(q.start_nm);
            let w = p.end_nm.min(q.end_nm);
            if w > u {
                total += product_integral(u, w, p.at(u), p.at(w), q.at(u), q.at(w));
            }
            if p.end_nm <= q.end_nm {
                a.next();
            } else {
                b.next();
            }
        }
        total
    }

    /// The spectrum seen through a Doppler shift: the wavelength axis is scaled by `s`
    /// (`lambda -> s lambda`), and values are transformed as `transform` says. With
    /// [`RadiometricTransform::None`] the integral is multiplied by exactly `s`; with
    /// [`RadiometricTransform::Invariant`] by `s^-4`.
    #[must_use]
    pub fn shifted(&self, shift: WavelengthShift, transform: RadiometricTransform) -> Self {
        let s = shift.value();
        let f = transform.value_factor(shift);
        let map = self
            .map
            .iter()
            .map(|(k, seg)| {
                (
                    Key(k.0 * s),
                    Seg {
                        end: seg.end * s,
                        v0: seg.v0 * f,
                        v1: seg.v1 * f,
                    },
                )
            })
            .collect();
        Self { map }
    }

    /// Multiplies by a constant transmittance in `[0, 1]`.
    pub fn attenuate_uniform(&mut self, transmittance: f64) -> Result<()> {
        if !(0.0..=1.0).contains(&transmittance) {
            return Err(Error::param(
                "transmittance",
                transmittance,
                "must lie in [0, 1]",
            ));
        }
        self.scale(transmittance)
    }

    /// The spectrum after passing through a medium of spectral optical depth
    /// `optical_depth(lambda)` (dimensionless, a piecewise-linear function, e.g.
    /// `rho * tau(lambda) * ds`): `S(lambda) exp(-optical_depth(lambda))`.
    ///
    /// The product is represented piecewise linearly on the union of both functions'
    /// breakpoints, each sub-piece further split so that the optical depth changes by at most
    /// `max_depth_step` over it. The result is exact at every sub-piece end and never exceeds
    /// the input anywhere (unlike the paper's linearised `1 - rho tau ds`, it cannot amplify).
    /// Between the ends it is the chord of `S exp(-tau)`; on a sub-piece where `S` changes by
    /// `dS`, peaks at `S_max` and the depth changes by `dtau <= max_depth_step`, the chord's
    /// error is at most `(2 |dS| dtau + S_max dtau^2) / 8` (the second derivative bound for
    /// linear interpolation). `max_depth_step` must be finite and > 0.
    pub fn attenuated(&self, optical_depth: &PiecewiseLinear, max_depth_step: f64) -> Result<Self> {
        crate::error::positive("max optical-depth step", max_depth_step)?;
        let mut out: Vec<Piece> = Vec::with_capacity(self.map.len());
        let mut depth = optical_depth.pieces().peekable();
        for p in self.pieces() {
            let mut u = p.start_nm;
            while u < p.end_nm {
                // Skip optical-depth pieces that end before u.
                while depth.peek().is_some_and(|q| q.end_nm <= u) {
                    depth.next();
                }
                // The optical depth is linear on [u, w): inside one of its pieces or a gap.
                let (w, tau_u, tau_w) = match depth.peek() {
                    Some(q) if q.start_nm <= u => {
                        let w = q.end_nm.min(p.end_nm);
                        (w, q.at(u), q.at(w))
                    }
                    Some(q) => (q.start_nm.min(p.end_nm), 0.0, 0.0),
                    None => (p.end_nm, 0.0, 0.0),
                };
                let steps = ((tau_w - tau_u).abs() / max_depth_step).ceil().max(1.0);
                let steps = steps.min(1.0e6) as usize;
                for i in 0..steps {
                    let t0 = i as f64 / steps as f64;
                    let t1 = (i + 1) as f64 / steps as f64;
                    let x0 = u + (w - u) * t0;
                    let x1 = if i + 1 == steps { w } else { u + (w - u) * t1 };
                    if x1 <= x0 {
                        continue;
                    }
                    let d0 = tau_u + (tau_w - tau_u) * t0;
                    let d1 = tau_u + (tau_w - tau_u) * t1;
                    out.push(Piece {
                        start_nm: x0,
                        end_nm: x1,
                        value_start: p.at(x0) * (-d0.max(0.0)).exp(),
                        value_end: p.at(x1) * (-d1.max(0.0)).exp(),
                    });
                }
                u = w;
            }
        }
        Ok(Self::from_sorted_unchecked(out))
    }

    /// Merges neighbouring pieces while the result stays within `max_abs_error` of this
    /// spectrum at every wavelength: `|merged(lambda) - self(lambda)| <= max_abs_error` for all
    /// `lambda` (sup norm, in the spectrum's value unit). Consequently the integral over any
    /// interval changes by at most `max_abs_error` times the covered width. Pieces are merged
    /// only across shared ends (never across a gap), identically zero pieces are dropped, and
    /// the result stays non-negative. Repeated merges add their tolerances.
    pub fn merged(&self, max_abs_error: f64) -> Result<Self> {
        non_negative("merge tolerance", max_abs_error)?;
        let mut out = Vec::with_capacity(self.map.len());
        merge_into(self.pieces(), max_abs_error, &mut out);
        Ok(Self::from_sorted_unchecked(out))
    }

    /// Merges with a tolerance relative to the spectrum's maximum:
    /// `merged(relative_tolerance * max_value())`.
    pub fn merged_relative(&self, relative_tolerance: f64) -> Result<Self> {
        non_negative("relative merge tolerance", relative_tolerance)?;
        self.merged(relative_tolerance * self.max_value())
    }
}

/// The sum of trapezoids `(start_nm, end_nm, value_start, value_end)` (validated:
/// `start < end`, values finite and >= 0; in any order, overlapping) as sorted, disjoint
/// pieces, each given to `piece(start, end, value_start, value_end)` in order, by one sweep
/// over their sorted ends: O(n log n) however much they overlap. Identically zero
/// trapezoids are left out; `events` is scratch.
pub fn sum_trapezoids(
    trapezoids: &[(f64, f64, f64, f64)],
    events: &mut Vec<(f64, u8, usize)>,
    mut piece: impl FnMut(f64, f64, f64, f64),
) {
    // Events: (x, kind, index); kind 0 ends a trapezoid, 1 starts one, so at equal x the
    // ending ones leave before the starting ones enter.
    events.clear();
    for (i, t) in trapezoids.iter().enumerate() {
        if t.2 != 0.0 || t.3 != 0.0 {
            events.push((t.0, 1, i));
            events.push((t.1, 0, i));
        }
    }
    events.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    let (mut active, mut value, mut slope) = (0usize, 0.0f64, 0.0f64);
    let mut x = f64::NEG_INFINITY;
    let mut k = 0;
    while k < events.len() {
        let next = events[k].0;
        if active > 0 && next > x {
            let v1 = (value + slope * (next - x)).max(0.0);
            piece(x, next, value.max(0.0), v1);
            value = v1;
        }
        x = next;
        // Every event at this x.
        while k < events.len() && events[k].0 == x {
            let (_, kind, i) = events[k];
            let t = trapezoids[i];
            let s = (t.3 - t.2) / (t.1 - t.0);
            if kind == 1 {
                active += 1;
                value += t.2;
                slope += s;
            } else {
                active -= 1;
                value -= t.3;
                slope -= s;
            }
            k += 1;
        }
        if active == 0 {
            // Exact zero between groups: no drift carried across a gap.
            value = 0.0;
            slope = 0.0;
        }
    }
}

/// [`PiecewiseLinear::merged`] on a plain slice of pieces (sorted by start, disjoint, values
/// non-negative; gaps allowed), for integrators that keep a spectrum in a flat array: the
/// result stays within `max_abs_error` of `pieces` at every wavelength, merges only across
/// shared ends and drops identically zero pieces. `out` is cleared first. Refuses a negative
/// or non-finite tolerance and unsorted or overlapping input.
pub fn merge_pieces(pieces: &[Piece], max_abs_error: f64, out: &mut Vec<Piece>) -> Result<()> {
    non_negative("merge tolerance", max_abs_error)?;
    if let Some(w) = pieces
        .windows(2)
        .find(|w| !(w[0].end_nm <= w[1].start_nm && w[0].start_nm < w[0].end_nm))
    {
        return Err(Error::Range {
            name: "piece overlapping or preceding its predecessor",
            min_nm: w[1].start_nm,
            max_nm: w[1].end_nm,
            reason: "pieces must be sorted and must not overlap",
        });
    }
    out.clear();
    merge_into(pieces.iter().copied(), max_abs_error, out);
    Ok(())
}

/// The merge of [`PiecewiseLinear::merged`] over sorted, disjoint pieces, appended to `out`.
fn merge_into(pieces: impl Iterator<Item = Piece>, tol: f64, out: &mut Vec<Piece>) {
    let mut run: Option<Run> = None;
    for p in pieces {
        if p.value_start == 0.0 && p.value_end == 0.0 {
            if let Some(r) = run.take() {
                out.push(r.piece());
            }
            continue;
        }
        run = Some(match run.take() {
            Some(mut r) => {
                if r.end.0 == p.start_nm && r.try_extend(&p, tol) {
                    r
                } else {
                    out.push(r.piece());
                    Run::start(&p)
                }
            }
            None => Run::start(&p),
        });
    }
    if let Some(r) = run {
        out.push(r.piece());
    }
}

/// A run of contiguous pieces being merged into one line from `anchor` to `end`; the slope
/// cone `[lo, hi]` holds every slope from `anchor` that stays within the tolerance of all
/// interior breakpoints seen so far.
struct Run {
    anchor: (f64, f64),
    end: (f64, f64),
    lo: f64,
    hi: f64,
}

impl Run {
    fn start(p: &Piece) -> Self {
        Self {
            anchor: (p.start_nm, p.value_start),
            end: (p.end_nm, p.value_end),
            lo: f64::NEG_INFINITY,
            hi: f64::INFINITY,
        }
    }

    fn try_extend(&mut self, p: &Piece, tol: f64) -> bool {
        let (x0, y0) = self.anchor;
        let dx = self.end.0 - x0;
        // The junction carries two values: the left limit (old end) and the right value.
        let mut lo = self.lo;
        let mut hi = self.hi;
        for y in [self.end.1, p.value_start] {
            lo = lo.max((y - tol - y0) / dx);
            hi = hi.min((y + tol - y0) / dx);
        }
        let slope = (p.value_end - y0) / (p.end_nm - x0);
        if lo <= slope && slope <= hi {
            self.lo = lo;
            self.hi = hi;
            self.end = (p.end_nm, p.value_end);
            true
        } else {
            false
        }
    }

    fn piece(&self) -> Piece {
        Piece {
            start_nm: self.anchor.0,
            end_nm: self.end.0,
            value_start: self.anchor.1,
            value_end: self.end.1,
        }
    }
}

fn check_piece(p: &Piece) -> Result<()> {
    range("piece", p.start_nm, p.end_nm)?;
    non_negative("piece start value", p.value_start)?;
    non_negative("piece end value", p.value_end)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_centroid_of_a_triangle_is_its_mean() {
        // A symmetric triangle 650-660 nm peaking at 655: centroid 655; a right triangle
        // rising from 0 at 650 to 1 at 660: centroid at 2/3 of the way, 656.667.
        let tri =
            PiecewiseLinear::from_samples(&[(650.0, 0.0), (655.0, 1.0), (660.0, 0.0)]).unwrap();
        assert!((tri.centroid(600.0, 700.0).unwrap() - 655.0).abs() < 1e-12);
        let ramp = PiecewiseLinear::from_samples(&[(650.0, 0.0), (660.0, 1.0)]).unwrap();
        let c = ramp.centroid(600.0, 700.0).unwrap();
        assert!((c - (650.0 + 20.0 / 3.0)).abs() < 1e-9, "{c}");
        // A window cutting the ramp at 655: the part 650-655 (a smaller right triangle).
        let c = ramp.centroid(640.0, 655.0).unwrap();
        assert!((c - (650.0 + 10.0 / 3.0)).abs() < 1e-9, "{c}");
        assert!(ramp.centroid(700.0, 710.0).is_none());
    }

    fn close(a: f64, b: f64, tol: f64) {
        assert!(
            (a - b).abs() <= tol,
            "expected {b}, got {a}, diff {}",
            a - b
        );
    }

    #[test]
    fn fig8_cases_every_relative_position_of_two_intervals() {
        // Green on [x1, x2] = [10, 20] with value 1 -> 2, magenta on [y1, y2] in each of the
        // relative positions of Fig. 8 (disjoint, touching, overlapping, nested, equal).
        let cases = [
            (0.0, 5.0),
            (0.0, 10.0),
            (0.0, 15.0),
            (0.0, 20.0),
            (0.0, 25.0),
            (10.0, 15.0),
            (10.0, 20.0),
            (10.0, 25.0),
            (12.0, 18.0),
            (12.0, 20.0),
            (12.0, 25.0),
            (20.0, 25.0),
            (22.0, 25.0),
        ];
        for (y1, y2) in cases {
            let mut s = PiecewiseLinear::new();
            s.add_trapezoid(10.0, 20.0, 1.0, 2.0).unwrap();
            s.add_trapezoid(y1, y2, 3.0, 0.5).unwrap();
            let f = |x: f64| {
                if (10.0..20.0).contains(&x) {
                    1.0 + (x - 10.0) / 10.0
                } else {
                    0.0
                }
            };
            let g = |x: f64| {
                if (y1..y2).contains(&x) {
                    3.0 + (0.5 - 3.0) * (x - y1) / (y2 - y1)
                } else {
                    0.0
                }
            };
            for i in 0..=300 {
                let x = -1.0 + i as f64 * 0.1;
                close(s.eval(x), f(x) + g(x), 1e-12);
            }
            let pieces: Vec<Piece> = s.pieces().collect();
            for w in pieces.windows(2) {
                assert!(w[0].end_nm <= w[1].start_nm);
            }
            assert!(pieces.len() <= 4, "case {y1}-{y2}: {} pieces", pieces.len());
            close(s.total(), 15.0 + 0.5 * (y2 - y1) * 3.5, 1e-12);
        }
    }

    #[test]
    fn merge_never_exceeds_its_tolerance() {
        let mut s = PiecewiseLinear::new();
        for i in 0..200 {
            let x = 400.0 + i as f64;
            let v = (x / 20.0).sin() + 1.5;
            let v2 = ((x + 1.0) / 20.0).sin() + 1.5;
            s.add_trapezoid(x, x + 1.0, v, v2).unwrap();
        }
        for tol in [1e-4, 1e-3, 1e-2, 1e-1] {
            let m = s.merged(tol).unwrap();
            assert!(m.piece_count() < s.piece_count());
            for i in 0..20_000 {
                let x = 399.0 + i as f64 * 0.0101;
                let d = (m.eval(x) - s.eval(x)).abs();
                assert!(d <= tol * (1.0 + 1e-9) + 1e-12, "tol {tol} at {x}: {d}");
            }
            // The slice form (with a gap and a jump added) stays within the same tolerance
            // of its input.
            let mut pieces: Vec<Piece> = s.pieces().collect();
            pieces.retain(|p| !(450.0..460.0).contains(&p.start_nm));
            pieces[10].value_end += 0.5;
            let mut out = Vec::new();
            merge_pieces(&pieces, tol, &mut out).unwrap();
            let input = PiecewiseLinear::from_pieces(pieces.iter().copied()).unwrap();
            let merged = PiecewiseLinear::from_pieces(out.iter().copied()).unwrap();
            assert!(out.len() < pieces.len());
            for i in 0..20_000 {
                let x = 399.0 + i as f64 * 0.0101;
                let d = (merged.eval(x) - input.eval(x)).abs();
                assert!(
                    d <= tol * (1.0 + 1e-9) + 1e-12,
                    "slice, tol {tol} at {x}: {d}"
                );
            }
        }
    }

    #[test]
    fn merge_pieces_refuses_unsorted_or_overlapping_input() {
        let a = Piece {
            start_nm: 500.0,
            end_nm: 501.0,
            value_start: 1.0,
            value_end: 1.0,
        };
        let b = Piece {
            start_nm: 500.5,
            end_nm: 502.0,
            ..a
        };
        let mut out = Vec::new();
        assert!(merge_pieces(&[a, b], 0.1, &mut out).is_err());
        assert!(merge_pieces(&[b, a], 0.1, &mut out).is_err());
        assert!(merge_pieces(&[a], -1.0, &mut out).is_err());
        assert!(merge_pieces(&[a], f64::NAN, &mut out).is_err());
        merge_pieces(&[a], 0.1, &mut out).unwrap();
        assert_eq!(out, vec![a]);
    }
}
