//! The integrators: Woodcock (delta) tracking, multi-density Woodcock tracking with N DDA
//! traversals (MDWT Listing 3) or one synchronised traversal (Listing 4), ratio-tracked
//! shadow rays, and the emission-absorption ray marcher (HDR VolVis section 3).
//!
//! # The model all methods estimate
//! Each blend defines, per channel n and point x, an effective extinction `s_n(x)` and
//! emitted colour `c_n(x)` from the channels' extinctions `sigma_n = opacity_n x density
//! scale` and transfer-function colours `f_n` (MDWT section 4.2):
//! - [`Blend::Density`] (Eq. 6-7): `s_n = sigma_n`, `c_n = f_n`.
//! - [`Blend::Max`] (Eq. 8-9): only the channel with the largest extinction counts
//!   (first one on ties): `s_n = sigma_n` there, 0 elsewhere; `c_n = f_n`. (The paper
//!   compares the raw fields theta_n; channels with different units are compared here after
//!   their transfer functions, which is what the user sees.)
//! - [`Blend::Mix`] (Eq. 10): `s_n` as for max; `c_n = sum_m f_m sigma_m w_m / max_m sigma_m`.
//! - [`Blend::Composite`]: each channel rendered alone (density model), images summed with
//!   weights (post-render compositing; no depth order between channels).
//!
//! The pixel value is `L = int_0^d T(t) sum_n s_n c_n dt + T(d) background` with
//! `T(t) = exp(-int_0^t sum_n s_n)`: the collision estimator (return `c_n` of the channel
//! whose real collision is first, or the background) is unbiased for it, and the ray marcher
//! is a quadrature of the same integral. Alpha is `1 - T(d)`.

use std::ops::ControlFlow;

use glam::Vec3;
use half::f16;

use crate::camera::Ray;
use crate::dda::{Dda, DdaMajorantIterator};
use crate::majorant::MajorantGrid;
use crate::rng::Rng;
use crate::scene::Scene;
use crate::{Error, Result};

/// How N channels are blended (MDWT section 4.2).
#[derive(Clone, Debug, PartialEq)]
pub enum Blend {
    /// Physically based density blending (Eq. 6-7).
    Density,
    /// Max opacity (Eq. 8-9).
    Max,
    /// Mix with user weights (Eq. 10); weights are normalised to sum 1.
    Mix {
        /// One weight per channel, non-negative, not all zero.
        weights: Vec<f32>,
    },
    /// Post-render compositing: channels rendered separately, summed with normalised weights.
    Composite {
        /// One weight per channel, non-negative, not all zero.
        weights: Vec<f32>,
    },
}

/// Which traversal multi-density Woodcock tracking uses.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DdaMode {
    /// One DDA traversal per channel, keep the closest collision (MDWT Listing 3).
    NDda,
    /// One synchronised traversal, all channels stepped per cell (MDWT Listing 4).
    OneDda,
}

/// Compositing precision of the ray marcher: the accumulated colour and alpha are rounded
/// to this precision after every step, as 8-bit or half-float blending hardware would.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Precision {
    /// 32-bit float (no rounding beyond f32 arithmetic).
    F32,
    /// IEEE half float.
    F16,
    /// 8-bit unsigned normalised (values clamped to [0, 1], rounded to multiples of 1/255).
    U8,
}

/// Most steps the marcher may take across the volume's diagonal.
pub const MAX_MARCH_STEPS: f32 = 1e6;

/// The emission-absorption ray marcher's settings.
#[derive(Clone, Debug, PartialEq)]
pub struct RayMarcher {
    /// Step length in world units; `None` = half the smallest voxel spacing (Nyquist).
    pub step: Option<f32>,
    /// Compositing precision.
    pub precision: Precision,
    /// Blend of the channels (same model as the trackers).
    pub blend: Blend,
    /// Stop when the accumulated alpha reaches this (early ray termination); 1 disables it.
    pub early_termination: f32,
}

impl Default for RayMarcher {
    fn default() -> Self {
        RayMarcher {
            step: None,
            precision: Precision::F32,
            blend: Blend::Density,
            early_termination: 0.999,
        }
    }
}

