//! Settings, ray sampling and the image loop shared by both integrators.

use blueshift_camera::{Observer, Progress, ProgressOnly};
use blueshift_spectrum::{DopplerModel, PiecewiseLinear, WavelengthShift, Xyz};
use glam::Vec3;
use rayon::prelude::*;
use std::sync::atomic::{AtomicU64, Ordering};

use super::model::{BB_UNIT, DopplerScene};
use super::prepared::{Prepared, RaySpan};
use super::{banded, pwl};
use crate::{Camera, Error, Ray, Result};
use blueshift_camera::named_enum;
use blueshift_relativity::MovingObserver;

/// How the banded integrator moves band values under a Doppler shift; spelt as the banded
/// integrators' prefix: `banded` (nearest) or `banded-ec` (energy-conserving).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BandShift {
    /// The paper's Algorithm 1: each rest-frame band value moves whole into the band holding
    /// `s` times its centre (apparent lines, a velocity threshold that depends on N).
    Nearest,
    /// Each line's shifted box is spread over the bands it overlaps (energy-conserving).
    EnergyConserving,
}

// The spellings are the banded integrators' (`banded:N`, `banded-ec:N`).
named_enum!(BandShift, "band shift", [Nearest => "banded", EnergyConserving => "banded-ec"]);

/// The spectral representation; spelt `pwl`, `banded:N` or `banded-ec:N` (`FromStr`,
/// `Display` and serde through the string).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SpectralIntegrator {
    /// Algorithm 2: exact piecewise-linear spectra (emission-only rays accumulate XYZ
    /// directly in closed form).
    PiecewiseLinear,
    /// Algorithm 1: `bands` equal bands over the wavelength range.
    Banded {
        /// Number of bands (>= 1).
        bands: usize,
        /// Shift rule.
        shift: BandShift,
    },
}

impl std::str::FromStr for SpectralIntegrator {
    type Err = Error;
    /// `pwl`, `banded:N` (nearest shift, the paper's) or `banded-ec:N` (energy-conserving).
    fn from_str(s: &str) -> Result<Self> {
        let s = s.trim();
        if s.eq_ignore_ascii_case("pwl") {
            return Ok(Self::PiecewiseLinear);
        }
        let (kind, n) = s.split_once(':').ok_or_else(|| {
            Error::parameter(format!(
                "integrator '{s}': use pwl, banded:N or banded-ec:N"
            ))
        })?;
        let bands: usize = n
            .parse()
            .map_err(|_| Error::parameter(format!("integrator '{s}': N must be an integer")))?;
        if !(1..=1_000_000).contains(&bands) {
            return Err(Error::parameter(format!(
                "integrator '{s}': N must be 1..=1000000"
            )));
        }
        let shift = kind.parse::<BandShift>().map_err(|_| {
            Error::parameter(format!(
                "integrator '{s}': use pwl, banded:N or banded-ec:N"
            ))
        })?;
        Ok(Self::Banded { bands, shift })
    }
}

impl std::fmt::Display for SpectralIntegrator {
    /// `pwl`, `banded:N` or `banded-ec:N` (what [`std::str::FromStr`] reads).
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::PiecewiseLinear => f.write_str("pwl"),
            Self::Banded { bands, shift } => write!(f, "{shift}:{bands}"),
        }
    }
}

blueshift_camera::serde_via_str!(SpectralIntegrator);

/// Render settings.
#[derive(Clone, Debug)]
pub struct DopplerSettings {
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// The camera (by default orthographic, the observer on the +z side looking towards -z).
    pub camera: Camera,
    /// Ray step in world units; `None`: half the smallest voxel spacing.
    pub step: Option<f32>,
    /// Doppler formula.
    pub model: DopplerModel,
    /// Use the relativistic radiance transform (`I_nu / nu^3` invariant) instead of the
    /// energy-conserving `k = 1 / s`.
    pub invariant: bool,
    /// The integrator.
    pub integrator: SpectralIntegrator,
    /// Wavelength range, nm.
    pub range_nm: (f64, f64),
    /// Minimum (rest) width of a line, nm.
    pub line_width_nm: f64,
    /// Wavelength samples of black bodies (piecewise-linear integrator), >= 2.
    pub blackbody_samples: usize,
    /// Error budget for a whole ray (piecewise-linear with absorption): the image path's XYZ
    /// stays within this fraction of the unattenuated emission's XYZ, per channel (merges of
    /// the optical depth in front, negligible absorption and line light left out; see the
    /// module docs), a kept spectrum within this fraction of its maximum.
    pub merge_tolerance: f64,
    /// Per-ray piece budget: when the optical depth (image path) or the spectrum (picks,
    /// traces) exceeds it, it is merged with 4 times the tolerance until it fits (the preview
    /// fallback, which gives up the bound; the rays that needed it are counted).
    pub piece_budget: usize,
    /// Largest optical-depth change inside one attenuated sub-piece of a kept spectrum (its
    /// chord errs by at most `max_depth_step^2 / 8` of the value per attenuation): picked
    /// pixels' spectra and traces; images and cubes integrate the attenuation in closed form.
    pub max_depth_step: f64,
    /// Line profile beyond the box: thermal and/or a Gaussian width (piecewise-linear
    /// integrator and cubes, emission and absorption lines; the banded integrators refuse it).
    pub broadening: super::profile::Broadening,
    /// Treat voxels as cells: rays cross the box of the voxel CENTRES grown by half a
    /// spacing on every side (values clamped at the edges), as cell-centred simulation
    /// codes (Enzo, yt) see their domain. Default false: the box of the voxel centres.
    pub cell_domain: bool,
    /// A moving observer (`None`: at rest in the volume's frame). Each pixel's ray is
    /// aberrated into the volume's frame and every sample's wavelength shift is composed with
    /// the observer's Doppler factor along the ray ([`MovingObserver`]); with
    /// [`DopplerSettings::invariant`] the brightness follows the searchlight effect.
    pub observer: Option<MovingObserver>,
}

