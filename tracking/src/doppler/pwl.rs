//! The piecewise-linear integrator (Algorithm 2, without its energy error).

use blueshift_spectrum::{Blackbody, Cmf, Piece, PiecewiseLinear, Xyz};

use super::profile::Emit;
use super::render::{Context, RayOut, RaySamples, TraceStep, Want};
use crate::{Error, Result};

/// Per-render tables: the black-body wavelength grid and the XYZ of each grid hat function.
#[derive(Debug)]
pub(crate) struct PwlTables {
    lambdas: Vec<f64>,
    hat_xyz: Vec<Xyz>,
    /// The CMF table (CIE 1931 2 degree): first wavelength, spacing (nm) and samples.
    cmf_lo: f64,
    cmf_step: f64,
    cmf: Vec<[f64; 3]>,
}

impl PwlTables {
    /// The piecewise-linear CMFs at `x` (inside the table's range).
    #[inline]
    fn cmf_at(&self, x: f64) -> [f64; 3] {
        let u = ((x - self.cmf_lo) / self.cmf_step).max(0.0);
        let i = (u as usize).min(self.cmf.len() - 2);
        let f = u - i as f64;
        let (a, b) = (self.cmf[i], self.cmf[i + 1]);
        [
            a[0] + (b[0] - a[0]) * f,
            a[1] + (b[1] - a[1]) * f,
            a[2] + (b[2] - a[2]) * f,
        ]
    }
}

impl PwlTables {
    pub fn new(settings: &super::DopplerSettings) -> Self {
        let (a, b) = settings.range_nm;
        let k = settings.blackbody_samples;
        let lambdas: Vec<f64> = (0..k)
            .map(|i| a + (b - a) * i as f64 / (k - 1) as f64)
            .collect();
        let cmf = Cmf::cie1931_2deg();
        let hat_xyz = (0..k)
            .map(|i| {
                let mut x = Xyz::ZERO;
                if i > 0 {
                    x += cmf.trapezoid_xyz(lambdas[i - 1], lambdas[i], 0.0, 1.0);
                }
                if i + 1 < k {
                    x += cmf.trapezoid_xyz(lambdas[i], lambdas[i + 1], 1.0, 0.0);
                }
                x
            })
            .collect();
        let (c_lo, c_hi) = cmf.range_nm();
        let table: Vec<[f64; 3]> = cmf.samples().map(|(_, v)| v).collect();
        let cmf_step = (c_hi - c_lo) / (table.len().max(2) - 1) as f64;
        Self {
            lambdas,
            hat_xyz,
            cmf_lo: c_lo,
            cmf_step,
            cmf: table,
        }
    }
}

/// The trapezoid a delta line at `centre` emits over a segment whose ends see shifts `sa`, `sb`
/// and line areas `area_a`, `area_b`: between the shifted positions (at least `min_width`
/// wide, centred), heights linear in the ends' areas, total area `(area_a + area_b) / 2`.
pub(crate) fn line_trapezoid(
    centre: f64,
    sa: f64,
    sb: f64,
    area_a: f64,
    area_b: f64,
    min_width: f64,
) -> (f64, f64, f64, f64) {
    let (la, lb) = (sa * centre, sb * centre);
    let w = (lb - la).abs().max(min_width);
    let m = 0.5 * (la + lb);
    let (lo, hi) = (m - 0.5 * w, m + 0.5 * w);
    if la <= lb {
        (lo, hi, area_a / w, area_b / w)
    } else {
        (lo, hi, area_b / w, area_a / w)
    }
}

fn spectrum_err(e: blueshift_spectrum::Error) -> Error {
    Error::parameter(format!("spectrum: {e}"))
}

