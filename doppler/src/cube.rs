//! Spectral (position-position-velocity) cubes: each pixel's light integrated in closed form
//! over velocity or wavelength channels, moment maps, and views along any direction.
//!
//! A channel's value is the integral of the pixel's spectrum over the channel's wavelength
//! interval (value unit x nm): with strength-1 lines and the energy-conserving transform, it
//! is the line emission `integral rho dl` that falls into the channel, which is what yt's
//! `PPVCube` projects (its channels hold `integral field x weight dl`). Summed over all
//! channels the cube gives the projected line emission (moment 0).
//!
//! Without absorption the cube path keeps no spectrum: every trapezoid a line emits over a
//! ray segment (with its [`super::Broadening`] profile) is integrated over the channels it
//! overlaps in closed form; the black-body continuum is left out (a continuum-subtracted
//! line cube). With absorption each ray is marched front to back over the channels' window
//! alone, continuum included, and its light binned straight into the channels (`cube_abs`).

use blueshift_camera::{Observer, Progress};
use blueshift_spectrum::{Piece, PwlGaussian, SPEED_OF_LIGHT_M_PER_S};
use glam::Vec3;
use rayon::prelude::*;
use std::sync::atomic::{AtomicU64, Ordering};

use super::model::DopplerScene;
use super::profile::Emit;
use super::render::{Context, DopplerImage, DopplerSettings, SpectralIntegrator};
use crate::{Camera, Error, Projection, Result};

/// The spectral axis of a cube; spelt `vrad`, `vopt` or `wave` (`FromStr` also reads
/// `radio`, `optical`, `wavelength`, in any case).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SpectralAxis {
    /// Radio velocity `v = c (1 - lambda_0 / lambda)` (FITS `VRAD`), m/s.
    RadioVelocity,
    /// Optical velocity `v = c (lambda / lambda_0 - 1)` (FITS `VOPT`; yt's `PPVCube` axis;
    /// with the classical Doppler model a parcel at line-of-sight velocity `v` lands exactly
    /// at `v`), m/s.
    OpticalVelocity,
    /// Wavelength (FITS `WAVE`), nm.
    Wavelength,
}

impl SpectralAxis {
    /// The FITS `CTYPE3`.
    #[must_use]
    pub fn ctype(self) -> &'static str {
        match self {
            Self::RadioVelocity => "VRAD",
            Self::OpticalVelocity => "VOPT",
            Self::Wavelength => "WAVE",
        }
    }
}

impl std::str::FromStr for SpectralAxis {
    type Err = Error;
    /// `vrad`, `vopt` or `wave`.
    fn from_str(s: &str) -> Result<Self> {
        match s.trim().to_ascii_lowercase().as_str() {
            "vrad" | "radio" => Ok(Self::RadioVelocity),
            "vopt" | "optical" => Ok(Self::OpticalVelocity),
            "wave" | "wavelength" => Ok(Self::Wavelength),
            _ => Err(Error::parameter(format!(
                "spectral axis '{s}': use vrad, vopt or wave"
            ))),
        }
    }
}

impl std::fmt::Display for SpectralAxis {
    /// `vrad`, `vopt` or `wave`.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::RadioVelocity => "vrad",
            Self::OpticalVelocity => "vopt",
            Self::Wavelength => "wave",
        })
    }
}

blueshift_camera::serde_via_str!(SpectralAxis);

/// The rest width of the lines' box in a cube.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum CubeLineWidth {
    /// A box one channel wide (the channel width in nm at the rest wavelength, for a
    /// velocity axis `rest_nm * width / c`): without broadening its exact channel integrals
    /// are yt's tent weights `1 - |v_c - v| / dv`. [`DopplerSettings::line_width_nm`] is
    /// not used.
    #[default]
    OneChannel,
    /// [`DopplerSettings::line_width_nm`].
    Settings,
}

/// The channels of a cube: `channels` equal channels from `min` to `max` along `axis`
/// (m/s for velocity axes, nm for wavelength) around the rest wavelength `rest_nm`, and the
/// lines' box width (`line_width`, one channel by default).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CubeSpec {
    /// Rest wavelength of the chosen line, nm.
    pub rest_nm: f64,
    /// Spectral axis.
    pub axis: SpectralAxis,
    /// Lower edge of the first channel (m/s or nm).
    pub min: f64,
    /// Upper edge of the last channel (m/s or nm).
    pub max: f64,
    /// Number of channels.
    pub channels: usize,
    /// The lines' box width ([`CubeSpec::line_width_nm`]).
    pub line_width: CubeLineWidth,
}

/// Most channels a cube may have.
pub const MAX_CHANNELS: usize = 1 << 16;

impl CubeSpec {
    /// Checks the channels: `1..=65536` channels, a non-empty finite range, velocities below
    /// `c`, a positive rest wavelength, and every channel edge inside `range_nm` (the
    /// spectrum's wavelength range).
    pub fn validate(&self, range_nm: (f64, f64)) -> Result<()> {
        if !(1..=MAX_CHANNELS).contains(&self.channels) {
            return Err(Error::parameter(format!(
                "{} channels: need 1..={MAX_CHANNELS}",
                self.channels
            )));
        }
        if !(self.min.is_finite() && self.max.is_finite() && self.min < self.max) {
            return Err(Error::parameter(format!(
                "empty or invalid channel range {}..{}",
                self.min, self.max
            )));
        }
        if !(self.rest_nm.is_finite() && self.rest_nm > 0.0) {
            return Err(Error::parameter(format!(
                "rest wavelength {} nm must be > 0",
                self.rest_nm
            )));
        }
        match self.axis {
            SpectralAxis::Wavelength if self.min <= 0.0 => {
                return Err(Error::parameter("wavelength channels must be > 0 nm"));
            }
            SpectralAxis::RadioVelocity | SpectralAxis::OpticalVelocity
                if self.min <= -SPEED_OF_LIGHT_M_PER_S || self.max >= SPEED_OF_LIGHT_M_PER_S =>
            {
                return Err(Error::parameter("channel velocities must be below c"));
            }
            _ => {}
        }
        let (lo, hi) = (self.edge_nm(0), self.edge_nm(self.channels));
        if lo < range_nm.0 || hi > range_nm.1 {
            return Err(Error::parameter(format!(
                "the channels span {lo:.4}-{hi:.4} nm, outside the spectrum's range {}-{} nm",
                range_nm.0, range_nm.1
            )));
        }
        Ok(())
    }

