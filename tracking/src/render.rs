//! Rendering an image: progressive accumulation of one sample per pixel per pass, with the
//! running mean and variance per pixel, rayon over rows, counter-based random numbers.

use image::Rgba32FImage;
use rayon::prelude::*;

use crate::camera::Camera;
use crate::integrator::Integrator;
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
        self.camera.validate()
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

/// A progressive accumulation buffer: per pixel the running mean and the sum of squared
/// deviations (Welford) of RGBA over the samples added so far.
#[derive(Clone, Debug)]
pub struct Progressive {
    width: u32,
    height: u32,
    samples: u32,
    mean: Vec<[f64; 4]>,
    m2: Vec<[f64; 4]>,
}

impl Progressive {
    /// An empty buffer of `width x height` pixels.
    pub fn new(width: u32, height: u32) -> Result<Self> {
        check_size(width, height)?;
        let n = width as usize * height as usize;
        Ok(Progressive {
            width,
            height,
            samples: 0,
            mean: vec![[0.0; 4]; n],
            m2: vec![[0.0; 4]; n],
        })
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
        if settings.width != self.width || settings.height != self.height {
            return Err(Error::parameter(
                "settings: image size differs from the accumulation buffer's",
            ));
        }
        let integrator = integrator.prepared(scene)?;
        let w = self.width as usize;
        let sample = self.samples;
        let count = f64::from(sample + 1);
        let (width, height) = (self.width, self.height);
        self.mean
            .par_chunks_mut(w)
            .zip(self.m2.par_chunks_mut(w))
            .enumerate()
            .for_each(|(y, (mean_row, m2_row))| {
                for x in 0..w {
                    let pixel = (y * w + x) as u64;
                    let mut rng = Rng::new(settings.seed, pixel, u64::from(sample));
                    let (jx, jy) = if settings.jitter_pixels {
                        (rng.uniform(), rng.uniform())
                    } else {
                        (0.5, 0.5)
                    };
                    let ray = settings
                        .camera
                        .ray(x as f32 + jx, y as f32 + jy, width, height);
                    let v = integrator.li(scene, &ray, &mut rng);
                    for c in 0..4 {
                        let v = f64::from(v[c]);
                        let d = v - mean_row[x][c];
                        mean_row[x][c] += d / count;
                        m2_row[x][c] += d * (v - mean_row[x][c]);
                    }
                }
            });
        self.samples += 1;
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

/// Renders `settings.spp` passes (or fewer when the noise target is met), calling
/// `progress(passes_done, noise)` after each pass, and returns the accumulation buffer.
pub fn render_progressive(
    scene: &Scene,
    integrator: &Integrator,
    settings: &RenderSettings,
    mut progress: impl FnMut(u32, f64),
) -> Result<Progressive> {
    settings.validate()?;
    let integrator = integrator.prepared(scene)?;
    let mut acc = Progressive::new(settings.width, settings.height)?;
    for _ in 0..settings.spp {
        acc.add_pass(scene, &integrator, settings)?;
        let noise = acc.noise();
        progress(acc.samples(), noise);
        if let Some(target) = settings.noise_target
            && acc.samples() >= 2
            && noise <= target
        {
            break;
        }
    }
    Ok(acc)
}

/// Renders the mean image (HDR, linear RGB; alpha = 1 - transmittance).
pub fn render(
    scene: &Scene,
    integrator: &Integrator,
    settings: &RenderSettings,
) -> Result<Rgba32FImage> {
    Ok(render_progressive(scene, integrator, settings, |_, _| {})?.mean_image())
}
