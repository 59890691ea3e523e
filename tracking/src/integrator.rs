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
//! - [`Blend::Weighted`]: `s_n = w_n sigma_n` (weights normalised to a largest of 1),
//!   `c_n = f_n`.
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

use crate::Ray;
use crate::dda::{Dda, DdaMajorantIterator};
use crate::majorant::MajorantGrid;
use crate::rng::Rng;
use crate::scene::Scene;
use crate::{Error, Result};
use blueshift_camera::named_enum;

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
    /// Weighted density blending: channel n's extinction is `w_n sigma_n` with the weights
    /// normalised to a largest weight of 1 (so every majorant stays valid), colours as
    /// density. [`Blend::majorant_weights`] gives the majorant-weighted choice
    /// `w_n ~ 1 / M_n`, which equalises the channels' peak extinctions.
    Weighted {
        /// One weight per channel, non-negative, not all zero.
        weights: Vec<f32>,
    },
    /// Post-render compositing: channels rendered separately, summed with normalised weights.
    Composite {
        /// One weight per channel, non-negative, not all zero.
        weights: Vec<f32>,
    },
}

/// The name of a [`Blend`], without its weights: `density`, `max`, `mix`, `weighted`,
/// `composite` (the CLI's `--blend` and a scene file's `"blend"`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
pub enum BlendKind {
    /// [`Blend::Density`].
    #[default]
    Density,
    /// [`Blend::Max`].
    Max,
    /// [`Blend::Mix`].
    Mix,
    /// [`Blend::Weighted`].
    Weighted,
    /// [`Blend::Composite`].
    Composite,
}

named_enum!(BlendKind, "blend", [
    Density => "density",
    Max => "max",
    Mix => "mix",
    Weighted => "weighted",
    Composite => "composite",
]);

impl BlendKind {
    /// The blend with these weights (one per channel; density and max ignore them).
    #[must_use]
    pub fn with_weights(self, weights: Vec<f32>) -> Blend {
        match self {
            BlendKind::Density => Blend::Density,
            BlendKind::Max => Blend::Max,
            BlendKind::Mix => Blend::Mix { weights },
            BlendKind::Weighted => Blend::Weighted { weights },
            BlendKind::Composite => Blend::Composite { weights },
        }
    }
}

/// Which traversal multi-density Woodcock tracking uses.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DdaMode {
    /// One DDA traversal per channel, keep the closest collision (MDWT Listing 3).
    NDda,
    /// One synchronised traversal, all channels stepped per cell (MDWT Listing 4).
    OneDda,
    /// One traversal and one free-flight stream against the cell-wise sum of the channels'
    /// majorants, the channel chosen by its share of the extinction at a real collision
    /// (the paper's discarded third method, section 6; Fong et al. 2017's overlapping
    /// volumes).
    Summed,
}

named_enum!(DdaMode, "dda mode", [NDda => "ndda", OneDda => "1dda", Summed => "summed"]);

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

named_enum!(Precision, "precision", [F32 => "f32", F16 => "f16", U8 => "u8"]);

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

/// The name of an [`Integrator`] (the CLI's `--method` and a scene file's `"method"`):
/// `woodcock`, `mdwt-ndda`, `mdwt-1dda` (the default), `mdwt-summed`, `marcher`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
pub enum Method {
    /// [`Integrator::Woodcock`].
    Woodcock,
    /// [`Integrator::Mdwt`] with [`DdaMode::NDda`].
    MdwtNDda,
    /// [`Integrator::Mdwt`] with [`DdaMode::OneDda`].
    #[default]
    MdwtOneDda,
    /// [`Integrator::Mdwt`] with [`DdaMode::Summed`].
    MdwtSummed,
    /// [`Integrator::Marcher`].
    Marcher,
}

named_enum!(Method, "method", [
    Woodcock => "woodcock",
    MdwtNDda => "mdwt-ndda",
    MdwtOneDda => "mdwt-1dda",
    MdwtSummed => "mdwt-summed",
    Marcher => "marcher",
]);

impl Method {
    /// The multi-density method of a traversal.
    #[must_use]
    pub fn mdwt(dda: DdaMode) -> Method {
        match dda {
            DdaMode::NDda => Method::MdwtNDda,
            DdaMode::OneDda => Method::MdwtOneDda,
            DdaMode::Summed => Method::MdwtSummed,
        }
    }

    /// The traversal of a multi-density method (`None` for woodcock and marcher).
    #[must_use]
    pub fn dda(self) -> Option<DdaMode> {
        match self {
            Method::MdwtNDda => Some(DdaMode::NDda),
            Method::MdwtOneDda => Some(DdaMode::OneDda),
            Method::MdwtSummed => Some(DdaMode::Summed),
            Method::Woodcock | Method::Marcher => None,
        }
    }
}

