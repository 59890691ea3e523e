//! [`DopplerSession`]: a Doppler render built once from (scene, settings), run many times.

use blueshift_camera::{Camera, DeviceKind, Observer, Session};
use blueshift_spectrum::PiecewiseLinear;

use super::cube::{CubeSpec, SpectralCube, render_cube_with};
use super::model::{DopplerScene, Factors};
use super::prepared::Prepared;
use super::render::{
    Context, DopplerImage, DopplerSettings, RawSamples, TraceStep, Want, integrate, pixel_ray,
    render_rows_cached,
};
use crate::Result;
use std::sync::{Arc, Mutex};

/// A Doppler render session on the CPU: the scene, its settings and their [`Prepared`]
/// tables. Images, picked spectra and traces reuse the tables (a cube prepares its own, for
/// its one-channel line width); an edit rebuilds
/// only what it touches:
/// - a camera edit ([`DopplerSession::set_camera`]) rebuilds nothing (the camera is
///   checked); the next render samples the volume again;
/// - a factors edit ([`DopplerSession::set_factors`]) rebuilds the banded rest-frame
///   values (Table 1's factors scale them); the piecewise-linear and broadening tables stay,
///   and so do the samples of the last render (densities, temperatures and velocities along
///   every pixel's ray before the factors, up to [`SAMPLE_CACHE_BYTES`]): the next render
///   only applies the factors and integrates;
/// - a settings edit ([`DopplerSession::set_settings`]) rebuilds everything.
///
/// The image is the same, bit for bit, as [`crate::render_doppler`]'s on any thread count.
#[derive(Debug)]
pub struct DopplerSession {
    scene: DopplerScene,
    settings: DopplerSettings,
    prepared: Prepared,
    /// Every pixel's samples before the factors, from the last render of this view (kept
    /// when they fit [`SAMPLE_CACHE_BYTES`]): a factor edit re-renders without re-sampling.
    raw: Mutex<Option<Arc<Vec<RawSamples>>>>,
    keep_samples: bool,
}

/// Most bytes of per-pixel samples a [`DopplerSession`] keeps between renders (a view
/// whose samples would need more re-samples the volume on every render).
pub const SAMPLE_CACHE_BYTES: usize = 256 << 20;

impl DopplerSession {
    /// Validates `settings` against `scene` and prepares the tables.
    ///
    /// # Errors
    /// As [`Prepared::new`].
    pub fn new(scene: DopplerScene, settings: DopplerSettings) -> Result<Self> {
        let prepared = Prepared::new(&scene, &settings)?;
        Ok(Self {
            scene,
            settings,
            prepared,
            raw: Mutex::new(None),
            keep_samples: true,
        })
    }

    /// The scene.
    #[must_use]
    pub fn scene(&self) -> &DopplerScene {
        &self.scene
    }

    /// The settings.
    #[must_use]
    pub fn settings(&self) -> &DopplerSettings {
        &self.settings
    }

    /// The prepared tables (what a GPU backend uploads).
    #[must_use]
    pub fn prepared(&self) -> &Prepared {
        &self.prepared
    }

    /// Gives the scene back.
    #[must_use]
    pub fn into_scene(self) -> DopplerScene {
        self.scene
    }

    /// Moves the camera; nothing is rebuilt.
    ///
    /// # Errors
    /// A degenerate camera (the session keeps its old one).
    pub fn set_camera(&mut self, camera: Camera) -> Result<()> {
        camera.validate()?;
        self.settings.camera = camera;
        self.forget_samples();
        Ok(())
    }

    /// Changes the scene's factors (paper Table 1); rebuilds only the factor-dependent
    /// tables.
    ///
    /// # Errors
    /// A factor that is negative or not finite (the session keeps its old factors).
    pub fn set_factors(&mut self, factors: Factors) -> Result<()> {
        let old = std::mem::replace(&mut self.scene.factors, factors);
        if let Err(e) = self.prepared.refresh_factors(&self.scene, &self.settings) {
            self.scene.factors = old;
            return Err(e);
        }
        Ok(())
    }

