//! Focus+context axes of the editor view (HDR VolVis section 5, Eq. 2, Fig. 6 and 7): a 1D
//! fisheye magnification of the normalised data axis with one or more focus regions, and a
//! logarithmic opacity/colour axis with a floor.

use crate::{Error, Result};

/// One focus region on the normalised data axis [0, 1] (HDR VolVis Fig. 6b).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct FocusRegion {
    /// Centre of the magnified range R_c, in [0, 1].
    pub center: f64,
    /// Width of R_c (> 0).
    pub width: f64,
    /// Magnification M_c > 1 inside R_c.
    pub magnification: f64,
    /// Width of the transition region R_tr on each side of R_c (>= 0), in which the
    /// magnification goes linearly from M_c to M_min.
    pub transition: f64,
}

impl FocusRegion {
    fn support(&self) -> (f64, f64) {
        let h = 0.5 * self.width + self.transition;
        (self.center - h, self.center + h)
    }
}

/// A piece of the magnification profile: on `[t0, t1]` the magnification goes linearly from
/// `m0` to `m1`; `s0` is the screen position at `t0`.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Piece {
    t0: f64,
    t1: f64,
    m0: f64,
    m1: f64,
    s0: f64,
}

impl Piece {
    fn forward(&self, t: f64) -> f64 {
        let d = (t - self.t0).clamp(0.0, self.t1 - self.t0);
        let k = (self.m1 - self.m0) / (self.t1 - self.t0);
        self.s0 + d * (self.m0 + 0.5 * k * d)
    }
    fn s1(&self) -> f64 {
        self.s0 + 0.5 * (self.m0 + self.m1) * (self.t1 - self.t0)
    }
    fn inverse(&self, s: f64) -> f64 {
        let len = self.t1 - self.t0;
        let ds = (s - self.s0).max(0.0);
        let k = (self.m1 - self.m0) / len;
        // Solve 0.5 k d^2 + m0 d - ds = 0 in the cancellation-free form.
        let disc = (self.m0 * self.m0 + 2.0 * k * ds).max(0.0);
        let d = 2.0 * ds / (self.m0 + disc.sqrt());
        self.t0 + d.clamp(0.0, len)
    }
}

/// A 1D fisheye map of the normalised data axis t in [0, 1] onto the window x in [0, 1]
/// (HDR VolVis Eq. 2). With no focus region it is the identity (the "linear axes" switch).
///
/// The magnification is M_c inside each focus region, M_min outside all of them, and linear
/// between the two across the transition regions; the screen position is its integral, so
/// the map is continuous, strictly increasing and piecewise quadratic. M_min is solved from
/// Eq. 2, the condition that the whole range still fits the window:
/// `∫_{R_min} M_min + ∫_{R_c} M_c + ∫_{R_tr} M_tr = 1`. Regions that reach past 0 or 1
/// are clipped, and the integral is taken over the clipped parts.
#[derive(Clone, Debug, PartialEq)]
pub struct Fisheye {
    regions: Vec<FocusRegion>,
    m_min: f64,
    pieces: Vec<Piece>,
}

impl Default for Fisheye {
    fn default() -> Self {
        Self::linear()
    }
}

impl Fisheye {
    /// The identity map (no magnification).
    #[must_use]
    pub fn linear() -> Self {
        Self {
            regions: Vec::new(),
            m_min: 1.0,
            pieces: vec![Piece {
                t0: 0.0,
                t1: 1.0,
                m0: 1.0,
                m1: 1.0,
                s0: 0.0,
            }],
        }
    }