impl DopplerSettings {
    /// Defaults for a scene: `width x height`, the orthographic view from +z (yt's; x right, y up) through the
    /// volume's centre framing its x-y extent, step half a voxel, classical Doppler,
    /// piecewise-linear, 380-780 nm, lines 1 nm wide, 32 black-body samples, merge 1e-4,
    /// budget 4096 pieces.
    #[must_use]
    pub fn default_for(scene: &DopplerScene, width: u32, height: u32) -> Self {
        let (lo, hi) = scene.frame_bounds(false);
        let aspect = width as f32 / height.max(1) as f32;
        Self {
            width,
            height,
            camera: Camera::default_view(lo, hi, aspect, true),
            step: None,
            model: DopplerModel::Classical,
            invariant: false,
            integrator: SpectralIntegrator::PiecewiseLinear,
            range_nm: (380.0, 780.0),
            line_width_nm: 1.0,
            blackbody_samples: 32,
            merge_tolerance: 1e-4,
            piece_budget: 4096,
            max_depth_step: 0.1,
            broadening: super::profile::Broadening::default(),
            cell_domain: false,
            observer: None,
        }
    }

    /// The ray through continuous pixel position `(px, py)`: the camera's ray, aberrated
    /// into the volume's frame for a moving observer.
    #[must_use]
    pub fn ray(&self, px: f32, py: f32) -> Ray {
        let mut ray = self.camera.ray(px, py, self.width, self.height);
        if let Some(o) = &self.observer {
            ray.dir = o.scene_direction(ray.dir);
        }
        ray
    }

    /// The observer's factor on every wavelength shift along a ray of scene-frame direction
    /// `dir` (`1 / D`; exactly 1 without a moving observer).
    #[must_use]
    pub fn observer_shift(&self, dir: Vec3) -> f64 {
        self.observer
            .filter(|o| !o.is_at_rest())
            .map_or(1.0, |o| o.wavelength_shift(dir.normalize()))
    }

    /// Views the scene as an astronomer inclines a disc: orthographic, the observer on the
    /// +z side tilted by `degrees` towards +y about the x axis through the volume's centre
    /// (0: face-on from +z, the default view; 90: edge-on from +y), world +x staying to the
    /// image's right, framing the projection of the volume's box.
    ///
    /// # Errors
    /// [`Error::Parameter`] when `degrees` is not finite or lies outside [-90, 90].
    pub fn incline(&mut self, scene: &DopplerScene, degrees: f32) -> Result<()> {
        if !(degrees.is_finite() && degrees.abs() <= 90.0) {
            return Err(Error::parameter(format!(
                "inclination {degrees} degrees must lie in [-90, 90]"
            )));
        }
        let (lo, hi) = scene.frame_bounds(false);
        let (si, ci) = degrees.to_radians().sin_cos();
        let normal = Vec3::new(0.0, si, ci);
        let up = Vec3::new(0.0, ci, -si);
        let aspect = self.width as f32 / self.height.max(1) as f32;
        self.camera = Camera::framing(lo, hi, normal, up, aspect, true, 30.0)?;
        Ok(())
    }

    /// Checks the settings against `scene` (as [`render_doppler`] does) and returns the ray
    /// step in world units (`step`, or half the smallest voxel spacing).
    pub fn validated_step(&self, scene: &DopplerScene) -> Result<f32> {
        self.validate(scene)
    }

