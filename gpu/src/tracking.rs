//! Woodcock tracking, multi-density Woodcock tracking and the emission-absorption ray
//! marcher on the GPU, behind the CPU's own types: a `blueshift_tracking::Scene`, an
//! `Integrator` and `RenderSettings` (one scene description, two backends).
//!
//! # What is the same as the CPU, and what is not
//! - The counter-based random numbers are the CPU's ([`blueshift_tracking::Rng`]) bit for
//!   bit: SplitMix64 keyed by (seed, pixel, sample, dimension), with 64-bit integers
//!   emulated by pairs of 32-bit words in WGSL ([`rng_probe`] exposes them for tests). Every
//!   pixel sample draws its numbers in the CPU's order, so the marcher's jitter and the
//!   pixel jitter are the CPU's, and the Monte Carlo estimators are the same estimators.
//! - The DDA over the macrocell grid, the camera rays, the trilinear sampling and every
//!   integrator are straight ports of `blueshift-tracking` in f32.
//! - The transfer functions are sampled on the device from lookup tables of
//!   [`GpuTracker::lut_entries`] entries (`TransferFunction::lut`, linear filtering between
//!   entries; on a log10 data axis the entries are uniform in log10 of the value and the
//!   device looks up log10 of the sample) instead of the CPU's exact knot evaluation. For
//!   piecewise-linear transfer functions whose knots fall on table entries this is exact up
//!   to f32 rounding; otherwise the difference is the table's interpolation error (below
//!   1e-4 in opacity for 4096 entries and a smooth function).
//! - The majorant grids are computed on the device from the volume crate's macrocell
//!   min/max ([`GpuScene::set_transfer_function`] re-runs only this pass): for each cell,
//!   the largest table opacity among the entries a linear lookup of any value in the cell's
//!   (slightly widened) range can blend, times the density scale. This bounds what the
//!   device samples exactly, so tracking stays unbiased.
//! - The progressive accumulation is Welford's running mean and sum of squared deviations
//!   per pixel, in f32 on the device (f64 on the CPU).
//! - Gradient shading (`Scene::shading`) and the ray statistics / heat maps are CPU-only:
//!   a scene with shading is refused with [`Error::InvalidInput`].
//!
//! # Loop limit of software adapters
//! lavapipe (llvmpipe) stops every loop of an invocation batch (the SIMD lanes run
//! together) after [`SOFTWARE_LOOP_LIMIT`] iterations in all, silently: a long ray (a small
//! marcher step, a dense volume) would stop half-way and the image come out darker. The
//! render and majorant shaders end with a probe that finds out whether the limiter ran out
//! and set a flag; on a software adapter the flag is read after every dispatch. A dispatch
//! of several samples that ran out is redone from the start one sample per dispatch; a
//! single sample (or a majorant table scan) that runs out is [`Error::Unsupported`] naming
//! the loop limit, never a silently darker image. Hardware adapters have no such limit.
//!
//! # Compositing precision of the marcher
//! `Precision::F16` rounds with the native `f16` type where the device has `SHADER_F16`
//! ([`GpuTracker::native_f16`]), else with an exact emulation of round-to-nearest-even in
//! f32 bit arithmetic; `Precision::U8` rounds half away from zero to multiples of 1/255 like
//! the CPU.

use blueshift_camera::{DeviceKind, Observer, Progress, ProgressOnly, Session, Silent};
use blueshift_tfedit::{DataAxis, TransferFunction};
use blueshift_tracking::{
    Blend, DdaMode, Integrator, Precision, Progressive, Projection, RenderSettings, Scene,
    TrackingOutput,
};
use bytemuck::{Pod, Zeroable};
use glam::Vec3;
use image::Rgba32FImage;

use crate::context::{GpuContext, WORKGROUP_1D, WORKGROUP_2D};
use crate::device::Unsupported;
use crate::error::{Error, Result};
use crate::pool::{DevicePool, PoolChannel};

/// WGSL of the tracking pipelines (render pass, majorant build, probes).
pub const TRACKING_WGSL: &str = concat!(
    include_str!("shaders/limiter.wgsl"),
    include_str!("shaders/tracking.wgsl"),
    include_str!("shaders/pool.wgsl")
);

/// Entries of each transfer function's lookup table unless told otherwise.
pub const DEFAULT_LUT_ENTRIES: usize = 4096;

/// Samples per pixel rendered by one dispatch (bounds the time of one submission).
pub const SAMPLES_PER_DISPATCH: u32 = 4;

/// Trip count of the shaders' loop-limiter probe (`limiter_exhausted`): a uniform, so that
/// the probe's loop is not unrolled.
const PROBE_N: u32 = 2;

/// The loop limit of software adapters: lavapipe (llvmpipe) stops every loop of an
/// invocation batch after this many loop iterations in all, silently.
pub const SOFTWARE_LOOP_LIMIT: u32 = 65535;

const F16_EMULATED_LINE: &str = "return f16_emulated(v); // F16_IMPL";

/// The tracking WGSL with native half-precision rounding (`enable f16;`, `f32(f16(v))`)
/// when `native_f16`, else the emulated rounding.
#[must_use]
pub fn tracking_wgsl(native_f16: bool) -> String {
    if native_f16 {
        format!(
            "enable f16;\n{}",
            TRACKING_WGSL.replace(F16_EMULATED_LINE, "return f32(f16(v));")
        )
    } else {
        TRACKING_WGSL.to_string()
    }
}

#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct Params {
    width: u32,
    height: u32,
    sample_begin: u32,
    sample_count: u32,
    seed_lo: u32,
    seed_hi: u32,
    n_channels: u32,
    lut_len: u32,
    dims: [u32; 3],
    k: u32,
    cdims: [u32; 3],
    n_cells: u32,
    origin: [f32; 3],
    density_scale: f32,
    spacing: [f32; 3],
    projection: u32,
    eye: [f32; 3],
    cam_h: f32,
    fwd: [f32; 3],
    jitter: u32,
    right: [f32; 3],
    kind: u32,
    up: [f32; 3],
    dda: u32,
    background: [f32; 3],
    blend: u32,
    light_dir: [f32; 3],
    has_light: u32,
    light_radiance: [f32; 3],
    ambient: f32,
    bounds_lo: [f32; 3],
    step: f32,
    bounds_hi: [f32; 3],
    early_termination: f32,
    precision: u32,
    channel: u32,
    probe_n: u32,
    pad1: u32,
    frame_lo: [f32; 3],
    framed: u32,
    frame_hi: [f32; 3],
    open_sides: u32,
}

#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct MajorantParams {
    n_cells: u32,
    n_channels: u32,
    lut_len: u32,
    channel: u32,
    density_scale: f32,
    probe_n: u32,
    pad: [u32; 2],
}

/// [`crate::layout::pod_layouts`] of this module, in both f16 variants of the shader.
pub(crate) fn pod_layouts() -> Vec<crate::layout::PodLayout> {
    use crate::layout::pod_layout;
    let mut out = Vec::new();
    for (native_f16, shader) in [
        (false, "tracking.wgsl (emulated f16)"),
        (true, "tracking.wgsl (native f16)"),
    ] {
        let src = tracking_wgsl(native_f16);
        out.push(pod_layout!(Params => "Params", shader, &src, {
            width, height, sample_begin, sample_count, seed_lo, seed_hi, n_channels, lut_len,
            dims, k, cdims, n_cells, origin, density_scale, spacing, projection, eye, cam_h, fwd,
            jitter, right, kind, up, dda, background, blend, light_dir, has_light,
            light_radiance, ambient, bounds_lo, step, bounds_hi, early_termination,
            precision as "prec_mode", channel, probe_n, pad1 as "_pad1", frame_lo, framed,
            frame_hi, open_sides,
        }));
        out.push(
            pod_layout!(MajorantParams => "MajorantParams", shader, &src, {
                n_cells, n_channels, lut_len, channel, density_scale, probe_n,
                pad as "_pad1", pad as "_pad2" + 4,
            }),
        );
    }
    out
}

