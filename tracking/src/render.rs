//! Rendering an image: progressive accumulation of one sample per pixel per pass, with the
//! running mean and variance per pixel, rayon over rows, counter-based random numbers.

use blueshift_camera::{Observer, Progress, Silent};
use image::Rgba32FImage;
use rayon::prelude::*;

use crate::{Camera, Ray};
use blueshift_relativity::MovingObserver;
use std::time::Instant;

use crate::integrator::{Integrator, RayStats};
use crate::rng::Rng;
use crate::scene::Scene;
use crate::{Error, Result};

/// Largest image edge accepted, pixels.
pub const MAX_IMAGE_EDGE: u32 = 16_384;
/// Largest pixel count accepted (64 Mpixel).
pub const MAX_PIXELS: u64 = 1 << 26;

/// What to render and how long.
#[derive(Clone, Debug, PartialEq)]
pub struct RenderSettings {
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Samples per pixel (the maximum when `noise_target` is set); at least 1.
    pub spp: u32,
    /// Seed of the counter-based random numbers.
    pub seed: u64,
    /// The camera.
    pub camera: Camera,
    /// Stop early once [`Progressive::noise`] falls to this (after at least 2 passes).
    pub noise_target: Option<f64>,
    /// Jitter the sample position inside the pixel (anti-aliasing); off samples the centre.
    pub jitter_pixels: bool,
    /// Count the work per pixel for heat maps ([`Progressive::heatmap`]; MDWT Fig. 1g).
    /// Timing each sample costs a little.
    pub heatmaps: bool,
    /// The timing protocol of MDWT section 6: `Some(frames)` renders `warmup` frames of 1
    /// spp (discarded), then `frames` timed frames of 1 spp each, accumulated; `spp` and the
    /// noise target are then ignored and the run reports [`FrameTimes`].
    pub timed_frames: Option<u32>,
    /// Warm-up frames of the timing protocol (with [`RenderSettings::timed_frames`]).
    pub warmup: u32,
    /// A moving observer (`None`: at rest in the volume's frame): each pixel's ray is
    /// aberrated into the volume's frame and the colour it brings is shifted by the
    /// observer's Doppler factor along it (`K(D)`, times `D^4` with the searchlight;
    /// [`MovingObserver`]).
    pub observer: Option<MovingObserver>,
}

impl RenderSettings {
    /// Settings with the default view of `scene` (perspective unless `orthographic`),
    /// 1 sample per pixel, seed 0, pixel jitter on.
    #[must_use]
    pub fn default_for(scene: &Scene, width: u32, height: u32, orthographic: bool) -> Self {
        let (lo, hi) = scene.bounds();
        RenderSettings {
            width,
            height,
            spp: 1,
            seed: 0,
            camera: Camera::default_view(lo, hi, width as f32 / height.max(1) as f32, orthographic),
            noise_target: None,
            jitter_pixels: true,
            heatmaps: false,
            timed_frames: None,
            warmup: 0,
            observer: None,
        }
    }

    /// Checks sizes, sample count and camera.
    pub fn validate(&self) -> Result<()> {
        check_size(self.width, self.height)?;
        if self.spp == 0 {
            return Err(Error::parameter("spp: must be at least 1"));
        }
        if let Some(t) = self.noise_target
            && !(t >= 0.0 && t.is_finite())
        {
            return Err(Error::parameter(format!(
                "noise_target: {t} must be finite and non-negative"
            )));
        }
        if self.timed_frames == Some(0) {
            return Err(Error::parameter(
                "frames: at least one timed frame is needed",
            ));
        }
        Ok(self.camera.validate()?)
    }
}

fn check_size(width: u32, height: u32) -> Result<()> {
    if width == 0
        || height == 0
        || width > MAX_IMAGE_EDGE
        || height > MAX_IMAGE_EDGE
        || u64::from(width) * u64::from(height) > MAX_PIXELS
    {
        return Err(Error::parameter(format!(
            "image size {width}x{height}: each edge must be 1..={MAX_IMAGE_EDGE} and at most {MAX_PIXELS} pixels"
        )));
    }
    Ok(())
}

