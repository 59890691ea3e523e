//! The banded integrator (Algorithm 1) with the nearest-band or energy-conserving shift.

use blueshift_spectrum::{BandLayout, BandWeights, Banded, Blackbody, Piece};

use super::DopplerScene;
use super::render::{BandShift, Context, RayOut, RaySamples, TraceStep, Want};
use crate::{Error, Result};

/// The banded integrator's tables (part of [`crate::Prepared`]): the band layout, each
/// band's CMF weights and centre, the shift rule, and every species' rest-frame emission and
/// absorption per unit density (its lines' boxes deposited into the bands as band means).
#[derive(Debug)]
pub struct BandTables {
    layout: BandLayout,
    weights: BandWeights,
    centres: Vec<f64>,
    shift: BandShift,
    /// Rest-frame emission per species per unit density (sparse band, value).
    rest_emission: Vec<Vec<(usize, f64)>>,
    /// Rest-frame absorption per species per unit density.
    rest_absorption: Vec<Vec<(usize, f64)>>,
}

/// Adds a box of `area` over `[lo, hi)` to the bands as band means.
fn deposit(layout: &BandLayout, lo: f64, hi: f64, area: f64, mut add: impl FnMut(usize, f64)) {
    let (a, b) = layout.range_nm();
    let bw = layout.width_nm();
    let (l, h) = (lo.max(a), hi.min(b));
    if h <= l || hi <= lo {
        return;
    }
    let height = area / (hi - lo);
    let n = layout.bands();
    let first = (((l - a) / bw).floor() as usize).min(n - 1);
    for i in first..n {
        let s = a + i as f64 * bw;
        if s >= h {
            break;
        }
        let ov = h.min(s + bw) - l.max(s);
        if ov > 0.0 {
            add(i, height * ov / bw);
        }
    }
}

impl BandTables {
    /// The tables of `bands` bands over `settings.range_nm` with shift rule `shift`.
    ///
    /// # Errors
    /// A band layout the spectrum crate refuses.
    pub fn new(
        scene: &DopplerScene,
        settings: &super::DopplerSettings,
        bands: usize,
        shift: BandShift,
    ) -> Result<Self> {
        let (a, b) = settings.range_nm;
        let layout = BandLayout::new(a, b, bands).map_err(|e| Error::parameter(e.to_string()))?;
        let w = settings.line_width_nm;
        let rest = |lines: &[blueshift_spectrum::EmissionLine], factor: f64| {
            let mut v = vec![0.0; bands];
            for l in lines {
                deposit(
                    &layout,
                    l.centre_nm - 0.5 * w,
                    l.centre_nm + 0.5 * w,
                    l.strength * factor,
                    |i, x| v[i] += x,
                );
            }
            v.into_iter()
                .enumerate()
                .filter(|(_, x)| *x > 0.0)
                .collect::<Vec<_>>()
        };
        let f = scene.factors;
        Ok(Self {
            layout,
            weights: BandWeights::new(layout, blueshift_spectrum::Cmf::cie1931_2deg()),
            centres: (0..bands).map(|i| layout.band_centre_nm(i)).collect(),
            shift,
            rest_emission: scene
                .species
                .iter()
                .map(|s| rest(&s.emission_lines, f.emission))
                .collect(),
            rest_absorption: scene
                .species
                .iter()
                .map(|s| rest(&s.absorption_lines, f.absorption))
                .collect(),
        })
    }
}

impl BandTables {
    /// The band layout.
    #[must_use]
    pub fn layout(&self) -> BandLayout {
        self.layout
    }
    /// The per-band CMF integrals (XYZ of a unit band value).
    #[must_use]
    pub fn weights(&self) -> &BandWeights {
        &self.weights
    }
    /// Band centres, nm.
    #[must_use]
    pub fn centres(&self) -> &[f64] {
        &self.centres
    }
    /// The shift rule.
    #[must_use]
    pub fn shift(&self) -> BandShift {
        self.shift
    }
    /// Rest-frame emission of species `m` per unit density: sparse `(band, value)`.
    #[must_use]
    pub fn rest_emission(&self, m: usize) -> &[(usize, f64)] {
        &self.rest_emission[m]
    }
    /// Rest-frame absorption of species `m` per unit density: sparse `(band, value)`.
    #[must_use]
    pub fn rest_absorption(&self, m: usize) -> &[(usize, f64)] {
        &self.rest_absorption[m]
    }
}