/// An integrator: what one pixel sample does.
#[derive(Clone, Debug, PartialEq)]
pub enum Integrator {
    /// Woodcock tracking of one channel (its index).
    Woodcock {
        /// Channel index.
        channel: usize,
    },
    /// Multi-density Woodcock tracking over all channels.
    Mdwt {
        /// N traversals or one.
        dda: DdaMode,
        /// Blend mode.
        blend: Blend,
    },
    /// Emission-absorption ray marcher.
    Marcher(RayMarcher),
}

fn normalised(weights: &[f32], n: usize, what: &str) -> Result<Vec<f32>> {
    if weights.len() != n {
        return Err(Error::parameter(format!(
            "{what}: {} weights for {n} channels",
            weights.len()
        )));
    }
    let sum: f32 = weights.iter().sum();
    if weights.iter().any(|w| !(*w >= 0.0 && w.is_finite())) || sum.is_nan() || sum <= 0.0 {
        return Err(Error::parameter(format!(
            "{what}: weights must be finite, non-negative and not all zero"
        )));
    }
    Ok(weights.iter().map(|w| w / sum).collect())
}

impl Blend {
    /// Equal weights for `n` channels.
    #[must_use]
    pub fn equal_weights(n: usize) -> Vec<f32> {
        vec![1.0 / n.max(1) as f32; n]
    }

    pub(crate) fn prepared(&self, n: usize) -> Result<Blend> {
        Ok(match self {
            Blend::Density => Blend::Density,
            Blend::Max => Blend::Max,
            Blend::Mix { weights } => Blend::Mix {
                weights: normalised(weights, n, "mix")?,
            },
            Blend::Composite { weights } => Blend::Composite {
                weights: normalised(weights, n, "composite")?,
            },
        })
    }
}

impl Integrator {
    /// Checks the integrator against a scene and normalises blend weights.
    pub fn prepared(&self, scene: &Scene) -> Result<Integrator> {
        let n = scene.channel_count();
        Ok(match self {
            Integrator::Woodcock { channel } => {
                if *channel >= n {
                    return Err(Error::parameter(format!(
                        "woodcock: channel {channel} out of range (scene has {n})"
                    )));
                }
                self.clone()
            }
            Integrator::Mdwt { dda, blend } => Integrator::Mdwt {
                dda: *dda,
                blend: blend.prepared(n)?,
            },
            Integrator::Marcher(m) => {
                if let Some(s) = m.step
                    && !(s > 0.0 && s.is_finite())
                {
                    return Err(Error::parameter(format!(
                        "marcher: step {s} must be positive and finite"
                    )));
                }
                if !(m.early_termination > 0.0 && m.early_termination <= 1.0) {
                    return Err(Error::parameter(
                        "marcher: early termination alpha must be in (0, 1]",
                    ));
                }
                let step = m
                    .step
                    .unwrap_or(0.5 * scene.geometry().spacing.min_element());
                let (lo, hi) = scene.bounds();
                let steps = (hi - lo).length() / step;
                if steps > MAX_MARCH_STEPS {
                    return Err(Error::parameter(format!(
                        "marcher: step {step} needs {steps:.0} steps across the volume (at most {MAX_MARCH_STEPS})"
                    )));
                }
                if scene.light.is_some() {
                    return Err(Error::parameter(
                        "marcher: shadows (a light) are supported by the tracking methods only",
                    ));
                }
                Integrator::Marcher(RayMarcher {
                    blend: m.blend.prepared(n)?,
                    ..m.clone()
                })
            }
        })
    }

    /// Estimates the radiance (RGB) and alpha along `ray` with random numbers from `rng`.
    /// Call [`Integrator::prepared`] once first (it checks the channel index and normalises
    /// weights); without it, a channel index out of range gives the background and missing
    /// weights count as 0.
    #[must_use]
    pub fn li(&self, scene: &Scene, ray: &Ray, rng: &mut Rng) -> [f32; 4] {
        match self {
            Integrator::Woodcock { channel } if *channel >= scene.channel_count() => {
                background(scene)
            }
            Integrator::Woodcock { channel } => woodcock(scene, *channel, ray, rng),
            Integrator::Mdwt { dda, blend } => match blend {
                Blend::Composite { weights } => composite(
                    scene.channel_count(),
                    weights,
                    |n, rng| woodcock(scene, n, ray, rng),
                    rng,
                ),
                _ => mdwt(scene, *dda, blend, ray, rng),
            },
            Integrator::Marcher(m) => match &m.blend {
                Blend::Composite { weights } => composite(
                    scene.channel_count(),
                    weights,
                    |n, rng| {
                        let b = Blend::Density;
                        march(scene, m, &b, Some(n), ray, rng)
                    },
                    rng,
                ),
                b => march(scene, m, b, None, ray, rng),
            },
        }
    }
}