/// One sample of pixel `(x, y)` (RGBA; `sample` is the sample index of the counter-based
/// random numbers, `Rng::new(seed, pixel, sample)`): what every pass of the render loop
/// computes per pixel, so distributed renders (sample- or tile-parallel) compute the same
/// values. `observer` is the settings' observer when it moves (`None` at rest, which
/// leaves the colour untouched). `integrator` must be prepared for `scene`.
#[must_use]
pub fn pixel_sample(
    scene: &Scene,
    integrator: &Integrator,
    settings: &RenderSettings,
    observer: Option<&MovingObserver>,
    (x, y): (u32, u32),
    sample: u32,
    stats: &mut RayStats,
) -> [f32; 4] {
    let (ray, mut rng) = primary_ray(settings, observer, (x, y), sample);
    let v = integrator.li_with_stats(scene, &ray, &mut rng, stats);
    observed(observer, &ray, v)
}

/// The camera ray of sample `sample` of pixel `(x, y)` (jittered when the settings say so,
/// aberrated into the scene's frame by a moving `observer`) and the random stream after
/// the jitter: where [`pixel_sample`] starts the integrator.
#[must_use]
pub fn primary_ray(
    settings: &RenderSettings,
    observer: Option<&MovingObserver>,
    (x, y): (u32, u32),
    sample: u32,
) -> (Ray, Rng) {
    let (width, height) = (settings.width, settings.height);
    let pixel = u64::from(y) * u64::from(width) + u64::from(x);
    let mut rng = Rng::new(settings.seed, pixel, u64::from(sample));
    let (jx, jy) = if settings.jitter_pixels {
        (rng.uniform(), rng.uniform())
    } else {
        (0.5, 0.5)
    };
    let mut ray = settings
        .camera
        .ray(x as f32 + jx, y as f32 + jy, width, height);
    if let Some(o) = observer {
        ray.dir = o.scene_direction(ray.dir);
    }
    (ray, rng)
}

/// A sample's radiance `v` along `ray` as a moving `observer` sees it (Doppler and
/// searchlight; unchanged for `None`): where [`pixel_sample`] ends.
#[must_use]
pub fn observed(observer: Option<&MovingObserver>, ray: &Ray, mut v: [f32; 4]) -> [f32; 4] {
    if let Some(o) = observer {
        let rgb = o.shift_rgb(ray.dir.normalize(), [v[0], v[1], v[2]]);
        v[..3].copy_from_slice(&rgb);
    }
    v
}

/// Adds the `count`-th sample `v` to a pixel's running mean and sum of squared deviations
/// (Welford), in the render loop's arithmetic: accumulating the same samples in the same
/// order anywhere gives the same bits.
#[inline]
pub fn welford_add(mean: &mut [f64; 4], m2: &mut [f64; 4], v: [f32; 4], count: f64) {
    for c in 0..4 {
        let v = f64::from(v[c]);
        let d = v - mean[c];
        mean[c] += d / count;
        m2[c] += d * (v - mean[c]);
    }
}

/// A progressive accumulation buffer: per pixel the running mean and the sum of squared
/// deviations (Welford) of RGBA over the samples added so far.
#[derive(Clone, Debug)]
pub struct Progressive {
    width: u32,
    height: u32,
    samples: u32,
    heat_samples: u32,
    mean: Vec<[f64; 4]>,
    m2: Vec<[f64; 4]>,
    /// Per pixel sums of cells, tentative collisions, rejections and seconds (heat maps).
    heat: Option<Vec<[f64; 4]>>,
}

/// A per-pixel heat map of the work done ([`Progressive::enable_heatmaps`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum HeatMap {
    /// Mean DDA cells visited per sample (marcher: samples taken).
    Steps,
    /// Mean tentative collisions per sample.
    Collisions,
    /// Mean null-collision rejections per sample.
    Rejections,
    /// Mean time per sample, microseconds (measured, so not reproducible).
    Time,
}