fn bb_row(
    ctx: &Context<'_>,
    t: &PwlTables,
    s: &RaySamples,
    j: usize,
    out: &mut [f64],
) -> Result<bool> {
    let (rho, temp) = (s.bb[j], s.temp[j]);
    if rho <= 0.0 || temp <= 0.0 {
        out.iter_mut().for_each(|v| *v = 0.0);
        return Ok(false);
    }
    let sh = s.shift[j];
    let k = ctx.value_factor(sh) * rho;
    let bb = Blackbody::new(temp).map_err(spectrum_err)?;
    for (o, &l) in out.iter_mut().zip(&t.lambdas) {
        *o = k * bb.eval(l / sh);
    }
    Ok(true)
}

pub(crate) fn integrate(
    ctx: &Context<'_>,
    t: &PwlTables,
    s: &RaySamples,
    want: Want,
) -> Result<RayOut> {
    let scene = ctx.scene;
    let st = ctx.settings;
    let f = scene.factors;
    let cmf = Cmf::cie1931_2deg();
    let n = s.len();
    let absorbing = f.absorption > 0.0
        && scene
            .species
            .iter()
            .any(|sp| !sp.absorption_lines.is_empty());
    if absorbing && want == Want::Xyz {
        return front_to_back(ctx, t, s);
    }
    let keep = absorbing || want != Want::Xyz;
    let direct_bb = absorbing || want == Want::Trace;
    let k = t.lambdas.len();
    let mut acc = vec![0.0; k];
    let mut fa = vec![0.0; k];
    let mut fb = vec![0.0; k];
    let mut has_a = bb_row(ctx, t, s, 0, &mut fa)?;
    let mut spec = PiecewiseLinear::new();
    let mut xyz = Xyz::ZERO;
    let mut out = RayOut::default();
    let mut tol_scale = 1.0;
    let mut half_tau = PiecewiseLinear::new();
    let mut lines = Vec::new();
    let segments = (n - 1) as f64;
    for j in 0..n - 1 {
        let dt = f64::from(s.t[j] - s.t[j + 1]).abs();
        if absorbing {
            let mut tau = PiecewiseLinear::new();
            // Half the segment's optical depth: the light from behind crosses one half
            // before and one half after the segment's emission is added.
            segment_lines(ctx, s, j, false, 0.5, &mut lines)?;
            for &(lo, hi, h0, h1) in &lines {
                tau.add_trapezoid(lo, hi, h0, h1).map_err(spectrum_err)?;
            }
            if !tau.is_empty() && !spec.is_empty() {
                spec = spec
                    .attenuated(&tau, st.max_depth_step)
                    .map_err(spectrum_err)?;
            }
            half_tau = tau;
        }
        // Line emission.
        segment_lines(ctx, s, j, true, 1.0, &mut lines)?;
        for &(lo, hi, h0, h1) in &lines {
            if keep {
                spec.add_trapezoid(lo, hi, h0, h1).map_err(spectrum_err)?;
            } else {
                xyz += cmf.trapezoid_xyz(lo, hi, h0, h1);
            }
        }
        // Black body: trapezoid rule along the ray on the fixed wavelength grid.
        let has_b = bb_row(ctx, t, s, j + 1, &mut fb)?;
        if has_a || has_b {
            if direct_bb {
                for i in 0..k - 1 {
                    let v0 = 0.5 * dt * (fa[i] + fb[i]);
                    let v1 = 0.5 * dt * (fa[i + 1] + fb[i + 1]);
                    if v0 > 0.0 || v1 > 0.0 {
                        spec.add_trapezoid(t.lambdas[i], t.lambdas[i + 1], v0, v1)
                            .map_err(spectrum_err)?;
                    }
                }
            } else {
                for i in 0..k {
                    acc[i] += 0.5 * dt * (fa[i] + fb[i]);
                }
            }
        }
        std::mem::swap(&mut fa, &mut fb);
        has_a = has_b;
        if !half_tau.is_empty() {
            spec = spec
                .attenuated(&half_tau, st.max_depth_step)
                .map_err(spectrum_err)?;
            half_tau = PiecewiseLinear::new();
        }
        if keep {
            // Merging against the ray's total: each merge may add `tol / segments` (relative
            // to the spectrum's maximum then); later attenuation only shrinks earlier errors,
            // so the sup error of the final spectrum stays below `tol` x the largest maximum.
            if absorbing && st.merge_tolerance > 0.0 && spec.piece_count() > 64 {
                spec = spec
                    .merged(st.merge_tolerance * tol_scale * spec.max_value() / segments)
                    .map_err(spectrum_err)?;
            }
            // Budget fallback: coarser merges until the spectrum fits (the preview strategy).
            let mut guard = 0;
            while spec.piece_count() > st.piece_budget && guard < 40 {
                tol_scale *= 4.0;
                let tol = st.merge_tolerance.max(1e-6) * tol_scale * spec.max_value();
                spec = spec.merged(tol).map_err(spectrum_err)?;
                out.fallback = true;
                guard += 1;
            }
            out.max_pieces = out.max_pieces.max(spec.piece_count());
            if want == Want::Trace {
                out.trace.push(TraceStep {
                    t: s.t[j + 1],
                    radial_velocity_m_per_s: s.v_r[j + 1],
                    spectrum: spec.clone(),
                });
            }
        }
    }
    for i in 0..k {
        xyz += t.hat_xyz[i].scaled(acc[i]);
    }
    if keep {
        xyz += cmf.xyz_of(&spec);
        if want != Want::Xyz && acc.iter().any(|&v| v > 0.0) {
            for i in 0..k - 1 {
                if acc[i] > 0.0 || acc[i + 1] > 0.0 {
                    spec.add_trapezoid(t.lambdas[i], t.lambdas[i + 1], acc[i], acc[i + 1])
                        .map_err(spectrum_err)?;
                }
            }
        }
        out.spectrum = Some(spec);
    }
    out.xyz = xyz;
    Ok(out)
}