    /// Channel width (m/s or nm).
    #[must_use]
    pub fn width(&self) -> f64 {
        (self.max - self.min) / self.channels as f64
    }

    /// Edge `i` (0..=channels) in the axis unit.
    #[must_use]
    pub fn edge(&self, i: usize) -> f64 {
        self.min + self.width() * i as f64
    }

    /// Centre of channel `k` in the axis unit.
    #[must_use]
    pub fn centre(&self, k: usize) -> f64 {
        self.min + self.width() * (k as f64 + 0.5)
    }

    /// The lines' rest box width this cube renders with, nm: one channel
    /// ([`CubeLineWidth::OneChannel`]) or `settings.line_width_nm`.
    #[must_use]
    pub fn line_width_nm(&self, settings: &DopplerSettings) -> f64 {
        match self.line_width {
            CubeLineWidth::Settings => settings.line_width_nm,
            CubeLineWidth::OneChannel => match self.axis {
                SpectralAxis::Wavelength => self.width(),
                SpectralAxis::RadioVelocity | SpectralAxis::OpticalVelocity => {
                    self.rest_nm * self.width() / SPEED_OF_LIGHT_M_PER_S
                }
            },
        }
    }

    /// Edge `i` as a wavelength, nm.
    #[must_use]
    pub fn edge_nm(&self, i: usize) -> f64 {
        let v = self.edge(i);
        match self.axis {
            SpectralAxis::RadioVelocity => self.rest_nm / (1.0 - v / SPEED_OF_LIGHT_M_PER_S),
            SpectralAxis::OpticalVelocity => self.rest_nm * (1.0 + v / SPEED_OF_LIGHT_M_PER_S),
            SpectralAxis::Wavelength => v,
        }
    }
}

/// A spectral cube.
#[derive(Clone, Debug)]
pub struct SpectralCube {
    /// Pixels along the image's horizontal axis (FITS axis 1).
    pub nx: usize,
    /// Pixels along the vertical axis (FITS axis 2).
    pub ny: usize,
    /// The channels.
    pub spec: CubeSpec,
    /// Values (value unit x nm per channel), x fastest, then y with row 0 at the BOTTOM
    /// (FITS order), then channel.
    pub data: Vec<f32>,
    /// Pixel size, world units (horizontal, vertical).
    pub pixel_world: (f64, f64),
}

impl SpectralCube {
    /// Value at `(x, y, channel)` (`y = 0` at the bottom).
    #[must_use]
    pub fn at(&self, x: usize, y: usize, k: usize) -> f32 {
        self.data[(k * self.ny + y) * self.nx + x]
    }

    /// The moment maps (row 0 at the bottom, like the cube).
    #[must_use]
    pub fn moments(&self) -> Moments {
        let n = self.nx * self.ny;
        let mut m = Moments {
            nx: self.nx,
            ny: self.ny,
            m0: vec![0.0; n],
            m1: vec![f32::NAN; n],
            m2: vec![f32::NAN; n],
        };
        let c: Vec<f64> = (0..self.spec.channels)
            .map(|k| self.spec.centre(k))
            .collect();
        for p in 0..n {
            let (mut s0, mut s1) = (0.0f64, 0.0f64);
            for (k, &ck) in c.iter().enumerate() {
                let v = f64::from(self.data[k * n + p]);
                s0 += v;
                s1 += v * ck;
            }
            m.m0[p] = s0 as f32;
            if s0 > 0.0 {
                let mean = s1 / s0;
                let s2: f64 = c
                    .iter()
                    .enumerate()
                    .map(|(k, &ck)| f64::from(self.data[k * n + p]) * (ck - mean).powi(2))
                    .sum();
                m.m1[p] = mean as f32;
                m.m2[p] = (s2 / s0).max(0.0).sqrt() as f32;
            }
        }
        m
    }
}

/// Moment maps of a cube: 0 (sum over channels: the projected line emission), 1
/// (intensity-weighted mean of the channel centres, the axis unit) and 2 (intensity-weighted
/// dispersion about moment 1). Pixels with no emission have NaN moments 1 and 2.
#[derive(Clone, Debug)]
pub struct Moments {
    /// Width.
    pub nx: usize,
    /// Height.
    pub ny: usize,
    /// Moment 0.
    pub m0: Vec<f32>,
    /// Moment 1.
    pub m1: Vec<f32>,
    /// Moment 2.
    pub m2: Vec<f32>,
}

impl Moments {
    /// The maps with moments 1 and 2 blanked (NaN) where moment 0 is below `min_m0`: a
    /// velocity mean or dispersion of a pixel with little signal is noise. Moment 0 is kept
    /// as it is; a NaN `min_m0` blanks nothing.
    #[must_use]
    pub fn masked(&self, min_m0: f32) -> Moments {
        let mut m = self.clone();
        for ((m0, m1), m2) in m.m0.iter().zip(&mut m.m1).zip(&mut m.m2) {
            if *m0 < min_m0 {
                *m1 = f32::NAN;
                *m2 = f32::NAN;
            }
        }
        m
    }
}

/// An orthographic camera for an observer along `normal` (yt's convention: the observer
/// sits at `+normal`, rays travel along `-normal`, and a positive line-of-sight velocity,
/// `-v . normal`, recedes). Axis-aligned normals get yt's image axes (`z`: x right, y up;
/// `x`: y right, z up; `y`: z right, x up); others get up = +z projected (+y when the
/// normal is near z). The view frames the projection of the scene's box (grown by half a
/// voxel with `cell_domain`, see [`DopplerSettings::cell_domain`]) for an image of aspect
/// `width / height`.
pub fn los_camera(
    scene: &DopplerScene,
    normal: Vec3,
    aspect: f32,
    cell_domain: bool,
) -> Result<Camera> {
    let n = normal
        .try_normalize()
        .filter(|n| n.is_finite())
        .ok_or_else(|| Error::parameter(format!("view normal {normal} must be non-zero")))?;
    let (lo, hi) = scene.frame_bounds(cell_domain);
    let mut camera = Camera::framing(
        lo,
        hi,
        n,
        blueshift_camera::up_for(n),
        aspect,
        true,
        blueshift_camera::DEFAULT_FOV_Y_DEG,
    )?;
    // Rays start a bounding radius plus one from the centre (as the cube tests were recorded),
    // plus the radius for a volume smaller than one unit, so every distance scales with a
    // volume in any units (in f64: the squared diagonal of a volume in centimetres overflows
    // f32).
    let r = (0.5 * (hi - lo).as_dvec3().length()) as f32;
    camera.eye = camera.target + n * (r + r.clamp(f32::MIN_POSITIVE, 1.0));
    Ok(camera)
}