impl HeatMap {
    /// All heat maps, in channel order.
    pub const ALL: [HeatMap; 4] = [
        HeatMap::Steps,
        HeatMap::Collisions,
        HeatMap::Rejections,
        HeatMap::Time,
    ];

    /// Its name (`steps`, `collisions`, `rejections`, `time`).
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            HeatMap::Steps => "steps",
            HeatMap::Collisions => "collisions",
            HeatMap::Rejections => "rejections",
            HeatMap::Time => "time",
        }
    }

    /// Its unit, for colour bars.
    #[must_use]
    pub fn unit(self) -> &'static str {
        match self {
            HeatMap::Steps => "DDA cells / sample",
            HeatMap::Collisions => "tentative collisions / sample",
            HeatMap::Rejections => "null collisions / sample",
            HeatMap::Time => "microseconds / sample",
        }
    }
}

impl std::str::FromStr for HeatMap {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        HeatMap::ALL
            .into_iter()
            .find(|h| h.name() == s)
            .ok_or_else(|| {
                Error::parameter(format!(
                    "heat map: unknown '{s}' (steps, collisions, rejections, time)"
                ))
            })
    }
}

impl std::fmt::Display for HeatMap {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

blueshift_camera::serde_via_str!(HeatMap);

impl Progressive {
    /// An empty buffer of `width x height` pixels.
    pub fn new(width: u32, height: u32) -> Result<Self> {
        check_size(width, height)?;
        let n = width as usize * height as usize;
        Ok(Progressive {
            width,
            height,
            samples: 0,
            heat_samples: 0,
            mean: vec![[0.0; 4]; n],
            m2: vec![[0.0; 4]; n],
            heat: None,
        })
    }

    /// A buffer from per-pixel moments computed elsewhere (a GPU backend's running mean and
    /// sum of squared deviations, row-major) after `samples` samples, so noise, variance and
    /// images come from this one implementation.
    ///
    /// # Errors
    /// A bad size, or `mean` / `m2` not one entry per pixel.
    pub fn from_moments(
        width: u32,
        height: u32,
        samples: u32,
        mean: Vec<[f64; 4]>,
        m2: Vec<[f64; 4]>,
    ) -> Result<Self> {
        check_size(width, height)?;
        let n = width as usize * height as usize;
        if mean.len() != n || m2.len() != n {
            return Err(Error::parameter(format!(
                "moments: {} means and {} squared deviations for {n} pixels",
                mean.len(),
                m2.len()
            )));
        }
        Ok(Progressive {
            width,
            height,
            samples,
            heat_samples: 0,
            mean,
            m2,
            heat: None,
        })
    }

    /// Starts counting the work per pixel for [`Progressive::heatmap`] (from the next pass
    /// on; the means are over the passes counted). Timing each sample costs a little.
    pub fn enable_heatmaps(&mut self) {
        if self.heat.is_none() {
            self.heat = Some(vec![[0.0; 4]; self.mean.len()]);
        }
    }

    /// The per-pixel mean of `map` over the samples counted (row-major), or `None` if heat
    /// maps were not enabled.
    #[must_use]
    pub fn heatmap(&self, map: HeatMap) -> Option<Vec<f32>> {
        let heat = self.heat.as_ref()?;
        let n = f64::from(self.heat_samples.max(1));
        let i = HeatMap::ALL.iter().position(|h| *h == map).unwrap_or(0);
        Some(heat.iter().map(|h| (h[i] / n) as f32).collect())
    }

    /// Samples per pixel accumulated so far.
    #[must_use]
    pub fn samples(&self) -> u32 {
        self.samples
    }

    /// Adds one sample per pixel (sample index = [`Progressive::samples`]). The result is
    /// identical for any number of threads: each pixel's numbers come from
    /// `Rng::new(seed, pixel, sample)` and each pixel's sums run in sample order.
    pub fn add_pass(
        &mut self,
        scene: &Scene,
        integrator: &Integrator,
        settings: &RenderSettings,
    ) -> Result<()> {
        settings.validate()?;
        let integrator = integrator.prepared(scene)?;
        self.add_prepared_pass(scene, &integrator, settings)
    }