impl Integrator {
    /// Its [`Method`].
    #[must_use]
    pub fn method(&self) -> Method {
        match self {
            Integrator::Woodcock { .. } => Method::Woodcock,
            Integrator::Mdwt { dda, .. } => Method::mdwt(*dda),
            Integrator::Marcher(_) => Method::Marcher,
        }
    }
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
    /// Its name.
    #[must_use]
    pub fn kind(&self) -> BlendKind {
        match self {
            Blend::Density => BlendKind::Density,
            Blend::Max => BlendKind::Max,
            Blend::Mix { .. } => BlendKind::Mix,
            Blend::Weighted { .. } => BlendKind::Weighted,
            Blend::Composite { .. } => BlendKind::Composite,
        }
    }

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
            Blend::Weighted { weights } => {
                let w = normalised(weights, n, "weighted")?;
                let top = w.iter().copied().fold(0.0, f32::max);
                Blend::Weighted {
                    weights: w.iter().map(|v| v / top).collect(),
                }
            }
        })
    }

    /// The majorant weights of `scene`'s channels: `w_n = (1 / M_n) / max_m (1 / M_m)` with
    /// `M_n` channel n's largest majorant (0 for an empty channel), for [`Blend::Weighted`]:
    /// every channel's peak extinction is then the weakest channel's.
    #[must_use]
    pub fn majorant_weights(scene: &Scene) -> Vec<f32> {
        let inv: Vec<f32> = scene
            .channels()
            .iter()
            .map(|ch| {
                let m = ch.majorant().values().iter().copied().fold(0.0, f32::max);
                if m > 0.0 { 1.0 / m } else { 0.0 }
            })
            .collect();
        let top = inv.iter().copied().fold(0.0, f32::max);
        if top > 0.0 {
            inv.iter().map(|v| v / top).collect()
        } else {
            vec![1.0; inv.len()]
        }
    }
}

