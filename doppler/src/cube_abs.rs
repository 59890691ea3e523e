//! Absorbing spectral cubes: each ray is marched front to back over the cube's window only,
//! and its light is binned straight into the channels (no spectrum is kept).
//!
//! Segments are numbered from the eye, `k = 0, 1, ...`; segment `k` has the line depth
//! `d_k` and line light `e_k` (both clipped to the window) and the continuum `c_k` (linear
//! on each cell: a channel cut at the black-body grid's nodes). `A_k = sum_{i<k} d_i` is the
//! depth in front, a flat sorted piece list over the window. As in the image integrators,
//! half of a segment's depth lies before its light and half after, so segment `k` adds
//! `integral (e_k + c_k) exp(-A_k - d_k / 2)` over each channel. Absorption acts at each
//! observed wavelength alone, so nothing outside the window can change a channel.
//!
//! * Lines: swept over the supports of `d_k` and `e_k`, each sub-interval cut at the
//!   breakpoints of `A`, `d_k`, `e_k` and the cells, where all three are linear, so the
//!   integral is exact (`front::depth_moments`).
//! * Continuum: `integral c exp(-A - d/2) = integral c - (alpha W0 + beta W1) -
//!   integral_{supp d} c exp(-A) (1 - exp(-d/2))` for `c = alpha + beta (x - x_cell)`,
//!   with `W_n(cell) = integral (x - x_cell)^n (1 - exp(-A))` kept up to date over the
//!   support of each new depth only: O(cells) a segment and no exponential.
//! * Runs (broadened lines): consecutive segments whose Gaussians merge by the emission-only
//!   cube's rule ([`GaussRun`]) and whose merged peak depth `D` stays at or below
//!   `D_max = sqrt(2 tol)` are swept once. Their light is attenuated by `A + f D`, `f` the
//!   light-weighted depth in front within the run as a fraction of `D`: where each member's
//!   light is proportional to its depth (a line that emits and absorbs, the only light a run
//!   takes, and no member in front with depth but no light), the first-order loss
//!   `sum_j e_j (D_<j + d_j / 2)` is exactly `E D / 2` = `E f D`, and what is left is
//!   Jensen's gap: with `y_j` in `[0, D]` and `exp(-y)`'s second derivative at most 1, the
//!   light is low by at most `D_max^2 / 8 = tol / 4` of itself. The continuum is attenuated
//!   by `A` plus its own depth in front within the run, `sum_j c_j (D_<j + d_j / 2) / C`,
//!   merged into one Gaussian from its moments (the same rule), exact to first order for
//!   members of one continuum shape; members join only while their continuum slopes across
//!   the window stay within `tol / (4 D_max)` of each other, which keeps the shape's part
//!   within `tol / 8`. One segment alone gives the exact march.
//! * Depth Gaussians are pieces between nodes of a dyadic lattice (`lattice_gaussian`):
//!   Gaussians of similar width share nodes, so `A`'s breakpoints stop multiplying with the
//!   segments. Emission keeps [`PwlGaussian`]'s pieces, the emission-only cube's model.
//! * `A` is merged as the image march merges its depth (`tol / 32` in all), and coarser
//!   where it passes the piece budget.
//!
//! Error budget against the piecewise-linear model: the merges `tol / 32`, the runs
//! `tol / 4 + tol / 8` (the tests measure 0.02 tol), [`GaussRun`]'s merge 0.12 % of a line's
//! peak, and the lattice Gaussian's own error, at most `h^2 / (8 sigma^2) + e^-8` of its
//! peak depth (0.8 %, as for [`PwlGaussian`]; in transmittance about `0.008 tau`).
//!
//! [`PwlGaussian`]: blueshift_spectrum::PwlGaussian

use blueshift_spectrum::{Blackbody, Piece, merge_pieces};

use super::cube::{GaussRun, MERGE_ERROR, line_reaches};
use super::front::{Carry, Cursor, add_sorted, depth_moments, ends};
use super::profile::Emit;
use super::pwl::spectrum_err;
use super::render::{Context, RaySamples};
use crate::{Error, Result};

type Trap = (f64, f64, f64, f64);

/// A cube's window, shared by its rays: the cells (a channel cut at the black-body grid's
/// nodes inside it: `(lo, hi, channel)`), the grid interval of each cell, and the nodes the
/// continuum needs.
pub(crate) struct Window {
    lo: f64,
    hi: f64,
    cells: Vec<(f64, f64, usize)>,
    grid: Vec<usize>,
    nodes: std::ops::RangeInclusive<usize>,
}

