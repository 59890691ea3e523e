//! [`TrackingSession`]: a Woodcock / MDWT / marcher render built once, run many times.

use blueshift_camera::{Camera, DeviceKind, Observer, Session};
use blueshift_tfedit::TransferFunction;

use crate::Result;
use crate::integrator::Integrator;
use crate::render::{Progressive, RenderSettings, TrackingOutput, run_loop};
use crate::scene::Scene;

/// A tracking render session on the CPU: the scene (volume, transfer functions, majorant
/// grids), the integrator prepared for it and the settings. Every run is the one render
/// loop (progressive passes, noise target, heat maps and the timing protocol as the settings
/// say), bit-reproducible for a seed on any thread count. An edit rebuilds only what it
/// touches:
/// - a camera edit ([`TrackingSession::set_camera`]) rebuilds nothing;
/// - a transfer-function edit ([`TrackingSession::set_transfer_function`]) rebuilds that
///   channel's majorant grid (the macrocells stay; MDWT section 4.3);
/// - a density-scale edit ([`TrackingSession::set_density_scale`]) rebuilds the majorants;
/// - a settings edit ([`TrackingSession::set_settings`]) rebuilds nothing but the checks.
#[derive(Debug)]
pub struct TrackingSession {
    scene: Scene,
    integrator: Integrator,
    prepared: Integrator,
    settings: RenderSettings,
}

impl TrackingSession {
    /// Checks `settings` and prepares `integrator` for `scene`.
    ///
    /// # Errors
    /// Invalid settings (sizes, spp, camera, noise target, zero timed frames) or an
    /// integrator that does not fit the scene (a channel out of range, bad weights).
    pub fn new(scene: Scene, integrator: Integrator, settings: RenderSettings) -> Result<Self> {
        settings.validate()?;
        let prepared = integrator.prepared(&scene)?;
        Ok(Self {
            scene,
            integrator,
            prepared,
            settings,
        })
    }

    /// The scene.
    #[must_use]
    pub fn scene(&self) -> &Scene {
        &self.scene
    }

    /// The integrator as given.
    #[must_use]
    pub fn integrator(&self) -> &Integrator {
        &self.integrator
    }

    /// The settings.
    #[must_use]
    pub fn settings(&self) -> &RenderSettings {
        &self.settings
    }

    /// Gives the scene back.
    #[must_use]
    pub fn into_scene(self) -> Scene {
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

    /// Replaces channel `channel`'s transfer function: only its majorant grid is rebuilt.
    ///
    /// # Errors
    /// A channel out of range.
    pub fn set_transfer_function(&mut self, channel: usize, tf: TransferFunction) -> Result<()> {
        self.scene.set_transfer_function(channel, tf)?;
        self.prepared = self.integrator.prepared(&self.scene)?;
        Ok(())
    }

    /// Changes the density scale: the majorant grids are rebuilt.
    ///
    /// # Errors
    /// A non-finite or non-positive scale, or one whose optical depths overflow.
    pub fn set_density_scale(&mut self, density_scale: f32) -> Result<()> {
        self.scene.set_density_scale(density_scale)?;
        self.prepared = self.integrator.prepared(&self.scene)?;
        Ok(())
    }

    /// Replaces the settings (image size, spp, seed, noise target, heat maps, timing).
    ///
    /// # Errors
    /// Invalid settings (the session keeps its old ones).
    pub fn set_settings(&mut self, settings: RenderSettings) -> Result<()> {
        settings.validate()?;
        self.settings = settings;
        Ok(())
    }

    /// Replaces the integrator.
    ///
    /// # Errors
    /// An integrator that does not fit the scene (the session keeps its old one).
    pub fn set_integrator(&mut self, integrator: Integrator) -> Result<()> {
        self.prepared = integrator.prepared(&self.scene)?;
        self.integrator = integrator;
        Ok(())
    }

    /// Renders under `observer`: progress and the accumulation buffer after every pass.
    ///
    /// # Errors
    /// [`crate::Error::Cancelled`] when the observer cancels.
    pub fn render(&self, observer: &dyn Observer<Progressive>) -> Result<TrackingOutput> {
        run_loop(
            &self.scene,
            &self.prepared,
            &self.settings,
            observer,
            &mut |_| {},
        )
    }
}

impl Session for TrackingSession {
    type Image = Progressive;
    type Output = TrackingOutput;
    type Error = crate::Error;

    fn run(&mut self, observer: &dyn Observer<Progressive>) -> Result<TrackingOutput> {
        self.render(observer)
    }

    fn device(&self) -> DeviceKind {
        DeviceKind::Cpu
    }
}
