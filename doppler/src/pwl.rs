//! The piecewise-linear integrator (Algorithm 2, without its energy error).

use blueshift_spectrum::{Blackbody, Cmf, PiecewiseLinear, Xyz};

use super::profile::Emit;
use super::render::{Context, RayOut, RaySamples, TraceStep, Want};
use crate::{Error, Result};

/// The piecewise-linear integrator's tables (part of [`crate::Prepared`]): the black-body
/// wavelength grid, the XYZ of each grid hat function, and the CMF table.
#[derive(Debug)]
pub struct PwlTables {
    /// The black-body wavelength grid, nm: `blackbody_samples` points spanning `range_nm`.
    pub lambdas: Vec<f64>,
    /// The XYZ of each grid point's hat function (1 at the point, 0 at its neighbours).
    pub hat_xyz: Vec<Xyz>,
    /// The CMF table (CIE 1931 2 degree): first wavelength, nm.
    pub cmf_lo: f64,
    /// The CMF table's spacing, nm.
    pub cmf_step: f64,
    /// The CMF samples (x-bar, y-bar, z-bar), from `cmf_lo` every `cmf_step`.
    pub cmf: Vec<[f64; 3]>,
    /// `1 / cmf_step`.
    cmf_inv_step: f64,
}

impl PwlTables {
    /// The piecewise-linear CMFs at `x` (inside the table's range).
    #[inline]
    pub(crate) fn cmf_at(&self, x: f64) -> [f64; 3] {
        let u = ((x - self.cmf_lo) * self.cmf_inv_step).max(0.0);
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
    /// The XYZ of a line trapezoid against the piecewise-linear CMFs: exact, interval by
    /// interval of the CMF table (lines are narrow; wide ones go to the prefix-sum form).
    pub(crate) fn line_xyz(&self, (lo, hi, h0, h1): (f64, f64, f64, f64)) -> [f64; 3] {
        let t = self;
        let cmf = Cmf::cie1931_2deg();
        let c_hi = t.cmf_lo + t.cmf_step * (t.cmf.len() - 1) as f64;
        let (a, b) = (lo.max(t.cmf_lo), hi.min(c_hi));
        if b <= a {
            return [0.0; 3];
        }
        if b - a > 8.0 * t.cmf_step {
            return cmf.trapezoid_xyz(lo, hi, h0, h1).to_array();
        }
        let slope = (h1 - h0) / (hi - lo);
        let step = t.cmf_step;
        let inv_cstep = t.cmf_inv_step;
        let last = t.cmf.len() - 2;
        // The CMF cell holding `a` (a node rounding puts a hair on either side gives the
        // same values), then cell by cell to `b`, the CMFs at inner nodes straight from the
        // table.
        let mut j = (((a - t.cmf_lo) * inv_cstep).max(0.0) as usize).min(last);
        let node = |j: usize| t.cmf_lo + j as f64 * step;
        let cmf_in = |j: usize, x: f64| {
            let (c0, c1) = (t.cmf[j], t.cmf[j + 1]);
            let f = (x - node(j)) * inv_cstep;
            [
                c0[0] + (c1[0] - c0[0]) * f,
                c0[1] + (c1[1] - c0[1]) * f,
                c0[2] + (c1[2] - c0[2]) * f,
            ]
        };
        let mut out = [0.0; 3];
        let mut u = a;
        let mut cu = cmf_in(j, u);
        let mut fu = h0 + slope * (u - lo);
        loop {
            let next = node(j + 1);
            let (w, cw) = if next < b && j < last {
                (next, t.cmf[j + 1])
            } else {
                (b, cmf_in(j, b))
            };
            let fw = if w >= hi { h1 } else { h0 + slope * (w - lo) };
            let h6 = (w - u) * (1.0 / 6.0);
            for c in 0..3 {
                out[c] += h6 * (fu * (2.0 * cu[c] + cw[c]) + fw * (cu[c] + 2.0 * cw[c]));
            }
            if w >= b {
                break;
            }
            (u, cu, fu) = (w, cw, fw);
            j += 1;
        }
        out
    }

    /// The tables for `settings` (its wavelength range and black-body samples).
    #[must_use]
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
            cmf_inv_step: 1.0 / cmf_step,
        }
    }
}