impl Window {
    /// The window of the channel edges `edges` (ascending, at least two).
    pub(crate) fn new(ctx: &Context<'_>, edges: &[f64]) -> Result<Self> {
        let lam = &ctx
            .pwl
            .as_ref()
            .ok_or_else(|| Error::parameter("cubes need the piecewise-linear integrator"))?
            .lambdas;
        if edges.len() < 2 || lam.len() < 2 {
            return Err(Error::parameter(
                "a cube needs a channel and a wavelength grid",
            ));
        }
        let mut cells = Vec::with_capacity(edges.len() + 2);
        for (c, e) in edges.windows(2).enumerate() {
            let mut x = e[0];
            for &g in lam.iter().filter(|&&g| g > e[0] && g < e[1]) {
                cells.push((x, g, c));
                x = g;
            }
            cells.push((x, e[1], c));
        }
        let grid: Vec<usize> = cells
            .iter()
            .map(|&(lo, hi, _)| {
                let m = 0.5 * (lo + hi);
                lam.partition_point(|&g| g <= m)
                    .saturating_sub(1)
                    .min(lam.len() - 2)
            })
            .collect();
        let nodes = grid[0]..=grid[grid.len() - 1] + 1;
        Ok(Self {
            lo: edges[0],
            hi: edges[edges.len() - 1],
            cells,
            grid,
            nodes,
        })
    }
}

/// A thread's reusable buffers.
#[derive(Default)]
pub(crate) struct Scratch {
    a: Vec<Piece>,
    a2: Vec<Piece>,
    d: Vec<Piece>,
    e: Vec<Piece>,
    c: Vec<Piece>,
    dtr: Vec<Trap>,
    etr: Vec<Trap>,
    ctr: Vec<Trap>,
    ev_e: Vec<Emit>,
    ev_d: Vec<Emit>,
    events: Vec<(f64, u8, usize)>,
    w: Vec<[f64; 2]>,
    cont: Vec<(f64, f64)>,
    run_cont: Vec<(f64, f64)>,
    near: Vec<f64>,
    far: Vec<f64>,
}

/// The depth in front (`A`) and its continuum moments `W`, with the merge schedule.
struct Depth<'s> {
    a: &'s mut Vec<Piece>,
    a2: &'s mut Vec<Piece>,
    d: &'s mut Vec<Piece>,
    e: &'s mut Vec<Piece>,
    c: &'s mut Vec<Piece>,
    events: &'s mut Vec<(f64, u8, usize)>,
    w: &'s mut [[f64; 2]],
    tol: f64,
    budget: usize,
    segments: f64,
    merges: u32,
    merged_len: usize,
}

impl Depth<'_> {
    /// Sweeps the depth `dtr` and light `etr` (trapezoids) behind `A` into `acc`, light
    /// attenuated by `A + fe d`, with the continuum `cont` per cell attenuated by `A` plus
    /// `ctr` (a run's continuum depth in front) or, for `None`, half of `d`; then adds `d` to
    /// `A` (and to `W`).
    #[allow(clippy::too_many_arguments)]
    fn sweep_add(
        &mut self,
        win: &Window,
        dtr: &[Trap],
        etr: &[Trap],
        ctr: Option<&[Trap]>,
        cont: &[(f64, f64)],
        fe: f64,
        acc: &mut [f64],
    ) -> Result<()> {
        sum_trapezoids(dtr, self.d, self.events);
        sum_trapezoids(etr, self.e, self.events);
        let cd = match ctr {
            Some(t) => {
                sum_trapezoids(t, self.c, self.events);
                ContDepth::Own(self.c)
            }
            None => ContDepth::Scaled(0.5),
        };
        sweep(win, self.a, self.d, self.e, cd, cont, self.w, acc, fe);
        if self.d.is_empty() {
            return Ok(());
        }
        add_sorted(self.a, self.d, self.a2);
        std::mem::swap(self.a, self.a2);
        if self.tol > 0.0 && self.a.len() > 2 * self.merged_len {
            // The image march's schedule: merge k may move A by tol/32 x 6/(pi k)^2, so all
            // of them by at most tol/32.
            self.merges += 1;
            let k = f64::from(self.merges);
            let t = self.tol / 32.0 * 6.0 / (std::f64::consts::PI * k).powi(2);
            merge_pieces(self.a, t, self.a2).map_err(spectrum_err)?;
            std::mem::swap(self.a, self.a2);
            self.merged_len = self.a.len().max(64);
        }
        // Budget fallback: coarser merges until A fits, from 4x this segment's share of the
        // tolerance up (the transmittance moves by at most the merge's depth error), as the
        // image march does: stops once only gaps separate the pieces, or at a scale that
        // merges everything mergeable (never overflowing).
        let mut scale = 1.0f64;
        while self.a.len() > self.budget {
            scale = (scale * 4.0).min(1e30);
            let t = (self.tol.max(1e-6) * scale / self.segments).min(f64::MAX);
            merge_pieces(self.a, t, self.a2).map_err(spectrum_err)?;
            let gained = self.a2.len() < self.a.len();
            std::mem::swap(self.a, self.a2);
            if !gained && (scale >= 1e30 || self.a.windows(2).all(|p| p[0].end_nm < p[1].start_nm))
            {
                break;
            }
        }
        Ok(())
    }
}

