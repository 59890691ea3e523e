//! [`TrackingSession`]: a Woodcock / MDWT / marcher render built once, run many times.

use blueshift_camera::{Camera, DeviceKind, Observer, ProgressOnly, Session};
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

impl TrackingSession {
    /// Progressive levels of detail (HDR VolVis section 6.3) for a scene of bricked channels
    /// ([`Scene::lod`]): one quick pass (one sample per pixel) at every level from the
    /// coarsest down to the one above the scene's own, then the full render at the scene's
    /// level, the same output as [`TrackingSession::render`]. While a level renders, the next
    /// finer level's bricks along every 16th pixel's ray load on the cache's I/O thread.
    /// `observer` hears [`Observer::level`] before each step (steps numbered from 1) and
    /// [`Observer::pass`] after each preview step; the final render's passes are its own,
    /// numbered from 1. A scene in memory is just rendered.
    ///
    /// # Errors
    /// As [`TrackingSession::render`].
    pub fn render_lod(&self, observer: &dyn Observer<Progressive>) -> Result<TrackingOutput> {
        let Some((level, count)) = self.scene.lod() else {
            return self.render(observer);
        };
        let st = &self.settings;
        let rays = st.camera.sparse_rays(st.width, st.height, 16);
        // The bricks of `level` along the rays (the fields alone: no scene to build).
        let prefetch = |level: usize| -> Result<()> {
            let fields = self
                .scene
                .channels()
                .iter()
                .filter_map(|c| c.grid().as_bricked())
                .map(|b| b.at_level(level))
                .collect::<blueshift_volume::Result<Vec<_>>>()?;
            let refs: Vec<_> = fields.iter().collect();
            blueshift_volume::BrickedField::prefetch_along(&refs, &rays);
            Ok(())
        };
        let preview = preview_settings(st);
        let mut step = 0;
        for l in (level + 1..count).rev() {
            step += 1;
            observer.level(step, l);
            let s = self.scene.at_level(l)?;
            prefetch(l - 1)?;
            let prepared = self.integrator.prepared(&s)?;
            let out = run_loop(
                &s,
                &prepared,
                &preview,
                &ProgressOnly(observer),
                &mut |_| {},
            )?;
            observer.pass(step, &out.image, None);
        }
        observer.level(step + 1, level);
        self.render(observer)
    }
}

impl TrackingSession {
    /// Progressive refinement brick by brick while the bricks load (HDR VolVis section 6.3),
    /// for a scene of bricked channels ([`Scene::lod`]): a quick pass (1 spp) at the coarsest
    /// level, then quick passes in which every region (one brick of the scene's level)
    /// samples the finest level the cache holds there ([`Scene::resident_view`]) while the
    /// cache's I/O thread loads the scene's level along every 16th pixel's ray
    /// ([`blueshift_volume::refine_while_loading`] says when it stops), then the full render
    /// at the scene's level: the same output as [`TrackingSession::render`].
    ///
    /// `observer` hears [`Observer::level`] before each step (steps numbered from 1) with the
    /// coarsest level the step samples and [`Observer::pass`] after each quick pass; the
    /// final render's passes are its own, numbered from 1. `on_step(step, at_level,
    /// regions)` hears, before each quick pass after the first, how many of the regions
    /// sample the scene's own level. A scene in memory is just rendered.
    ///
    /// # Errors
    /// As [`TrackingSession::render`].
    pub fn render_bricks(
        &self,
        observer: &dyn Observer<Progressive>,
        on_step: &mut dyn FnMut(u32, usize, usize),
    ) -> Result<TrackingOutput> {
        let Some((level, count)) = self.scene.lod() else {
            return self.render(observer);
        };
        let st = &self.settings;
        let rays = st.camera.sparse_rays(st.width, st.height, 16);
        let fields: Vec<&blueshift_volume::BrickedField> = self
            .scene
            .channels()
            .iter()
            .filter_map(|c| c.grid().as_bricked())
            .collect();
        let preview = preview_settings(st);
        let quick = |s: &Scene, step: u32, coarsest: usize| -> Result<()> {
            observer.level(step, coarsest);
            let prepared = self.integrator.prepared(s)?;
            let out = run_loop(s, &prepared, &preview, &ProgressOnly(observer), &mut |_| {})?;
            observer.pass(step, &out.image, None);
            Ok(())
        };
        // The scene's level loads on the I/O thread from the start.
        blueshift_volume::BrickedField::prefetch_along(&fields, &rays);
        let mut step = 0;
        if count > level + 1 {
            step = 1;
            quick(&self.scene.at_level(count - 1)?, step, count - 1)?;
            step = blueshift_volume::refine_while_loading(
                &fields,
                &rays,
                2,
                || self.scene.resident_view(),
                |step, view: Scene, at_level, regions| {
                    on_step(step, at_level, regions);
                    let coarsest = view.coarsest_sampled_level().unwrap_or(level);
                    quick(&view, step, coarsest)
                },
                || observer.cancelled(),
            )?;
        }
        observer.level(step + 1, level);
        self.render(observer)
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

/// The settings of a progressive render's quick passes: one sample per pixel, no noise
/// target, heat maps, timed frames or warm-up.
fn preview_settings(st: &RenderSettings) -> RenderSettings {
    RenderSettings {
        spp: 1,
        noise_target: None,
        heatmaps: false,
        timed_frames: None,
        warmup: 0,
        ..st.clone()
    }
}