    /// [`Progressive::add_pass`] with an integrator already prepared for `scene` and
    /// validated settings.
    pub(crate) fn add_prepared_pass(
        &mut self,
        scene: &Scene,
        integrator: &Integrator,
        settings: &RenderSettings,
    ) -> Result<()> {
        self.add_prepared_passes(scene, integrator, settings, 1)
    }

    /// `passes` passes in one parallel sweep over the rows: each pixel takes its samples
    /// `samples .. samples + passes` in order, so the sums are those of as many single
    /// passes, bit for bit.
    pub(crate) fn add_prepared_passes(
        &mut self,
        scene: &Scene,
        integrator: &Integrator,
        settings: &RenderSettings,
        passes: u32,
    ) -> Result<()> {
        if settings.width != self.width || settings.height != self.height {
            return Err(Error::parameter(
                "settings: image size differs from the accumulation buffer's",
            ));
        }
        let w = self.width as usize;
        let first = self.samples;
        let height = self.height;
        // At rest the observer changes nothing: skip it, so images keep their bytes.
        let observer = settings.observer.filter(|o| !o.is_at_rest());
        let mut no_heat = Vec::new();
        let counting = self.heat.is_some();
        let heat = self.heat.as_mut().unwrap_or(&mut no_heat);
        let mut heat_rows: Vec<&mut [[f64; 4]]> = if counting {
            heat.chunks_mut(w).collect()
        } else {
            (0..height).map(|_| &mut [][..]).collect()
        };
        self.mean
            .par_chunks_mut(w)
            .zip(self.m2.par_chunks_mut(w))
            .zip(heat_rows.par_iter_mut())
            .enumerate()
            .for_each(|(y, ((mean_row, m2_row), heat_row))| {
                for (x, sample) in (0..w).flat_map(|x| (first..first + passes).map(move |s| (x, s)))
                {
                    let count = f64::from(sample + 1);
                    let start = counting.then(Instant::now);
                    let mut stats = RayStats::default();
                    let v = pixel_sample(
                        scene,
                        integrator,
                        settings,
                        observer.as_ref(),
                        (x as u32, y as u32),
                        sample,
                        &mut stats,
                    );
                    if let Some(start) = start {
                        let h = &mut heat_row[x];
                        h[0] += f64::from(stats.cells);
                        h[1] += f64::from(stats.tentative);
                        h[2] += f64::from(stats.rejections);
                        h[3] += start.elapsed().as_secs_f64() * 1e6;
                    }
                    welford_add(&mut mean_row[x], &mut m2_row[x], v, count);
                }
            });
        // A brick that failed to read mid-pass voids the pass.
        scene.check_io()?;
        self.samples += passes;
        if counting {
            self.heat_samples += passes;
        }
        Ok(())
    }

    /// The mean image.
    #[must_use]
    pub fn mean_image(&self) -> Rgba32FImage {
        let data = self.mean.iter().flat_map(|p| p.map(|v| v as f32)).collect();
        Rgba32FImage::from_raw(self.width, self.height, data).unwrap_or_default()
    }

    /// Mean RGBA of pixel `(x, y)`.
    #[must_use]
    pub fn mean(&self, x: u32, y: u32) -> [f64; 4] {
        self.mean[(y * self.width + x) as usize]
    }

    /// Sample variance of RGBA of pixel `(x, y)` (0 before two samples).
    #[must_use]
    pub fn variance(&self, x: u32, y: u32) -> [f64; 4] {
        let n = f64::from(self.samples);
        let m = self.m2[(y * self.width + x) as usize];
        if self.samples < 2 {
            [0.0; 4]
        } else {
            m.map(|v| v / (n - 1.0))
        }
    }