/// An open run of consecutive segments (module docs): its merged light and depth
/// Gaussians, its depth so far `t`, the light-weighted depth in front within the run `s_e`
/// with its weight, the continuum's weight `w_c` and the raw moments of its depth in front
/// within the run `yc` (about the depth run's first centre), the continuum's slope across
/// the window of its first lit member, and whether a member has depth but no light.
#[derive(Clone, Copy)]
struct Run {
    e: GaussRun,
    d: GaussRun,
    t: f64,
    e_area: f64,
    s_e: f64,
    w_c: f64,
    yc: [f64; 5],
    slope: Option<f64>,
    dark: bool,
    segments: u32,
}

/// One segment as a candidate run member: its light and depth events, its continuum's
/// integral over the window and slope across it (`(hi - lo) / (hi + lo)` of its values at
/// the window's ends).
struct Member<'a> {
    light: &'a [Emit],
    depth: &'a [Emit],
    wc: f64,
    slope: f64,
}

/// The limits of a run: the merged peak depth `d_max`, and the spread of its members'
/// continuum slopes.
#[derive(Clone, Copy)]
struct Limits {
    d_max: f64,
    slope_spread: f64,
}

impl Limits {
    /// The limits for the merge tolerance `tol`: a peak depth of `sqrt(2 tol)` (Jensen's gap
    /// `D^2 / 8` is then `tol / 4`), a slope spread whose first-order continuum error
    /// `spread x D / 2` stays within `tol / 8`.
    fn new(tol: f64) -> Self {
        let d_max = (2.0 * tol).sqrt();
        Self {
            d_max,
            slope_spread: if d_max > 0.0 {
                tol / (4.0 * d_max)
            } else {
                0.0
            },
        }
    }
}

impl Run {
    const EMPTY: Self = Self {
        e: GaussRun::EMPTY,
        d: GaussRun::EMPTY,
        t: 0.0,
        e_area: 0.0,
        s_e: 0.0,
        w_c: 0.0,
        yc: [0.0; 5],
        slope: None,
        dark: false,
        segments: 0,
    };

    /// This run with the member `m` added, if: every Gaussian merges ([`GaussRun`]'s rule,
    /// also for the continuum's depth in front); the merged peak depth stays at or below
    /// `lim.d_max`; the member's light is proportional to its depth (each light Gaussian at
    /// the centre and width of the depth Gaussian beside it: a line that emits and absorbs)
    /// and no member in front had depth without light, so the light's first-order loss
    /// inside the run is exactly `E D / 2`; and the member's continuum slope is within
    /// `lim.slope_spread` of the run's.
    fn with(&self, m: &Member<'_>, lim: Limits) -> Option<Self> {
        if !m.light.is_empty() && (self.dark || !proportional(m.light, m.depth)) {
            return None;
        }
        let mut r = *self;
        if m.wc > 0.0 {
            match r.slope {
                None => r.slope = Some(m.slope),
                Some(s) if (m.slope - s).abs() <= lim.slope_spread => {}
                Some(_) => return None,
            }
        }
        let add = |run: &mut GaussRun, ev: &[Emit]| -> Option<f64> {
            let mut area = 0.0;
            for &e in ev {
                match e {
                    Emit::Gaussian(c, sg, a) if run.try_add(c, sg, a) => area += a,
                    _ => return None,
                }
            }
            Some(area)
        };
        let (before, _) = r.d.sums();
        let ej = add(&mut r.e, m.light)?;
        let tau = add(&mut r.d, m.depth)?;
        if !r.d.is_empty() {
            let (_, sd, da) = { r.d }.take();
            if da / ((2.0 * std::f64::consts::PI).sqrt() * sd) > lim.d_max {
                return None;
            }
        }
        // The continuum's depth in front: each member's continuum sees the run's depth in
        // front of it plus half its own.
        let (after, _) = r.d.sums();
        for (y, (b, a)) in r.yc.iter_mut().zip(before.iter().zip(&after)) {
            *y += m.wc * 0.5 * (b + a);
        }
        if r.yc[0] > 0.0 {
            let (_, var, err) = GaussRun::shape(&r.yc);
            if !(var > 0.0 && err <= MERGE_ERROR) {
                return None;
            }
        }
        r.s_e += ej * (r.t + 0.5 * tau);
        r.e_area += ej;
        r.w_c += m.wc;
        r.t += tau;
        r.dark |= m.light.is_empty() && !m.depth.is_empty();
        r.segments += 1;
        Some(r)
    }