    /// Replaces the settings and prepares everything again.
    ///
    /// # Errors
    /// As [`Prepared::new`] (the session keeps its old settings).
    pub fn set_settings(&mut self, settings: DopplerSettings) -> Result<()> {
        self.prepared = Prepared::new(&self.scene, &settings)?;
        self.settings = settings;
        self.forget_samples();
        Ok(())
    }

    /// Whether renders keep their samples for the next factor edit (default on; a caller
    /// that renders once, like the CLI, turns it off to save the memory).
    pub fn set_keep_samples(&mut self, keep: bool) {
        self.keep_samples = keep;
        if !keep {
            self.forget_samples();
        }
    }

    fn forget_samples(&mut self) {
        if let Ok(raw) = self.raw.get_mut() {
            *raw = None;
        }
    }

    /// Bytes the kept samples of this view would take (an upper bound).
    fn sample_bytes(&self) -> usize {
        let g = &self.scene.geometry;
        let (lo, hi) = g.world_bounds();
        let diag = (hi - lo + 2.0 * g.spacing).as_dvec3().length();
        let steps = (diag / f64::from(self.prepared.step())).ceil() as usize + 2;
        let per_step = 4 + 12 + 8 * (self.scene.species.len() + 3);
        let pixels = self.settings.width as usize * self.settings.height as usize;
        let per_pixel = std::mem::size_of::<RawSamples>() + steps.saturating_mul(per_step);
        pixels.saturating_mul(per_pixel)
    }

    fn context(&self) -> Context<'_> {
        Context::with_prepared(&self.scene, &self.settings, &self.prepared)
    }

    /// Renders the XYZ image under `observer` (progress once per row; cancel polled per row).
    ///
    /// # Errors
    /// [`crate::Error::Cancelled`] when the observer cancels; a Doppler shift out of range.
    pub fn render(&self, observer: &dyn Observer<DopplerImage>) -> Result<DopplerImage> {
        let cached = self.raw.lock().ok().and_then(|r| r.clone());
        let keep =
            self.keep_samples && cached.is_none() && self.sample_bytes() <= SAMPLE_CACHE_BYTES;
        let (img, kept) = render_rows_cached(
            &self.context(),
            observer,
            cached.as_deref().map(Vec::as_slice),
            keep,
        )?;
        if let (Some(k), Ok(mut slot)) = (kept, self.raw.lock()) {
            *slot = Some(Arc::new(k));
        }
        Ok(img)
    }

    /// The final spectrum of pixel `(x, y)` (banded integrators give their step function).
    ///
    /// # Errors
    /// A pixel outside the image.
    pub fn pixel_spectrum(&self, x: u32, y: u32) -> Result<PiecewiseLinear> {
        let ctx = self.context();
        let out = integrate(&ctx, &pixel_ray(&self.settings, x, y)?, Want::Spectrum)?;
        self.scene.check_io()?;
        Ok(out.spectrum.unwrap_or_default())
    }

    /// The step-by-step accumulation of pixel `(x, y)`'s ray: the spectrum after each
    /// segment, back to front.
    ///
    /// # Errors
    /// A pixel outside the image.
    pub fn trace(&self, x: u32, y: u32) -> Result<Vec<TraceStep>> {
        let ctx = self.context();
        let out = integrate(&ctx, &pixel_ray(&self.settings, x, y)?, Want::Trace)?;
        self.scene.check_io()?;
        Ok(out.trace)
    }

    /// A spectral cube of this session's view (see [`crate::render_cube`]).
    ///
    /// # Errors
    /// As [`crate::render_cube`]; [`crate::Error::Cancelled`] when the observer cancels.
    pub fn cube(
        &self,
        spec: &CubeSpec,
        observer: &dyn Observer<DopplerImage>,
    ) -> Result<SpectralCube> {
        render_cube_with(&self.scene, &self.settings, spec, observer)
    }
}

impl Session for DopplerSession {
    type Image = DopplerImage;
    type Output = DopplerImage;
    type Error = crate::Error;

    fn run(&mut self, observer: &dyn Observer<DopplerImage>) -> Result<DopplerImage> {
        self.render(observer)
    }

    fn device(&self) -> DeviceKind {
        DeviceKind::Cpu
    }
}
