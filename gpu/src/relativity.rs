//! The relativistic environment renderer on the GPU, mirroring
//! [`blueshift_relativity::render`] with the same [`Camera`], [`Velocity`], [`Effects`],
//! [`Environment`] and [`DopplerColourTable`].
//!
//! One invocation per pixel (`shaders/relativity.wgsl`): the pinhole direction, inverse
//! aberration, the environment lookup (equirectangular, cube map with the CPU's edge taps,
//! or the procedural checker), the Doppler colour shift through the CPU's table of 3x3
//! matrices (sampled at 2048 nodes uniform in `ln D` over
//! [`TABLE_D_MIN`]..[`TABLE_D_MAX`], the nodes of [`DopplerColourTable::global`], and
//! uploaded as a storage buffer), and the searchlight factor `D^4`.
//!
//! Precision: the GPU works in f32 where the CPU works in f64. Parity (tested in
//! `gpu/tests/relativity.rs`): on smooth environment maps every channel agrees within
//! 2e-3 of the pixel's brightest channel + 1e-5 absolute; on the checker, whose colour jumps at cell edges, at
//! least 99.5% of pixels agree exactly (the rest sit on an edge where an f32 rounding moves
//! the direction across it); on a map with independent texels over two decades (like the
//! lamps and stars of real HDR photos), at least 99.5% (on the 1k-2k real maps of
//! `shared/data`, at most one pixel in 1500 outside, most maps none). The polar angle is
//! taken as `atan2(|xz|, y)`, well conditioned at the poles where f32 `acos(y)` is not. The
//! aberration and the Doppler factor use `1 - |beta|` computed in f64 on the host and
//! `1 - cos` from the perpendicular part, so they keep f32 precision at speeds near 1 (the
//! textbook forms lose it: f32 holds `1 - 0.999999` to 6 %). What f32 cannot avoid: the
//! camera ray's own rounding (6e-8 rad) is magnified by up to `sqrt((1 + b) / (1 - b))`
//! ahead (141 at b = 0.9999), so maps with texel-level detail seen through a narrow field
//! of view along the motion differ from the CPU there (real maps at b = 0.999999, fov 1-10
//! degrees: at most 1 pixel in 3000 outside the tolerance).
//!
//! Environment maps live in one storage buffer, so they are limited by the device's
//! `max_storage_buffer_binding_size` (128 MiB on lavapipe: a 6 x 1024^2 cube map fits); a
//! larger map is refused with [`Error::LimitExceeded`] naming that limit.

use blueshift_camera::{DeviceKind, Observer, Session, single_pass_done};
use blueshift_relativity::{
    Camera, CameraFrame, DopplerColourTable, Effects, Environment, RelativitySession, TABLE_D_MAX,
    TABLE_D_MIN, Velocity,
};
use glam::DVec3;
use image::Rgb32FImage;

use crate::context::{GpuContext, WORKGROUP_2D};
use crate::error::{Error, Result};

const WGSL: &str = include_str!("shaders/relativity.wgsl");

/// Number of colour-table nodes uploaded to the GPU (those of the global CPU table).
pub const TABLE_NODES: usize = 2048;

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct Params {
    forward: [f32; 4],
    right: [f32; 4],
    up: [f32; 4],
    beta: [f32; 4],
    width: u32,
    height: u32,
    half_w: f32,
    half_h: f32,
    gamma: f32,
    aberration: u32,
    doppler: u32,
    searchlight: u32,
    env_kind: u32,
    env_w: u32,
    env_h: u32,
    table_len: u32,
    ln_min: f32,
    ln_max: f32,
    ln_step: f32,
    cell_deg: f32,
    grid_deg: f32,
    line_deg: f32,
    one_minus_speed: f32,
    p1: f32,
    light: [f32; 4],
    dark: [f32; 4],
    line: [f32; 4],
}

/// [`crate::layout::pod_layouts`] of this module.
pub(crate) fn pod_layouts() -> Vec<crate::layout::PodLayout> {
    vec![
        crate::layout::pod_layout!(Params => "Params", "relativity.wgsl", WGSL, {
            forward, right, up, beta, width, height, half_w, half_h, gamma, aberration, doppler,
            searchlight, env_kind, env_w, env_h, table_len, ln_min, ln_max, ln_step, cell_deg,
            grid_deg, line_deg, one_minus_speed, p1 as "_p1", light, dark, line,
        }),
    ]
}