    /// The continuum's depth in front within the run as one Gaussian `(centre, sigma, area)`
    /// per unit of continuum, if any.
    fn continuum_depth(&self, c0: f64) -> Option<(f64, f64, f64)> {
        if !(self.yc[0] > 0.0 && self.w_c > 0.0) {
            return None;
        }
        let (mean, var, _) = GaussRun::shape(&self.yc);
        Some((c0 + mean, var.max(0.0).sqrt(), self.yc[0] / self.w_c))
    }
}

/// Whether each light Gaussian sits at the centre and width of the depth Gaussian at its
/// place in the lists (equal lengths, Gaussians only).
fn proportional(light: &[Emit], depth: &[Emit]) -> bool {
    light.len() == depth.len()
        && light.iter().zip(depth).all(|(l, d)| match (*l, *d) {
            (Emit::Gaussian(cl, sl, _), Emit::Gaussian(cd, sd, _)) => cl == cd && sl == sd,
            _ => false,
        })
}

/// One absorbing ray's channel values into `acc` (overwritten); `front`: the optical depth
/// in front of the context's clip box (distributed rendering; empty: none).
pub(crate) fn ray_channels(
    ctx: &Context<'_>,
    win: &Window,
    ray: &crate::Ray,
    front: &[Piece],
    acc: &mut [f64],
    sc: &mut Scratch,
) -> Result<()> {
    acc.iter_mut().for_each(|v| *v = 0.0);
    let s = ctx.sample(ray)?;
    let n = s.len();
    if n < 2 {
        return Ok(());
    }
    let lam = &ctx
        .pwl
        .as_ref()
        .ok_or_else(|| Error::parameter("cubes need the piecewise-linear integrator"))?
        .lambdas;
    let Scratch {
        a,
        a2,
        d,
        e,
        c,
        dtr,
        etr,
        ctr,
        ev_e,
        ev_d,
        events,
        w,
        cont,
        run_cont,
        near,
        far,
    } = sc;
    let nc = win.cells.len();
    w.clear();
    w.resize(nc, [0.0; 2]);
    cont.clear();
    cont.resize(nc, (0.0, 0.0));
    run_cont.clear();
    run_cont.resize(nc, (0.0, 0.0));
    a.clear();
    let tol = ctx.settings.merge_tolerance;
    let mut depth = Depth {
        a,
        a2,
        d,
        e,
        c,
        events,
        w,
        tol,
        budget: ctx.settings.piece_budget.max(2),
        segments: (n - 1) as f64,
        merges: 0,
        merged_len: 64,
    };
    if !front.is_empty() {
        // The depth in front of the box: W from one sweep of it behind nothing (no light,
        // no continuum), then A is it.
        dtr.clear();
        for p in front {
            clip_push(dtr, win, p.start_nm, p.end_nm, p.value_start, p.value_end);
        }
        etr.clear();
        depth.sweep_add(win, dtr, etr, None, cont, 0.5, acc)?;
    }
    // Runs form only where a segment's events are Gaussians that merge (broadening), so a
    // window with two lines, or trapezoids, is marched segment by segment.
    let limits = Limits::new(tol);
    let bb_nodes = |j: usize, out: &mut Vec<f64>| -> Result<bool> {
        out.clear();
        let (rho, temp) = (s.bb[j], s.bb_temp[j]);
        if rho <= 0.0 || temp <= 0.0 {
            out.resize(win.nodes.clone().count(), 0.0);
            return Ok(false);
        }
        let sh = s.shift[j];
        let k = ctx.value_factor(sh) * rho;
        let bb = Blackbody::new(temp).map_err(spectrum_err)?;
        out.extend(win.nodes.clone().map(|i| k * bb.eval(lam[i] / sh)));
        Ok(true)
    };
    let i0 = *win.nodes.start();
    let mut has_near = bb_nodes(n - 1, near)?;
    let mut run = Run::EMPTY;
    for j in (0..n - 1).rev() {
        let has_far = bb_nodes(j, far)?;
        let dt = f64::from(s.t[j] - s.t[j + 1]).abs();
        // This segment's continuum per cell (trapezoid rule along the ray on the grid).
        let mut wc = 0.0;
        let (mut c_lo, mut c_hi) = (0.0, 0.0);
        let lit = has_near || has_far;
        for (ci, &(lo, hi, _)) in win.cells.iter().enumerate() {
            cont[ci] = if lit {
                let i = win.grid[ci];
                let v0 = 0.5 * dt * (far[i - i0] + near[i - i0]);
                let v1 = 0.5 * dt * (far[i + 1 - i0] + near[i + 1 - i0]);
                let slope = (v1 - v0) / (lam[i + 1] - lam[i]);
                let alpha = v0 + slope * (lo - lam[i]);
                let len = hi - lo;
                wc += alpha * len + 0.5 * slope * len * len;
                if ci == 0 {
                    c_lo = alpha;
                }
                c_hi = alpha + slope * len;
                (alpha, slope)
            } else {
                (0.0, 0.0)
            };
        }
        ev_e.clear();
        ev_d.clear();
        window_events(ctx, &s, j, true, win, ev_e)?;
        window_events(ctx, &s, j, false, win, ev_d)?;
        let member = Member {
            light: ev_e,
            depth: ev_d,
            wc,
            slope: if c_lo + c_hi > 0.0 {
                (c_hi - c_lo) / (c_hi + c_lo)
            } else {
                0.0
            },
        };
        let joined = run.with(&member, limits);
        if joined.is_none() {
            flush(
                ctx,
                win,
                &mut run,
                run_cont,
                &mut depth,
                [dtr, etr, ctr],
                acc,
            )?;
        }
        // The continuum past everything swept so far (all in front of this segment).
        if lit {
            for (ci, &(lo, hi, ch)) in win.cells.iter().enumerate() {
                let (alpha, slope) = cont[ci];
                let len = hi - lo;
                let wd = &depth.w[ci];
                acc[ch] += alpha * len + 0.5 * slope * len * len - (alpha * wd[0] + slope * wd[1]);
            }
        }
        if let Some(r) = joined {
            run = r;
            for (rc, c) in run_cont.iter_mut().zip(cont.iter()) {
                rc.0 += c.0;
                rc.1 += c.1;
            }
        } else if let Some(r) = Run::EMPTY.with(
            &member,
            Limits {
                d_max: f64::INFINITY,
                ..limits
            },
        ) {
            // A new run (its peak may pass D_max: one segment alone is exact).
            run = r;
            run_cont.copy_from_slice(cont);
        } else {
            events_to_traps(ctx, ev_d, win, dtr, true);
            events_to_traps(ctx, ev_e, win, etr, false);
            depth.sweep_add(win, dtr, etr, None, cont, 0.5, acc)?;
        }
        std::mem::swap(near, far);
        has_near = has_far;
    }
    flush(
        ctx,
        win,
        &mut run,
        run_cont,
        &mut depth,
        [dtr, etr, ctr],
        acc,
    )?;
    // The continuum behind a saturated depth is a difference of nearly equal terms: never
    // let its rounding go below zero (a NaN from overflowing factors stays, to be refused).
    acc.iter_mut().filter(|v| **v < 0.0).for_each(|v| *v = 0.0);
    Ok(())
}