    /// The noise estimate: root mean square over pixels and RGB of the standard error of the
    /// pixel means, `sqrt(mean(var / n))`. Infinite before two samples.
    #[must_use]
    pub fn noise(&self) -> f64 {
        if self.samples < 2 {
            return f64::INFINITY;
        }
        let n = f64::from(self.samples);
        let sum: f64 = self
            .m2
            .iter()
            .map(|m| (m[0] + m[1] + m[2]) / (n - 1.0) / n)
            .sum();
        (sum / (3.0 * self.m2.len() as f64)).sqrt()
    }
}

/// Renders `settings.spp` passes (or fewer when the noise target is met; the timing
/// protocol instead when [`RenderSettings::timed_frames`] is set), calling
/// `progress(passes_done, noise)` after each pass, and returns the accumulation buffer.
/// A wrapper of the one render loop, [`crate::TrackingSession`]'s, for borrowed scenes.
pub fn render_progressive(
    scene: &Scene,
    integrator: &Integrator,
    settings: &RenderSettings,
    mut progress: impl FnMut(u32, f64),
) -> Result<Progressive> {
    settings.validate()?;
    let integrator = integrator.prepared(scene)?;
    let mut on_pass = |acc: &Progressive| progress(acc.samples(), acc.noise());
    Ok(run_loop(scene, &integrator, settings, &Silent, &mut on_pass)?.image)
}

/// Renders the mean image (HDR, linear RGB; alpha = 1 - transmittance) of `settings.spp`
/// passes (see [`render_progressive`]).
pub fn render(
    scene: &Scene,
    integrator: &Integrator,
    settings: &RenderSettings,
) -> Result<Rgba32FImage> {
    settings.validate()?;
    let integrator = integrator.prepared(scene)?;
    Ok(
        run_loop(scene, &integrator, settings, &Sweeps, &mut |_| {})?
            .image
            .mean_image(),
    )
}

/// Sees nothing and lets passes run in sweeps ([`Observer::every_pass`] is `false`).
struct Sweeps;

impl Observer<Progressive> for Sweeps {
    fn every_pass(&self) -> bool {
        false
    }
}

/// What a tracking run returns: the accumulation buffer (mean image, variance, noise, heat
/// maps) and, under the timing protocol, the frame times.
#[derive(Clone, Debug)]
pub struct TrackingOutput {
    /// The accumulated samples.
    pub image: Progressive,
    /// Frame times when [`RenderSettings::timed_frames`] is set.
    pub frame_times: Option<FrameTimes>,
}

/// The longest a sweep of several passes grows to (see [`run_loop`]).
const SWEEP_SECONDS: f64 = 0.05;

/// The one render loop: progressive passes under `observer` (or the timing protocol when
/// `settings.timed_frames` is set), `on_pass` called after every counted pass.
/// `integrator` must be prepared for `scene` and `settings` validated.
pub(crate) fn run_loop(
    scene: &Scene,
    integrator: &Integrator,
    settings: &RenderSettings,
    observer: &dyn Observer<Progressive>,
    on_pass: &mut dyn FnMut(&Progressive),
) -> Result<TrackingOutput> {
    // The CPU has always prepared the integrator once more per render (blend weights
    // normalised twice, which is not idempotent in f32): kept so images stay bit for bit.
    let integrator = &integrator.prepared(scene)?;
    let mut acc = Progressive::new(settings.width, settings.height)?;
    if let Some(frames) = settings.timed_frames {
        let total = u64::from(settings.warmup) + u64::from(frames);
        if settings.warmup > 0 {
            let mut scratch = Progressive::new(settings.width, settings.height)?;
            for i in 0..settings.warmup {
                if observer.cancelled() {
                    return Err(Error::Cancelled);
                }
                scratch.add_prepared_pass(scene, integrator, settings)?;
                observer.progress(Progress {
                    done: u64::from(i) + 1,
                    total,
                    pass: 0,
                });
            }
        }
        if settings.heatmaps {
            acc.enable_heatmaps();
        }
        let mut times = Vec::with_capacity(frames.min(1 << 20) as usize);
        for _ in 0..frames {
            if observer.cancelled() {
                return Err(Error::Cancelled);
            }
            let start = Instant::now();
            acc.add_prepared_pass(scene, integrator, settings)?;
            times.push(start.elapsed().as_secs_f64());
            report(observer, &acc, u64::from(settings.warmup), total);
            on_pass(&acc);
        }
        return Ok(TrackingOutput {
            image: acc,
            frame_times: Some(FrameTimes {
                warmup: settings.warmup,
                frames: times,
            }),
        });
    }
    if settings.heatmaps {
        acc.enable_heatmaps();
    }
    // Passes run in sweeps of several when the observer does not need every pass and no
    // noise target can stop the run between passes: a sweep grows (doubling, up to 64
    // passes) while it takes under SWEEP_SECONDS, so progress and cancellation still come
    // a few times a second. The image is the same bit for bit.
    let batch = !observer.every_pass() && settings.noise_target.is_none();
    let mut sweep = 1u32;
    while acc.samples() < settings.spp {
        if observer.cancelled() {
            return Err(Error::Cancelled);
        }
        let n = if batch {
            sweep.min(settings.spp - acc.samples())
        } else {
            1
        };
        let start = Instant::now();
        acc.add_prepared_passes(scene, integrator, settings, n)?;
        if start.elapsed().as_secs_f64() < SWEEP_SECONDS {
            sweep = (sweep * 2).min(64);
        }
        let noise = report(observer, &acc, 0, u64::from(settings.spp));
        on_pass(&acc);
        if let Some(target) = settings.noise_target
            && acc.samples() >= 2
            && noise <= target
        {
            break;
        }
    }
    Ok(TrackingOutput {
        image: acc,
        frame_times: None,
    })
}

/// Tells `observer` about a finished pass; returns the noise estimate.
fn report(observer: &dyn Observer<Progressive>, acc: &Progressive, before: u64, total: u64) -> f64 {
    let noise = acc.noise();
    observer.progress(Progress {
        done: before + u64::from(acc.samples()),
        total,
        pass: acc.samples(),
    });
    observer.pass(acc.samples(), acc, noise.is_finite().then_some(noise));
    noise
}

/// Frame times of the timing protocol ([`render_timed`]), seconds.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameTimes {
    /// Warm-up frames rendered (and discarded) before timing.
    pub warmup: u32,
    /// Wall time of each timed frame (1 spp each), in order.
    pub frames: Vec<f64>,
}