fn composite(
    n_channels: usize,
    weights: &[f32],
    mut f: impl FnMut(usize, &mut Rng) -> [f32; 4],
    rng: &mut Rng,
) -> [f32; 4] {
    let mut acc = [0.0f32; 4];
    for (n, &w) in weights.iter().enumerate().take(n_channels) {
        let v = f(n, rng);
        for i in 0..4 {
            acc[i] += w * v[i];
        }
    }
    acc
}

/// `t + step`, but at least the next float after `t`: far from the origin a tiny step would
/// otherwise not move `t` and a run of null collisions would never end.
#[inline]
fn advance(t: f32, step: f32) -> f32 {
    let next = t + step;
    if next > t { next } else { t.next_up() }
}

/// A tentative collision handed to the [`sample_t_maj`] callback.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TentativeCollision {
    /// Ray parameter (world length).
    pub t: f32,
    /// World position.
    pub p: Vec3,
    /// Majorant extinction where the collision was sampled.
    pub sigma_maj: f32,
}

/// Samples tentative collisions along `ray` up to `t_max` against the majorant `grid` with
/// exponential steps (delta tracking), handing each to `callback` with the random stream;
/// `ControlFlow::Break` stops the walk (CONVENTIONS C6, pbrt's `SampleT_maj`). Returns
/// `Break` if the callback stopped it, `Continue` if the ray left the volume or passed
/// `t_max`. Cells with a zero majorant are skipped without drawing random numbers.
pub fn sample_t_maj(
    grid: &MajorantGrid,
    ray: &Ray,
    t_max: f32,
    rng: &mut Rng,
    mut callback: impl FnMut(&mut Rng, TentativeCollision) -> ControlFlow<()>,
) -> ControlFlow<()> {
    for seg in DdaMajorantIterator::new(grid, ray, t_max) {
        if seg.sigma_maj <= 0.0 {
            continue;
        }
        let mut t = seg.t_min;
        loop {
            t = advance(t, rng.exponential(seg.sigma_maj));
            if t >= seg.t_max {
                break;
            }
            callback(
                rng,
                TentativeCollision {
                    t,
                    p: ray.at(t),
                    sigma_maj: seg.sigma_maj,
                },
            )?;
        }
    }
    ControlFlow::Continue(())
}

/// Effective extinction and colour of channel `n` at `p` under `blend` (see module docs).
#[inline]
fn blended(scene: &Scene, blend: &Blend, n: usize, p: Vec3) -> (f32, [f32; 3]) {
    match blend {
        Blend::Density | Blend::Composite { .. } => scene.sample(n, p),
        Blend::Max | Blend::Mix { .. } => {
            let mut best = 0usize;
            let mut best_s = f32::NEG_INFINITY;
            let mut mix = [0.0f32; 3];
            let mut own = [0.0f32; 3];
            for m in 0..scene.channel_count() {
                let (s, c) = scene.sample(m, p);
                if s > best_s {
                    best_s = s;
                    best = m;
                }
                if m == n {
                    own = c;
                }
                if let Blend::Mix { weights } = blend {
                    for i in 0..3 {
                        mix[i] += c[i] * s * weights.get(m).copied().unwrap_or(0.0);
                    }
                }
            }
            if best != n || best_s.is_nan() || best_s <= 0.0 {
                return (0.0, own);
            }
            match blend {
                Blend::Mix { .. } => (best_s, mix.map(|v| v / best_s)),
                _ => (best_s, own),
            }
        }
    }
}

/// Sum of the effective extinctions over channels (the blend's total extinction).
fn total_sigma(scene: &Scene, blend: &Blend, p: Vec3) -> f32 {
    match blend {
        Blend::Max | Blend::Mix { .. } => (0..scene.channel_count())
            .map(|m| scene.sample(m, p).0)
            .fold(0.0, f32::max),
        _ => (0..scene.channel_count())
            .map(|m| scene.sample(m, p).0)
            .sum(),
    }
}