/// The optical depth over the window of the ray's segments (inside the context's clip box),
/// each segment's depth as the march adds it (depth Gaussians on the lattice): what a
/// distributed cube passes on as the depth in front of the boxes behind. Summed pairwise,
/// as a balanced tree.
pub(crate) fn total_depth(ctx: &Context<'_>, win: &Window, ray: &crate::Ray) -> Result<Vec<Piece>> {
    let s = ctx.sample(ray)?;
    let (mut ev, mut tr, mut events) = (Vec::new(), Vec::new(), Vec::new());
    let mut level: Vec<Vec<Piece>> = Vec::new();
    for j in 0..s.len().saturating_sub(1) {
        ev.clear();
        window_events(ctx, &s, j, false, win, &mut ev)?;
        events_to_traps(ctx, &ev, win, &mut tr, true);
        if tr.is_empty() {
            continue;
        }
        let mut one = Vec::new();
        sum_trapezoids(&tr, &mut one, &mut events);
        level.push(one);
    }
    while level.len() > 1 {
        level = level
            .chunks(2)
            .map(|c| match c {
                [a, b] => super::front::add_depths(a, b),
                [a] => a.clone(),
                _ => unreachable!("chunks of at most two"),
            })
            .collect();
    }
    Ok(level.pop().unwrap_or_default())
}