/// The trapezoid a delta line at `centre` emits over a segment whose ends see shifts `sa`, `sb`
/// and line areas `area_a`, `area_b`: between the shifted positions (at least `min_width`
/// wide, centred), total area `(area_a + area_b) / 2`, its centroid the swept emission's
/// exactly. When the sweep covers the whole width the heights are `area_a / w` and
/// `area_b / w` at the two shifted ends; a sweep narrower than the box tilts it only by the
/// swept fraction (a still line emits a flat box, whatever its end densities), so the result
/// is continuous in the velocity.
pub(crate) fn line_trapezoid(
    centre: f64,
    sa: f64,
    sb: f64,
    area_a: f64,
    area_b: f64,
    min_width: f64,
) -> (f64, f64, f64, f64) {
    Sweep::of(centre, sa, sb, min_width).trapezoid(area_a, area_b)
}

/// A line's swept box ([`line_trapezoid`]) before its areas: shared by a line's emission and
/// absorption.
#[derive(Clone, Copy)]
struct Sweep {
    lo: f64,
    hi: f64,
    w: f64,
    sweep: f64,
    rising: bool,
}

impl Sweep {
    #[inline]
    fn of(centre: f64, sa: f64, sb: f64, min_width: f64) -> Self {
        let (la, lb) = (sa * centre, sb * centre);
        let sweep = (lb - la).abs();
        let w = sweep.max(min_width);
        let m = 0.5 * (la + lb);
        Self {
            lo: m - 0.5 * w,
            hi: m + 0.5 * w,
            w,
            sweep,
            rising: la <= lb,
        }
    }

    #[inline]
    fn trapezoid(self, area_a: f64, area_b: f64) -> (f64, f64, f64, f64) {
        let w = self.w;
        let mean = 0.5 * (area_a + area_b) / w;
        let tilt = 0.5 * (area_b - area_a) / w * (self.sweep / w);
        let (h_a, h_b) = ((mean - tilt).max(0.0), (mean + tilt).max(0.0));
        if self.rising {
            (self.lo, self.hi, h_a, h_b)
        } else {
            (self.lo, self.hi, h_b, h_a)
        }
    }
}

/// The cell of a uniform grid (`origin + i step`) holding `u` and the cell's right end:
/// `origin + i step <= u < origin + (i + 1) step`, exactly on the grid's own nodes (the
/// index from `(u - origin) / step` alone can be one off when `u` is a node computed by
/// rounding). `u >= origin`.
#[inline]
pub(crate) fn cell_of(origin: f64, step: f64, inv_step: f64, u: f64) -> (usize, f64) {
    // One correction each way suffices: the quotient is off by at most one cell.
    // `floor` without a libm call (the default target has no SSE4.1 rounding): for q > 0
    // truncation is the floor, and every q <= 0 (or NaN) clamps to cell 0 either way.
    let q = (u - origin) * inv_step;
    let mut k = if q > 0.0 { (q as u64) as f64 } else { 0.0 };
    let mut next = origin + (k + 1.0) * step;
    if next <= u {
        k += 1.0;
        next = origin + (k + 1.0) * step;
    } else if k > 0.0 && origin + k * step > u {
        k -= 1.0;
        next = origin + (k + 1.0) * step;
    }
    (k as usize, next)
}

pub(crate) fn spectrum_err(e: blueshift_spectrum::Error) -> Error {
    Error::parameter(format!("spectrum: {e}"))
}