/// Adds the integral of the trapezoid `(lo, hi, h0, h1)` over each channel `[e[k], e[k+1]]`.
fn bin_trapezoid(edges: &[f64], acc: &mut [f64], lo: f64, hi: f64, h0: f64, h1: f64) {
    if hi <= lo || hi <= edges[0] || lo >= edges[edges.len() - 1] {
        return;
    }
    let slope = (h1 - h0) / (hi - lo);
    let at = |x: f64| h0 + slope * (x - lo);
    let mut k = edges.partition_point(|&e| e <= lo).saturating_sub(1);
    while k + 1 < edges.len() && edges[k] < hi {
        let a = lo.max(edges[k]);
        let b = hi.min(edges[k + 1]);
        if b > a {
            acc[k] += 0.5 * (b - a) * (at(a) + at(b));
        }
        k += 1;
    }
}

/// Adds the exact channel integrals of the [`PwlGaussian`] `(c, sigma, area)` through its
/// piecewise-quadratic cumulative area (the same numbers as integrating its 32 pieces).
fn bin_gaussian(g: &PwlGaussian, edges: &[f64], acc: &mut [f64], c: f64, sigma: f64, area: f64) {
    let half = g.half_width_sigmas() * sigma;
    let (lo, hi) = (c - half, c + half);
    if hi <= edges[0] || lo >= edges[edges.len() - 1] {
        return;
    }
    let inv = 1.0 / sigma;
    let mut k = edges.partition_point(|&e| e <= lo).saturating_sub(1);
    let mut f0 = g.cdf((edges[k] - c) * inv);
    while k + 1 < edges.len() && edges[k] < hi {
        let f1 = g.cdf((edges[k + 1] - c) * inv);
        acc[k] += area * (f1 - f0);
        f0 = f1;
        k += 1;
    }
}

/// Exact channel integrals of a sum of wide [`PwlGaussian`]s through their kinks, in time
/// independent of how many channels each spans: a piecewise-linear profile is
/// `sum_i d_i max(x - x_i, 0)`, so its integral up to an edge `e` is
/// `sum_{x_i < e} d_i (e - x_i)^2 / 2`, a quadratic in `e` whose three coefficients are
/// summed per channel as the kinks arrive and prefix-summed over the channels once per ray.
/// (Binning each Gaussian's piecewise-quadratic CDF at every edge it spans costs one CDF
/// per channel: all 128 for the galaxy's hot gas.) Positions are taken relative to the
/// window's middle, so the quadratic's terms stay within a few thousand times the result.
struct KinkBins<'a> {
    edges: &'a [f64],
    spec: &'a CubeSpec,
    origin: f64,
    /// Kinks below the first edge: they reach every edge.
    below: [f64; 3],
    /// `bins[k]`: kinks in `[edges[k], edges[k + 1])`.
    bins: Vec<[f64; 3]>,
    used: bool,
}

impl<'a> KinkBins<'a> {
    fn new(edges: &'a [f64], spec: &'a CubeSpec) -> Self {
        Self {
            edges,
            spec,
            origin: 0.5 * (edges[0] + edges[edges.len() - 1]),
            below: [0.0; 3],
            bins: vec![[0.0; 3]; edges.len() - 1],
            used: false,
        }
    }

    /// The channel holding `x` (nm): `None` below the first edge, `Some(channels)` at or
    /// past the last.
    #[inline]
    fn channel_of(&self, x: f64) -> Option<usize> {
        let e = self.edges;
        let n = e.len() - 1;
        if x < e[0] {
            return None;
        }
        if x >= e[n] {
            return Some(n);
        }
        let a = match self.spec.axis {
            SpectralAxis::OpticalVelocity => SPEED_OF_LIGHT_M_PER_S * (x / self.spec.rest_nm - 1.0),
            SpectralAxis::RadioVelocity => SPEED_OF_LIGHT_M_PER_S * (1.0 - self.spec.rest_nm / x),
            SpectralAxis::Wavelength => x,
        };
        // Truncation is the floor where it matters (guess > 0); the walks below correct
        // any rounding.
        let guess = (a - self.spec.min) / self.spec.width();
        let mut k = if guess > 0.0 {
            (guess as usize).min(n - 1)
        } else {
            0
        };
        while k > 0 && x < e[k] {
            k -= 1;
        }
        while k + 1 < n && x >= e[k + 1] {
            k += 1;
        }
        Some(k)
    }

    #[inline]
    fn add_gaussian(&mut self, g: &PwlGaussian, c: f64, sigma: f64, area: f64) {
        self.used = true;
        let origin = self.origin;
        let e = self.edges;
        let n = self.bins.len();
        // The kinks come in ascending x: locate the first, then walk up the edges.
        let mut k: Option<usize> = None;
        let mut first = true;
        let mut kink = |x: f64, d: f64| {
            if first {
                k = self.channel_of(x);
                first = false;
            } else if let Some(j) = k.as_mut() {
                while *j < n && x >= e[*j + 1] {
                    *j += 1;
                }
            } else if x >= e[0] {
                k = self.channel_of(x);
            }
            let target = match k {
                None => &mut self.below,
                Some(j) if j < n => &mut self.bins[j],
                Some(_) => return,
            };
            let u = x - origin;
            target[0] += 0.5 * d;
            target[1] -= d * u;
            target[2] += 0.5 * d * u * u;
        };
        g.for_each_kink(c, sigma, area, &mut kink);
    }