/// The line trapezoids (`lo, hi, h_lo, h_hi`) of one segment: emission (`emission = true`,
/// values include the shift factor) or the segment's optical depth, times `scale`. With
/// broadening ([`super::profile::Broadening`]) each line's sweep comes out as its profile's
/// pieces (thermal / Gaussian), for emission and absorption alike; otherwise as the paper's
/// box swept into one trapezoid.
fn segment_lines(
    ctx: &Context<'_>,
    s: &RaySamples,
    j: usize,
    emission: bool,
    scale: f64,
    out: &mut Vec<(f64, f64, f64, f64)>,
) -> Result<()> {
    let scene = ctx.scene;
    let st = ctx.settings;
    let f = scene.factors;
    let nsp = scene.species.len();
    let (range_lo, range_hi) = st.range_nm;
    let dt = f64::from(s.t[j] - s.t[j + 1]).abs();
    let (sa, sb) = (s.shift[j], s.shift[j + 1]);
    let (ga, gb) = if emission {
        (ctx.value_factor(sa) * sa, ctx.value_factor(sb) * sb)
    } else {
        (1.0, 1.0)
    };
    out.clear();
    let mut push = |lo: f64, hi: f64, h0: f64, h1: f64| -> Result<()> {
        if !(hi < range_lo || lo > range_hi || (h0 <= 0.0 && h1 <= 0.0)) {
            out.push((lo, hi, h0, h1));
        }
        Ok(())
    };
    for (m, sp) in scene.species.iter().enumerate() {
        let (ra, rb) = (s.rho[j * nsp + m], s.rho[(j + 1) * nsp + m]);
        if ra <= 0.0 && rb <= 0.0 {
            continue;
        }
        let (lines, factor) = if emission {
            (&sp.emission_lines, f.emission)
        } else {
            (&sp.absorption_lines, f.absorption)
        };
        let (siga, sigb) = if ctx.profiles.active {
            (
                ctx.profiles.sigma_v(m, s.temp[j]),
                ctx.profiles.sigma_v(m, s.temp[j + 1]),
            )
        } else {
            (0.0, 0.0)
        };
        for l in lines {
            let base = scale * dt * l.strength * factor;
            let (a0, a1) = (base * ra * ga, base * rb * gb);
            if ctx.profiles.active {
                super::profile::emit_line(
                    l.centre_nm,
                    sa,
                    sb,
                    a0,
                    a1,
                    siga,
                    sigb,
                    st.line_width_nm,
                    &mut |e| match e {
                        Emit::Trapezoid(lo, hi, h0, h1) => push(lo, hi, h0, h1),
                        Emit::Gaussian(c, sg, area) => {
                            ctx.profiles.gauss.for_each_piece(c, sg, area, &mut push)
                        }
                    },
                )?;
            } else {
                let (lo, hi, h0, h1) =
                    line_trapezoid(l.centre_nm, sa, sb, a0, a1, st.line_width_nm);
                push(lo, hi, h0, h1)?;
            }
        }
    }
    Ok(())
}