/// Ratio-tracking estimate of the transmittance from `p` towards the light through the
/// total extinction `sigma` bounded by `grid`.
fn shadow_transmittance(
    grid: &MajorantGrid,
    p: Vec3,
    dir: Vec3,
    rng: &mut Rng,
    sigma: impl Fn(Vec3) -> f32,
) -> f32 {
    let Some(ray) = Ray::new(p, dir) else {
        return 1.0;
    };
    let mut tr = 1.0f32;
    let _ = sample_t_maj(grid, &ray, f32::INFINITY, rng, |_, ev| {
        tr *= (1.0 - sigma(ev.p) / ev.sigma_maj).max(0.0);
        if tr <= 0.0 {
            ControlFlow::Break(())
        } else {
            ControlFlow::Continue(())
        }
    });
    tr
}

/// The radiance returned at a real collision: the emitted colour, lit by the light if any.
fn shade(
    scene: &Scene,
    colour: [f32; 3],
    p: Vec3,
    rng: &mut Rng,
    grid: &MajorantGrid,
    sigma: impl Fn(Vec3) -> f32,
) -> [f32; 3] {
    match &scene.light {
        None => colour,
        Some(light) => {
            let t = shadow_transmittance(grid, p, light.direction, rng, sigma);
            [0, 1, 2].map(|i| colour[i] * (light.ambient + light.radiance[i] * t))
        }
    }
}

fn background(scene: &Scene) -> [f32; 4] {
    let [r, g, b] = scene.background;
    [r, g, b, 0.0]
}

/// Woodcock tracking of channel `n` alone (MDWT Listings 1-2).
fn woodcock(scene: &Scene, n: usize, ray: &Ray, rng: &mut Rng) -> [f32; 4] {
    let grid = scene.channels()[n].majorant();
    let mut hit: Option<(Vec3, [f32; 3])> = None;
    let _ = sample_t_maj(grid, ray, f32::INFINITY, rng, |rng, ev| {
        let (s, c) = scene.sample(n, ev.p);
        if rng.uniform() * ev.sigma_maj < s {
            hit = Some((ev.p, c));
            ControlFlow::Break(())
        } else {
            ControlFlow::Continue(())
        }
    });
    match hit {
        None => background(scene),
        Some((p, c)) => {
            let [r, g, b] = shade(scene, c, p, rng, grid, |q| scene.sample(n, q).0);
            [r, g, b, 1.0]
        }
    }
}

/// Multi-density Woodcock tracking (MDWT Listings 3 and 4) for the density, max and mix
/// blends.
fn mdwt(scene: &Scene, dda: DdaMode, blend: &Blend, ray: &Ray, rng: &mut Rng) -> [f32; 4] {
    let mut hit_t = f32::INFINITY;
    let mut hit_c = [0.0f32; 3];
    match dda {
        DdaMode::NDda => {
            for n in 0..scene.channel_count() {
                let grid = scene.channels()[n].majorant();
                let _ = sample_t_maj(grid, ray, hit_t, rng, |rng, ev| {
                    let (s, c) = blended(scene, blend, n, ev.p);
                    if rng.uniform() * ev.sigma_maj < s {
                        hit_t = ev.t;
                        hit_c = c;
                        ControlFlow::Break(())
                    } else {
                        ControlFlow::Continue(())
                    }
                });
            }
        }
        DdaMode::OneDda => {
            let total = scene.total_majorant().values();
            for cell in Dda::new(scene.layout(), ray, f32::INFINITY) {
                // Empty for every channel: skip the cell without touching N majorants.
                if total[cell.cell] <= 0.0 {
                    continue;
                }
                for (n, ch) in scene.channels().iter().enumerate() {
                    let maj = ch.majorant().values()[cell.cell];
                    if maj <= 0.0 {
                        continue;
                    }
                    let mut t = cell.t_min;
                    loop {
                        t = advance(t, rng.exponential(maj));
                        if t > hit_t || t >= cell.t_max {
                            break;
                        }
                        let (s, c) = blended(scene, blend, n, ray.at(t));
                        if rng.uniform() * maj < s {
                            hit_t = t;
                            hit_c = c;
                            break;
                        }
                    }
                }
                if hit_t.is_finite() {
                    break;
                }
            }
        }
    }
    if !hit_t.is_finite() {
        return background(scene);
    }
    let p = ray.at(hit_t);
    let [r, g, b] = shade(scene, hit_c, p, rng, scene.total_majorant(), |q| {
        total_sigma(scene, blend, q)
    });
    [r, g, b, 1.0]
}