/// Creates a bind group for `pipeline`'s group 0 with explicit `(binding, buffer)` pairs.
fn bind(
    ctx: &GpuContext,
    pipeline: &wgpu::ComputePipeline,
    entries: &[(u32, &wgpu::Buffer)],
) -> Result<wgpu::BindGroup> {
    ctx.scoped(|| {
        let layout = pipeline.get_bind_group_layout(0);
        let entries: Vec<wgpu::BindGroupEntry<'_>> = entries
            .iter()
            .map(|(b, buf)| wgpu::BindGroupEntry {
                binding: *b,
                resource: buf.as_entire_binding(),
            })
            .collect();
        ctx.device().create_bind_group(&wgpu::BindGroupDescriptor {
            label: None,
            layout: &layout,
            entries: &entries,
        })
    })
}

/// Writes `data` into `buffer` at byte `offset`, checking the range first.
fn write_at<T: Pod>(
    ctx: &GpuContext,
    buffer: &wgpu::Buffer,
    offset: u64,
    data: &[T],
) -> Result<()> {
    let bytes: &[u8] = bytemuck::cast_slice(data);
    if offset + bytes.len() as u64 > buffer.size() {
        return Err(Error::InvalidInput(format!(
            "writing {} bytes at {offset} into a buffer of {}",
            bytes.len(),
            buffer.size()
        )));
    }
    ctx.scoped(|| ctx.queue().write_buffer(buffer, offset, bytes))
}

/// What to change when a tracking shader runs out of the loop limit.
const TRACKING_HINT: &str = "fewer steps per ray (a larger marcher step, a smaller density \
                             scale or volume)";

/// Reads a loop-limit flag written by a shader's probe (`limiter_exhausted`); set means
/// that some invocation batch ran out of the adapter's loop limit, so loops may have
/// stopped early: [`Error::Unsupported`] naming the limit (never a silently wrong result).
pub(crate) fn check_loop_limit(
    ctx: &GpuContext,
    flag: &wgpu::Buffer,
    what: &str,
    hint: &str,
) -> Result<()> {
    let v: Vec<u32> = ctx.read_buffer(flag, 1)?;
    if v[0] == 0 {
        return Ok(());
    }
    Err(loop_limit_error(ctx, what, hint))
}

pub(crate) fn loop_limit_error(ctx: &GpuContext, what: &str, hint: &str) -> Error {
    Error::Unsupported(format!(
        "{what} passed the loop limit of the adapter {:?}: software adapters such as \
         lavapipe stop every loop of an invocation batch after {SOFTWARE_LOOP_LIMIT} \
         iterations in all, which would silently give a wrong result; use a hardware GPU or \
         the CPU (--device cpu), or {hint}",
        ctx.info().name
    ))
}

/// Zero-fills `buffers` on the device and waits.
fn clear_buffers(ctx: &GpuContext, buffers: &[&wgpu::Buffer]) -> Result<()> {
    ctx.scoped(|| {
        let mut enc = ctx
            .device()
            .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: None });
        for b in buffers {
            enc.clear_buffer(b, 0, None);
        }
        ctx.queue().submit([enc.finish()]);
    })?;
    ctx.wait()
}

/// Element count times element size, checked against the device's storage limits (and
/// the 32-bit indexing of the shaders) before anything is allocated.
fn checked_bytes(ctx: &GpuContext, what: &str, count: u64, elem: u64) -> Result<u64> {
    let bytes = count
        .checked_mul(elem)
        .ok_or_else(|| Error::LimitExceeded {
            what: what.into(),
            limit: "max_buffer_size",
            requested: u64::MAX,
            max: ctx.limits().max_buffer_size,
        })?;
    ctx.check_storage_size(what, bytes)?;
    if count > u64::from(u32::MAX) {
        return Err(Error::LimitExceeded {
            what: what.into(),
            limit: "u32 element index of the shaders",
            requested: count,
            max: u64::from(u32::MAX),
        });
    }
    Ok(bytes)
}

/// Checks what a scene of `n_channels` channels of `dims` voxels with macrocells of `k`
/// voxels needs on the device besides its voxels: the brick pool's page table, the
/// macrocell ranges and the majorant grids against `max_buffer_size` and
/// `max_storage_buffer_binding_size`, and the shaders' 32-bit indices. The voxels go to the
/// device brick pool ([`crate::pool`]), which holds only non-constant bricks and is checked
/// as it fills. The error names the limit; nothing is allocated.
pub fn check_volume_fits(
    ctx: &GpuContext,
    n_channels: usize,
    dims: [usize; 3],
    k: usize,
) -> Result<()> {
    for (a, d) in dims.iter().enumerate() {
        if u32::try_from(*d).is_err() {
            return Err(Error::LimitExceeded {
                what: format!("volume dimension {a}"),
                limit: "u32 voxel coordinate",
                requested: *d as u64,
                max: u64::from(u32::MAX),
            });
        }
    }
    let n = n_channels as u64;
    let bricks = crate::pool::pool_bricks(dims)
        .iter()
        .fold(1u64, |a, &d| a.saturating_mul(d as u64));
    let what = format!(
        "brick pool page table ({n} channels of {}x{}x{} voxels)",
        dims[0], dims[1], dims[2]
    );
    checked_bytes(ctx, &what, n.saturating_mul(bricks), 8)?;
    let k = k.max(1) as u64;
    let cells = dims.iter().fold(1u64, |a, &d| {
        a.saturating_mul((d as u64).div_ceil(k).max(1))
    });
    checked_bytes(
        ctx,
        "macrocell ranges",
        n.saturating_mul(2).saturating_mul(cells),
        4,
    )?;
    checked_bytes(ctx, "majorant grids", (n + 1).saturating_mul(cells), 4)?;
    Ok(())
}

/// The compiled tracking pipelines of one [`GpuContext`]; compile once, upload many scenes
/// (cloning shares the pipelines).
#[derive(Clone, Debug)]
pub struct GpuTracker<'c> {
    ctx: &'c GpuContext,
    render: wgpu::ComputePipeline,
    build_majorants: wgpu::ComputePipeline,
    sum_majorants: wgpu::ComputePipeline,
    native_f16: bool,
    lut_entries: usize,
}

impl<'c> GpuTracker<'c> {
    /// Compiles the pipelines (native f16 where the device has `SHADER_F16`) with
    /// [`DEFAULT_LUT_ENTRIES`]-entry transfer-function tables.
    pub fn new(ctx: &'c GpuContext) -> Result<Self> {
        Self::with_options(ctx, ctx.has_f16(), DEFAULT_LUT_ENTRIES)
    }

    /// Compiles the pipelines with native half precision or not (`native_f16` is refused
    /// without `SHADER_F16`) and `lut_entries` entries per table (2 to 2^20).
    pub fn with_options(ctx: &'c GpuContext, native_f16: bool, lut_entries: usize) -> Result<Self> {
        if native_f16 && !ctx.has_f16() {
            return Err(Error::InvalidInput(
                "native f16 asked for, but the device has no SHADER_F16".into(),
            ));
        }
        if !(2..=1 << 20).contains(&lut_entries) {
            return Err(Error::InvalidInput(format!(
                "lut_entries: {lut_entries} must be in 2..=1048576"
            )));
        }
        let src = tracking_wgsl(native_f16);
        Ok(GpuTracker {
            ctx,
            render: ctx.compute_pipeline("tracking render_pass", &src, "render_pass")?,
            build_majorants: ctx.compute_pipeline(
                "tracking build_majorants",
                &src,
                "build_majorants",
            )?,
            sum_majorants: ctx.compute_pipeline("tracking sum_majorants", &src, "sum_majorants")?,
            native_f16,
            lut_entries,
        })
    }