/// The piece of `pieces` (sorted, disjoint) holding `x`, advancing the cursor `i`.
fn piece_at(pieces: &[Piece], i: &mut usize, x: f64) -> Option<Piece> {
    while *i < pieces.len() && pieces[*i].end_nm <= x {
        *i += 1;
    }
    pieces.get(*i).copied().filter(|p| p.start_nm <= x)
}

/// `[int_0^h x^n exp(-s x) dx for n = 0, 1, 2]` (`s` may be 0 or negative), by recurrence,
/// or by its series where `|s h|` is small (the recurrence cancels there).
#[inline]
fn exp_moments(s: f64, h: f64) -> [f64; 3] {
    let z = s * h;
    if z.abs() < 0.05 {
        // sum_k (-z)^k / k! h^(n+1) / (n + k + 1); 8 terms: error < 0.05^8 / 8! ~ 1e-15.
        let mut m = [0.0; 3];
        let mut term = 1.0;
        for k in 0..8 {
            for (n, v) in m.iter_mut().enumerate() {
                *v += term / (n + k + 1) as f64;
            }
            term *= -z / (k + 1) as f64;
        }
        [m[0] * h, m[1] * h * h, m[2] * h * h * h]
    } else {
        let e = (-z).exp();
        let i0 = (1.0 - e) / s;
        let i1 = (i0 - h * e) / s;
        let i2 = (2.0 * i1 - h * h * e) / s;
        [i0, i1, i2]
    }
}