/// Sweeps the open run (if any) and empties it: its merged light attenuated by `A + f D`
/// (`f` its light-weighted depth in front within the run, as a fraction of `D`), its
/// continuum by `A` plus its continuum depth in front.
fn flush(
    ctx: &Context<'_>,
    win: &Window,
    run: &mut Run,
    run_cont: &mut [(f64, f64)],
    depth: &mut Depth<'_>,
    [dtr, etr, ctr]: [&mut Vec<Trap>; 3],
    acc: &mut [f64],
) -> Result<()> {
    if run.segments == 0 {
        return Ok(());
    }
    let (_, c0) = run.d.sums();
    ctr.clear();
    if let Some((c, sg, area)) = run.continuum_depth(c0) {
        lattice_gaussian(c, sg, area, win, ctr);
    }
    let (ce, se, ea) = run.e.take();
    let (cd, sd, da) = run.d.take();
    let ev_e = (ea > 0.0).then_some(Emit::Gaussian(ce, se, ea));
    let ev_d = (da > 0.0).then_some(Emit::Gaussian(cd, sd, da));
    events_to_traps(ctx, ev_d.as_slice(), win, dtr, true);
    events_to_traps(ctx, ev_e.as_slice(), win, etr, false);
    let fe = if da > 0.0 && run.e_area > 0.0 {
        (run.s_e / (run.e_area * da)).clamp(0.0, 1.0)
    } else {
        0.5
    };
    depth.sweep_add(win, dtr, etr, Some(ctr), run_cont, fe, acc)?;
    run_cont.iter_mut().for_each(|c| *c = (0.0, 0.0));
    *run = Run::EMPTY;
    Ok(())
}

/// Calls `sink(species, line, segment areas (a0, a1))` for every line of segment `j` that
/// reaches the window: emission (shift factor included) or depth.
fn for_window_lines(
    ctx: &Context<'_>,
    s: &RaySamples,
    j: usize,
    emission: bool,
    win: &Window,
    mut sink: impl FnMut(usize, usize, (f64, f64, f64, f64)),
) {
    let scene = ctx.scene;
    let f = scene.factors;
    let nsp = scene.species.len();
    let dt = f64::from(s.t[j] - s.t[j + 1]).abs();
    let (sa, sb) = (s.shift[j], s.shift[j + 1]);
    let (ga, gb) = if emission {
        (ctx.value_factor(sa) * sa, ctx.value_factor(sb) * sb)
    } else {
        (1.0, 1.0)
    };
    for (m, sp) in scene.species.iter().enumerate() {
        let (lines, factor) = if emission {
            (&sp.emission_lines, f.emission)
        } else {
            (&sp.absorption_lines, f.absorption)
        };
        let (ra, rb) = (s.rho[j * nsp + m], s.rho[(j + 1) * nsp + m]);
        if (ra <= 0.0 && rb <= 0.0) || factor == 0.0 {
            continue;
        }
        let (siga, sigb) = if ctx.profiles.active {
            (
                ctx.profiles.sigma_v(m, s.temp[j]),
                ctx.profiles.sigma_v(m, s.temp[j + 1]),
            )
        } else {
            (0.0, 0.0)
        };
        for (i, l) in lines.iter().enumerate() {
            if !line_reaches(
                l.centre_nm,
                (sa, sb),
                siga.max(sigb),
                ctx.settings.line_width_nm,
                (win.lo, win.hi),
            ) {
                continue;
            }
            let base = dt * l.strength * factor;
            sink(m, i, (base * ra * ga, base * rb * gb, siga, sigb));
        }
    }
}

/// Segment `j`'s events (trapezoids, Gaussians) of the lines that reach the window, as
/// [`super::profile::emit_line`] gives them (one trapezoid each without broadening).
fn window_events(
    ctx: &Context<'_>,
    s: &RaySamples,
    j: usize,
    emission: bool,
    win: &Window,
    out: &mut Vec<Emit>,
) -> Result<()> {
    let (sa, sb) = (s.shift[j], s.shift[j + 1]);
    let lw = ctx.settings.line_width_nm;
    let mut result = Ok(());
    for_window_lines(ctx, s, j, emission, win, |m, i, (a0, a1, siga, sigb)| {
        if result.is_err() {
            return;
        }
        let sp = &ctx.scene.species[m];
        let l = if emission {
            &sp.emission_lines[i]
        } else {
            &sp.absorption_lines[i]
        };
        if ctx.profiles.active {
            result = super::profile::emit_line(
                l.centre_nm,
                sa,
                sb,
                a0,
                a1,
                siga,
                sigb,
                lw,
                &mut |e| -> Result<()> {
                    out.push(e);
                    Ok(())
                },
            );
        } else {
            let (lo, hi, h0, h1) = super::pwl::line_trapezoid(l.centre_nm, sa, sb, a0, a1, lw);
            out.push(Emit::Trapezoid(lo, hi, h0, h1));
        }
    });
    result
}