    fn validate(&self, scene: &DopplerScene) -> Result<f32> {
        if self.width == 0
            || self.height == 0
            || u64::from(self.width) * u64::from(self.height) > 1 << 26
        {
            return Err(Error::parameter(format!(
                "image size {}x{} must be non-zero and at most 2^26 pixels",
                self.width, self.height
            )));
        }
        self.camera.validate()?;
        let (a, b) = self.range_nm;
        if !(a.is_finite() && b.is_finite() && a > 0.0 && a < b) {
            return Err(Error::parameter(format!("wavelength range {a}-{b} nm")));
        }
        if !(self.line_width_nm.is_finite() && self.line_width_nm > 0.0) {
            return Err(Error::parameter("line width must be finite and > 0"));
        }
        if !(2..=100_000).contains(&self.blackbody_samples) {
            return Err(Error::parameter("black-body samples must be 2..=100000"));
        }
        if !(self.merge_tolerance.is_finite() && self.merge_tolerance >= 0.0) {
            return Err(Error::parameter("merge tolerance must be finite and >= 0"));
        }
        if self.piece_budget < 8 {
            return Err(Error::parameter("piece budget must be >= 8"));
        }
        if !(self.max_depth_step.is_finite() && self.max_depth_step > 0.0) {
            return Err(Error::parameter(
                "max optical-depth step must be finite and > 0",
            ));
        }
        let f = scene.factors;
        for (n, v) in [
            ("velocity factor", f.velocity),
            ("temperature factor", f.temperature),
            ("emission factor", f.emission),
            ("absorption factor", f.absorption),
            ("black-body factor", f.blackbody),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(Error::parameter(format!("{n} {v} must be finite and >= 0")));
            }
        }
        let sp = scene.geometry.spacing;
        let step = self.step.unwrap_or(0.5 * sp.min_element());
        if !(step.is_finite() && step > 0.0) {
            return Err(Error::parameter(format!(
                "step {step} must be finite and > 0"
            )));
        }
        let (lo, hi) = scene.frame_bounds(false);
        // In f64: the squared diagonal of a volume in centimetres overflows f32.
        let diag = (hi - lo).as_dvec3().length();
        if diag / f64::from(step) > 1.0e6 {
            return Err(Error::parameter(format!(
                "step {step} gives more than 1e6 steps per ray"
            )));
        }
        Ok(step)
    }
}

/// The samples of one ray, far to near (the light's direction).
#[derive(Debug, Default)]
pub(crate) struct RaySamples {
    /// Path position of each sample (distance from the ray's entry), far first.
    pub t: Vec<f32>,
    /// Densities, `species.len()` per sample.
    pub rho: Vec<f64>,
    /// Black-body density x factor x BB_UNIT.
    pub bb: Vec<f64>,
    /// Temperature x factor, K (thermal broadening).
    pub temp: Vec<f64>,
    /// The black body's temperature x factor, K: the brightness temperature of the
    /// interpolated emission (see [`DopplerScene::set_blackbody`]).
    pub bb_temp: Vec<f64>,
    /// Wavelength shift s.
    pub shift: Vec<f64>,
    /// Radial velocity (scaled), m/s.
    pub v_r: Vec<f64>,
}

impl RaySamples {
    pub fn len(&self) -> usize {
        self.t.len()
    }
}

/// A render's view of the scene, its settings and their [`Prepared`] tables (owned when the
/// caller did not prepare them).
#[derive(Debug)]
pub(crate) struct Context<'a> {
    pub scene: &'a DopplerScene,
    pub settings: &'a DopplerSettings,
    prep: Prep<'a>,
    /// Keep only the segments whose middle lies in this box (distributed rendering).
    pub clip: Option<blueshift_camera::ClipBox>,
    /// How far (optical depth) a given depth in front already strays from the exact one
    /// (chords taken before it was sent: distributed rendering); the sweep's chords take
    /// the rest of their budget.
    pub front_eps: f64,
}

#[derive(Debug)]
enum Prep<'a> {
    Owned(Box<Prepared>),
    Borrowed(&'a Prepared),
}

impl std::ops::Deref for Context<'_> {
    type Target = Prepared;
    fn deref(&self) -> &Prepared {
        match &self.prep {
            Prep::Owned(p) => p,
            Prep::Borrowed(p) => p,
        }
    }
}

impl<'a> Context<'a> {
    /// Validates and prepares `scene` + `settings` (see [`Prepared::new`]).
    pub fn new(scene: &'a DopplerScene, settings: &'a DopplerSettings) -> Result<Self> {
        Ok(Self {
            scene,
            settings,
            prep: Prep::Owned(Box::new(Prepared::new(scene, settings)?)),
            clip: None,
            front_eps: 0.0,
        })
    }