    /// The context.
    #[must_use]
    pub fn context(&self) -> &'c GpuContext {
        self.ctx
    }

    /// Whether f16 compositing uses the native type (else the exact emulation).
    #[must_use]
    pub fn native_f16(&self) -> bool {
        self.native_f16
    }

    /// Entries of each transfer function's lookup table.
    #[must_use]
    pub fn lut_entries(&self) -> usize {
        self.lut_entries
    }

    /// Uploads `scene` (its channels into the device brick pool, lookup tables, macrocell
    /// ranges) and builds its majorant grids on the device. Page tables, macrocells and
    /// majorants over the device's limits are refused with [`Error::LimitExceeded`] naming
    /// the limit before anything is allocated; non-constant bricks beyond the pool's
    /// capacity with the pool's [`crate::pool::POOL_LIMIT`].
    pub fn upload(&self, scene: Scene) -> Result<GpuScene<'c>> {
        GpuScene::new(self.clone(), scene)
    }

    /// [`GpuTracker::upload`] at the scene's level of detail when its brick pool fits the
    /// device, else at the finest coarser level that fits (every channel bricked alike,
    /// [`Scene::lod`]; levels known to overflow from stored macrocells are skipped without
    /// reading a brick). Returns the uploaded scene and the level it holds (`None` in core).
    pub fn upload_fitting(&self, scene: Scene) -> Result<(GpuScene<'c>, Option<usize>)> {
        let Some((first, levels)) = scene.lod() else {
            return Ok((self.upload(scene)?, None));
        };
        let mut last = None;
        for level in first..levels {
            let s = if level == first {
                scene.clone()
            } else {
                scene
                    .at_level(level)
                    .map_err(|e| Error::InvalidInput(e.to_string()))?
            };
            let est = scene_estimate(self.ctx, &s)?;
            if est.surely_full() {
                continue;
            }
            match self.upload(s) {
                Ok(gs) => return Ok((gs, Some(level))),
                Err(e) if crate::pool::is_pool_full(&e) => last = Some(e),
                Err(e) => return Err(e),
            }
        }
        // Even the coarsest level overflows: the finest level's error says by how much.
        match last {
            Some(e) => Err(e),
            None => self.upload(scene).map(|gs| (gs, Some(first))),
        }
    }

    /// [`GpuTracker::upload`] of a scene with per-brick levels of detail (`--lod brick`):
    /// when its pool does not fit the device, every region is moved one level coarser
    /// ([`Scene::coarser_regions`]) until it fits (views known to overflow from stored
    /// macrocells are skipped without reading a brick). Returns the uploaded scene and how
    /// many levels coarser than asked its regions are (0: as asked). A scene without
    /// per-region levels is uploaded as it is.
    ///
    /// # Errors
    /// The pool's [`Error::LimitExceeded`] of the view asked when even every region at the
    /// coarsest level does not fit; as [`GpuTracker::upload`].
    pub fn upload_fitting_regions(&self, scene: Scene) -> Result<(GpuScene<'c>, usize)> {
        let per_region = scene.channels().iter().any(|c| {
            c.grid()
                .as_bricked()
                .is_some_and(|b| b.level_map().is_some())
        });
        if !per_region {
            return Ok((self.upload(scene)?, 0));
        }
        let mut first_err = None;
        for k in 0..=usize::from(u8::MAX) {
            let (s, moved) = if k == 0 {
                (scene.clone(), true)
            } else {
                scene
                    .coarser_regions(k)
                    .map_err(|e| Error::InvalidInput(e.to_string()))?
            };
            if !moved {
                break;
            }
            let est = scene_estimate(self.ctx, &s)?;
            let attempt = if est.surely_full() {
                Err(crate::pool::pool_full(self.ctx, est.slots))
            } else {
                self.upload(s)
            };
            match attempt {
                Ok(gs) => return Ok((gs, k)),
                Err(e) if crate::pool::is_pool_full(&e) => {
                    first_err.get_or_insert(e);
                }
                Err(e) => return Err(e),
            }
        }
        Err(first_err.unwrap_or_else(|| Error::InvalidInput("no per-brick view fits".into())))
    }

    /// Renders `settings.spp` passes (or fewer once `settings.noise_target` is met),
    /// calling `progress(samples, noise)` after each dispatch, and returns the per-pixel
    /// mean and variance. [`GpuTrackingSession`] runs the same loop under an observer.
    pub fn render_progressive(
        &self,
        scene: &GpuScene<'c>,
        integrator: &Integrator,
        settings: &RenderSettings,
        mut progress: impl FnMut(u32, f64),
    ) -> Result<Progressive> {
        self.render_loop(scene, integrator, settings, &Silent, &mut progress)
    }

    /// The render loop under `observer`: progress after every dispatch, the accumulation
    /// buffer whenever it is read back (every pass with a noise target, else at the end),
    /// cancel polled before every dispatch ([`Error::Cancelled`]).
    ///
    /// # Errors
    /// As [`GpuTracker::render_progressive`]; [`Error::Cancelled`].
    pub fn render_observed(
        &self,
        scene: &GpuScene<'c>,
        integrator: &Integrator,
        settings: &RenderSettings,
        observer: &dyn Observer<Progressive>,
    ) -> Result<Progressive> {
        self.render_loop(scene, integrator, settings, observer, &mut |_, _| {})
    }

    /// The loop of [`GpuTracker::render_observed`], also calling `on_dispatch(samples,
    /// noise)` after every dispatch (noise infinite when it was not read back).
    fn render_loop(
        &self,
        scene: &GpuScene<'c>,
        integrator: &Integrator,
        settings: &RenderSettings,
        observer: &dyn Observer<Progressive>,
        on_dispatch: &mut dyn FnMut(u32, f64),
    ) -> Result<Progressive> {
        settings
            .validate()
            .map_err(|e| Error::InvalidInput(e.to_string()))?;
        let cpu = &scene.scene;
        supports(cpu, settings)?;
        if !scene.pool.is_valid() {
            return Err(Error::InvalidInput(
                "the scene's brick pool failed to update: set a view or upload it again".into(),
            ));
        }
        let integrator = integrator
            .prepared(cpu)
            .map_err(|e| Error::InvalidInput(e.to_string()))?;
        let mut params = scene.base_params();
        fill_settings(&mut params, settings);
        let weights = fill_integrator(&mut params, &integrator, cpu);
        // The blend weights go into this render's own copy of the channel table, so the
        // scene on the device is never written by a render.
        let mut chan = scene.chan.clone();
        for (n, w) in weights.iter().enumerate() {
            chan[2 * n][2] = *w;
        }
        let chan_buf = self
            .ctx
            .storage_buffer("tracking channels (render)", &chan)?;

        let pixels = u64::from(settings.width) * u64::from(settings.height);
        checked_bytes(
            self.ctx,
            "accumulation buffer (pixels x RGBA f32)",
            pixels,
            16,
        )?;
        let mean = self
            .ctx
            .storage_buffer_zeroed("tracking mean", pixels * 16)?;
        let m2 = self.ctx.storage_buffer_zeroed("tracking m2", pixels * 16)?;
        let pbuf = self.ctx.uniform_buffer("tracking params", &params)?;
        let limited = self
            .ctx
            .storage_buffer("tracking loop-limit flag", &[0u32])?;
        let bg = bind(
            self.ctx,
            &self.render,
            &[
                (0, &pbuf),
                (1, &scene.pool.pool),
                (8, &scene.pool.pages),
                (2, &scene.luts),
                (3, &scene.majorants),
                (4, &mean),
                (5, &m2),
                (6, &chan_buf),
                (7, &limited),
            ],
        )?;
        let gx = self
            .ctx
            .groups("tracking image width", settings.width, WORKGROUP_2D)?;
        let gy = self
            .ctx
            .groups("tracking image height", settings.height, WORKGROUP_2D)?;
        let mut done = 0u32;
        // With a noise target every pass is read back to test it; else larger batches.
        let mut batch = if settings.noise_target.is_some() {
            1
        } else {
            SAMPLES_PER_DISPATCH
        };
        // Software adapters have a loop limit per invocation batch (see
        // `check_loop_limit`): the flag is read after every dispatch there, and a dispatch
        // of several samples that ran out is redone from the start one sample at a time.
        let software = !self.ctx.is_hardware();
        while done < settings.spp {
            if observer.cancelled() {
                return Err(Error::Cancelled);
            }
            let count = batch.min(settings.spp - done);
            params.sample_begin = done;
            params.sample_count = count;
            self.ctx
                .write_buffer(&pbuf, std::slice::from_ref(&params))?;
            self.ctx.dispatch(&self.render, &bg, [gx, gy, 1])?;
            if software || done + count >= settings.spp {
                let flag: Vec<u32> = self.ctx.read_buffer(&limited, 1)?;
                if flag[0] != 0 {
                    if count == 1 {
                        return Err(loop_limit_error(
                            self.ctx,
                            "a pixel sample's ray",
                            TRACKING_HINT,
                        ));
                    }
                    batch = 1;
                    done = 0;
                    clear_buffers(self.ctx, &[&mean, &m2, &limited])?;
                    continue;
                }
            }
            done += count;
            if let Some(target) = settings.noise_target {
                let out = read_progressive(self.ctx, settings, &mean, &m2, done)?;
                let noise = out.noise();
                observer.progress(Progress {
                    done: u64::from(done),
                    total: u64::from(settings.spp),
                    pass: done,
                });
                observer.pass(done, &out, noise.is_finite().then_some(noise));
                on_dispatch(done, noise);
                if done >= 2 && noise <= target {
                    return Ok(out);
                }
            } else {
                observer.progress(Progress {
                    done: u64::from(done),
                    total: u64::from(settings.spp),
                    pass: done,
                });
                on_dispatch(done, f64::INFINITY);
            }
        }
        let out = read_progressive(self.ctx, settings, &mean, &m2, done)?;
        if settings.noise_target.is_none() {
            let noise = out.noise();
            observer.pass(done, &out, noise.is_finite().then_some(noise));
        }
        Ok(out)
    }

    /// Renders the mean image (linear HDR RGB, alpha = 1 - transmittance), like
    /// `blueshift_tracking::render`.
    pub fn render(
        &self,
        scene: &GpuScene<'c>,
        integrator: &Integrator,
        settings: &RenderSettings,
    ) -> Result<Rgba32FImage> {
        Ok(self
            .render_progressive(scene, integrator, settings, |_, _| {})?
            .mean_image())
    }
}