fn v4(v: DVec3) -> [f32; 4] {
    [v.x as f32, v.y as f32, v.z as f32, 0.0]
}

fn c4(c: [f32; 3]) -> [f32; 4] {
    [c[0], c[1], c[2], 0.0]
}

/// `Ok` when the GPU renders `effects` (aberration, Doppler and searchlight in any
/// combination, every environment kind): always, as the kernel mirrors
/// [`blueshift_relativity::render`] whole; what does not fit an adapter (a map over its
/// texture or buffer limits) fails at run time with [`Error::LimitExceeded`], on which
/// `--device auto` falls back. Here so that every backend answers the question the same way.
pub fn supports(_effects: Effects) -> std::result::Result<(), crate::device::Unsupported> {
    Ok(())
}

/// The relativity pipeline compiled for a context, with the colour table uploaded.
#[derive(Debug)]
pub struct GpuRelativity<'a> {
    ctx: &'a GpuContext,
    pipeline: wgpu::ComputePipeline,
    table: wgpu::Buffer,
}

impl<'a> GpuRelativity<'a> {
    /// Compiles the shader and uploads `table` (default: [`DopplerColourTable::global`]).
    pub fn new(ctx: &'a GpuContext, table: Option<&DopplerColourTable>) -> Result<Self> {
        let table = table.unwrap_or_else(|| DopplerColourTable::global());
        let (ln_min, ln_max) = (TABLE_D_MIN.ln(), TABLE_D_MAX.ln());
        let step = (ln_max - ln_min) / (TABLE_NODES - 1) as f64;
        let mut flat = Vec::with_capacity(TABLE_NODES * 9);
        for k in 0..TABLE_NODES {
            // Clamp the last node inside the table's range against rounding of exp/ln.
            let l = (ln_min + step * k as f64).min(ln_max);
            let m = table.matrix(l.exp().clamp(TABLE_D_MIN, TABLE_D_MAX));
            flat.extend(m.iter().flatten().map(|v| *v as f32));
        }
        Ok(Self {
            ctx,
            pipeline: ctx.compute_pipeline("relativity", WGSL, "main")?,
            table: ctx.storage_buffer("doppler colour table", &flat)?,
        })
    }

    /// Renders what an observer moving with `velocity` sees, like
    /// [`blueshift_relativity::render`] (same validation of the camera).
    ///
    /// # Errors
    /// The relativity crate's errors for a bad camera; [`Error::LimitExceeded`] for a map
    /// or image over the device's limits; GPU errors.
    pub fn render(
        &self,
        env: &Environment,
        cam: &Camera,
        velocity: Velocity,
        effects: Effects,
    ) -> Result<Rgb32FImage> {
        let ctx = self.ctx;
        // The CPU's own frame: validation and basis are shared, not re-derived.
        let frame = CameraFrame::new(cam)?;
        let (forward, right, up) = frame.basis();
        let (half_w, half_h) = frame.half_extents();

        let (w, h) = (cam.width, cam.height);
        let n = u64::from(w) * u64::from(h);
        ctx.check_storage_size("relativity image", n * 12)?;
        let mut params = Params {
            forward: v4(forward),
            right: v4(right),
            up: v4(up),
            beta: {
                let b = velocity.beta();
                [b.x as f32, b.y as f32, b.z as f32, velocity.speed() as f32]
            },
            width: w,
            height: h,
            half_w: half_w as f32,
            half_h: half_h as f32,
            gamma: velocity.gamma() as f32,
            aberration: effects.aberration.into(),
            doppler: effects.doppler.into(),
            searchlight: effects.searchlight.into(),
            env_kind: 2,
            env_w: 0,
            env_h: 0,
            table_len: TABLE_NODES as u32,
            ln_min: TABLE_D_MIN.ln() as f32,
            ln_max: TABLE_D_MAX.ln() as f32,
            ln_step: ((TABLE_D_MAX.ln() - TABLE_D_MIN.ln()) / (TABLE_NODES - 1) as f64) as f32,
            cell_deg: 10.0,
            grid_deg: 0.0,
            line_deg: 0.0,
            one_minus_speed: (1.0 - velocity.speed()) as f32,
            p1: 0.0,
            light: [0.0; 4],
            dark: [0.0; 4],
            line: [0.0; 4],
        };
        let texels: Vec<f32> = match env {
            Environment::Equirect(m) => {
                let img = m.image();
                params.env_kind = 0;
                (params.env_w, params.env_h) = img.dimensions();
                ctx.check_storage_size(
                    "equirectangular map",
                    u64::from(img.width()) * u64::from(img.height()) * 12,
                )?;
                img.as_raw().clone()
            }
            Environment::Cube(m) => {
                params.env_kind = 1;
                params.env_w = m.size();
                let face = u64::from(m.size()) * u64::from(m.size()) * 12;
                ctx.check_storage_size("cube map", face * 6)?;
                m.faces()
                    .iter()
                    .flat_map(|f| f.as_raw().iter().copied())
                    .collect()
            }
            Environment::Checker(c) => {
                if !(c.cell_deg.is_finite() && c.cell_deg > 0.0) {
                    return Err(Error::InvalidInput(format!(
                        "checker cell size must be positive, got {}",
                        c.cell_deg
                    )));
                }
                params.env_kind = 2;
                params.cell_deg = c.cell_deg as f32;
                params.grid_deg = c.grid_deg as f32;
                params.line_deg = c.line_deg as f32;
                params.light = c4(c.light);
                params.dark = c4(c.dark);
                params.line = c4(c.line);
                vec![0.0]
            }
        };
        let env_b = ctx.storage_buffer("environment", &texels)?;
        let out = ctx.storage_buffer_zeroed("relativity out", n * 12)?;
        let pb = ctx.uniform_buffer("relativity params", &params)?;
        let bg = ctx.bind_group(&self.pipeline, 0, &[&env_b, &self.table, &out, &pb])?;
        let groups = [
            ctx.groups("relativity", w, WORKGROUP_2D)?,
            ctx.groups("relativity", h, WORKGROUP_2D)?,
            1,
        ];
        ctx.dispatch(&self.pipeline, &bg, groups)?;
        let data = ctx.read_buffer::<f32>(&out, (n * 3) as usize)?;
        Rgb32FImage::from_raw(w, h, data)
            .ok_or_else(|| Error::Internal("readback size does not match the image".into()))
    }
}