/// The events as trapezoids clipped to the window: Gaussians as [`PwlGaussian`] pieces, or
/// on the dyadic lattice (`lattice`, for depths).
///
/// [`PwlGaussian`]: blueshift_spectrum::PwlGaussian
fn events_to_traps(
    ctx: &Context<'_>,
    ev: &[Emit],
    win: &Window,
    out: &mut Vec<Trap>,
    lattice: bool,
) {
    out.clear();
    let g = &ctx.profiles.gauss;
    for &e in ev {
        match e {
            Emit::Trapezoid(lo, hi, h0, h1) => clip_push(out, win, lo, hi, h0, h1),
            Emit::Gaussian(c, sg, area) if lattice => lattice_gaussian(c, sg, area, win, out),
            Emit::Gaussian(c, sg, area) => {
                let half = g.half_width_sigmas() * sg;
                if c + half > win.lo && c - half < win.hi {
                    // The closure never fails.
                    let _ = g.for_each_piece(c, sg, area, |lo, hi, h0, h1| -> Result<()> {
                        clip_push(out, win, lo, hi, h0, h1);
                        Ok(())
                    });
                }
            }
        }
    }
}

/// Appends the trapezoid `lo..hi` (`h0` to `h1`) clipped to the window, if anything of it
/// is left.
#[inline]
fn clip_push(out: &mut Vec<Trap>, win: &Window, lo: f64, hi: f64, h0: f64, h1: f64) {
    if hi <= win.lo || lo >= win.hi || hi <= lo {
        return;
    }
    let s = (h1 - h0) / (hi - lo);
    let (a, b) = (lo.max(win.lo), hi.min(win.hi));
    let v0 = if a == lo {
        h0
    } else {
        (h0 + s * (a - lo)).max(0.0)
    };
    let v1 = if b == hi {
        h1
    } else {
        (h0 + s * (b - lo)).max(0.0)
    };
    if b > a && (v0 > 0.0 || v1 > 0.0) {
        out.push((a, b, v0, v1));
    }
}

/// The Gaussian `(c, sigma, area)` as pieces between the nodes of the dyadic lattice of
/// spacing `h = 2^floor(log2(sigma / 4))` (so `sigma / 8 < h <= sigma / 4`) over
/// `c +- 4 sigma`: the Gaussian's values at the inner nodes, zero at the two end nodes,
/// scaled to the exact area, clipped to the window. Off the Gaussian by at most
/// `h^2 / (8 sigma^2) + e^-8` of its peak plus the rescaling (0.8 %).
fn lattice_gaussian(c: f64, sg: f64, area: f64, win: &Window, out: &mut Vec<Trap>) {
    if !(sg > 0.0 && area > 0.0 && sg.is_finite() && area.is_finite()) {
        return;
    }
    let (lo, hi) = (c - 4.0 * sg, c + 4.0 * sg);
    if hi <= win.lo || lo >= win.hi {
        return;
    }
    let h = (sg / 4.0).log2().floor().exp2();
    let (k0, k1) = ((lo / h).floor(), (hi / h).ceil());
    // Nodes k0..=k1: at most 8 sigma / h + 2 < 66 of them; the ends are zero.
    let nodes = ((k1 - k0) as usize + 1).min(LATTICE_NODES);
    let mut v = [0.0f64; LATTICE_NODES];
    let inv2 = 0.5 / (sg * sg);
    for (i, vi) in v.iter_mut().enumerate().take(nodes - 1).skip(1) {
        let x = (k0 + i as f64) * h - c;
        *vi = (-x * x * inv2).exp();
    }
    // The trapezoid rule's area (the ends are zero).
    let sum: f64 = v[1..nodes - 1].iter().sum::<f64>() * h;
    if sum <= 0.0 {
        return;
    }
    let scale = area / sum;
    for i in 0..nodes - 1 {
        let x0 = (k0 + i as f64) * h;
        clip_push(out, win, x0, x0 + h, v[i] * scale, v[i + 1] * scale);
    }
}

/// Most nodes of a lattice Gaussian (8 sigma over a spacing above sigma / 8, plus the two
/// ends and rounding).
const LATTICE_NODES: usize = 72;

/// Sums trapezoids (any order, possibly overlapping) into sorted, disjoint pieces in `out`
/// (cleared first): as they are where they are sorted and disjoint already (one Gaussian's
/// pieces, one trapezoid), else by the spectrum crate's sweep over their sorted ends.
fn sum_trapezoids(tr: &[Trap], out: &mut Vec<Piece>, events: &mut Vec<(f64, u8, usize)>) {
    out.clear();
    let piece = |start_nm, end_nm, value_start, value_end| Piece {
        start_nm,
        end_nm,
        value_start,
        value_end,
    };
    if tr.windows(2).all(|w| w[0].1 <= w[1].0) {
        out.extend(tr.iter().map(|&(lo, hi, h0, h1)| piece(lo, hi, h0, h1)));
        return;
    }
    blueshift_spectrum::sum_trapezoids(tr, events, |a, b, v0, v1| {
        out.push(piece(a, b, v0, v1));
    });
}