/// What `scene`'s pool needs, known without reading a brick ([`crate::pool::estimate`]).
fn scene_estimate(ctx: &GpuContext, scene: &Scene) -> Result<crate::pool::PoolEstimate> {
    let channels: Vec<PoolChannel<'_>> = scene
        .channels()
        .iter()
        .map(|c| PoolChannel::Scalar(c.grid()))
        .collect();
    crate::pool::estimate(ctx, &channels)
}

/// `Ok` when the GPU tracker covers `scene` + `settings`, else why not: gradient shading,
/// heat maps and the timing protocol are CPU-only.
pub fn supports(scene: &Scene, settings: &RenderSettings) -> std::result::Result<(), Unsupported> {
    crate::pool::per_brick_unsupported(scene.channels().iter().map(|c| c.grid()))?;
    if scene.shading.is_some() {
        return Err(Unsupported(
            "gradient shading (scene.shading) is CPU-only; render it with --device cpu".into(),
        ));
    }
    if settings.heatmaps {
        return Err(Unsupported("heat maps are CPU-only".into()));
    }
    if scene.clip.is_some() {
        return Err(Unsupported(
            "a clip box (data-parallel distributed rendering) is CPU-only".into(),
        ));
    }
    if settings.observer.is_some_and(|o| !o.is_at_rest()) {
        return Err(Unsupported(
            "a moving observer (aberration and colour shift are CPU-only)".into(),
        ));
    }
    if settings.timed_frames.is_some() {
        return Err(Unsupported(
            "the timing protocol (warm-up and timed frames) is CPU-only".into(),
        ));
    }
    Ok(())
}

fn v3(v: Vec3) -> [f32; 3] {
    v.to_array()
}

fn fill_settings(p: &mut Params, s: &RenderSettings) {
    let cam = &s.camera;
    let (f, r, u) = cam.basis();
    p.width = s.width;
    p.height = s.height;
    p.seed_lo = s.seed as u32;
    p.seed_hi = (s.seed >> 32) as u32;
    p.eye = v3(cam.eye);
    p.fwd = v3(f);
    p.right = v3(r);
    p.up = v3(u);
    match cam.projection {
        Projection::Perspective { fov_y_deg } => {
            p.projection = 0;
            p.cam_h = (fov_y_deg.to_radians() * 0.5).tan();
        }
        Projection::Orthographic { height } => {
            p.projection = 1;
            p.cam_h = 0.5 * height;
        }
    }
    p.jitter = u32::from(s.jitter_pixels);
}

fn blend_code(b: &Blend) -> (u32, Option<&[f32]>) {
    match b {
        Blend::Density => (0, None),
        Blend::Max => (1, None),
        Blend::Mix { weights } => (2, Some(weights)),
        Blend::Weighted { weights } => (3, Some(weights)),
        Blend::Composite { weights } => (4, Some(weights)),
    }
}

/// Fills the integrator fields; returns the per-channel weights (0 where unused).
fn fill_integrator(p: &mut Params, integ: &Integrator, scene: &Scene) -> Vec<f32> {
    let n = scene.channel_count();
    let mut weights = vec![0.0f32; n];
    let mut set_blend = |p: &mut Params, b: &Blend| {
        let (code, w) = blend_code(b);
        p.blend = code;
        if let Some(w) = w {
            for (dst, src) in weights.iter_mut().zip(w) {
                *dst = *src;
            }
        }
    };
    match integ {
        Integrator::Woodcock { channel } => {
            p.kind = 0;
            p.channel = *channel as u32;
        }
        Integrator::Mdwt { dda, blend } => {
            p.kind = 1;
            p.dda = match dda {
                DdaMode::NDda => 0,
                DdaMode::OneDda => 1,
                DdaMode::Summed => 2,
            };
            set_blend(p, blend);
        }
        Integrator::Marcher(m) => {
            p.kind = 2;
            p.step = m
                .step
                .unwrap_or(0.5 * scene.geometry().spacing.min_element());
            p.early_termination = m.early_termination;
            p.precision = match m.precision {
                Precision::F32 => 0,
                Precision::F16 => 1,
                Precision::U8 => 2,
            };
            set_blend(p, &m.blend);
        }
    }
    weights
}

/// A scene on the device: the channels' voxels, lookup tables, macrocell ranges and
/// majorant grids (built on the device), with the CPU scene it came from.
#[derive(Debug)]
pub struct GpuScene<'c> {
    tracker: GpuTracker<'c>,
    scene: Scene,
    pool: DevicePool,
    luts: wgpu::Buffer,
    cell_ranges: wgpu::Buffer,
    majorants: wgpu::Buffer,
    chan_buf: wgpu::Buffer,
    chan: Vec<[f32; 4]>,
    n_cells: u32,
}