    /// Adds the channel integrals to `acc` and clears the bins.
    fn flush(&mut self, acc: &mut [f64]) {
        if !self.used {
            return;
        }
        let mut s = self.below;
        let f = |s: &[f64; 3], e: f64| {
            let u = e - self.origin;
            (s[0] * u + s[1]) * u + s[2]
        };
        let mut f_lo = f(&s, self.edges[0]);
        for (k, a) in acc.iter_mut().enumerate() {
            for (t, b) in s.iter_mut().zip(&self.bins[k]) {
                *t += b;
            }
            let f_hi = f(&s, self.edges[k + 1]);
            *a += f_hi - f_lo;
            f_lo = f_hi;
        }
        self.below = [0.0; 3];
        self.bins.iter_mut().for_each(|b| *b = [0.0; 3]);
        self.used = false;
    }
}

/// Gaussians spanning more channels than this go through [`KinkBins`] (33 kinks each),
/// narrower ones through their CDF at each edge.
const KINK_MIN_CHANNELS: f64 = 24.0;

/// The largest estimated error, as a fraction of the peak, of replacing a run of a line's
/// Gaussians by one Gaussian of the same area, mean and variance ([`GaussRun`]).
pub(crate) const MERGE_ERROR: f64 = 1.2e-3;

/// Consecutive Gaussians of one line along a ray (a segment's sub-Gaussians and those of the
/// next segments), replaced by one Gaussian of the same area, mean and variance while the
/// sum stays close to a Gaussian: binning costs one Gaussian per run, not per segment.
///
/// The rule: a Gaussian joins the run if, with it, the sum's skewness `g1` and excess
/// kurtosis `g2` (its third and fourth cumulants over the variance's powers) give a
/// Gram-Charlier error estimate `0.231 |g1| + |g2| / 8` of at most [`MERGE_ERROR`] of the
/// peak (the sup of `|He3(x)| phi(x) / 6` is 0.231 `phi(0)`, `|He4(0)| / 24` is 1/8), and
/// the centres stay within two of the narrowest sigma of each other and the sigmas within a
/// factor 1.5, where the estimate holds. Area and first moment are kept exactly, so moment
/// maps 0 and 1 keep their values; the sum's shape errs by at most 0.25 % of its peak
/// (`merged_runs_stay_within_the_stated_error` checks the true sums, including the
/// estimate's worst case, a weak narrow Gaussian beside a strong wide one, where the true
/// error is about twice the estimate: hence the limit of 0.12 %), below the 0.87 % of the
/// piecewise-linear Gaussian itself. With broadening, a cube rendered in boxes (data
/// parallel) merges only within each box, so it differs from the whole cube within this
/// bound.
#[derive(Clone, Copy, Debug)]
pub(crate) struct GaussRun {
    /// The first Gaussian's centre (nm): the moments are taken about it.
    c0: f64,
    /// Sum of the areas, then of each area times its Gaussian's raw moments 1..=4 about
    /// `c0`.
    s: [f64; 5],
    /// Range of the centres (relative to `c0`) and of the sigmas.
    d_lo: f64,
    d_hi: f64,
    s_lo: f64,
    s_hi: f64,
}

impl GaussRun {
    pub(crate) const EMPTY: Self = Self {
        c0: 0.0,
        s: [0.0; 5],
        d_lo: 0.0,
        d_hi: 0.0,
        s_lo: 0.0,
        s_hi: 0.0,
    };

    pub(crate) fn is_empty(&self) -> bool {
        self.s[0] == 0.0
    }

    /// Area times the raw moments 0..=4 of the Gaussian `(d, sigma)` (centre `d` about `c0`).
    fn raw(d: f64, sigma: f64, area: f64) -> [f64; 5] {
        let (d2, v) = (d * d, sigma * sigma);
        [
            area,
            area * d,
            area * (d2 + v),
            area * d * (d2 + 3.0 * v),
            area * (d2 * d2 + 6.0 * d2 * v + 3.0 * v * v),
        ]
    }

    /// Mean (about `c0`), variance, and the error estimate of the sums `s`.
    pub(crate) fn shape(s: &[f64; 5]) -> (f64, f64, f64) {
        let inv = 1.0 / s[0];
        let (e1, e2, e3, e4) = (s[1] * inv, s[2] * inv, s[3] * inv, s[4] * inv);
        let m2 = e2 - e1 * e1;
        let m3 = e3 - e1 * (3.0 * e2 - 2.0 * e1 * e1);
        let m4 = e4 - e1 * (4.0 * e3 - e1 * (6.0 * e2 - 3.0 * e1 * e1));
        let k4 = m4 - 3.0 * m2 * m2;
        let err = 0.231 * m3.abs() / (m2 * m2.sqrt()) + 0.125 * k4.abs() / (m2 * m2);
        (e1, m2, err)
    }

    /// Adds the Gaussian `(c, sigma, area)` (`sigma`, `area` > 0) if the run stays within the
    /// rule; returns whether it did (an empty run always takes it).
    pub(crate) fn try_add(&mut self, c: f64, sigma: f64, area: f64) -> bool {
        if self.is_empty() {
            *self = Self {
                c0: c,
                s: Self::raw(0.0, sigma, area),
                d_lo: 0.0,
                d_hi: 0.0,
                s_lo: sigma,
                s_hi: sigma,
            };
            return true;
        }
        let d = c - self.c0;
        let (d_lo, d_hi) = (self.d_lo.min(d), self.d_hi.max(d));
        let (s_lo, s_hi) = (self.s_lo.min(sigma), self.s_hi.max(sigma));
        if d_hi - d_lo > 2.0 * s_lo || s_hi > 1.5 * s_lo {
            return false;
        }
        let r = Self::raw(d, sigma, area);
        let s = std::array::from_fn(|i| self.s[i] + r[i]);
        let (_, m2, err) = Self::shape(&s);
        // Not `err > MERGE_ERROR`: a NaN estimate refuses too.
        if !(m2 > 0.0 && err <= MERGE_ERROR) {
            return false;
        }
        *self = Self {
            c0: self.c0,
            s,
            d_lo,
            d_hi,
            s_lo,
            s_hi,
        };
        true
    }

    /// The sums of each area times its Gaussian's raw moments 0..=4 about the first
    /// Gaussian's centre, and that centre (zeros for an empty run).
    pub(crate) fn sums(&self) -> ([f64; 5], f64) {
        (self.s, self.c0)
    }