/// Calls `add(band, depth)` for every band that sample `j` absorbs in over the path length
/// `len`, with that band's optical depth there.
fn for_each_depth(
    t: &BandTables,
    scene: &DopplerScene,
    s: &RaySamples,
    j: usize,
    len: f64,
    w: f64,
    mut add: impl FnMut(usize, f64),
) {
    let f = scene.factors;
    let nsp = scene.species.len();
    let sh = s.shift[j];
    for (m, sp) in scene.species.iter().enumerate() {
        let rho = s.rho[j * nsp + m];
        if rho <= 0.0 {
            continue;
        }
        match t.shift {
            BandShift::Nearest => {
                for &(i, k) in &t.rest_absorption[m] {
                    if let Some(d) = t.layout.band_of(t.centres[i] * sh) {
                        add(d, len * rho * k);
                    }
                }
            }
            BandShift::EnergyConserving => {
                for l in &sp.absorption_lines {
                    let c = l.centre_nm;
                    deposit(
                        &t.layout,
                        sh * (c - 0.5 * w),
                        sh * (c + 0.5 * w),
                        l.strength * f.absorption,
                        |i, k| add(i, len * rho * k),
                    );
                }
            }
        }
    }
}

/// Attenuates the bands by the optical depth of sample `j` over the path length `len`.
fn absorb_half(
    t: &BandTables,
    scene: &DopplerScene,
    s: &RaySamples,
    j: usize,
    len: f64,
    w: f64,
    v: &mut [f64],
) {
    for_each_depth(t, scene, s, j, len, w, |d, x| v[d] *= (-x).exp());
}

/// The trapezoid-rule weight of sample `j` along the ray.
fn weight(s: &RaySamples, j: usize) -> f64 {
    let n = s.len();
    let d_prev = if j > 0 {
        f64::from(s.t[j - 1] - s.t[j]).abs()
    } else {
        0.0
    };
    let d_next = if j + 1 < n {
        f64::from(s.t[j] - s.t[j + 1]).abs()
    } else {
        0.0
    };
    0.5 * (d_prev + d_next)
}

/// The optical depth of the samples per band (what [`integrate`] attenuates by), as
/// constant pieces over the bands that absorb (for distributed compositing: these sum
/// exactly over pieces of the ray, see [`crate::part`]).
pub(crate) fn total_depth(ctx: &Context<'_>, t: &BandTables, s: &RaySamples) -> Vec<Piece> {
    let mut d = vec![0.0; t.layout.bands()];
    if ctx.scene.factors.absorption > 0.0 {
        for j in 0..s.len() {
            let wt = weight(s, j);
            let w = ctx.settings.line_width_nm;
            for_each_depth(t, ctx.scene, s, j, wt, w, |i, x| d[i] += x);
        }
    }
    let bw = t.layout.width_nm();
    d.iter()
        .enumerate()
        .filter(|(_, x)| **x > 0.0)
        .map(|(i, &x)| {
            let start = t.layout.band_start_nm(i);
            Piece {
                start_nm: start,
                end_nm: start + bw,
                value_start: x,
                value_end: x,
            }
        })
        .collect()
}