    /// A context over tables prepared earlier for the same scene and settings.
    pub fn with_prepared(
        scene: &'a DopplerScene,
        settings: &'a DopplerSettings,
        prepared: &'a Prepared,
    ) -> Self {
        Self {
            scene,
            settings,
            prep: Prep::Borrowed(prepared),
            clip: None,
            front_eps: 0.0,
        }
    }

    /// The shift factor `k(s)` applied to observed values.
    pub fn value_factor(&self, s: f64) -> f64 {
        if self.settings.invariant {
            s.powi(-5)
        } else {
            1.0 / s
        }
    }

    /// Samples a ray back to front. Returns an empty set if the ray misses the volume.
    /// The black body is sampled only where it shines (a zero factor makes its samples
    /// zero, and they are read only where its density is positive), the gas temperature
    /// only for thermal broadening or the black body: absent samples are zero.
    pub fn sample(&self, ray: &Ray) -> Result<RaySamples> {
        let blackbody = self.scene.factors.blackbody != 0.0;
        self.sample_with(ray, blackbody, self.profiles.active)
    }

    /// The factor-independent part of [`Context::sample`]: the trilinear values along the
    /// ray, before any of the scene's factors (kept by sessions across factor edits).
    pub fn sample_raw(&self, ray: &Ray) -> RawSamples {
        self.sample_raw_with(ray, true, true)
    }

    /// [`Context::sample`] for emission lines alone (spectral cubes): no black-body
    /// densities or temperatures (their samples are zero), and the gas temperature only when
    /// `temperature` (thermal broadening). The other samples are [`Context::sample`]'s bits.
    pub(crate) fn sample_lines(&self, ray: &Ray, temperature: bool) -> Result<RaySamples> {
        self.sample_with(ray, false, temperature)
    }

    /// [`Context::sample_raw_with`] then the factors and the Doppler model.
    fn sample_with(&self, ray: &Ray, blackbody: bool, temperature: bool) -> Result<RaySamples> {
        let mut raw = self.sample_raw_with(ray, blackbody, temperature);
        let (t, rho) = (std::mem::take(&mut raw.t), std::mem::take(&mut raw.rho));
        self.finish_with(&raw, t, rho)
    }

    /// [`Context::sample_raw`], the black body's samples only when `blackbody` and the
    /// temperature only when `temperature` (or `blackbody`).
    fn sample_raw_with(&self, ray: &Ray, blackbody: bool, temperature: bool) -> RawSamples {
        let g = &self.scene.geometry;
        let mut out = RawSamples::default();
        let Some(span) = RaySpan::clip(self.scene, self.settings, self.step, ray) else {
            return out;
        };
        let (t0, len, n_seg) = (span.t0, span.len, span.n_seg as usize);
        let path = |i: usize| {
            if i == n_seg {
                len
            } else {
                (i as f32 * self.step).min(len)
            }
        };
        // With a clip box: the segments whose middle lies inside (a contiguous run, as the
        // box is convex and the middles' coordinates are monotonic along the ray), sampled
        // at their global positions; an empty run gives no samples.
        let (first, last) = match &self.clip {
            None => (0, n_seg),
            Some(c) => {
                let inside = |g: usize| c.contains(ray.at(t0 + 0.5 * (path(g) + path(g + 1))));
                match (0..n_seg).position(inside) {
                    None => return out,
                    Some(a) => (a, a + (a..n_seg).take_while(|&g| inside(g)).count()),
                }
            }
        };
        let dir = ray.dir.normalize();
        out.los = [f64::from(dir.x), f64::from(dir.y), f64::from(dir.z)];
        // Exact capacities, so kept samples take what the session's budget counts.
        let n = last - first + 1;
        out.t.reserve_exact(n);
        out.rho.reserve_exact(n * self.scene.species.len());
        let temperature = temperature || blackbody;
        if self.scene.blackbody.is_some() {
            if blackbody {
                out.bb.reserve_exact(n);
                out.bb_temp.reserve_exact(n);
            }
            if temperature {
                out.temp.reserve_exact(n);
            }
        }
        if self.scene.velocity.is_some() {
            out.vel.reserve_exact(n);
        }
        for i in (first..=last).rev() {
            let t = path(i);
            let p = g.world_to_index(ray.at(t0 + t));
            out.t.push(t);
            for sp in &self.scene.species {
                out.rho
                    .push(f64::from(sp.density.sample_scalar_index(p)).max(0.0));
            }
            if let (Some((d, temp)), Some(rho_t)) = (&self.scene.blackbody, &self.scene.rho_t) {
                // Thermal broadening takes the interpolated T; the black body the brightness
                // temperature of the interpolated emission (see
                // DopplerScene::set_blackbody), not B of the interpolated T.
                if temperature {
                    out.temp
                        .push(f64::from(temp.sample_scalar_index(p)).max(0.0));
                }
                if blackbody {
                    let rho = f64::from(d.sample_scalar_index(p)).max(0.0);
                    out.bb.push(rho);
                    let g = f64::from(rho_t.sample_scalar_index(p)).max(0.0);
                    out.bb_temp.push(if rho > 0.0 {
                        super::model::brightness_temperature(g / rho)
                    } else {
                        0.0
                    });
                }
            }
            if let Some(vg) = &self.scene.velocity {
                out.vel.push(vg.sample_index(p));
            }
        }
        out
    }