/// What the optical depth in front, `tau`, takes from a segment's emission (black body on
/// the uniform grid `t.lambdas` with values `bb`, lines `lines`):
/// `integral E(lambda) (1 - exp(-tau(lambda))) cmf(lambda) d lambda`, over `tau`'s support.
///
/// The support is cut at every breakpoint of `E`, of `tau` and of the (piecewise-linear)
/// CMFs. On each sub-interval `E` and the CMFs are linear, so their product is a quadratic,
/// and `tau` is linear, so `exp(-tau)` is an exponential of the wavelength: the integral
/// has a closed form (the moments of [`exp_moments`]), exact up to rounding.
fn absorbed_xyz(
    t: &PwlTables,
    tau: impl Iterator<Item = Piece>,
    bb: Option<&[f64]>,
    lines: &[Piece],
) -> Xyz {
    let c_lo = t.cmf_lo;
    let c_step = t.cmf_step;
    let c_hi = c_lo + c_step * (t.cmf.len() - 1) as f64;
    let mut out = [0.0f64; 3];
    let k = t.lambdas.len();
    let (g0, g1) = (t.lambdas[0], t.lambdas[k - 1]);
    let gstep = (g1 - g0) / (k - 1) as f64;
    let bb_at = |x: f64| -> f64 {
        match bb {
            Some(v) if x >= g0 && x <= g1 => {
                let u = (x - g0) / gstep;
                let i = (u as usize).min(k - 2);
                let f = u - i as f64;
                v[i] + (v[i + 1] - v[i]) * f
            }
            _ => 0.0,
        }
    };
    let mut li = 0usize;
    for p in tau {
        if p.value_start <= 0.0 && p.value_end <= 0.0 {
            continue;
        }
        let (lo, hi) = (p.start_nm.max(c_lo), p.end_nm.min(c_hi));
        if hi <= lo {
            continue;
        }
        let slope = (p.value_end - p.value_start) / (p.end_nm - p.start_nm);
        let mut u = lo;
        let mut c_u = t.cmf_at(u);
        let mut trans_u = (-p.at(u).max(0.0)).exp();
        while u < hi {
            let mut w = hi;
            // The next CMF node, black-body grid point and line break.
            let node = c_lo + (((u - c_lo) / c_step) as usize + 1) as f64 * c_step;
            if node > u {
                w = w.min(node);
            }
            if bb.is_some() {
                if u < g0 {
                    w = w.min(g0);
                } else if u < g1 {
                    let next = g0 + (((u - g0) / gstep) as usize + 1) as f64 * gstep;
                    if next > u {
                        w = w.min(next);
                    }
                }
            }
            let line = piece_at(lines, &mut li, u);
            match line {
                Some(q) => w = w.min(q.end_nm),
                None => {
                    if let Some(q) = lines.get(li).filter(|q| q.start_nm > u) {
                        w = w.min(q.start_nm);
                    }
                }
            }
            if w <= u {
                // A breakpoint that rounding put at u.
                w = hi.min(u + 1e-9 * u.abs().max(1.0));
                if w <= u {
                    break;
                }
            }
            let h = w - u;
            let c_w = t.cmf_at(w);
            let e_u = bb_at(u) + line.map_or(0.0, |q| q.at(u));
            let e_w = bb_at(w) + line.map_or(0.0, |q| q.at(w));
            let trans_w = (-p.at(w).max(0.0)).exp();
            if e_u > 0.0 || e_w > 0.0 {
                // tau(u + x) = tau(u) + slope x. The exponential is taken from the end where
                // tau is smaller (exp(-tau) there, decaying from it), so nothing overflows.
                let de = (e_w - e_u) / h;
                let (base, m, flip) = if slope >= 0.0 {
                    (trans_u, exp_moments(slope, h), false)
                } else {
                    (trans_w, exp_moments(-slope, h), true)
                };
                for c in 0..3 {
                    let dc = (c_w[c] - c_u[c]) / h;
                    // E C = q0 + q1 x + q2 x^2 in x = lambda - u.
                    let (q0, q1, q2) = (e_u * c_u[c], e_u * dc + de * c_u[c], de * dc);
                    let full = q0 * h + q1 * h * h / 2.0 + q2 * h * h * h / 3.0;
                    // From the right end (y = h - x) when tau decreases.
                    let (r0, r1, r2) = if flip {
                        (q0 + q1 * h + q2 * h * h, -q1 - 2.0 * q2 * h, q2)
                    } else {
                        (q0, q1, q2)
                    };
                    // integral of E C minus integral of E C exp(-tau).
                    out[c] += full - base * (r0 * m[0] + r1 * m[1] + r2 * m[2]);
                }
            }
            u = w;
            c_u = c_w;
            trans_u = trans_w;
        }
    }
    Xyz::from_array(out)
}