impl Integrator {
    /// Checks the integrator against a scene and normalises blend weights.
    pub fn prepared(&self, scene: &Scene) -> Result<Integrator> {
        let n = scene.channel_count();
        if let Some(sh) = &scene.shading {
            sh.validate()?;
        }
        if let Some(l) = &scene.light {
            crate::scene::check_light(l)?;
        }
        if scene.clip.is_some() && !matches!(self, Integrator::Marcher(_)) {
            return Err(Error::parameter(
                "a clip box (data-parallel rendering) is supported by the ray marcher only; \
                 the trackers run sample- or tile-parallel",
            ));
        }
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
                // In f64: the squared diagonal of a volume in centimetres overflows f32.
                let steps = (hi - lo).as_dvec3().length() / f64::from(step);
                if steps > f64::from(MAX_MARCH_STEPS) {
                    return Err(Error::parameter(format!(
                        "marcher: step {step} needs {steps:.0} steps across the volume (at most {MAX_MARCH_STEPS})"
                    )));
                }
                if scene.light.is_some() || scene.shading.is_some() {
                    return Err(Error::parameter(
                        "marcher: shadows (a light) and shading are supported by the tracking methods only",
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
        self.li_with_stats(scene, ray, rng, &mut RayStats::default())
    }

    /// [`Integrator::li`], adding the ray's work (cells, tentative collisions, rejections)
    /// to `stats`. The estimate is the same as `li`'s for the same random numbers.
    pub fn li_with_stats(
        &self,
        scene: &Scene,
        ray: &Ray,
        rng: &mut Rng,
        stats: &mut RayStats,
    ) -> [f32; 4] {
        match self {
            Integrator::Woodcock { channel } if *channel >= scene.channel_count() => {
                background(scene)
            }
            Integrator::Woodcock { channel } => woodcock(scene, *channel, ray, rng, stats),
            Integrator::Mdwt { dda, blend } => match blend {
                Blend::Composite { weights } => composite(
                    scene.channel_count(),
                    weights,
                    |n, rng| woodcock(scene, n, ray, rng, stats),
                    rng,
                ),
                _ => mdwt(scene, *dda, blend, ray, rng, stats),
            },
            Integrator::Marcher(m) => match &m.blend {
                Blend::Composite { weights } => composite(
                    scene.channel_count(),
                    weights,
                    |n, rng| {
                        let b = Blend::Density;
                        march(scene, m, &b, Some(n), ray, rng, stats)
                    },
                    rng,
                ),
                b => march(scene, m, b, None, ray, rng, stats),
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

/// Work counters of one ray, for heat maps: DDA cells visited, tentative collisions and
/// null-collision rejections of the primary tracking walk (shadow rays are not counted).
/// The ray marcher counts its samples as `cells` and has no collisions.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RayStats {
    /// DDA cells visited (every cell entered, empty ones included).
    pub cells: u32,
    /// Tentative collisions sampled against the majorant.
    pub tentative: u32,
    /// Tentative collisions rejected as null collisions.
    pub rejections: u32,
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
    callback: impl FnMut(&mut Rng, TentativeCollision) -> ControlFlow<()>,
) -> ControlFlow<()> {
    sample_t_maj_counted(grid, ray, t_max, rng, &mut RayStats::default(), callback)
}

/// [`sample_t_maj`] counting cells and tentative collisions into `stats`.
fn sample_t_maj_counted(
    grid: &MajorantGrid,
    ray: &Ray,
    t_max: f32,
    rng: &mut Rng,
    stats: &mut RayStats,
    mut callback: impl FnMut(&mut Rng, TentativeCollision) -> ControlFlow<()>,
) -> ControlFlow<()> {
    for seg in DdaMajorantIterator::new(grid, ray, t_max) {
        stats.cells += 1;
        if seg.sigma_maj <= 0.0 {
            continue;
        }
        let mut t = seg.t_min;
        loop {
            t = advance(t, rng.exponential(seg.sigma_maj));
            if t >= seg.t_max {
                break;
            }
            stats.tentative += 1;
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

/// The channel with the largest extinction at `p` (first on ties), its extinction, and the
/// colour max (`mix = false`) or mix (`mix = true`, weights `w`) assigns to it.
fn winner(scene: &Scene, weights: Option<&[f32]>, p: Vec3) -> (usize, f32, [f32; 3]) {
    let mut best = 0usize;
    let mut best_s = f32::NEG_INFINITY;
    let mut best_c = [0.0f32; 3];
    let mut mix = [0.0f32; 3];
    for m in 0..scene.channel_count() {
        let (s, c) = scene.sample(m, p);
        if s > best_s {
            best_s = s;
            best = m;
            best_c = c;
        }
        if let Some(w) = weights {
            for i in 0..3 {
                mix[i] += c[i] * s * w.get(m).copied().unwrap_or(0.0);
            }
        }
    }
    if best_s.is_nan() || best_s <= 0.0 {
        return (best, 0.0, best_c);
    }
    match weights {
        Some(_) => (best, best_s, mix.map(|v| v / best_s)),
        None => (best, best_s, best_c),
    }
}

/// Effective extinction and colour of channel `n` at `p` under `blend` (see module docs).
#[inline]
fn blended(scene: &Scene, blend: &Blend, n: usize, p: Vec3) -> (f32, [f32; 3]) {
    match blend {
        Blend::Density | Blend::Composite { .. } => scene.sample(n, p),
        Blend::Weighted { weights } => {
            let (s, c) = scene.sample(n, p);
            (s * weights.get(n).copied().unwrap_or(0.0), c)
        }
        Blend::Max | Blend::Mix { .. } => {
            let w = match blend {
                Blend::Mix { weights } => Some(weights.as_slice()),
                _ => None,
            };
            let (best, s, c) = winner(scene, w, p);
            if best != n || s <= 0.0 {
                (0.0, scene.sample(n, p).1)
            } else {
                (s, c)
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
            .map(|m| blended(scene, blend, m, p).0)
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

/// A real collision: where, with which channel, and the colour it emits.
struct Hit {
    p: Vec3,
    channel: usize,
    colour: [f32; 3],
}

/// The radiance returned at a real collision: the emitted colour, lit by the light if any;
/// with [`Scene::shading`], the Blinn-Phong shading of the collided channel's gradient.
fn shade(
    scene: &Scene,
    hit: &Hit,
    ray: &Ray,
    rng: &mut Rng,
    grid: &MajorantGrid,
    sigma: impl Fn(Vec3) -> f32,
) -> [f32; 3] {
    let colour = hit.colour;
    match (&scene.shading, &scene.light) {
        (None, None) => colour,
        (None, Some(light)) => {
            let t = shadow_transmittance(grid, hit.p, light.direction, rng, sigma);
            [0, 1, 2].map(|i| colour[i] * (light.ambient + light.radiance[i] * t))
        }
        (Some(sh), light) => {
            let view = -ray.dir;
            let (dir, radiance, ambient, shadows) = match light {
                Some(l) => (
                    l.direction.try_normalize().unwrap_or(view),
                    l.radiance,
                    l.ambient,
                    sh.shadows,
                ),
                None => (view, [1.0; 3], HEADLIGHT_AMBIENT, false),
            };
            let m = sh.material(hit.channel);
            let normal = crate::shading::normal_direction(scene, hit.channel, hit.p);
            let (amb, direct) = crate::shading::blinn_phong(&m, colour, normal, dir, view);
            let lit = direct.iter().any(|v| *v > 0.0);
            let t = if shadows && lit {
                shadow_transmittance(grid, hit.p, dir, rng, sigma)
            } else {
                1.0
            };
            [0, 1, 2].map(|i| ambient * amb[i] + t * radiance[i] * direct[i])
        }
    }
}

/// Ambient light of the headlight used by shading when the scene has no light.
pub const HEADLIGHT_AMBIENT: f32 = 0.1;

fn background(scene: &Scene) -> [f32; 4] {
    let [r, g, b] = scene.background;
    [r, g, b, 0.0]
}

/// Woodcock tracking of channel `n` alone (MDWT Listings 1-2).
fn woodcock(scene: &Scene, n: usize, ray: &Ray, rng: &mut Rng, stats: &mut RayStats) -> [f32; 4] {
    match woodcock_walk(scene, n, ray, rng, None, |_| true, stats) {
        WalkStop::Done(v) => v,
        WalkStop::Left { .. } => background(scene),
    }
}

/// Where a resumable Woodcock walk ([`woodcock_walk`]) stopped.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum WalkStop {
    /// The sample's radiance: the real collision shaded, or the background.
    Done([f32; 4]),
    /// A tentative collision at ray parameter `t` (world point `p`) outside the region the
    /// walk was given: the random stream stands just after the distance that reached it, so
    /// whoever holds the data there continues with `pending = Some(t)`.
    Left {
        /// Ray parameter.
        t: f32,
        /// World position.
        p: Vec3,
    },
}

/// Woodcock tracking of channel `n` ([`Integrator::Woodcock`]) that stops at the first
/// tentative collision outside the points `inside` accepts: the walk of data-parallel
/// tracking, where each rank holds a piece of the volume and forwards the ray to the rank
/// that holds the next tentative collision (as Wald et al.'s barney does).
///
/// `pending = Some(t)` resumes a walk that stopped with [`WalkStop::Left`] at `t`, with
/// `rng` restored to where it stood then: the majorant segments are recomputed from the
/// ray, the one holding `t` is found, the collision at `t` is tested and the walk goes
/// on. A walk stopped and resumed any number of times draws the same numbers and returns
/// the same value, bit for bit, as one walk with `inside` always true (which is what
/// [`Integrator::Woodcock`] runs). Shading at the collision (gradients, shadow rays)
/// samples the scene wherever it needs to.
pub fn woodcock_walk(
    scene: &Scene,
    n: usize,
    ray: &Ray,
    rng: &mut Rng,
    pending: Option<f32>,
    inside: impl Fn(Vec3) -> bool,
    stats: &mut RayStats,
) -> WalkStop {
    if n >= scene.channel_count() {
        return WalkStop::Done(background(scene));
    }
    let grid = scene.channels()[n].majorant();
    let t0 = stats.tentative;
    let mut resume = pending;
    let mut hit: Option<Hit> = None;
    'segments: for seg in DdaMajorantIterator::new(grid, ray, f32::INFINITY) {
        if resume.is_some_and(|t| seg.t_max <= t) {
            continue;
        }
        stats.cells += 1;
        if seg.sigma_maj <= 0.0 {
            continue;
        }
        let mut t = seg.t_min;
        let mut at = resume.take();
        loop {
            t = match at.take() {
                Some(t) => t,
                None => {
                    let next = advance(t, rng.exponential(seg.sigma_maj));
                    if next >= seg.t_max {
                        break;
                    }
                    stats.tentative += 1;
                    next
                }
            };
            let p = ray.at(t);
            if !inside(p) {
                return WalkStop::Left { t, p };
            }
            let (s, c) = scene.sample(n, p);
            if rng.uniform() * seg.sigma_maj < s {
                hit = Some(Hit {
                    p,
                    channel: n,
                    colour: c,
                });
                break 'segments;
            }
        }
    }
    stats.rejections += (stats.tentative - t0).saturating_sub(u32::from(hit.is_some()));
    WalkStop::Done(match hit {
        None => background(scene),
        Some(h) => {
            let [r, g, b] = shade(scene, &h, ray, rng, grid, |q| scene.sample(n, q).0);
            [r, g, b, 1.0]
        }
    })
}

/// Whether shading a real collision of `scene` traces shadow rays (which cross the whole
/// volume, not only the piece around the collision).
#[must_use]
pub fn traces_shadows(scene: &Scene) -> bool {
    match (&scene.shading, &scene.light) {
        (None, Some(_)) => true,
        (Some(sh), Some(_)) => sh.shadows,
        _ => false,
    }
}

/// Multi-density Woodcock tracking (MDWT Listings 3 and 4, and the summed-majorant variant)
/// for the density, weighted, max and mix blends.
fn mdwt(
    scene: &Scene,
    dda: DdaMode,
    blend: &Blend,
    ray: &Ray,
    rng: &mut Rng,
    stats: &mut RayStats,
) -> [f32; 4] {
    let mut hit_t = f32::INFINITY;
    let mut hit_c = [0.0f32; 3];
    let mut hit_n = 0usize;
    let t0 = stats.tentative;
    match dda {
        DdaMode::NDda => {
            for n in 0..scene.channel_count() {
                let grid = scene.channels()[n].majorant();
                let _ = sample_t_maj_counted(grid, ray, hit_t, rng, stats, |rng, ev| {
                    let (s, c) = blended(scene, blend, n, ev.p);
                    if rng.uniform() * ev.sigma_maj < s {
                        hit_t = ev.t;
                        hit_c = c;
                        hit_n = n;
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
                stats.cells += 1;
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
                        stats.tentative += 1;
                        let (s, c) = blended(scene, blend, n, ray.at(t));
                        if rng.uniform() * maj < s {
                            hit_t = t;
                            hit_c = c;
                            hit_n = n;
                            break;
                        }
                    }
                }
                if hit_t.is_finite() {
                    break;
                }
            }
        }
        DdaMode::Summed => {
            // One free-flight stream against the summed majorant; a tentative collision is
            // real with probability sum_n s_n / m, and then belongs to channel n with
            // probability s_n / sum s (one uniform number decides both).
            let grid = scene.total_majorant();
            let mix = match blend {
                Blend::Mix { weights } => Some(weights.as_slice()),
                _ => None,
            };
            let _ = sample_t_maj_counted(grid, ray, f32::INFINITY, rng, stats, |rng, ev| {
                let u = rng.uniform() * ev.sigma_maj;
                match blend {
                    Blend::Max | Blend::Mix { .. } => {
                        let (n, s, c) = winner(scene, mix, ev.p);
                        if u < s {
                            (hit_t, hit_c, hit_n) = (ev.t, c, n);
                            return ControlFlow::Break(());
                        }
                    }
                    _ => {
                        let mut acc = 0.0f32;
                        for n in 0..scene.channel_count() {
                            let (s, c) = blended(scene, blend, n, ev.p);
                            acc += s;
                            if u < acc {
                                (hit_t, hit_c, hit_n) = (ev.t, c, n);
                                return ControlFlow::Break(());
                            }
                        }
                    }
                }
                ControlFlow::Continue(())
            });
        }
    }
    let real = u32::from(hit_t.is_finite());
    stats.rejections += (stats.tentative - t0).saturating_sub(real);
    if !hit_t.is_finite() {
        return background(scene);
    }
    let hit = Hit {
        p: ray.at(hit_t),
        channel: hit_n,
        colour: hit_c,
    };
    let [r, g, b] = shade(scene, &hit, ray, rng, scene.total_majorant(), |q| {
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
    stats: &mut RayStats,
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
        // With a clip box: the steps whose sample may lie in it (a margin of two steps),
        // each then tested, so boxes tiling space share out the same global samples.
        let (first, last) = match &scene.clip {
            None => (0, n_steps),
            Some(c) => match c.ray_range(ray, lo, hi, 2.0 * step) {
                None => (0, 0),
                Some((ca, cb)) => (
                    (((ca - t0) / step).floor().max(0.0) as u64).min(n_steps),
                    ((((cb - t0) / step).ceil().max(0.0) as u64) + 1).min(n_steps),
                ),
            },
        };
        for i in first..last {
            let ta = t0 + i as f32 * step;
            let tb = (ta + step).min(t1);
            let len = tb - ta;
            if len <= 0.0 {
                break;
            }
            stats.cells += 1;
            let p = ray.at(ta + jitter * len);
            if scene.clip.as_ref().is_some_and(|c| !c.contains(p)) {
                continue;
            }
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
    let bg = if scene.clip.is_some() {
        [0.0; 3]
    } else {
        scene.background
    };
    [
        c[0] + (1.0 - a) * bg[0],
        c[1] + (1.0 - a) * bg[1],
        c[2] + (1.0 - a) * bg[2],
        a,
    ]
}