#[inline]
fn quantise(v: f32, precision: Precision) -> f32 {
    match precision {
        Precision::F32 => v,
        Precision::F16 => f16::from_f32(v).to_f32(),
        Precision::U8 => (v.clamp(0.0, 1.0) * 255.0).round() / 255.0,
    }
}

/// Total effective extinction and emission `sum_n s_n c_n` over `channels` at `p`, with
/// each channel sampled once (max and mix need all channels at once).
fn point_emission(scene: &Scene, blend: &Blend, channels: &[usize], p: Vec3) -> (f32, [f32; 3]) {
    match blend {
        Blend::Max | Blend::Mix { .. } if channels.len() > 1 => {
            let mut best_s = 0.0f32;
            let mut best_c = [0.0f32; 3];
            let mut mix = [0.0f32; 3];
            for &m in channels {
                let (s, c) = scene.sample(m, p);
                if s > best_s {
                    best_s = s;
                    best_c = c;
                }
                if let Blend::Mix { weights } = blend {
                    for i in 0..3 {
                        mix[i] += c[i] * s * weights.get(m).copied().unwrap_or(0.0);
                    }
                }
            }
            // Emission s c with s = max sigma: max keeps the winner's colour; mix's colour is
            // sum f sigma w / max sigma, so s c = sum f sigma w.
            match blend {
                Blend::Mix { .. } => (best_s, mix),
                _ => (best_s, best_c.map(|v| v * best_s)),
            }
        }
        _ => {
            let mut sigma = 0.0f32;
            let mut emit = [0.0f32; 3];
            for &n in channels {
                let (s, col) = blended(scene, blend, n, p);
                sigma += s;
                for k in 0..3 {
                    emit[k] += s * col[k];
                }
            }
            (sigma, emit)
        }
    }
}

/// Front-to-back emission-absorption marching; `only` restricts to one channel (composite).
fn march(
    scene: &Scene,
    m: &RayMarcher,
    blend: &Blend,
    only: Option<usize>,
    ray: &Ray,
    rng: &mut Rng,
) -> [f32; 4] {
    let (lo, hi) = scene.bounds();
    let sp = scene.geometry().spacing;
    let step = m.step.unwrap_or(0.5 * sp.min_element());
    let jitter = rng.uniform();
    let mut c = [0.0f32; 3];
    let mut a = 0.0f32;
    if let Some((t0, t1)) = ray.clip_box(lo, hi) {
        let n_steps = ((t1 - t0) / step).ceil().max(1.0) as u64;
        let channels: Vec<usize> = match only {
            Some(n) => vec![n],
            None => (0..scene.channel_count()).collect(),
        };
        for i in 0..n_steps {
            let ta = t0 + i as f32 * step;
            let tb = (ta + step).min(t1);
            let len = tb - ta;
            if len <= 0.0 {
                break;
            }
            let p = ray.at(ta + jitter * len);
            let (sigma, emit) = point_emission(scene, blend, &channels, p);
            if sigma <= 0.0 {
                continue;
            }
            // Opacity corrected for the step: alpha = 1 - exp(-sigma * len), the exact
            // absorption of a homogeneous stretch (the classic 1 - (1 - a0)^(len / l0)).
            let alpha = 1.0 - (-sigma * len).exp();
            let w = (1.0 - a) * alpha / sigma;
            for k in 0..3 {
                c[k] = quantise(c[k] + w * emit[k], m.precision);
            }
            a = quantise(a + (1.0 - a) * alpha, m.precision);
            if a >= m.early_termination {
                break;
            }
        }
    }
    let bg = scene.background;
    [
        c[0] + (1.0 - a) * bg[0],
        c[1] + (1.0 - a) * bg[1],
        c[2] + (1.0 - a) * bg[2],
        a,
    ]
}