/// The XYZ of a ray with absorption, front to back, without any emitted spectrum.
///
/// Marching from the eye, only the optical depth in front, `tau_front(lambda)`, is kept (a
/// piecewise-linear function, non-zero only inside the shifted absorption lines). A segment's
/// emission `E` reaches the eye as `E exp(-tau_front - tau_seg / 2)` (the light emitted in a
/// segment crosses half of its own optical depth, the convention of the back-to-front path
/// and of the banded integrator), so its XYZ is the closed-form XYZ of `E` minus
/// [`absorbed_xyz`] over `tau`'s support.
///
/// Error bound (`tol = merge_tolerance`): the correction itself is exact (closed form per
/// sub-interval); merges of `tau_front` use the tolerances `tol 6 / (pi^2 k^2)` for the
/// `k`-th merge, so the optical depth is off by at most `tol` anywhere (the series sums to
/// `tol`) and the transmittance by at most `tol`; so every XYZ channel is within `tol` x the
/// same channel of the unattenuated emission, for the whole ray (not per segment). Only the
/// piece-budget fallback (counted) can break this bound.
fn front_to_back(ctx: &Context<'_>, t: &PwlTables, s: &RaySamples) -> Result<RayOut> {
    let st = ctx.settings;
    let cmf = Cmf::cie1931_2deg();
    let n = s.len();
    let k = t.lambdas.len();
    let tol = st.merge_tolerance;
    let mut out = RayOut::default();
    let mut acc = vec![0.0; k];
    let mut row = vec![0.0; k];
    let mut f_near = vec![0.0; k];
    let mut f_far = vec![0.0; k];
    let mut has_near = bb_row(ctx, t, s, n - 1, &mut f_near)?;
    let mut tau = PiecewiseLinear::new();
    let mut line_pieces: Vec<Piece> = Vec::new();
    let mut emit = Vec::new();
    let mut absorb = Vec::new();
    let mut xyz = Xyz::ZERO;
    let mut taken = Xyz::ZERO;
    let mut merges = 0u32;
    let mut merge_at = 64usize;
    let mut budget_scale = 1.0;
    for j in (0..n - 1).rev() {
        let dt = f64::from(s.t[j] - s.t[j + 1]).abs();
        segment_lines(ctx, s, j, false, 1.0, &mut absorb)?;
        segment_lines(ctx, s, j, true, 1.0, &mut emit)?;
        let has_far = bb_row(ctx, t, s, j, &mut f_far)?;
        let has_bb = has_near || has_far;
        if has_bb {
            for i in 0..k {
                row[i] = 0.5 * dt * (f_near[i] + f_far[i]);
                acc[i] += row[i];
            }
        }
        for &(lo, hi, h0, h1) in &emit {
            xyz += cmf.trapezoid_xyz(lo, hi, h0, h1);
        }
        // Half of the segment's own depth, then the correction, then the other half.
        for &(lo, hi, h0, h1) in &absorb {
            tau.add_trapezoid(lo, hi, 0.5 * h0, 0.5 * h1)
                .map_err(spectrum_err)?;
        }
        if !tau.is_empty() && (has_bb || !emit.is_empty()) {
            line_pieces.clear();
            if !emit.is_empty() {
                let mut lines_pwl = PiecewiseLinear::new();
                for &(lo, hi, h0, h1) in &emit {
                    lines_pwl
                        .add_trapezoid(lo, hi, h0, h1)
                        .map_err(spectrum_err)?;
                }
                line_pieces.extend(lines_pwl.pieces());
            }
            taken += absorbed_xyz(t, tau.pieces(), has_bb.then_some(&row[..]), &line_pieces);
        }
        for &(lo, hi, h0, h1) in &absorb {
            tau.add_trapezoid(lo, hi, 0.5 * h0, 0.5 * h1)
                .map_err(spectrum_err)?;
        }
        if tau.piece_count() > merge_at {
            merges += 1;
            let share = 6.0 / (std::f64::consts::PI.powi(2) * f64::from(merges).powi(2));
            tau = tau.merged(tol * share).map_err(spectrum_err)?;
            merge_at = (2 * tau.piece_count()).max(64);
        }
        // Budget fallback: coarser merges until tau fits (the preview strategy; this breaks
        // the error bound above and is counted).
        let mut guard = 0;
        while tau.piece_count() > st.piece_budget && guard < 40 {
            budget_scale *= 4.0;
            tau = tau.merged(tol * budget_scale).map_err(spectrum_err)?;
            out.fallback = true;
            guard += 1;
        }
        out.max_pieces = out.max_pieces.max(tau.piece_count());
        std::mem::swap(&mut f_near, &mut f_far);
        has_near = has_far;
    }
    for i in 0..k {
        xyz += t.hat_xyz[i].scaled(acc[i]);
    }
    let a = xyz.to_array();
    let b = taken.to_array();
    out.xyz = Xyz::from_array([
        (a[0] - b[0]).max(0.0),
        (a[1] - b[1]).max(0.0),
        (a[2] - b[2]).max(0.0),
    ]);
    Ok(out)
}