    /// The merged Gaussian `(centre, sigma, area)`, and the run emptied.
    pub(crate) fn take(&mut self) -> (f64, f64, f64) {
        let (e1, m2, _) = Self::shape(&self.s);
        let out = if self.s_lo == self.s_hi && self.d_lo == self.d_hi {
            // One Gaussian (or several at one place and width): exactly it.
            (self.c0 + self.d_lo, self.s_lo, self.s[0])
        } else {
            (self.c0 + e1, m2.max(0.0).sqrt(), self.s[0])
        };
        *self = Self::EMPTY;
        out
    }
}

/// A ray's binning of broadened lines: each line's open [`GaussRun`], then each merged
/// Gaussian through the kinks (wide) or its CDF at the edges (narrow).
struct LineBins<'a> {
    kinks: KinkBins<'a>,
    /// One run per reachable line (species by species, in `lines`' order).
    runs: Vec<GaussRun>,
    /// The narrowest channel (nm), against which a Gaussian's span is measured.
    chan_nm: f64,
}

impl<'a> LineBins<'a> {
    fn new(edges: &'a [f64], spec: &'a CubeSpec, lines: usize) -> Self {
        Self {
            kinks: KinkBins::new(edges, spec),
            runs: vec![GaussRun::EMPTY; lines],
            chan_nm: edges
                .windows(2)
                .map(|w| w[1] - w[0])
                .fold(f64::INFINITY, f64::min),
        }
    }

    /// Adds line `i`'s Gaussian `(c, sigma, area)` to its run, binning the run first if
    /// the Gaussian cannot join it.
    #[inline]
    fn add(&mut self, g: &PwlGaussian, acc: &mut [f64], i: usize, c: f64, sigma: f64, area: f64) {
        if !self.runs[i].try_add(c, sigma, area) {
            let (c1, s1, a1) = self.runs[i].take();
            self.bin(g, acc, c1, s1, a1);
            self.runs[i].try_add(c, sigma, area);
        }
    }

    fn bin(&mut self, g: &PwlGaussian, acc: &mut [f64], c: f64, sigma: f64, area: f64) {
        if 2.0 * g.half_width_sigmas() * sigma > KINK_MIN_CHANNELS * self.chan_nm {
            self.kinks.add_gaussian(g, c, sigma, area);
        } else {
            bin_gaussian(g, self.kinks.edges, acc, c, sigma, area);
        }
    }

    /// Bins every open run and adds the ray's kinks to `acc`.
    fn flush(&mut self, g: &PwlGaussian, acc: &mut [f64]) {
        for i in 0..self.runs.len() {
            if !self.runs[i].is_empty() {
                let (c, sigma, area) = self.runs[i].take();
                self.bin(g, acc, c, sigma, area);
            }
        }
        self.kinks.flush(acc);
    }
}

/// Per species, the emission lines that can reach the channels at all: the largest speed in
/// the scene bounds the shift (classical or relativistic), the hottest temperature bounds
/// the thermal width (8 sigma), plus the box width.
fn reachable_lines(ctx: &Context<'_>, edges: &[f64]) -> Vec<Vec<blueshift_spectrum::EmissionLine>> {
    let scene = ctx.scene;
    let vmax = scene
        .velocity
        .as_ref()
        .map_or(0.0, blueshift_volume::VectorField::max_speed)
        * scene.factors.velocity;
    let beta = vmax / SPEED_OF_LIGHT_M_PER_S;
    // A moving observer's velocity composes with the gas's: the largest speed of the two
    // composed bounds every shift.
    let b_obs = ctx.settings.observer.map_or(0.0, |o| o.velocity.speed());
    let beta = if beta < 1.0 {
        (beta + b_obs) / (1.0 + beta * b_obs)
    } else {
        beta
    };
    let tmax = scene.blackbody.as_ref().map_or(0.0, |(_, t)| {
        t.finite_range()
            .map_or(0.0, |(_, hi)| f64::from(hi).max(0.0))
    }) * scene.factors.temperature;
    let (wlo, whi) = (edges[0], edges[edges.len() - 1]);
    scene
        .species
        .iter()
        .enumerate()
        .map(|(m, sp)| {
            if beta >= 0.99 {
                return sp.emission_lines.clone();
            }
            let g = (1.0 - beta * beta).sqrt();
            let (slo, shi) = ((1.0 - beta).min((1.0 - beta) / g), (1.0 + beta) / g);
            let sig = if ctx.profiles.active {
                ctx.profiles.sigma_v(m, tmax) / SPEED_OF_LIGHT_M_PER_S
            } else {
                0.0
            };
            sp.emission_lines
                .iter()
                .filter(|l| {
                    let reach = 8.0 * sig * shi * l.centre_nm + ctx.settings.line_width_nm;
                    shi * l.centre_nm + reach >= wlo && slo * l.centre_nm - reach <= whi
                })
                .copied()
                .collect()
        })
        .collect()
}

/// Whether a line at rest `centre` (nm), seen through the shifts `(sa, sb)` with a velocity
/// dispersion up to `sigma_max` (m/s) and the box `line_width` (nm), can reach the window
/// `(lo, hi)` (nm): its shift range plus 8 sigma and the box.
pub(crate) fn line_reaches(
    centre: f64,
    (sa, sb): (f64, f64),
    sigma_max: f64,
    line_width: f64,
    (lo, hi): (f64, f64),
) -> bool {
    let (lmin, lmax) = (sa.min(sb) * centre, sa.max(sb) * centre);
    let reach = 8.0 * sigma_max / SPEED_OF_LIGHT_M_PER_S * lmax + line_width;
    lmax + reach >= lo && lmin - reach <= hi
}