impl<'c> GpuScene<'c> {
    fn new(tracker: GpuTracker<'c>, scene: Scene) -> Result<Self> {
        let ctx = tracker.ctx;
        let n = scene.channel_count();
        let g = *scene.geometry();
        let layout = *scene.layout();
        let n_cells = layout.len() as u64;
        let lut_len = tracker.lut_entries as u64;
        // Every size is checked against the device before anything is allocated.
        check_volume_fits(ctx, n, g.dims, layout.k)?;
        checked_bytes(ctx, "lookup tables", n as u64 * lut_len, 16)?;
        let channels: Vec<PoolChannel<'_>> = scene
            .channels()
            .iter()
            .map(|c| PoolChannel::Scalar(c.grid()))
            .collect();
        let pool = crate::pool::upload(ctx, "tracking volume", &channels)?;
        drop(channels);
        let mut lut_data: Vec<[f32; 4]> = Vec::with_capacity(n * tracker.lut_entries);
        let mut chan = Vec::with_capacity(2 * n);
        let mut ranges: Vec<f32> = Vec::with_capacity(2 * n * n_cells as usize);
        for ch in scene.channels() {
            let tf = ch.transfer_function();
            push_lut(&mut lut_data, tf, tracker.lut_entries)?;
            chan.extend(chan_info(tf));
            ranges.extend_from_slice(ch.macrocells().mins());
            ranges.extend_from_slice(ch.macrocells().maxs());
        }
        let luts = ctx.storage_buffer("tracking lookup tables", &lut_data)?;
        let cell_ranges = ctx.storage_buffer("tracking macrocell ranges", &ranges)?;
        let majorants =
            ctx.storage_buffer_zeroed("tracking majorants", (n as u64 + 1) * n_cells * 4)?;
        let chan_buf = ctx.storage_buffer("tracking channels", &chan)?;
        let gs = GpuScene {
            tracker,
            scene,
            pool,
            luts,
            cell_ranges,
            majorants,
            chan_buf,
            chan,
            n_cells: n_cells as u32,
        };
        gs.build_majorants(None)?;
        Ok(gs)
    }

    /// Samples another view of this scene's channels from now on: `view` has the scene's
    /// channels from the same `.bsv` sources, at another level of detail
    /// (`Scene::at_level`) or with per-region levels (`Scene::resident_view`, `--lod
    /// brick`). The device pool keeps the bricks it holds and uploads only the missing ones
    /// ([`crate::pool::DevicePool::update`]: a device brick cache, evicting the least
    /// recently used bricks when full); the macrocell ranges and majorants are rebuilt. The
    /// transfer functions, background and light stay this scene's.
    ///
    /// # Errors
    /// A view of other channels, [`Error::Unsupported`] for channels whose regions differ,
    /// the pool's [`Error::LimitExceeded`] when the view's bricks exceed it, a read error.
    /// After an error the scene renders nothing until a view is set successfully.
    pub fn set_view(&mut self, view: Scene) -> Result<()> {
        let n = self.scene.channel_count();
        let uid =
            |c: &blueshift_tracking::SceneChannel| c.grid().as_bricked().map(|b| b.source().uid());
        let same = view.channel_count() == n
            && self
                .scene
                .channels()
                .iter()
                .zip(view.channels())
                .all(|(a, b)| uid(a).is_some() && uid(a) == uid(b));
        if !same {
            return Err(Error::InvalidInput(
                "a view of a GPU scene must have the scene's own .bsv channels".into(),
            ));
        }
        crate::pool::per_brick_unsupported(view.channels().iter().map(|c| c.grid()))
            .map_err(|u| Error::Unsupported(u.0))?;
        let ctx = self.tracker.ctx;
        let layout = *view.layout();
        check_volume_fits(ctx, n, view.geometry().dims, layout.k)?;
        // Everything that can fail before the pool changes; after it, only the majorant
        // build (a failure there leaves the pool invalid: the scene renders nothing).
        let n_cells = layout.len() as u64;
        let mut ranges: Vec<f32> = Vec::with_capacity(2 * n * n_cells as usize);
        for ch in view.channels() {
            ranges.extend_from_slice(ch.macrocells().mins());
            ranges.extend_from_slice(ch.macrocells().maxs());
        }
        let cell_ranges = ctx.storage_buffer("tracking macrocell ranges", &ranges)?;
        let majorants =
            ctx.storage_buffer_zeroed("tracking majorants", (n as u64 + 1) * n_cells * 4)?;
        let mut view = view;
        for i in 0..n {
            let tf = self.scene.channels()[i].transfer_function();
            if view.channels()[i].transfer_function() != tf {
                view.set_transfer_function(i, tf.clone())
                    .map_err(|e| Error::InvalidInput(e.to_string()))?;
            }
        }
        view.background = self.scene.background;
        view.light = self.scene.light;
        let channels: Vec<PoolChannel<'_>> = view
            .channels()
            .iter()
            .map(|c| PoolChannel::Scalar(c.grid()))
            .collect();
        self.pool.update(ctx, "tracking volume", &channels)?;
        drop(channels);
        self.cell_ranges = cell_ranges;
        self.majorants = majorants;
        self.n_cells = n_cells as u32;
        self.scene = view;
        if let Err(e) = self.build_majorants(None) {
            self.pool.invalidate();
            return Err(e);
        }
        Ok(())
    }

    /// What the device brick pool holds.
    #[must_use]
    pub fn pool_stats(&self) -> crate::pool::PoolStats {
        self.pool.stats
    }

    /// The CPU scene this was uploaded from (kept in step with every edit).
    #[must_use]
    pub fn scene(&self) -> &Scene {
        &self.scene
    }

    /// Sets the background colour (no upload: it is a render parameter).
    pub fn set_background(&mut self, rgb: [f32; 3]) {
        self.scene.background = rgb;
    }

    /// Sets or clears the directional light (shadow rays).
    pub fn set_light(&mut self, light: Option<blueshift_tracking::DirectionalLight>) {
        self.scene.light = light;
    }

    /// Replaces channel `i`'s transfer function: uploads its lookup table and rebuilds only
    /// the majorants on the device (channel `i`'s grid, then the total); the volume stays.
    /// The CPU scene is updated too.
    pub fn set_transfer_function(&mut self, i: usize, tf: TransferFunction) -> Result<()> {
        let n = self.scene.channel_count();
        if i >= n {
            return Err(Error::InvalidInput(format!(
                "channel {i} out of range (0..{n})"
            )));
        }
        let ctx = self.tracker.ctx;
        let mut lut = Vec::with_capacity(self.tracker.lut_entries);
        push_lut(&mut lut, &tf, self.tracker.lut_entries)?;
        write_at(
            ctx,
            &self.luts,
            (i * self.tracker.lut_entries * 16) as u64,
            &lut,
        )?;
        let info = chan_info(&tf);
        self.chan[2 * i] = info[0];
        self.chan[2 * i + 1] = info[1];
        write_at(ctx, &self.chan_buf, 0, &self.chan)?;
        self.scene
            .set_transfer_function(i, tf)
            .map_err(|e| Error::InvalidInput(e.to_string()))?;
        self.build_majorants(Some(i))
    }