    /// Builds the map for the given focus regions (in any order). Refuses regions with a
    /// centre outside [0, 1], a non-positive width, M_c <= 1, a negative transition,
    /// non-finite numbers, regions (with their transitions) that overlap, and settings that
    /// leave no room for the context (M_min would be <= 0).
    pub fn new(mut regions: Vec<FocusRegion>) -> Result<Self> {
        for (i, r) in regions.iter().enumerate() {
            let finite = [r.center, r.width, r.magnification, r.transition]
                .iter()
                .all(|v| v.is_finite());
            if !finite {
                return Err(Error::parameter(format!("focus region {i}: numbers must be finite, got {r:?}")));
            }
            if !(0.0..=1.0).contains(&r.center) {
                return Err(Error::parameter(format!(
                    "focus region {i}: centre {} is outside the normalised axis [0, 1]",
                    r.center
                )));
            }
            if r.width <= 0.0 {
                return Err(Error::parameter(format!("focus region {i}: width {} must be > 0", r.width)));
            }
            if r.magnification <= 1.0 {
                return Err(Error::parameter(format!(
                    "focus region {i}: magnification M_c = {} must be > 1",
                    r.magnification
                )));
            }
            if r.transition < 0.0 {
                return Err(Error::parameter(format!(
                    "focus region {i}: transition width {} must be >= 0",
                    r.transition
                )));
            }
        }
        if regions.is_empty() {
            return Ok(Self::linear());
        }
        regions.sort_by(|a, b| a.center.total_cmp(&b.center));
        for w in regions.windows(2) {
            let (_, a_hi) = w[0].support();
            let (b_lo, _) = w[1].support();
            if a_hi > b_lo {
                return Err(Error::parameter(format!(
                    "focus regions centred at {} and {} overlap (with their transitions they span up to {a_hi} and from {b_lo})",
                    w[0].center, w[1].center
                )));
            }
        }
        // Profile as pieces [t0, t1] with magnification (a0 + b0 M_min) .. (a1 + b1 M_min).
        struct Sym {
            t0: f64,
            t1: f64,
            a0: f64,
            b0: f64,
            a1: f64,
            b1: f64,
        }
        let mut sym: Vec<Sym> = Vec::new();
        let mut push = |t0: f64, t1: f64, m0: (f64, f64), m1: (f64, f64)| {
            // Clip to [0, 1], interpolating the symbolic magnification linearly.
            let (c0, c1) = (t0.max(0.0), t1.min(1.0));
            if c1 <= c0 {
                return;
            }
            let at = |t: f64| {
                let f = if t1 > t0 { (t - t0) / (t1 - t0) } else { 0.0 };
                (m0.0 + (m1.0 - m0.0) * f, m0.1 + (m1.1 - m0.1) * f)
            };
            let (p, q) = (at(c0), at(c1));
            sym.push(Sym { t0: c0, t1: c1, a0: p.0, b0: p.1, a1: q.0, b1: q.1 });
        };
        let ctx = (0.0, 1.0);
        let mut cursor = 0.0f64;
        for r in &regions {
            let mc = (r.magnification, 0.0);
            let h = 0.5 * r.width;
            let (s_lo, s_hi) = r.support();
            push(cursor, s_lo, ctx, ctx);
            push(s_lo, r.center - h, ctx, mc);
            push(r.center - h, r.center + h, mc, mc);
            push(r.center + h, s_hi, mc, ctx);
            cursor = s_hi;
        }
        push(cursor, 1.0, ctx, ctx);
        // Eq. 2: sum over pieces of the mean magnification times the length = 1.
        let (mut a, mut b) = (0.0, 0.0);
        for p in &sym {
            let len = p.t1 - p.t0;
            a += 0.5 * (p.a0 + p.a1) * len;
            b += 0.5 * (p.b0 + p.b1) * len;
        }
        let m_min = if b > 0.0 { (1.0 - a) / b } else { f64::NEG_INFINITY };
        if !(m_min > 0.0) {
            return Err(Error::parameter(format!(
                "the focus regions magnify {a:.4} of the window's width on their own, leaving no room for the context (M_min = {m_min:.4} <= 0); lower a magnification or a width"
            )));
        }
        let mut pieces = Vec::with_capacity(sym.len());
        let mut s = 0.0;
        for p in &sym {
            let piece = Piece {
                t0: p.t0,
                t1: p.t1,
                m0: p.a0 + p.b0 * m_min,
                m1: p.a1 + p.b1 * m_min,
                s0: s,
            };
            s = piece.s1();
            pieces.push(piece);
        }
        Ok(Self {
            regions,
            m_min,
            pieces,
        })
    }