/// One emission-only ray's channel values into `acc`.
fn ray_channels(
    ctx: &Context<'_>,
    lines: &[Vec<blueshift_spectrum::EmissionLine>],
    ray: &crate::Ray,
    edges: &[f64],
    bins: &mut LineBins<'_>,
    acc: &mut [f64],
) -> Result<()> {
    let scene = ctx.scene;
    let st = ctx.settings;
    let f = scene.factors;
    let s = ctx.sample_lines(ray, ctx.profiles.active)?;
    let nsp = scene.species.len();
    let (wlo, whi) = (edges[0], edges[edges.len() - 1]);
    let g = &ctx.profiles.gauss;
    for j in 0..s.len().saturating_sub(1) {
        let dt = f64::from(s.t[j] - s.t[j + 1]).abs();
        let (sa, sb) = (s.shift[j], s.shift[j + 1]);
        let (ga, gb) = (ctx.value_factor(sa) * sa, ctx.value_factor(sb) * sb);
        let mut first_line = 0;
        for m in 0..nsp {
            let line0 = first_line;
            first_line += lines[m].len();
            let (ra, rb) = (s.rho[j * nsp + m], s.rho[(j + 1) * nsp + m]);
            if ra <= 0.0 && rb <= 0.0 {
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
            for (i, l) in lines[m].iter().enumerate() {
                if !line_reaches(
                    l.centre_nm,
                    (sa, sb),
                    siga.max(sigb),
                    st.line_width_nm,
                    (wlo, whi),
                ) {
                    continue;
                }
                let base = dt * l.strength * f.emission;
                super::profile::emit_line(
                    l.centre_nm,
                    sa,
                    sb,
                    base * ra * ga,
                    base * rb * gb,
                    siga,
                    sigb,
                    st.line_width_nm,
                    &mut |e| -> Result<()> {
                        match e {
                            Emit::Trapezoid(lo, hi, h0, h1) => {
                                bin_trapezoid(edges, acc, lo, hi, h0, h1);
                            }
                            Emit::Gaussian(c, sg, area) => bins.add(g, acc, line0 + i, c, sg, area),
                        }
                        Ok(())
                    },
                )?;
            }
        }
    }
    bins.flush(g, acc);
    Ok(())
}

/// Renders a spectral cube: one orthographic ray per pixel of `settings` (use
/// [`los_camera`] for a view along any direction), channels from `spec`, lines
/// [`CubeSpec::line_width_nm`] wide (one channel unless `spec.line_width` is
/// [`CubeLineWidth::Settings`]). Rows run in
/// parallel, each pixel independently (deterministic on any thread count). Needs the
/// piecewise-linear integrator; `progress` is called once per finished row.
pub fn render_cube(
    scene: &DopplerScene,
    settings: &DopplerSettings,
    spec: &CubeSpec,
    progress: &(dyn Fn() + Sync),
) -> Result<SpectralCube> {
    render_cube_with(scene, settings, spec, &RowCallback(progress))
}

/// Calls a plain closure once per finished row.
struct RowCallback<'a>(&'a (dyn Fn() + Sync));

impl Observer<DopplerImage> for RowCallback<'_> {
    fn progress(&self, _: Progress) {
        (self.0)();
    }
}

/// [`render_cube`] under an observer: progress once per finished row, cancel polled before
/// each pixel ([`Error::Cancelled`]).
pub(crate) fn render_cube_with(
    scene: &DopplerScene,
    settings: &DopplerSettings,
    spec: &CubeSpec,
    observer: &dyn Observer<DopplerImage>,
) -> Result<SpectralCube> {
    let plan = CubePlan::new(settings, spec)?;
    let rows = plan.rows(scene, None, None, 0..plan.h, observer)?;
    plan.assemble(rows.iter().map(Vec::as_slice))
}

/// A checked cube render: the settings with the lines' width, the image size and the pixel
/// size ([`render_cube`]'s arithmetic, shared with the partial renders of
/// [`crate::part`]).
pub(crate) struct CubePlan<'a> {
    settings: std::borrow::Cow<'a, DopplerSettings>,
    spec: CubeSpec,
    pub(crate) w: usize,
    pub(crate) h: usize,
    ph: f64,
}

impl<'a> CubePlan<'a> {
    /// Checks the integrator, the channels, the projection and the size.
    pub(crate) fn new(settings: &'a DopplerSettings, spec: &CubeSpec) -> Result<Self> {
        if settings.integrator != SpectralIntegrator::PiecewiseLinear {
            return Err(Error::parameter(
                "spectral cubes need the piecewise-linear integrator",
            ));
        }
        spec.validate(settings.range_nm)?;
        let ph = match settings.camera.projection {
            Projection::Orthographic { height } => f64::from(height) / f64::from(settings.height),
            Projection::Perspective { .. } => {
                return Err(Error::parameter(
                    "spectral cubes need an orthographic camera",
                ));
            }
        };
        // The rays' light over the cube's window only: light at one wavelength never
        // reaches another (each sample's shift is applied to its own lines), so lines,
        // depths and continuum outside the window cannot change a channel (a thermally
        // broadened Enzo ray's whole 380-780 nm spectrum once went past the piece budget,
        // and the budget's coarser merges raised the window's continuum: +98 % in a 32x32
        // H-alpha cube).
        let (lo, hi) = (spec.edge_nm(0), spec.edge_nm(spec.channels));
        let line_width_nm = match spec.line_width {
            CubeLineWidth::Settings => settings.line_width_nm,
            CubeLineWidth::OneChannel => spec.line_width_nm(settings),
        };
        let settings: std::borrow::Cow<'_, DopplerSettings> =
            std::borrow::Cow::Owned(DopplerSettings {
                line_width_nm,
                range_nm: (lo.min(hi), lo.max(hi)),
                ..settings.clone()
            });
        let (w, h) = (settings.width as usize, settings.height as usize);
        w.checked_mul(h)
            .and_then(|n| n.checked_mul(spec.channels))
            .filter(|&n| n <= 1 << 30)
            .ok_or_else(|| Error::parameter("cube larger than 2^30 values"))?;
        Ok(Self {
            settings,
            spec: *spec,
            w,
            h,
            ph,
        })
    }

    /// The settings the rays use (the lines' box width applied).
    pub(crate) fn settings(&self) -> &DopplerSettings {
        &self.settings
    }