    fn build_majorants(&self, channel: Option<usize>) -> Result<()> {
        let t = &self.tracker;
        let ctx = t.ctx;
        let n = self.scene.channel_count() as u32;
        let mp = MajorantParams {
            n_cells: self.n_cells,
            n_channels: n,
            lut_len: t.lut_entries as u32,
            channel: channel.map_or(n, |c| c as u32),
            density_scale: self.scene.density_scale(),
            probe_n: PROBE_N,
            pad: [0; 2],
        };
        let pbuf = ctx.uniform_buffer("majorant params", &mp)?;
        let entries = [
            (10, &pbuf),
            (11, &self.cell_ranges),
            (12, &self.luts),
            (13, &self.chan_buf),
            (14, &self.majorants),
        ];
        let limited = ctx.storage_buffer("majorant loop-limit flag", &[0u32])?;
        let entries = [
            entries[0],
            entries[1],
            entries[2],
            entries[3],
            entries[4],
            (15, &limited),
        ];
        let bg_build = bind(ctx, &t.build_majorants, &entries)?;
        let bg_sum = bind(ctx, &t.sum_majorants, &[(10, &pbuf), (14, &self.majorants)])?;
        let gx = ctx.groups("majorant cells", self.n_cells, WORKGROUP_1D)?;
        let gy = if channel.is_some() { 1 } else { n };
        ctx.run_passes(&[
            crate::context::Pass {
                pipeline: &t.build_majorants,
                bind_groups: &[&bg_build],
                workgroups: [gx, gy, 1],
            },
            crate::context::Pass {
                pipeline: &t.sum_majorants,
                bind_groups: &[&bg_sum],
                workgroups: [gx, 1, 1],
            },
        ])?;
        check_loop_limit(
            ctx,
            &limited,
            "building the majorants (scanning the lookup tables)",
            "shorter lookup tables",
        )
    }

    /// The majorant grids read back from the device: one per channel (cells x fastest, like
    /// `MajorantGrid::values`), then the cell-wise total.
    pub fn majorants(&self) -> Result<Vec<Vec<f32>>> {
        let n = self.scene.channel_count() + 1;
        let cells = self.n_cells as usize;
        let all: Vec<f32> = self.tracker.ctx.read_buffer(&self.majorants, n * cells)?;
        Ok(all.chunks(cells).map(<[f32]>::to_vec).collect())
    }

    fn base_params(&self) -> Params {
        let g = self.scene.geometry();
        let l = self.scene.layout();
        let (lo, hi) = self.scene.bounds();
        let light = self.scene.light;
        let mut p = Params::zeroed();
        p.n_channels = self.scene.channel_count() as u32;
        p.lut_len = self.tracker.lut_entries as u32;
        p.dims = g.dims.map(|d| d as u32);
        p.k = l.k as u32;
        p.cdims = l.dims.map(|d| d as u32);
        p.n_cells = self.n_cells;
        p.origin = v3(g.origin);
        p.spacing = v3(g.spacing);
        p.density_scale = self.scene.density_scale();
        p.background = self.scene.background;
        if let Some(l) = light {
            p.has_light = 1;
            p.light_dir = v3(l.direction.try_normalize().unwrap_or(Vec3::Z));
            p.light_radiance = l.radiance;
            p.ambient = l.ambient;
        }
        p.bounds_lo = v3(lo);
        p.bounds_hi = v3(hi);
        // A coarser level: rays clipped to the finest level's box (CellLayout::frame).
        let [flo, fhi] = l.frame;
        let top = Vec3::new(
            (g.dims[0] - 1) as f32,
            (g.dims[1] - 1) as f32,
            (g.dims[2] - 1) as f32,
        );
        if flo != Vec3::ZERO || fhi != top {
            p.framed = 1;
            p.frame_lo = v3(flo);
            p.frame_hi = v3(fhi);
            for a in 0..3 {
                p.open_sides |= u32::from(flo[a] < 0.0) << a;
                p.open_sides |= u32::from(fhi[a] > top[a]) << (a + 3);
            }
        }
        p.early_termination = 1.0;
        p.step = 1.0;
        p.probe_n = PROBE_N;
        p
    }
}

/// The device's table of `tf`: entries uniform in the transfer function's interpolation
/// coordinate, i.e. in the data value (`TransferFunction::lut`) or, on a logarithmic data
/// axis, in log10 of it, so that linear filtering between entries follows the function
/// as closely on either axis (a table uniform in the data value would put the lowest
/// decades of a log axis between its first two entries).
fn push_lut(out: &mut Vec<[f32; 4]>, tf: &TransferFunction, entries: usize) -> Result<()> {
    if tf.data_axis() == DataAxis::Log {
        if !(2..=1 << 24).contains(&entries) {
            return Err(Error::InvalidInput(format!(
                "a lookup table needs 2 to 2^24 entries, got {entries}"
            )));
        }
        let axis = DataAxis::Log;
        let [lo, hi] = tf.domain().map(|v| axis.coord(v));
        let step = (hi - lo) / (entries - 1) as f64;
        out.extend((0..entries).map(|i| {
            let c = if i + 1 == entries {
                hi
            } else {
                lo + i as f64 * step
            };
            tf.eval(axis.value(c))
        }));
        return Ok(());
    }
    let lut = tf
        .lut(entries)
        .map_err(|e| Error::InvalidInput(e.to_string()))?;
    out.extend(
        lut.as_rgba()
            .chunks_exact(4)
            .map(|c| [c[0], c[1], c[2], c[3]]),
    );
    Ok(())
}

/// The channel table's entries: (axis coordinate of the domain's min and max, blend weight
/// (set per render), 1 on a log10 axis), (NaN colour, 0).
fn chan_info(tf: &TransferFunction) -> [[f32; 4]; 2] {
    let axis = tf.data_axis();
    let [lo, hi] = tf.domain().map(|v| axis.coord(v));
    let log = if axis == DataAxis::Log { 1.0 } else { 0.0 };
    let [r, g, b] = tf.nan_color();
    [[lo as f32, hi as f32, 0.0, log], [r, g, b, 0.0]]
}

/// Reads the device's running mean and sum of squared deviations (f32 Welford) into the
/// CPU's accumulation buffer, so noise, variance and the mean image are computed by the one
/// implementation, `blueshift_tracking::Progressive`.
fn read_progressive(
    ctx: &GpuContext,
    settings: &RenderSettings,
    mean: &wgpu::Buffer,
    m2: &wgpu::Buffer,
    samples: u32,
) -> Result<Progressive> {
    let n = settings.width as usize * settings.height as usize;
    let widen = |v: Vec<[f32; 4]>| v.into_iter().map(|p| p.map(f64::from)).collect();
    let mean: Vec<[f32; 4]> = ctx.read_buffer(mean, n)?;
    let m2: Vec<[f32; 4]> = ctx.read_buffer(m2, n)?;
    Progressive::from_moments(
        settings.width,
        settings.height,
        samples,
        widen(mean),
        widen(m2),
    )
    .map_err(|e| Error::InvalidInput(e.to_string()))
}

/// The raw 64-bit outputs of the device's counter-based generator for each key
/// `(seed, pixel, sample)`: dimensions 0..8, for comparison with
/// `blueshift_tracking::Rng::at`. Pixel and sample indices are 32-bit on the device.
pub fn rng_probe(tracker: &GpuTracker<'_>, keys: &[(u64, u32, u32)]) -> Result<Vec<[u64; 8]>> {
    let ctx = tracker.ctx;
    if keys.is_empty() {
        return Ok(Vec::new());
    }
    let n =
        u32::try_from(keys.len()).map_err(|_| Error::InvalidInput("too many probe keys".into()))?;
    let pipeline = probe_pipeline(tracker, "rng_probe")?;
    let k: Vec<[u32; 4]> = keys
        .iter()
        .map(|&(s, p, q)| [s as u32, (s >> 32) as u32, p, q])
        .collect();
    let kb = ctx.storage_buffer("rng probe keys", &k)?;
    let ob = ctx.storage_buffer_zeroed("rng probe bits", u64::from(n) * 64)?;
    let bg = bind(ctx, &pipeline, &[(20, &kb), (21, &ob)])?;
    let g = ctx.groups("rng probe", n, WORKGROUP_1D)?;
    ctx.dispatch(&pipeline, &bg, [g, 1, 1])?;
    let bits: Vec<[u32; 2]> = ctx.read_buffer(&ob, keys.len() * 8)?;
    Ok(bits
        .chunks_exact(8)
        .map(|c| std::array::from_fn(|d| u64::from(c[d][0]) | (u64::from(c[d][1]) << 32)))
        .collect())
}