    /// Applies the scene's factors and the Doppler model to raw samples.
    pub fn finish(&self, raw: &RawSamples) -> Result<RaySamples> {
        self.finish_with(raw, raw.t.clone(), raw.rho.clone())
    }

    /// [`Context::finish`] with the path positions and densities given (moved out of `raw`).
    fn finish_with(&self, raw: &RawSamples, t: Vec<f32>, rho: Vec<f64>) -> Result<RaySamples> {
        let f = self.scene.factors;
        let n = t.len();
        let los = raw.los;
        let observer_shift =
            self.settings
                .observer_shift(Vec3::new(los[0] as f32, los[1] as f32, los[2] as f32));
        let mut out = RaySamples {
            t,
            rho,
            bb: Vec::with_capacity(n),
            temp: Vec::with_capacity(n),
            bb_temp: Vec::with_capacity(n),
            shift: Vec::with_capacity(n),
            v_r: Vec::with_capacity(n),
        };
        for i in 0..n {
            // Absent samples (no black body, or not asked for) are zero.
            let (bb, bb_temp) = match (raw.bb.get(i), raw.bb_temp.get(i)) {
                (Some(&b), Some(&t)) => (b * f.blackbody * BB_UNIT, t * f.temperature),
                _ => (0.0, 0.0),
            };
            out.bb.push(bb);
            out.bb_temp.push(bb_temp);
            out.temp
                .push(raw.temp.get(i).map_or(0.0, |&t| t * f.temperature));
            let v = match raw.vel.get(i) {
                Some(&v) => v * f.velocity as f32,
                None => Vec3::ZERO,
            };
            let v = [f64::from(v.x), f64::from(v.y), f64::from(v.z)];
            let s = WavelengthShift::from_velocity(self.settings.model, v, los)
                .map_err(|e| Error::parameter(format!("Doppler shift: {e}")))?;
            // The gas's shift composed with the observer's (relativistic composition of
            // the two velocities; a factor of exactly 1 at rest).
            out.shift.push(s.value() * observer_shift);
            out.v_r.push(v[0] * los[0] + v[1] * los[1] + v[2] * los[2]);
        }
        Ok(out)
    }
}

/// The samples of one ray before the scene's factors: what a factor edit does not change.
#[derive(Clone, Debug, Default)]
pub(crate) struct RawSamples {
    /// Path position of each sample, far first.
    pub t: Vec<f32>,
    /// Densities (>= 0), `species.len()` per sample.
    pub rho: Vec<f64>,
    /// Black-body density (>= 0), one per sample; empty without a black body.
    pub bb: Vec<f64>,
    /// Temperature (>= 0), K; empty without a black body.
    pub temp: Vec<f64>,
    /// The black body's temperature (>= 0), K; empty without a black body.
    pub bb_temp: Vec<f64>,
    /// Velocity, m/s, before the velocity factor; empty without a velocity field.
    pub vel: Vec<Vec3>,
    /// The ray's unit direction (the line of sight).
    pub los: [f64; 3],
}

/// Piece counts per ray: in images, the pieces of the optical depth in front kept by rays
/// with absorption (emission-only rays keep nothing and count 0); for picks and traces, the
/// kept spectrum's.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PieceStats {
    /// Mean over rays of the largest piece count a ray held.
    pub mean: f64,
    /// Largest piece count any ray held.
    pub max: usize,
    /// Rays that needed the piece-budget fallback.
    pub fallback_rays: usize,
}

/// An XYZ image (row 0 at the top) and the render's statistics.
#[derive(Clone, Debug)]
pub struct DopplerImage {
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// CIE 1931 XYZ per pixel, row-major.
    pub xyz: Vec<[f64; 3]>,
    /// Piece statistics.
    pub pieces: PieceStats,
}

/// One step of a traced ray: the spectrum after the segment ending at path position `t`.
#[derive(Clone, Debug)]
pub struct TraceStep {
    /// Distance (world units) of the segment's near end from the ray's entry.
    pub t: f32,
    /// Radial velocity at that end, m/s.
    pub radial_velocity_m_per_s: f64,
    /// The spectrum reaching that point (after this segment).
    pub spectrum: PiecewiseLinear,
}