    /// Image rows `rows` (top row 0), each `w x channels` values (x, then channel), of the
    /// segments inside `clip` (all of them for `None`). `front`, for an absorbing scene cut
    /// by `clip`: the optical depth in front of the box per pixel of the whole image
    /// (row-major; `None` or an empty entry: nothing in front), behind which each pixel's
    /// light is marched.
    pub(crate) fn rows(
        &self,
        scene: &DopplerScene,
        clip: Option<&blueshift_camera::ClipBox>,
        front: Option<&[Vec<Piece>]>,
        rows: std::ops::Range<usize>,
        observer: &dyn Observer<DopplerImage>,
    ) -> Result<Vec<Vec<f64>>> {
        let (spec, settings, w) = (&self.spec, self.settings(), self.w);
        let mut ctx = Context::new(scene, settings)?;
        if let Some(f) = front
            && f.len() != w * self.h
        {
            return Err(Error::parameter(format!(
                "front depth: {} pixels given, the cube has {}",
                f.len(),
                w * self.h
            )));
        }
        ctx.clip = clip.copied();
        let edges: Vec<f64> = (0..=spec.channels).map(|i| spec.edge_nm(i)).collect();
        // Absorbing rays take the window's lines as they come (cube_abs).
        let lines = if ctx.absorbing {
            Vec::new()
        } else {
            reachable_lines(&ctx, &edges)
        };
        let window = if ctx.absorbing {
            Some(super::cube_abs::Window::new(&ctx, &edges)?)
        } else {
            None
        };
        let done = AtomicU64::new(0);
        let total = rows.len() as u64;
        let out: Vec<Result<Vec<f64>>> = rows
            .into_par_iter()
            .map(|y| {
                if observer.cancelled() {
                    return Err(Error::Cancelled);
                }
                let mut bins = LineBins::new(&edges, spec, lines.iter().map(Vec::len).sum());
                let mut row = vec![0.0; w * spec.channels];
                let mut scratch = super::cube_abs::Scratch::default();
                for (x, acc) in row.chunks_exact_mut(spec.channels).enumerate() {
                    // Per pixel too: an absorbing, broadened row can take seconds.
                    if observer.cancelled() {
                        return Err(Error::Cancelled);
                    }
                    let ray = settings.ray(x as f32 + 0.5, y as f32 + 0.5);
                    let f = front.map_or(&[][..], |f| &f[y * w + x][..]);
                    match &window {
                        Some(win) => {
                            super::cube_abs::ray_channels(&ctx, win, &ray, f, acc, &mut scratch)?
                        }
                        None => ray_channels(&ctx, &lines, &ray, &edges, &mut bins, acc)?,
                    }
                }
                observer.progress(Progress {
                    done: done.fetch_add(1, Ordering::Relaxed) + 1,
                    total,
                    pass: 0,
                });
                Ok(row)
            })
            .collect();
        scene.check_io()?;
        out.into_iter().collect()
    }

    /// The optical depth over the cube's window of the segments inside `clip`, per pixel
    /// (row-major; empty entries for a scene that does not absorb): the depth in front that
    /// the boxes behind take in [`Self::rows`].
    pub(crate) fn optical_depths(
        &self,
        scene: &DopplerScene,
        clip: &blueshift_camera::ClipBox,
    ) -> Result<Vec<Vec<Piece>>> {
        let settings = self.settings();
        let mut ctx = Context::new(scene, settings)?;
        ctx.clip = Some(*clip);
        if !ctx.absorbing {
            return Ok(vec![Vec::new(); self.w * self.h]);
        }
        let edges: Vec<f64> = (0..=self.spec.channels)
            .map(|i| self.spec.edge_nm(i))
            .collect();
        let window = super::cube_abs::Window::new(&ctx, &edges)?;
        let rows: Vec<Result<Vec<Vec<Piece>>>> = (0..self.h)
            .into_par_iter()
            .map(|y| {
                (0..self.w)
                    .map(|x| {
                        let ray = settings.ray(x as f32 + 0.5, y as f32 + 0.5);
                        super::cube_abs::total_depth(&ctx, &window, &ray)
                    })
                    .collect()
            })
            .collect();
        scene.check_io()?;
        let mut out = Vec::with_capacity(self.w * self.h);
        for row in rows {
            out.extend(row?);
        }
        Ok(out)
    }