pub(crate) fn bb_row(
    ctx: &Context<'_>,
    t: &PwlTables,
    s: &RaySamples,
    j: usize,
    out: &mut [f64],
) -> Result<bool> {
    let (rho, temp) = (s.bb[j], s.bb_temp[j]);
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
    let st = ctx.settings;
    let cmf = Cmf::cie1931_2deg();
    let n = s.len();
    let absorbing = ctx.absorbing;
    if absorbing && want == Want::Xyz {
        return super::front::front_to_back(ctx, t, s);
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
                xyz += Xyz::from_array(t.line_xyz((lo, hi, h0, h1)));
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
                    .merged(st.merge_tolerance * spec.max_value() / segments)
                    .map_err(spectrum_err)?;
            }
            // Budget fallback: coarser merges until the spectrum fits, from 4x this segment's
            // share of the tolerance up, for this segment only. (It once started at the
            // whole ray's tolerance and kept its scale for the rest of the ray, each segment
            // raising it 4x again: the error compounded, and the continuum beside strong,
            // broadened lines came out many times too bright.) At most 40 tries, the scale
            // capped so it never overflows.
            let mut tol_scale = 1.0f64;
            let mut guard = 0;
            while spec.piece_count() > st.piece_budget && guard < 40 {
                tol_scale = (tol_scale * 4.0).min(1e30);
                let tol = (st.merge_tolerance.max(1e-6) * tol_scale * spec.max_value() / segments)
                    .min(f64::MAX);
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
pub(crate) fn segment_lines(
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
    let factor = if emission { f.emission } else { f.absorption };
    fn lines_of(sp: &crate::Species, emission: bool) -> &[blueshift_spectrum::EmissionLine] {
        if emission {
            &sp.emission_lines
        } else {
            &sp.absorption_lines
        }
    }
    let list = |sp| lines_of(sp, emission);
    // Without broadening: every species' lines in rest-wavelength order, so the trapezoids
    // come out sorted by middle and by start (one shift for all species).
    let order = if emission {
        &ctx.emission_order
    } else {
        &ctx.absorption_order
    };
    if !ctx.profiles.active
        && nsp <= 16
        && order.len() == scene.species.iter().map(|sp| list(sp).len()).sum::<usize>()
    {
        let mut rho = [(0.0f64, 0.0f64); 16];
        for (m, r) in rho.iter_mut().enumerate().take(nsp) {
            *r = (s.rho[j * nsp + m], s.rho[(j + 1) * nsp + m]);
        }
        for &(m, i) in order {
            let (m, i) = (m as usize, i as usize);
            let Some(&(ra, rb)) = rho.get(m).filter(|_| m < nsp) else {
                continue;
            };
            if ra <= 0.0 && rb <= 0.0 {
                continue;
            }
            let Some(l) = list(&scene.species[m]).get(i) else {
                continue;
            };
            let base = scale * dt * l.strength * factor;
            let (a0, a1) = (base * ra * ga, base * rb * gb);
            let (lo, hi, h0, h1) = line_trapezoid(l.centre_nm, sa, sb, a0, a1, st.line_width_nm);
            push(lo, hi, h0, h1)?;
        }
        return Ok(());
    }
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

/// [`segment_lines`] for both kinds at once, `scale` 1: the segment's absorption into `abs`
/// and its emission into `emit`, the same trapezoids as two calls give. Where every species
/// emits and absorbs at the same lines (in the same order, without broadening) each line's
/// swept box is computed once for both.
pub(crate) fn segment_lines_both(
    ctx: &Context<'_>,
    s: &RaySamples,
    j: usize,
    abs: &mut Vec<(f64, f64, f64, f64)>,
    emit: &mut Vec<(f64, f64, f64, f64)>,
) -> Result<()> {
    let scene = ctx.scene;
    let nsp = scene.species.len();
    if !ctx.paired_lines || ctx.profiles.active || nsp > 16 {
        segment_lines(ctx, s, j, false, 1.0, abs)?;
        return segment_lines(ctx, s, j, true, 1.0, emit);
    }
    let st = ctx.settings;
    let f = scene.factors;
    let (range_lo, range_hi) = st.range_nm;
    let dt = f64::from(s.t[j] - s.t[j + 1]).abs();
    let (sa, sb) = (s.shift[j], s.shift[j + 1]);
    let (ga, gb) = (ctx.value_factor(sa) * sa, ctx.value_factor(sb) * sb);
    abs.clear();
    emit.clear();
    let mut rho = [(0.0f64, 0.0f64); 16];
    for (m, r) in rho.iter_mut().enumerate().take(nsp) {
        *r = (s.rho[j * nsp + m], s.rho[(j + 1) * nsp + m]);
    }
    let keep = |(lo, hi, h0, h1): (f64, f64, f64, f64)| {
        !(hi < range_lo || lo > range_hi || (h0 <= 0.0 && h1 <= 0.0))
    };
    for &(m, i) in &ctx.emission_order {
        let (m, i) = (m as usize, i as usize);
        let Some(&(ra, rb)) = rho.get(m).filter(|_| m < nsp) else {
            continue;
        };
        if ra <= 0.0 && rb <= 0.0 {
            continue;
        }
        let sp = &scene.species[m];
        let (Some(le), Some(la)) = (sp.emission_lines.get(i), sp.absorption_lines.get(i)) else {
            continue;
        };
        let sweep = Sweep::of(le.centre_nm, sa, sb, st.line_width_nm);
        let base = dt * la.strength * f.absorption;
        let t = sweep.trapezoid(base * ra, base * rb);
        if keep(t) {
            abs.push(t);
        }
        let base = dt * le.strength * f.emission;
        let t = sweep.trapezoid(base * ra * ga, base * rb * gb);
        if keep(t) {
            emit.push(t);
        }
    }
    Ok(())
}