impl FrameTimes {
    /// Mean frame time (0 without frames).
    #[must_use]
    pub fn mean(&self) -> f64 {
        if self.frames.is_empty() {
            return 0.0;
        }
        self.frames.iter().sum::<f64>() / self.frames.len() as f64
    }

    /// Median frame time (mean of the middle two for an even count; 0 without frames).
    #[must_use]
    pub fn median(&self) -> f64 {
        let mut v = self.frames.clone();
        v.sort_by(f64::total_cmp);
        match v.len() {
            0 => 0.0,
            n if n % 2 == 1 => v[n / 2],
            n => 0.5 * (v[n / 2 - 1] + v[n / 2]),
        }
    }
}

/// The timing protocol of MDWT section 6: `warmup` frames of 1 spp rendered and thrown
/// away, then `frames` timed frames of 1 spp each accumulated progressively (the image is
/// the accumulation of the timed frames). `heatmaps` turns on the per-pixel counters for the
/// timed frames. `settings.spp` and the noise target are ignored. A wrapper of the one render
/// loop with [`RenderSettings::timed_frames`], [`RenderSettings::warmup`] and
/// [`RenderSettings::heatmaps`] set.
pub fn render_timed(
    scene: &Scene,
    integrator: &Integrator,
    settings: &RenderSettings,
    warmup: u32,
    frames: u32,
    heatmaps: bool,
) -> Result<(Progressive, FrameTimes)> {
    let mut settings = settings.clone();
    settings.timed_frames = Some(frames);
    settings.warmup = warmup;
    settings.heatmaps = heatmaps;
    settings.validate()?;
    let integrator = integrator.prepared(scene)?;
    let out = run_loop(scene, &integrator, &settings, &Silent, &mut |_| {})?;
    let times = out.frame_times.unwrap_or(FrameTimes {
        warmup,
        frames: Vec::new(),
    });
    Ok((out.image, times))
}