/// The device's compositing roundings of each value: `(f16, u8)` as the marcher applies
/// them (native or emulated f16 as the tracker was compiled).
pub fn quantise_probe(tracker: &GpuTracker<'_>, values: &[f32]) -> Result<Vec<(f32, f32)>> {
    let ctx = tracker.ctx;
    if values.is_empty() {
        return Ok(Vec::new());
    }
    let n = u32::try_from(values.len())
        .map_err(|_| Error::InvalidInput("too many probe values".into()))?;
    let pipeline = probe_pipeline(tracker, "quantise_probe")?;
    let ib = ctx.storage_buffer("quantise probe in", values)?;
    let ob = ctx.storage_buffer_zeroed("quantise probe out", u64::from(n) * 8)?;
    let bg = bind(ctx, &pipeline, &[(22, &ib), (23, &ob)])?;
    let g = ctx.groups("quantise probe", n, WORKGROUP_1D)?;
    ctx.dispatch(&pipeline, &bg, [g, 1, 1])?;
    let out: Vec<[f32; 2]> = ctx.read_buffer(&ob, values.len())?;
    Ok(out.into_iter().map(|[a, b]| (a, b)).collect())
}

/// The device's trilinear samples of `scene` through its brick pool at each `(channel,
/// index coordinates)`, for comparison with the CPU's `Field::sample_scalar_index`.
pub fn sample_probe(scene: &GpuScene<'_>, points: &[(usize, Vec3)]) -> Result<Vec<f32>> {
    let ctx = scene.tracker.ctx;
    if points.is_empty() {
        return Ok(Vec::new());
    }
    let n = u32::try_from(points.len())
        .map_err(|_| Error::InvalidInput("too many probe points".into()))?;
    let channels = scene.scene.channel_count();
    let mut p = Vec::with_capacity(points.len());
    for &(c, q) in points {
        if c >= channels {
            return Err(Error::InvalidInput(format!(
                "channel {c} of a scene of {channels}"
            )));
        }
        p.push([q.x, q.y, q.z, f32::from_bits(c as u32)]);
    }
    let pipeline = probe_pipeline(&scene.tracker, "sample_probe")?;
    let pb = ctx.uniform_buffer("sample probe params", &scene.base_params())?;
    let ib = ctx.storage_buffer("sample probe points", &p)?;
    let ob = ctx.storage_buffer_zeroed("sample probe out", u64::from(n) * 4)?;
    let bg = bind(
        ctx,
        &pipeline,
        &[
            (0, &pb),
            (1, &scene.pool.pool),
            (8, &scene.pool.pages),
            (24, &ib),
            (25, &ob),
        ],
    )?;
    let g = ctx.groups("sample probe", n, WORKGROUP_1D)?;
    ctx.dispatch(&pipeline, &bg, [g, 1, 1])?;
    ctx.read_buffer(&ob, points.len())
}

fn probe_pipeline(tracker: &GpuTracker<'_>, entry: &str) -> Result<wgpu::ComputePipeline> {
    // Probes are for tests: compiled on demand, not kept.
    tracker.ctx.compute_pipeline(
        &format!("tracking {entry}"),
        &tracking_wgsl(tracker.native_f16),
        entry,
    )
}

/// A tracking render session on a GPU: the scene uploaded once (volume, lookup tables,
/// majorant grids on the device), the integrator and the settings; the GPU twin of
/// `blueshift_tracking::TrackingSession` with the same edits:
/// [`GpuTrackingSession::set_camera`] rebuilds nothing, [`GpuTrackingSession::set_transfer_function`]
/// re-uploads one lookup table and rebuilds that channel's majorants on the device.
#[derive(Debug)]
pub struct GpuTrackingSession<'c> {
    scene: GpuScene<'c>,
    /// The scene the session renders (the uploaded view may be a coarser one:
    /// [`GpuTrackingSession::new_progressive`]).
    full: Scene,
    /// Whether the uploaded view is `full`.
    at_full: bool,
    integrator: Integrator,
    settings: RenderSettings,
}

impl<'c> GpuTrackingSession<'c> {
    /// Checks that the GPU supports the job ([`supports`]), validates the settings and the
    /// integrator as the CPU does, compiles the pipelines and uploads `scene`.
    ///
    /// # Errors
    /// [`Error::Unsupported`] (shading, heat maps, the timing protocol),
    /// [`Error::InvalidInput`] with the CPU's message, limits, GPU errors.
    pub fn new(
        ctx: &'c GpuContext,
        scene: Scene,
        integrator: Integrator,
        settings: RenderSettings,
    ) -> Result<Self> {
        supports(&scene, &settings)?;
        settings
            .validate()
            .map_err(|e| Error::InvalidInput(e.to_string()))?;
        integrator
            .prepared(&scene)
            .map_err(|e| Error::InvalidInput(e.to_string()))?;
        let tracker = GpuTracker::new(ctx)?;
        let full = scene.clone();
        let scene = tracker.upload(scene)?;
        Ok(Self {
            scene,
            full,
            at_full: true,
            integrator,
            settings,
        })
    }

    /// [`GpuTrackingSession::new`] for a progressive render
    /// ([`GpuTrackingSession::render_lod`], [`GpuTrackingSession::render_bricks`]): only the
    /// coarsest level of a bricked scene is uploaded now, so the first pass does not wait
    /// for the scene's own level. [`GpuTrackingSession::render`] refuses until a
    /// progressive render (or [`Session::run`]) has put the scene's own level on the device.
    ///
    /// # Errors
    /// As [`GpuTrackingSession::new`].
    pub fn new_progressive(
        ctx: &'c GpuContext,
        scene: Scene,
        integrator: Integrator,
        settings: RenderSettings,
    ) -> Result<Self> {
        // A scene whose own level surely overflows the pool would fail after every pass.
        let est = scene_estimate(ctx, &scene)?;
        if est.surely_full() {
            return Err(crate::pool::pool_full(ctx, est.slots));
        }
        let view = match scene.lod() {
            Some((level, count)) if count > level + 1 => scene
                .at_level(count - 1)
                .map_err(|e| Error::InvalidInput(e.to_string()))?,
            _ => return Self::new(ctx, scene, integrator, settings),
        };
        let mut s = Self::new(ctx, view, integrator, settings)?;
        s.full = scene;
        s.at_full = false;
        Ok(s)
    }