/// The continuum's depth beyond `A` in a sweep: a fraction of the segment's depth, or a
/// run's own.
#[derive(Clone, Copy)]
enum ContDepth<'a> {
    Scaled(f64),
    Own(&'a [Piece]),
}

/// One sweep over the supports of `d`, `e` and the continuum's depth behind the depth `a`
/// (module docs): the light `e` attenuated by `a + fe d` into `acc`, the continuum `cont` of
/// each cell less its loss to its depth beyond `a`, and `W` updated for `a + d`.
#[allow(clippy::too_many_arguments)]
fn sweep(
    win: &Window,
    a: &[Piece],
    d: &[Piece],
    e: &[Piece],
    cd: ContDepth<'_>,
    cont: &[(f64, f64)],
    w: &mut [[f64; 2]],
    acc: &mut [f64],
    fe: f64,
) {
    let own: &[Piece] = match cd {
        ContDepth::Own(p) => p,
        ContDepth::Scaled(_) => &[],
    };
    let first = |p: &[Piece]| p.first().map_or(f64::INFINITY, |q| q.start_nm);
    let last = |p: &[Piece]| p.last().map_or(f64::NEG_INFINITY, |q| q.end_nm);
    let start = first(d).min(first(e)).min(first(own));
    let end = last(d).max(last(e)).max(last(own));
    if start >= end {
        return;
    }
    let cells = &win.cells;
    let mut ci = cells.partition_point(|c| c.1 <= start);
    let (mut ac, mut dc, mut ec, mut oc) = (
        Cursor::new(a),
        Cursor::new(d),
        Cursor::new(e),
        Cursor::new(own),
    );
    let (mut before, mut light, mut after, mut dim) =
        (Carry::NONE, Carry::NONE, Carry::NONE, Carry::NONE);
    let mut u = start;
    while u < end {
        while ci < cells.len() && cells[ci].1 <= u {
            ci += 1;
        }
        if ci >= cells.len() {
            break;
        }
        let (dp, ep, op) = (dc.at(u), ec.at(u), oc.at(u));
        if dp.is_none() && ep.is_none() && op.is_none() {
            u = dc
                .next_break(None)
                .min(ec.next_break(None))
                .min(oc.next_break(None));
            continue;
        }
        let pp = ac.at(u);
        let mut v = cells[ci]
            .1
            .min(dc.next_break(dp))
            .min(ec.next_break(ep))
            .min(oc.next_break(op))
            .min(ac.next_break(pp));
        if v <= u {
            // Never stall on a breakpoint that rounds onto u.
            v = u + 1e-12 * u.abs().max(1.0);
        }
        let h = v - u;
        let (pu, pw) = ends(pp, u, v);
        let (du, dw) = ends(dp, u, v);
        let (eu, ew) = ends(ep, u, v);
        let has_d = du > 0.0 || dw > 0.0;
        let (lo, _, ch) = cells[ci];
        let off = u - lo;
        let jb = depth_moments(pu, pw, before.trans(u, pu), before.trans(v, pw), h);
        let moments = |carry: &mut Carry, (xu, xw): (f64, f64)| {
            let (xu, xw) = (pu + xu, pw + xw);
            depth_moments(xu, xw, carry.trans(u, xu), carry.trans(v, xw), h)
        };
        let jl = if has_d {
            moments(&mut light, (fe * du, fe * dw))
        } else {
            jb
        };
        if eu > 0.0 || ew > 0.0 {
            acc[ch] += eu * jl[0] + (ew - eu) / h * jl[1];
        }
        if has_d {
            let ja = moments(&mut after, (du, dw));
            let (d0, d1) = (jb[0] - ja[0], jb[1] - ja[1]);
            w[ci][0] += d0;
            w[ci][1] += off * d0 + d1;
        }
        let (alpha, slope) = cont[ci];
        if alpha != 0.0 || slope != 0.0 {
            let (cu, cw) = match cd {
                ContDepth::Scaled(f) => (f * du, f * dw),
                ContDepth::Own(_) => ends(op, u, v),
            };
            if cu > 0.0 || cw > 0.0 {
                let jc = match cd {
                    ContDepth::Scaled(f) if f == fe => jl,
                    _ => moments(&mut dim, (cu, cw)),
                };
                acc[ch] -= (alpha + slope * off) * (jb[0] - jc[0]) + slope * (jb[1] - jc[1]);
            }
        }
        u = v;
    }
}