/// Result of one ray.
#[derive(Debug, Default)]
pub(crate) struct RayOut {
    pub xyz: Xyz,
    pub max_pieces: usize,
    pub fallback: bool,
    pub spectrum: Option<PiecewiseLinear>,
    pub trace: Vec<TraceStep>,
}

/// What a ray must return besides XYZ.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Want {
    Xyz,
    Spectrum,
    Trace,
}

pub(crate) fn integrate(ctx: &Context<'_>, ray: &Ray, want: Want) -> Result<RayOut> {
    integrate_samples(ctx, &ctx.sample(ray)?, want)
}

/// Integrates a ray's samples with the context's integrator.
pub(crate) fn integrate_samples(
    ctx: &Context<'_>,
    samples: &RaySamples,
    want: Want,
) -> Result<RayOut> {
    if samples.len() < 2 {
        return Ok(RayOut {
            spectrum: (want != Want::Xyz).then(PiecewiseLinear::new),
            ..RayOut::default()
        });
    }
    match (&ctx.pwl, &ctx.banded) {
        (Some(t), _) => pwl::integrate(ctx, t, samples, want),
        (_, Some(t)) => banded::integrate(ctx, t, samples, want),
        _ => Err(Error::parameter("no integrator tables")),
    }
}

pub(crate) fn pixel_ray(settings: &DopplerSettings, x: u32, y: u32) -> Result<Ray> {
    if x >= settings.width || y >= settings.height {
        return Err(Error::parameter(format!(
            "pixel ({x}, {y}) outside the {}x{} image",
            settings.width, settings.height
        )));
    }
    Ok(settings.ray(x as f32 + 0.5, y as f32 + 0.5))
}

/// Renders the XYZ image; rows in parallel, each pixel independent (deterministic on any
/// thread count). `progress` is called once per finished row. [`crate::DopplerSession`]
/// keeps the prepared tables between renders and takes an observer (progress, cancel).
pub fn render_doppler(
    scene: &DopplerScene,
    settings: &DopplerSettings,
    progress: &(dyn Fn() + Sync),
) -> Result<DopplerImage> {
    let ctx = Context::new(scene, settings)?;
    render_rows(&ctx, &RowCallback(progress))
}

/// The coarsest level of a scene whose fields are all bricked alike, checking that
/// `target` is one of its levels.
fn coarsest_level(scene: &DopplerScene, target: usize) -> Result<usize> {
    let levels = scene.levels().ok_or_else(|| {
        Error::parameter("progressive levels of detail need every field bricked (.bsv) alike")
    })?;
    let coarsest = levels.len() - 1;
    if target > coarsest {
        return Err(Error::parameter(format!(
            "level {target} of {} levels",
            levels.len()
        )));
    }
    Ok(coarsest)
}

/// Progressive levels of detail (HDR VolVis section 6.3) for a scene whose fields are all
/// bricked alike ([`DopplerScene::levels`]), given at level 0: pass 1 renders the coarsest
/// level, each further pass the next finer one, down to `target` (0: the exact image).
/// While a level renders, the bricks of the next finer one along every 16th pixel's ray are
/// prefetched on the cache's I/O thread, so each refinement finds most of its data loaded.
/// `observer` hears [`Observer::level`] before and [`Observer::pass`] after every pass,
/// and row progress within it; the last pass's image is returned, the same bytes as
/// [`render_doppler`] on `scene.at_level(target)`.
///
/// # Errors
/// A scene without levels, a target past the coarsest level, a brick that fails to read,
/// or [`Error::Cancelled`].
pub fn render_doppler_lod(
    scene: &DopplerScene,
    settings: &DopplerSettings,
    target: usize,
    observer: &dyn Observer<DopplerImage>,
) -> Result<DopplerImage> {
    render_doppler_lod_with(scene, settings, target, observer, &mut |s| {
        cpu_pass(s, settings, observer)
    })
}

/// [`render_doppler_lod`] with each level's image made by `image` (a GPU renders them
/// through one device pool): the same passes, prefetches and observer calls.
///
/// # Errors
/// As [`render_doppler_lod`], and `image`'s.
pub fn render_doppler_lod_with<E: From<Error>>(
    scene: &DopplerScene,
    settings: &DopplerSettings,
    target: usize,
    observer: &dyn Observer<DopplerImage>,
    image: &mut dyn FnMut(&DopplerScene) -> std::result::Result<DopplerImage, E>,
) -> std::result::Result<DopplerImage, E> {
    let coarsest = coarsest_level(scene, target)?;
    let rays = settings
        .camera
        .sparse_rays(settings.width, settings.height, 16);
    // The bricks of `level` along the rays (the fields alone: no scene to build).
    let prefetch = |level: usize| -> Result<()> {
        let fields = scene
            .fields()
            .into_iter()
            .filter_map(blueshift_volume::Field::as_bricked)
            .map(|b| b.at_level(level))
            .collect::<blueshift_volume::Result<Vec<_>>>()?;
        let refs: Vec<_> = fields.iter().collect();
        blueshift_volume::BrickedField::prefetch_along(&refs, &rays);
        Ok(())
    };
    prefetch(coarsest)?;
    let mut last = None;
    for (i, level) in (target..=coarsest).rev().enumerate() {
        let pass = i as u32 + 1;
        observer.level(pass, level);
        let s = scene.at_level(level)?;
        if level > target {
            prefetch(level - 1)?;
        }
        let img = image(&s)?;
        observer.pass(pass, &img, None);
        last = Some(img);
    }
    Ok(last.ok_or_else(|| Error::parameter("no level rendered"))?)
}