    /// The cube of every image row (top row first, as [`Self::rows`] gives them).
    pub(crate) fn assemble<'r>(
        &self,
        rows: impl ExactSizeIterator<Item = &'r [f64]>,
    ) -> Result<SpectralCube> {
        let (w, h, nc) = (self.w, self.h, self.spec.channels);
        if rows.len() != h {
            return Err(Error::parameter(format!(
                "cube: {} rows given, the image has {h}",
                rows.len()
            )));
        }
        let mut data = vec![0.0f32; w * h * nc];
        for (y, row) in rows.enumerate() {
            if row.len() != w * nc {
                return Err(Error::parameter(format!(
                    "cube row {y}: {} values, expected {}",
                    row.len(),
                    w * nc
                )));
            }
            let fy = h - 1 - y;
            for (x, acc) in row.chunks_exact(nc).enumerate() {
                for (k, &v) in acc.iter().enumerate() {
                    let f = v as f32;
                    if !f.is_finite() {
                        // Factors or units far out of range (a temperature factor of 1e300
                        // makes the lines' widths, and the black body, overflow).
                        return Err(Error::parameter(format!(
                            "cube: pixel ({x}, {y}) channel {k} is {v} (not finite in f32): the \
                             scene's factors or units are out of range"
                        )));
                    }
                    data[(k * h + fy) * w + x] = f;
                }
            }
        }
        Ok(SpectralCube {
            nx: w,
            ny: h,
            spec: self.spec,
            data,
            pixel_world: (self.ph, self.ph),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The kink form gives each channel the exact integral of the piecewise-linear
    /// Gaussians, as the CDF at every edge does: on all three axes (uniform and non-uniform
    /// edges), with Gaussians inside, across and outside the window, summed on one ray.
    #[test]
    fn kink_bins_equal_the_cdf_at_every_edge() {
        let g = PwlGaussian::default();
        for axis in [
            SpectralAxis::OpticalVelocity,
            SpectralAxis::RadioVelocity,
            SpectralAxis::Wavelength,
        ] {
            let (min, max) = match axis {
                SpectralAxis::Wavelength => (656.0, 656.6),
                _ => (-300e3, 300e3),
            };
            let spec = CubeSpec {
                rest_nm: 656.2816,
                axis,
                min,
                max,
                channels: 128,
                line_width: CubeLineWidth::Settings,
            };
            let edges: Vec<f64> = (0..=spec.channels).map(|i| spec.edge_nm(i)).collect();
            let mut kinks = KinkBins::new(&edges, &spec);
            let mut by_kinks = vec![0.0; spec.channels];
            let mut by_cdf = vec![0.0; spec.channels];
            // Centres from below the window to above it, widths from 5 to 60 channels.
            let (lo, hi) = (edges[0], edges[spec.channels]);
            for i in 0..40 {
                let t = f64::from(i) / 39.0;
                let c = lo - 0.3 * (hi - lo) + 1.6 * (hi - lo) * t;
                let sigma = (hi - lo) / 128.0 * (5.0 + 55.0 * ((7 * i) % 11) as f64 / 10.0) / 8.0;
                let area = 1.0 + f64::from(i % 5);
                kinks.add_gaussian(&g, c, sigma, area);
                bin_gaussian(&g, &edges, &mut by_cdf, c, sigma, area);
            }
            kinks.flush(&mut by_kinks);
            let total: f64 = by_cdf.iter().sum();
            assert!(total > 10.0, "{axis}: the window holds most of the area");
            for k in 0..spec.channels {
                assert!(
                    (by_kinks[k] - by_cdf[k]).abs() <= 1e-11 * total,
                    "{axis} channel {k}: {} vs {}",
                    by_kinks[k],
                    by_cdf[k]
                );
            }
            // Flushing cleared the bins: a second ray starts from zero.
            let mut again = vec![0.0; spec.channels];
            kinks.flush(&mut again);
            assert!(again.iter().all(|&v| v == 0.0));
        }
    }

    /// Runs of Gaussians drifting in centre and width, merged by [`GaussRun`]: each merged
    /// Gaussian keeps the run's area and mean, and differs from the true sum of its members
    /// (exact Gaussian densities) by at most 0.25 % of the sum's peak; slowly drifting
    /// Gaussians merge four or more to a run, and far-apart or very unequal Gaussians are refused.
    #[test]
    fn merged_runs_stay_within_the_stated_error() {
        let density = |x: f64, c: f64, s: f64, a: f64| {
            let z = (x - c) / s;
            a * (-0.5 * z * z).exp() / (s * (2.0 * std::f64::consts::PI).sqrt())
        };
        let mut state = 0x2545_f491_4f6c_dd1d_u64;
        let mut uniform = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let (mut worst, mut runs, mut slow) = (0.0f64, 0, [0usize; 2]);
        for walk in 0..200 {
            // Drift per step: up to 0.05 sigma for the first walks, up to 0.8 for the last;
            // widths change by up to a fifth of that fraction.
            let drift = 0.05 + 0.75 * f64::from(walk) / 199.0;
            let (mut c, mut sigma) = (656.0, 0.05 + 0.2 * uniform());
            let mut run = GaussRun::EMPTY;
            let mut members: Vec<(f64, f64, f64)> = Vec::new();
            for _ in 0..60 {
                c += drift * sigma * (2.0 * uniform() - 1.0);
                sigma *= 1.0 + 0.2 * drift * (2.0 * uniform() - 1.0);
                let area = 0.05 + 2.0 * uniform();
                if run.try_add(c, sigma, area) {
                    members.push((c, sigma, area));
                    continue;
                }
                let (mc, ms, ma) = run.take();
                let total: f64 = members.iter().map(|m| m.2).sum();
                let mean = members.iter().map(|m| m.0 * m.2).sum::<f64>() / total;
                assert!((ma - total).abs() <= 1e-12 * total, "area {ma} vs {total}");
                assert!((mc - mean).abs() <= 1e-9 * ms, "mean {mc} vs {mean}");
                let (mut err, mut peak) = (0.0f64, 0.0f64);
                for i in 0..=4000 {
                    let x = mc + ms * (-8.0 + 16.0 * f64::from(i) / 4000.0);
                    let sum: f64 = members.iter().map(|&(c, s, a)| density(x, c, s, a)).sum();
                    err = err.max((sum - density(x, mc, ms, ma)).abs());
                    peak = peak.max(sum);
                }
                worst = worst.max(err / peak);
                runs += 1;
                if drift < 0.2 {
                    slow[0] += 1;
                    slow[1] += members.len();
                }
                members.clear();
                assert!(run.is_empty() && run.try_add(c, sigma, area));
                members.push((c, sigma, area));
            }
        }
        let per_run = slow[1] as f64 / slow[0] as f64;
        println!(
            "{runs} runs, worst error {worst:.2e} of the peak; slow drifts: {per_run:.1} per run"
        );
        assert!(worst <= 2.5e-3, "worst error {worst:.3e} of the peak");
        // The estimate's worst case (found in review): a weak narrow Gaussian beside a strong
        // wide one at the same centre, where the true error is about twice the estimate.
        for (area, wide) in [(0.0178, 1.49), (0.03, 1.45), (0.01, 1.3), (0.05, 1.4)] {
            let mut r = GaussRun::EMPTY;
            assert!(r.try_add(656.0, 0.1, area));
            if r.try_add(656.0, 0.1 * wide, 1.0) {
                let (mc, ms, ma) = r.take();
                let (mut err, mut peak) = (0.0f64, 0.0f64);
                for i in 0..=4000 {
                    let x = mc + ms * (-8.0 + 16.0 * f64::from(i) / 4000.0);
                    let sum = density(x, 656.0, 0.1, area) + density(x, 656.0, 0.1 * wide, 1.0);
                    err = err.max((sum - density(x, mc, ms, ma)).abs());
                    peak = peak.max(sum);
                }
                assert!(err / peak <= 2.5e-3, "{area} {wide}: {:.3e}", err / peak);
            }
        }
        assert!(
            runs > 500 && per_run >= 4.0,
            "{runs} runs; {per_run} per slow run"
        );
        // Refused: centres three sigma apart; widths a factor 1.6 apart.
        let mut r = GaussRun::EMPTY;
        assert!(r.try_add(656.0, 0.1, 1.0));
        assert!(!r.try_add(656.3, 0.1, 1.0));
        assert!(!r.try_add(656.0, 0.16, 1.0));
        assert!(r.try_add(656.01, 0.1, 1.0));
        // A single Gaussian comes back exactly.
        let mut one = GaussRun::EMPTY;
        assert!(one.try_add(656.123, 0.0456, 2.5));
        assert_eq!(one.take(), (656.123, 0.0456, 2.5));
    }
}