/// One-shot [`GpuRelativity::render`] with the global colour table.
pub fn render(
    ctx: &GpuContext,
    env: &Environment,
    cam: &Camera,
    velocity: Velocity,
    effects: Effects,
) -> Result<Rgb32FImage> {
    GpuRelativity::new(ctx, None)?.render(env, cam, velocity, effects)
}

/// A relativity render session on a GPU: the CPU's [`RelativitySession`] (environment,
/// camera, velocity, effects: its edits apply here too) rendered by the kernel compiled once.
#[derive(Debug)]
pub struct GpuRelativitySession<'c> {
    gpu: GpuRelativity<'c>,
    cpu: RelativitySession,
}

impl<'c> GpuRelativitySession<'c> {
    /// Compiles the kernel and uploads the colour table for `cpu`'s renders.
    ///
    /// # Errors
    /// GPU errors.
    pub fn new(ctx: &'c GpuContext, cpu: RelativitySession) -> Result<Self> {
        Ok(Self {
            gpu: GpuRelativity::new(ctx, None)?,
            cpu,
        })
    }

    /// The CPU session (state and edits).
    #[must_use]
    pub fn cpu(&self) -> &RelativitySession {
        &self.cpu
    }

    /// The CPU session, for edits (velocity, camera, effects).
    pub fn cpu_mut(&mut self) -> &mut RelativitySession {
        &mut self.cpu
    }

    /// Renders the frame on the GPU under `observer`.
    ///
    /// # Errors
    /// As [`GpuRelativity::render`]; [`Error::Cancelled`].
    pub fn render(&self, observer: &dyn Observer<Rgb32FImage>) -> Result<Rgb32FImage> {
        if observer.cancelled() {
            return Err(Error::Cancelled);
        }
        let c = &self.cpu;
        let img = self
            .gpu
            .render(c.environment(), c.camera(), c.velocity(), c.effects())?;
        single_pass_done(observer, u64::from(img.height()), &img);
        Ok(img)
    }
}

impl Session for GpuRelativitySession<'_> {
    type Image = Rgb32FImage;
    type Output = Rgb32FImage;
    type Error = Error;

    fn run(&mut self, observer: &dyn Observer<Rgb32FImage>) -> Result<Rgb32FImage> {
        self.render(observer)
    }

    fn device(&self) -> DeviceKind {
        DeviceKind::Gpu
    }
}