/// [`integrate`]'s XYZ of the samples' light after it crosses `front`, an optical depth per
/// band ([`total_depth`] of what lies in front, summed): each band's value is multiplied by
/// `exp(-depth)` at the band's centre.
pub(crate) fn integrate_behind(
    ctx: &Context<'_>,
    t: &BandTables,
    s: &RaySamples,
    front: &[Piece],
) -> Result<RayOut> {
    let mut out = RayOut::default();
    let mut v = bands(ctx, t, s, Want::Xyz, &mut out)?;
    for p in front {
        let first = t.layout.band_of(p.start_nm).unwrap_or(0).saturating_sub(1);
        for (i, x) in v.iter_mut().enumerate().skip(first) {
            let c = t.centres[i];
            if c >= p.end_nm {
                break;
            }
            if c >= p.start_nm {
                *x *= (-p.at(c)).exp();
            }
        }
    }
    let b = Banded::from_values(t.layout, v).map_err(|e| Error::parameter(e.to_string()))?;
    out.xyz = t
        .weights
        .xyz(&b)
        .map_err(|e| Error::parameter(e.to_string()))?;
    Ok(out)
}

pub(crate) fn integrate(
    ctx: &Context<'_>,
    t: &BandTables,
    s: &RaySamples,
    want: Want,
) -> Result<RayOut> {
    let mut out = RayOut::default();
    let v = bands(ctx, t, s, want, &mut out)?;
    let b = Banded::from_values(t.layout, v).map_err(|e| Error::parameter(e.to_string()))?;
    out.xyz = t
        .weights
        .xyz(&b)
        .map_err(|e| Error::parameter(e.to_string()))?;
    if want != Want::Xyz {
        out.spectrum = Some(b.to_piecewise());
    }
    Ok(out)
}

/// The band values of the samples' light at the ray's near end (Algorithm 1), with the
/// trace's steps in `out` for [`Want::Trace`].
fn bands(
    ctx: &Context<'_>,
    t: &BandTables,
    s: &RaySamples,
    want: Want,
    out: &mut RayOut,
) -> Result<Vec<f64>> {
    let scene = ctx.scene;
    let f = scene.factors;
    let w = ctx.settings.line_width_nm;
    let nsp = scene.species.len();
    let n = s.len();
    let nb = t.layout.bands();
    let mut v = vec![0.0; nb];
    for j in 0..n {
        let wt = weight(s, j);
        let sh = s.shift[j];
        let g = ctx.value_factor(sh) * sh;
        // Half of the sample's optical depth before its emission and half after (the
        // convention of the piecewise-linear integrator: emitted light crosses half of its
        // own segment).
        if f.absorption > 0.0 {
            absorb_half(t, scene, s, j, 0.5 * wt, w, &mut v);
        }
        for (m, sp) in scene.species.iter().enumerate() {
            let rho = s.rho[j * nsp + m];
            if rho <= 0.0 {
                continue;
            }
            match t.shift {
                BandShift::Nearest => {
                    for &(i, e) in &t.rest_emission[m] {
                        if let Some(d) = t.layout.band_of(t.centres[i] * sh) {
                            v[d] += wt * rho * g * e;
                        }
                    }
                }
                BandShift::EnergyConserving => {
                    for l in &sp.emission_lines {
                        let c = l.centre_nm;
                        deposit(
                            &t.layout,
                            sh * (c - 0.5 * w),
                            sh * (c + 0.5 * w),
                            wt * rho * g * l.strength * f.emission,
                            |i, e| v[i] += e,
                        );
                    }
                }
            }
        }
        let (rho, temp) = (s.bb[j], s.bb_temp[j]);
        if rho > 0.0 && temp > 0.0 {
            let bb = Blackbody::new(temp).map_err(|e| Error::parameter(e.to_string()))?;
            let k = wt * rho * ctx.value_factor(sh);
            for (x, &c) in v.iter_mut().zip(&t.centres) {
                *x += k * bb.eval(c / sh);
            }
        }
        if f.absorption > 0.0 {
            absorb_half(t, scene, s, j, 0.5 * wt, w, &mut v);
        }
        if want == Want::Trace && j > 0 {
            let b = Banded::from_values(t.layout, v.clone())
                .map_err(|e| Error::parameter(e.to_string()))?;
            out.trace.push(TraceStep {
                t: s.t[j],
                radial_velocity_m_per_s: s.v_r[j],
                spectrum: b.to_piecewise(),
            });
        }
    }
    Ok(v)
}