    /// The focus regions, sorted by centre.
    #[must_use]
    pub fn regions(&self) -> &[FocusRegion] {
        &self.regions
    }

    /// The solved context magnification M_min (1 without focus regions).
    #[must_use]
    pub fn m_min(&self) -> f64 {
        self.m_min
    }

    /// Whether this is the identity map.
    #[must_use]
    pub fn is_linear(&self) -> bool {
        self.regions.is_empty()
    }

    /// The magnification M(t) at normalised data position `t` (Fig. 6b).
    #[must_use]
    pub fn magnification(&self, t: f64) -> f64 {
        let p = self.piece_at_t(t.clamp(0.0, 1.0));
        let f = (t.clamp(p.t0, p.t1) - p.t0) / (p.t1 - p.t0);
        p.m0 + (p.m1 - p.m0) * f
    }

    fn piece_at_t(&self, t: f64) -> &Piece {
        let i = self.pieces.partition_point(|p| p.t1 < t);
        &self.pieces[i.min(self.pieces.len() - 1)]
    }

    /// Window position x in [0, 1] of normalised data position `t` (clamped to [0, 1]).
    #[must_use]
    pub fn forward(&self, t: f64) -> f64 {
        if t.is_nan() {
            return f64::NAN;
        }
        let t = t.clamp(0.0, 1.0);
        if t >= 1.0 {
            return 1.0;
        }
        self.piece_at_t(t).forward(t).clamp(0.0, 1.0)
    }

    /// Normalised data position t of window position `x` (clamped to [0, 1]); the inverse
    /// of [`Fisheye::forward`].
    #[must_use]
    pub fn inverse(&self, x: f64) -> f64 {
        if x.is_nan() {
            return f64::NAN;
        }
        let x = x.clamp(0.0, 1.0);
        if x >= 1.0 {
            return 1.0;
        }
        let i = self.pieces.partition_point(|p| p.s1() < x);
        self.pieces[i.min(self.pieces.len() - 1)]
            .inverse(x)
            .clamp(0.0, 1.0)
    }

    /// Eq. 2's left-hand side for this map, integrated piece by piece: 1 up to rounding.
    #[must_use]
    pub fn total_width(&self) -> f64 {
        self.pieces
            .iter()
            .map(|p| 0.5 * (p.m0 + p.m1) * (p.t1 - p.t0))
            .sum()
    }
}

/// The vertical (opacity or colour) axis of the editor view.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase", tag = "kind")]
pub enum ValueAxis {
    /// y = value, for values in [0, 1].
    Linear,
    /// y = (log10 v - log10 floor) / (-log10 floor): [floor, 1] fills the axis, values
    /// below the floor sit at the bottom (HDR VolVis section 5, Fig. 7). `floor` in (0, 1).
    Log {
        /// Smallest value shown, in (0, 1), e.g. 1e-4.
        floor: f64,
    },
}

impl ValueAxis {
    /// A logarithmic axis; refuses floors outside (0, 1).
    pub fn log(floor: f64) -> Result<Self> {
        if !(floor > 0.0 && floor < 1.0) {
            return Err(Error::parameter(format!(
                "the floor of a logarithmic axis must be in (0, 1), got {floor}"
            )));
        }
        Ok(ValueAxis::Log { floor })
    }

    /// Axis position y in [0, 1] of value `v` (clamped).
    #[must_use]
    pub fn forward(self, v: f64) -> f64 {
        match self {
            ValueAxis::Linear => v.clamp(0.0, 1.0),
            ValueAxis::Log { floor } => {
                let v = v.clamp(floor, 1.0);
                (1.0 - v.log10() / floor.log10()).clamp(0.0, 1.0)
            }
        }
    }

    /// Value at axis position `y` in [0, 1] (clamped); inverse of [`ValueAxis::forward`] on
    /// `[floor, 1]`.
    #[must_use]
    pub fn inverse(self, y: f64) -> f64 {
        let y = y.clamp(0.0, 1.0);
        match self {
            ValueAxis::Linear => y,
            ValueAxis::Log { floor } => floor.powf(1.0 - y),
        }
    }
}