/// Progressive refinement brick by brick while the bricks load (HDR VolVis section 6.3): the
/// coarsest level first, then images in which every region (one brick of level `target`)
/// samples the finest level its cache holds there ([`DopplerScene::resident_view`]) while
/// level `target` loads along every 16th pixel's ray
/// ([`blueshift_volume::refine_while_loading`] says when that stops), then the image at
/// level `target`, returned: [`render_doppler`] on `scene.at_level(target)`.
///
/// `observer` hears [`Observer::level`] before each image (numbered from 1) with the
/// coarsest level it samples and [`Observer::pass`] after it; `on_step(step, at_level,
/// regions)` hears, before each image of mixed levels, how many regions sample level
/// `target`.
///
/// # Errors
/// As [`render_doppler_lod`].
pub fn render_doppler_bricks(
    scene: &DopplerScene,
    settings: &DopplerSettings,
    target: usize,
    observer: &dyn Observer<DopplerImage>,
    on_step: &mut dyn FnMut(u32, usize, usize),
) -> Result<DopplerImage> {
    render_doppler_bricks_with(scene, settings, target, observer, on_step, &mut |s| {
        cpu_pass(s, settings, observer)
    })
}

/// One pass of a progressive render on the CPU: `scene`'s image, with row progress and
/// cancellation forwarded to `observer`, and any brick that failed to read as an error.
fn cpu_pass(
    scene: &DopplerScene,
    settings: &DopplerSettings,
    observer: &dyn Observer<DopplerImage>,
) -> Result<DopplerImage> {
    let ctx = Context::new(scene, settings)?;
    let img = render_rows(&ctx, &ProgressOnly(observer))?;
    scene.check_io()?;
    Ok(img)
}

/// [`render_doppler_bricks`] with each image made by `image` (a GPU renders them through
/// one device pool, uploading only the bricks each view adds): the same passes, views and
/// observer calls.
///
/// # Errors
/// As [`render_doppler_bricks`], and `image`'s.
pub fn render_doppler_bricks_with<E: From<Error>>(
    scene: &DopplerScene,
    settings: &DopplerSettings,
    target: usize,
    observer: &dyn Observer<DopplerImage>,
    on_step: &mut dyn FnMut(u32, usize, usize),
    image: &mut dyn FnMut(&DopplerScene) -> std::result::Result<DopplerImage, E>,
) -> std::result::Result<DopplerImage, E> {
    let coarsest = coarsest_level(scene, target)?;
    let rays = settings
        .camera
        .sparse_rays(settings.width, settings.height, 16);
    let goal = scene.at_level(target)?;
    let fields: Vec<&blueshift_volume::BrickedField> = goal
        .fields()
        .into_iter()
        .filter_map(blueshift_volume::Field::as_bricked)
        .collect();
    blueshift_volume::BrickedField::prefetch_along(&fields, &rays);
    let image = std::cell::RefCell::new(image);
    let render =
        |s: &DopplerScene, pass: u32, level: usize| -> std::result::Result<DopplerImage, E> {
            observer.level(pass, level);
            let img = (image.borrow_mut())(s)?;
            observer.pass(pass, &img, None);
            Ok(img)
        };
    let mut step = 0;
    if coarsest > target {
        step = 1;
        render(&scene.at_level(coarsest)?, step, coarsest)?;
        step = blueshift_volume::refine_while_loading(
            &fields,
            &rays,
            2,
            || goal.resident_view().map_err(E::from),
            |step, view: DopplerScene, at_level, regions| {
                on_step(step, at_level, regions);
                let level = view
                    .fields()
                    .into_iter()
                    .filter_map(blueshift_volume::Field::as_bricked)
                    .map(blueshift_volume::BrickedField::coarsest_sampled_level)
                    .max()
                    .unwrap_or(target);
                render(&view, step, level).map(|_| ())
            },
            || observer.cancelled(),
        )?;
    }
    render(&goal, step + 1, target)
}

