//! [`RelativitySession`]: one environment seen by an observer whose speed, view and effects
//! change between frames.

use blueshift_camera::{DeviceKind, Observer, Session, single_pass_done};
use image::Rgb32FImage;

use crate::colour::DopplerColourTable;
use crate::envmap::Environment;
use crate::error::{Error, Result};
use crate::lorentz::Velocity;
use crate::render::{Camera, CameraFrame, Effects, render};

/// A relativity render session on the CPU: the environment (loaded once), the observer's
/// camera, velocity and effects, and the Doppler colour table (built once). Every edit
/// ([`RelativitySession::set_velocity`], [`RelativitySession::set_camera`],
/// [`RelativitySession::set_effects`]) is checked and costs nothing until the next run, so a
/// speed ramp (`--ramp`) or a viewer's fly-through re-renders only.
#[derive(Debug)]
pub struct RelativitySession {
    env: Environment,
    camera: Camera,
    velocity: Velocity,
    effects: Effects,
    table: &'static DopplerColourTable,
}

impl RelativitySession {
    /// Checks the camera and keeps everything for the runs.
    ///
    /// # Errors
    /// [`Error::Parameter`] for a bad camera (field of view, size, direction).
    pub fn new(
        env: Environment,
        camera: Camera,
        velocity: Velocity,
        effects: Effects,
    ) -> Result<Self> {
        CameraFrame::new(&camera)?;
        Ok(Self {
            env,
            camera,
            velocity,
            effects,
            table: DopplerColourTable::global(),
        })
    }

    /// The environment.
    #[must_use]
    pub fn environment(&self) -> &Environment {
        &self.env
    }

    /// The camera.
    #[must_use]
    pub fn camera(&self) -> &Camera {
        &self.camera
    }

    /// The velocity.
    #[must_use]
    pub fn velocity(&self) -> Velocity {
        self.velocity
    }

    /// The effects.
    #[must_use]
    pub fn effects(&self) -> Effects {
        self.effects
    }

    /// Changes the observer's velocity (already checked: `|beta| < 1` by construction).
    pub fn set_velocity(&mut self, velocity: Velocity) {
        self.velocity = velocity;
    }

    /// Changes the camera.
    ///
    /// # Errors
    /// [`Error::Parameter`] for a bad camera (the session keeps its old one).
    pub fn set_camera(&mut self, camera: Camera) -> Result<()> {
        CameraFrame::new(&camera)?;
        self.camera = camera;
        Ok(())
    }

    /// Changes the effects.
    pub fn set_effects(&mut self, effects: Effects) {
        self.effects = effects;
    }

    /// Renders the frame ([`crate::render`], the same bytes) under `observer`.
    ///
    /// # Errors
    /// [`Error::Cancelled`] when the observer cancels before the frame starts.
    pub fn render(&self, observer: &dyn Observer<Rgb32FImage>) -> Result<Rgb32FImage> {
        if observer.cancelled() {
            return Err(Error::Cancelled);
        }
        let img = render(
            &self.env,
            &self.camera,
            self.velocity,
            self.effects,
            Some(self.table),
        )?;
        single_pass_done(observer, u64::from(img.height()), &img);
        Ok(img)
    }
}

impl Session for RelativitySession {
    type Image = Rgb32FImage;
    type Output = Rgb32FImage;
    type Error = Error;

    fn run(&mut self, observer: &dyn Observer<Rgb32FImage>) -> Result<Rgb32FImage> {
        self.render(observer)
    }

    fn device(&self) -> DeviceKind {
        DeviceKind::Cpu
    }
}
