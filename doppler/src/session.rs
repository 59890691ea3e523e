//! [`DopplerSession`]: a Doppler render built once from (scene, settings), run many times.

use blueshift_camera::{Camera, DeviceKind, Observer, Session};
use blueshift_spectrum::PiecewiseLinear;

use super::cube::{CubeSpec, SpectralCube, render_cube_with};
use super::model::{DopplerScene, Factors};
use super::prepared::Prepared;
use super::render::{
    Context, DopplerImage, DopplerSettings, TraceStep, Want, integrate, pixel_ray, render_rows,
};
use crate::Result;

/// A Doppler render session on the CPU: the scene, its settings and their [`Prepared`]
/// tables. Images, picked spectra, traces and cubes all reuse the tables; an edit rebuilds
/// only what it touches:
/// - [`DopplerSession::set_camera`][]: nothing (the camera is checked);
/// - [`DopplerSession::set_factors`][]: the banded rest-frame values (Table 1's factors scale
///   them); the piecewise-linear and broadening tables stay;
/// - [`DopplerSession::set_settings`][]: everything.
///
/// The image is the same, bit for bit, as [`crate::render_doppler`]'s on any thread count.
#[derive(Debug)]
pub struct DopplerSession {
    scene: DopplerScene,
    settings: DopplerSettings,
    prepared: Prepared,
}

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
        Ok(())
    }

    fn context(&self) -> Context<'_> {
        Context::with_prepared(&self.scene, &self.settings, &self.prepared)
    }

    /// Renders the XYZ image under `observer` (progress once per row; cancel polled per row).
    ///
    /// # Errors
    /// [`crate::Error::Cancelled`] when the observer cancels; a Doppler shift out of range.
    pub fn render(&self, observer: &dyn Observer<DopplerImage>) -> Result<DopplerImage> {
        render_rows(&self.context(), observer)
    }

    /// The final spectrum of pixel `(x, y)` (banded integrators give their step function).
    ///
    /// # Errors
    /// A pixel outside the image.
    pub fn pixel_spectrum(&self, x: u32, y: u32) -> Result<PiecewiseLinear> {
        let ctx = self.context();
        let out = integrate(&ctx, &pixel_ray(&self.settings, x, y)?, Want::Spectrum)?;
        Ok(out.spectrum.unwrap_or_default())
    }

    /// The step-by-step accumulation of pixel `(x, y)`'s ray: the spectrum after each
    /// segment, back to front.
    ///
    /// # Errors
    /// A pixel outside the image.
    pub fn trace(&self, x: u32, y: u32) -> Result<Vec<TraceStep>> {
        let ctx = self.context();
        Ok(integrate(&ctx, &pixel_ray(&self.settings, x, y)?, Want::Trace)?.trace)
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