/// Calls a plain closure once per finished row.
struct RowCallback<'a>(&'a (dyn Fn() + Sync));

impl Observer<DopplerImage> for RowCallback<'_> {
    fn progress(&self, _: Progress) {
        (self.0)();
    }
}

/// The image loop: rows in parallel, `observer` told after each row and polled before it.
pub(crate) fn render_rows(
    ctx: &Context<'_>,
    observer: &dyn Observer<DopplerImage>,
) -> Result<DopplerImage> {
    Ok(render_rows_cached(ctx, observer, None, false)?.0)
}

/// [`render_rows`] over raw samples kept from an earlier render of the same view
/// (`cached`, one per pixel, row-major), or keeping this render's (`keep`) for the next.
pub(crate) fn render_rows_cached(
    ctx: &Context<'_>,
    observer: &dyn Observer<DopplerImage>,
    cached: Option<&[RawSamples]>,
    keep: bool,
) -> Result<(DopplerImage, Option<Vec<RawSamples>>)> {
    let settings = ctx.settings;
    let (w, h) = (settings.width, settings.height);
    let keep = keep && cached.is_none();
    let done = AtomicU64::new(0);
    type Row = (Vec<RayOut>, Vec<RawSamples>);
    let rows: Vec<Result<Row>> = (0..h)
        .into_par_iter()
        .map(|y| {
            if observer.cancelled() {
                return Err(Error::Cancelled);
            }
            let mut outs = Vec::with_capacity(w as usize);
            let mut raws = Vec::with_capacity(if keep { w as usize } else { 0 });
            for x in 0..w {
                let samples = match cached {
                    Some(c) => ctx.finish(&c[(y * w + x) as usize])?,
                    None if keep => {
                        let raw = ctx.sample_raw(&pixel_ray(settings, x, y)?);
                        let samples = ctx.finish(&raw)?;
                        raws.push(raw);
                        samples
                    }
                    None => ctx.sample(&pixel_ray(settings, x, y)?)?,
                };
                outs.push(integrate_samples(ctx, &samples, Want::Xyz)?);
            }
            observer.progress(Progress {
                done: done.fetch_add(1, Ordering::Relaxed) + 1,
                total: u64::from(h),
                pass: 0,
            });
            Ok((outs, raws))
        })
        .collect();
    // A brick that failed to read mid-render voids the image.
    ctx.scene.check_io()?;
    let mut kept = keep.then(|| Vec::with_capacity(w as usize * h as usize));
    let mut xyz = Vec::with_capacity(w as usize * h as usize);
    let (mut sum, mut max, mut fb) = (0.0f64, 0usize, 0usize);
    for row in rows {
        let (outs, raws) = row?;
        if let Some(k) = kept.as_mut() {
            k.extend(raws);
        }
        for r in outs {
            xyz.push(r.xyz.to_array());
            sum += r.max_pieces as f64;
            max = max.max(r.max_pieces);
            fb += usize::from(r.fallback);
        }
    }
    let n = xyz.len().max(1) as f64;
    let image = DopplerImage {
        width: w,
        height: h,
        xyz,
        pieces: PieceStats {
            mean: sum / n,
            max,
            fallback_rays: fb,
        },
    };
    observer.pass(1, &image, None);
    Ok((image, kept))
}

/// The final spectrum of pixel `(x, y)` (banded integrators give their step function).
pub fn pixel_spectrum(
    scene: &DopplerScene,
    settings: &DopplerSettings,
    x: u32,
    y: u32,
) -> Result<PiecewiseLinear> {
    let ctx = Context::new(scene, settings)?;
    let out = integrate(&ctx, &pixel_ray(settings, x, y)?, Want::Spectrum)?;
    Ok(out.spectrum.unwrap_or_default())
}

/// The step-by-step accumulation of pixel `(x, y)`'s ray: the spectrum after each segment,
/// back to front.
pub fn trace_ray(
    scene: &DopplerScene,
    settings: &DopplerSettings,
    x: u32,
    y: u32,
) -> Result<Vec<TraceStep>> {
    let ctx = Context::new(scene, settings)?;
    Ok(integrate(&ctx, &pixel_ray(settings, x, y)?, Want::Trace)?.trace)
}

/// Integrates one given ray (for tests and benches that build their own rays).
#[cfg(test)]
pub(crate) fn ray_spectrum(
    scene: &DopplerScene,
    settings: &DopplerSettings,
    ray: &Ray,
) -> Result<(Xyz, PiecewiseLinear)> {
    let ctx = Context::new(scene, settings)?;
    let o = integrate(&ctx, ray, Want::Spectrum)?;
    Ok((o.xyz, o.spectrum.unwrap_or_default()))
}
