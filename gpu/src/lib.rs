//! # blueshift-gpu
//!
//! wgpu compute backends for blueshift, each mirroring a CPU function of another crate and
//! checked against it in tests: tone mapping (blueshift-tonemap), the relativistic
//! environment renderer (blueshift-relativity), the tracking integrators
//! (blueshift-tracking) and the Doppler integrators (blueshift-doppler). It runs on any
//! adapter wgpu finds: a hardware GPU, or the software Vulkan driver lavapipe (Debian's
//! `mesa-vulkan-drivers`), which is what CI uses.
//!
//! ## Where do I start?
//! - [`GpuContext::new`] with [`GpuOptions`] picks an adapter ([`AdapterChoice`]; the
//!   environment variable `BLUESHIFT_GPU=auto|hardware|software|<name>` forces one) and
//!   creates a device; [`GpuContext::report`] says what it got. [`GpuContext::shared`] is
//!   one context per process.
//! - Every wgpu failure is an [`Error`]: no adapter, device request, device lost, out of
//!   memory, validation, a limit exceeded (checked before creating anything), map failure.
//! - The helpers [`GpuContext::compute_pipeline`], [`GpuContext::storage_buffer`],
//!   [`GpuContext::uniform_buffer`], [`GpuContext::bind_group`], [`GpuContext::dispatch`]
//!   and [`GpuContext::read_buffer`] are what every pipeline is made of.
//! - Doppler volume rendering: [`doppler::render_doppler_gpu`] takes the CPU's
//!   `DopplerScene` and `DopplerSettings`; [`doppler::check_supported`] says what it lacks.
//!   It runs in f64 where the adapter has `SHADER_F64` (the CPU's image to rounding) and in
//!   f32 elsewhere; [`doppler::render_doppler_gpu_with`] and [`doppler::DopplerPrecision`]
//!   force one.
//!
//! ```no_run
//! use blueshift_gpu::{GpuContext, GpuOptions};
//! let ctx = GpuContext::new(GpuOptions::default())?;
//! println!("{} on {}", ctx.report().name, ctx.report().backend);
//! # Ok::<(), blueshift_gpu::Error>(())
//! ```
//!
//! - Tone mapping: [`tonemap::GpuTonemapper`] (or [`tonemap::tonemap`]) takes the same
//!   [`blueshift_tonemap::Operator`] as the CPU and returns the same image within a
//!   tested tolerance.
//! - Relativity: [`relativity::GpuRelativity`] (or [`relativity::render`]) takes the same
//!   camera, velocity, effects and environment as [`blueshift_relativity::render`].
//! - The CLI's `--device cpu|gpu|auto` is [`DeviceChoice`].
//!
//! ## Glossary
//! | paper / GPU term | here |
//! |---|---|
//! | adapter (physical GPU or software driver) | [`AdapterChoice`], [`GpuReport`] |
//! | lavapipe (Mesa's software Vulkan) | [`AdapterChoice::Software`] |
//! | compute shader (WGSL, `gpu/src/shaders/`) | [`GpuContext::compute_pipeline`] |
//! | Drago 2003, Reinhard 2002 global curves (HDR VolVis Sec. 4) | [`tonemap::GpuTonemapper`], `shaders/tonemap_global.wgsl` |
//! | Reinhard 2002 dodging and burning, Eq. 7-9 | `shaders/reinhard_dodge.wgsl` |
//! | Durand 2002 fast bilateral filter (splat / blur / slice) | `shaders/durand_*.wgsl`, `shaders/blur.wgsl` |
//! | Fattal 2002 attenuated gradients, Poisson equation (Neumann) | `shaders/fattal_div.wgsl`, `shaders/axis_transform.wgsl`, `shaders/poisson_divide.wgsl` |
//! | relativistic aberration, Doppler shift, searchlight (relativity paper Eq. 2-3) | [`relativity::GpuRelativity`], `shaders/relativity.wgsl` |
//! | Doppler paper Algorithms 1 and 2 on the GPU | [`doppler::render_doppler_gpu`] |
//! | optical depth in front as pieces, preview budget (Algorithm 2 with absorption) | [`doppler::absorption_layout`], [`doppler::DEVICE_PIECE_CAP`] |
//! | double precision where the adapter has it (`SHADER_F64`) | [`doppler::DopplerPrecision`], [`doppler::shader_source`] |
//!
//! ## Shaders
//! WGSL sources live in `gpu/src/shaders/` and are included with `include_str!`; a test
//! parses and validates every one of them with naga (`doppler.wgsl` with both of its
//! precision preludes, the callers of the loop-limiter probe with [`LIMITER_WGSL`]), so a
//! shader error fails the tests. The same test compares the size and field offsets of every
//! `#[repr(C)]` Pod struct uploaded into a WGSL struct with naga's layout of that struct
//! (`layout::pod_layouts`). [`GpuContext::compute_pipeline`] compiles each (source, entry
//! point) once per context.

pub mod context;
pub mod device;
pub mod doppler;
pub mod error;
#[doc(hidden)]
pub mod layout;
pub mod pool;
pub mod relativity;
pub mod tonemap;
pub mod tracking;

pub use context::{
    AdapterChoice, AdapterSummary, DeviceChoice, ENV_ADAPTER, GpuContext, GpuOptions, GpuReport,
    Pass, WORKGROUP_1D, WORKGROUP_2D, list_adapters, runtime_dir_problem,
};
pub use device::{Ran, Unsupported, run_with_fallback};
pub use error::{Error, Result};

/// WGSL of `limiter_exhausted(n)`, the probe of lavapipe's loop limiter (every loop of an
/// invocation batch stops silently after 65535 iterations in all): prepended to the tracking,
/// Doppler, Durand-splat and row min/max shaders, whose kernels call it.
pub const LIMITER_WGSL: &str = include_str!("shaders/limiter.wgsl");

/// WGSL of the smoke-test kernel `y = a x + b` (see [`scale`]).
pub const SCALE_WGSL: &str = include_str!("shaders/scale.wgsl");

/// Computes `a * x + b` element-wise on the GPU: the smallest complete pipeline, used by
/// `blueshift gpu-info --check` and the context tests.
pub fn scale(ctx: &GpuContext, x: &[f32], a: f32, b: f32) -> Result<Vec<f32>> {
    let n = u32::try_from(x.len())
        .map_err(|_| Error::InvalidInput(format!("{} elements exceed u32", x.len())))?;
    let pipeline = ctx.compute_pipeline("scale", SCALE_WGSL, "main")?;
    let xb = ctx.storage_buffer("scale x", x)?;
    let yb = ctx.storage_buffer_zeroed("scale y", u64::from(n) * 4)?;
    let pb = ctx.uniform_buffer("scale params", &ScaleParams { a, b, n, pad: 0 })?;
    let bg = ctx.bind_group(&pipeline, 0, &[&xb, &yb, &pb])?;
    let g = ctx.groups("scale", n, WORKGROUP_1D)?;
    ctx.dispatch(&pipeline, &bg, [g, 1, 1])?;
    ctx.read_buffer(&yb, x.len())
}

/// The uniform of `scale.wgsl` (its `Params`).
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct ScaleParams {
    a: f32,
    b: f32,
    n: u32,
    pad: u32,
}

/// [`layout::pod_layouts`] of this module.
fn scale_pod_layouts() -> Vec<layout::PodLayout> {
    vec![
        layout::pod_layout!(ScaleParams => "Params", "scale.wgsl", SCALE_WGSL, {
            a, b, n, pad as "_pad",
        }),
    ]
}