    /// The uploaded scene.
    #[must_use]
    pub fn scene(&self) -> &GpuScene<'c> {
        &self.scene
    }

    /// The settings.
    #[must_use]
    pub fn settings(&self) -> &RenderSettings {
        &self.settings
    }

    /// Moves the camera; nothing is rebuilt or uploaded.
    ///
    /// # Errors
    /// A degenerate camera.
    pub fn set_camera(&mut self, camera: blueshift_tracking::Camera) -> Result<()> {
        camera
            .validate()
            .map_err(|e| Error::InvalidInput(e.to_string()))?;
        self.settings.camera = camera;
        Ok(())
    }

    /// The uploaded scene, for its device-side edits (background, light).
    pub fn scene_mut(&mut self) -> &mut GpuScene<'c> {
        &mut self.scene
    }

    /// Replaces the settings (image size, spp, seed, noise target); nothing is uploaded.
    ///
    /// # Errors
    /// Invalid settings, [`Error::Unsupported`] for CPU-only ones (the session keeps its
    /// old settings).
    pub fn set_settings(&mut self, settings: RenderSettings) -> Result<()> {
        supports(&self.scene.scene, &settings)?;
        settings
            .validate()
            .map_err(|e| Error::InvalidInput(e.to_string()))?;
        self.settings = settings;
        Ok(())
    }

    /// Replaces the integrator; nothing is uploaded.
    ///
    /// # Errors
    /// An integrator that does not fit the scene (the session keeps its old one).
    pub fn set_integrator(&mut self, integrator: Integrator) -> Result<()> {
        integrator
            .prepared(&self.scene.scene)
            .map_err(|e| Error::InvalidInput(e.to_string()))?;
        self.integrator = integrator;
        Ok(())
    }

    /// Replaces channel `channel`'s transfer function: its table is re-uploaded and its
    /// majorant grid rebuilt on the device.
    ///
    /// # Errors
    /// As [`GpuScene::set_transfer_function`].
    pub fn set_transfer_function(&mut self, channel: usize, tf: TransferFunction) -> Result<()> {
        self.scene.set_transfer_function(channel, tf.clone())?;
        self.full
            .set_transfer_function(channel, tf)
            .map_err(|e| Error::InvalidInput(e.to_string()))
    }

    /// Renders under `observer`.
    ///
    /// # Errors
    /// As [`GpuTracker::render_observed`]; [`Error::InvalidInput`] while a session made by
    /// [`GpuTrackingSession::new_progressive`] holds only a coarser level.
    pub fn render(&self, observer: &dyn Observer<Progressive>) -> Result<TrackingOutput> {
        if !self.at_full {
            return Err(Error::InvalidInput(
                "the session holds a coarser level: render it progressively first".into(),
            ));
        }
        let image = self.scene.tracker.render_observed(
            &self.scene,
            &self.integrator,
            &self.settings,
            observer,
        )?;
        Ok(TrackingOutput {
            image,
            frame_times: None,
        })
    }
}

impl GpuTrackingSession<'_> {
    /// One quick pass (one sample per pixel) of the scene's current view, as step `step` at
    /// `level` (the CPU's preview).
    fn quick(&self, observer: &dyn Observer<Progressive>, step: u32, level: usize) -> Result<()> {
        observer.level(step, level);
        let preview = RenderSettings {
            spp: 1,
            noise_target: None,
            heatmaps: false,
            timed_frames: None,
            warmup: 0,
            ..self.settings.clone()
        };
        let image = self.scene.tracker.render_observed(
            &self.scene,
            &self.integrator,
            &preview,
            &ProgressOnly(observer),
        )?;
        observer.pass(step, &image, None);
        Ok(())
    }

    /// Progressive levels of detail on the GPU, as `TrackingSession::render_lod`: a quick
    /// pass at every level from the coarsest down to the one above the scene's own, then
    /// the full render. Each level is a view of the same pool
    /// ([`GpuScene::set_view`]): the bricks of the levels rendered stay on the device while
    /// the pool has room, and the next level's bricks along every 16th pixel's ray load on
    /// the cache's I/O thread while a level renders. A scene in memory is just rendered.
    ///
    /// # Errors
    /// As [`GpuTrackingSession::render`] and [`GpuScene::set_view`].
    pub fn render_lod(&mut self, observer: &dyn Observer<Progressive>) -> Result<TrackingOutput> {
        let full = self.full.clone();
        let Some((level, count)) = full.lod() else {
            return self.render(observer);
        };
        let bad = |e: blueshift_tracking::Error| Error::InvalidInput(e.to_string());
        let st = &self.settings;
        let rays = st.camera.sparse_rays(st.width, st.height, 16);
        // The passes load coarser views: the full scene is not on the device until the end.
        self.at_full = self.at_full && count <= level + 1;
        let mut step = 0;
        let out: Result<()> = (|| {
            for l in (level + 1..count).rev() {
                step += 1;
                let view = full.at_level(l).map_err(bad)?;
                let next = full.at_level(l - 1).map_err(bad)?;
                let fields: Vec<&blueshift_volume::BrickedField> = next
                    .channels()
                    .iter()
                    .filter_map(|c| c.grid().as_bricked())
                    .collect();
                blueshift_volume::BrickedField::prefetch_along(&fields, &rays);
                self.scene.set_view(view)?;
                self.quick(observer, step, l)?;
            }
            Ok(())
        })();
        // The full scene after the passes (after an error or a cancel it is put back only
        // when needed: `Session::run`).
        out?;
        self.scene.set_view(full)?;
        self.at_full = true;
        observer.level(step + 1, level);
        self.render(observer)
    }

    /// Progressive refinement brick by brick on the GPU (HDR VolVis 6.3), as
    /// `TrackingSession::render_bricks`: a quick pass at the coarsest level, then quick
    /// passes of `Scene::resident_view` (each region at the finest level its cache holds
    /// now) while the scene's level loads along every 16th pixel's ray, then the full
    /// render. Each pass is a view of one device pool ([`GpuScene::set_view`]): only the
    /// bricks that arrived since the last pass are uploaded. `on_step(step, at_level,
    /// regions)` hears, before each quick pass after the first, how many regions sample the
    /// scene's own level. A scene in memory is just rendered.
    ///
    /// # Errors
    /// As [`GpuTrackingSession::render`] and [`GpuScene::set_view`].
    pub fn render_bricks(
        &mut self,
        observer: &dyn Observer<Progressive>,
        on_step: &mut dyn FnMut(u32, usize, usize),
    ) -> Result<TrackingOutput> {
        let full = self.full.clone();
        let Some((level, count)) = full.lod() else {
            return self.render(observer);
        };
        let bad = |e: blueshift_tracking::Error| Error::InvalidInput(e.to_string());
        let st = &self.settings;
        let rays = st.camera.sparse_rays(st.width, st.height, 16);
        let fields: Vec<&blueshift_volume::BrickedField> = full
            .channels()
            .iter()
            .filter_map(|c| c.grid().as_bricked())
            .collect();
        blueshift_volume::BrickedField::prefetch_along(&fields, &rays);
        // The passes load coarser views: the full scene is not on the device until the end.
        self.at_full = self.at_full && count <= level + 1;
        let mut step = 0;
        let out: Result<()> = if count > level + 1 {
            step = 1;
            (|| {
                self.scene
                    .set_view(full.at_level(count - 1).map_err(bad)?)?;
                self.quick(observer, step, count - 1)?;
                step = blueshift_volume::refine_while_loading(
                    &fields,
                    &rays,
                    2,
                    // One level per region for every channel: what one pool lookup serves.
                    || {
                        let (v, at, n) = full.resident_view().map_err(bad)?;
                        Ok((v.shared_regions().map_err(bad)?, at, n))
                    },
                    |step, view: Scene, at_level, regions| {
                        on_step(step, at_level, regions);
                        let coarsest = view.coarsest_sampled_level().unwrap_or(level);
                        self.scene.set_view(view)?;
                        self.quick(observer, step, coarsest)
                    },
                    || observer.cancelled(),
                )?;
                Ok(())
            })()
        } else {
            Ok(())
        };
        out?;
        if step > 0 || !self.at_full {
            self.scene.set_view(full.clone())?;
        }
        self.at_full = true;
        observer.level(step + 1, level);
        self.render(observer)
    }
}

impl Session for GpuTrackingSession<'_> {
    type Image = Progressive;
    type Output = TrackingOutput;
    type Error = Error;

    fn run(&mut self, observer: &dyn Observer<Progressive>) -> Result<TrackingOutput> {
        if !self.at_full {
            self.scene.set_view(self.full.clone())?;
            self.at_full = true;
        }
        self.render(observer)
    }

    fn device(&self) -> DeviceKind {
        DeviceKind::Gpu
    }
}
