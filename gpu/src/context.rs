//! The GPU context: adapter choice, device, error capture, and the helpers every pipeline
//! uses (compute pipelines from WGSL, buffer upload with limit checks, dispatch, readback).
//!
//! Adapter choice ([`AdapterChoice`]): `auto` prefers a hardware GPU (discrete, then
//! integrated, then virtual) and falls back to a software one (lavapipe, Debian's
//! `mesa-vulkan-drivers`); `hardware` and `software` insist on one kind; any other string
//! picks the first adapter whose name contains it (case-insensitive). The option wins over
//! the environment variable [`ENV_ADAPTER`] (`BLUESHIFT_GPU`), which wins over `auto`.

use std::sync::{Arc, Mutex, OnceLock};

use bytemuck::Pod;
use serde::Serialize;

use crate::error::{Error, Result};

/// Environment variable that forces an adapter: `auto`, `hardware`, `software` or a
/// substring of the adapter's name.
pub const ENV_ADAPTER: &str = "BLUESHIFT_GPU";

/// Environment variable that turns a test's "SKIP: no wgpu adapter" into a failure (CI).
/// A test hook: reached at this path only, not re-exported at the crate root.
#[doc(hidden)]
pub const ENV_REQUIRE_GPU_TESTS: &str = "BLUESHIFT_REQUIRE_GPU_TESTS";

/// Which adapter to pick.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub enum AdapterChoice {
    /// A hardware GPU when there is one, else a software adapter (lavapipe).
    #[default]
    Auto,
    /// A hardware GPU (discrete, integrated or virtual) or an error.
    Hardware,
    /// A software adapter (device type CPU, e.g. lavapipe) or an error.
    Software,
    /// The first adapter whose name contains this string (case-insensitive).
    Name(String),
}

impl AdapterChoice {
    /// Parses `auto`, `hardware`, `software` (also `hw`, `sw`, `gpu`, `cpu`, `lavapipe`), or
    /// takes the text as a name substring. An empty string is `auto`.
    pub fn parse(text: &str) -> Self {
        let t = text.trim();
        match t.to_ascii_lowercase().as_str() {
            "" | "auto" => AdapterChoice::Auto,
            "hardware" | "hw" | "gpu" => AdapterChoice::Hardware,
            "software" | "sw" | "cpu" | "lavapipe" => AdapterChoice::Software,
            _ => AdapterChoice::Name(t.to_string()),
        }
    }

    /// Reads [`ENV_ADAPTER`]; `None` when unset.
    pub fn from_env() -> Option<Self> {
        std::env::var(ENV_ADAPTER).ok().map(|v| Self::parse(&v))
    }
}

impl std::fmt::Display for AdapterChoice {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            AdapterChoice::Auto => f.write_str("auto"),
            AdapterChoice::Hardware => f.write_str("hardware"),
            AdapterChoice::Software => f.write_str("software"),
            AdapterChoice::Name(n) => write!(f, "name containing {n:?}"),
        }
    }
}

/// Options of [`GpuContext::new`].
#[derive(Debug, Clone, Default)]
pub struct GpuOptions {
    /// The adapter to pick; `None` reads [`ENV_ADAPTER`], then defaults to `auto`.
    pub adapter: Option<AdapterChoice>,
}

impl GpuOptions {
    /// Options forcing one adapter choice (ignores the environment).
    pub fn with_adapter(choice: AdapterChoice) -> Self {
        GpuOptions {
            adapter: Some(choice),
        }
    }

    /// The effective choice: the option, else the environment, else `auto`.
    pub fn effective_choice(&self) -> AdapterChoice {
        self.adapter
            .clone()
            .or_else(AdapterChoice::from_env)
            .unwrap_or_default()
    }
}

/// What [`GpuContext`] got, for `blueshift gpu-info` (serialisable to JSON).
#[derive(Debug, Clone, Serialize)]
pub struct GpuReport {
    /// Adapter name (e.g. "llvmpipe (LLVM 15.0.6, 256 bits)").
    pub name: String,
    /// Backend (Vulkan, Metal, Dx12, Gl).
    pub backend: String,
    /// Device type (DiscreteGpu, IntegratedGpu, VirtualGpu, Cpu, Other).
    pub device_type: String,
    /// Whether this is a hardware adapter (not `Cpu`).
    pub hardware: bool,
    /// PCI vendor id.
    pub vendor: u32,
    /// PCI device id.
    pub device: u32,
    /// Driver name.
    pub driver: String,
    /// Driver details.
    pub driver_info: String,
    /// Features enabled on the device (wgpu names).
    pub features: Vec<String>,
    /// Whether `SHADER_F16` is enabled.
    pub shader_f16: bool,
    /// Whether `SHADER_F64` is enabled.
    pub shader_f64: bool,
    /// Whether `TIMESTAMP_QUERY` is enabled.
    pub timestamp_query: bool,
    /// The device limits that matter for compute (name, value).
    pub limits: Vec<(String, u64)>,
}

/// One adapter as listed by [`list_adapters`].
#[derive(Debug, Clone, Serialize)]
pub struct AdapterSummary {
    /// Adapter name.
    pub name: String,
    /// Backend.
    pub backend: String,
    /// Device type.
    pub device_type: String,
}

fn summary(info: &wgpu::AdapterInfo) -> AdapterSummary {
    AdapterSummary {
        name: info.name.clone(),
        backend: format!("{:?}", info.backend),
        device_type: format!("{:?}", info.device_type),
    }
}

/// Whether the adapter is a hardware one (anything but `DeviceType::Cpu`).
pub fn is_hardware(info: &wgpu::AdapterInfo) -> bool {
    info.device_type != wgpu::DeviceType::Cpu
}

fn hardware_rank(t: wgpu::DeviceType) -> u32 {
    match t {
        wgpu::DeviceType::DiscreteGpu => 0,
        wgpu::DeviceType::IntegratedGpu => 1,
        wgpu::DeviceType::VirtualGpu => 2,
        wgpu::DeviceType::Other => 3,
        wgpu::DeviceType::Cpu => 4,
    }
}

/// What is wrong with `XDG_RUNTIME_DIR` for the Vulkan loader's window-system layers, which
/// print "XDG_RUNTIME_DIR is invalid or not set in the environment" on stderr while wgpu
/// creates its instance: unset or empty, not an absolute path to a folder, or (Linux) a
/// folder another user owns or others may enter (the XDG spec asks for a 0700 folder of the
/// user). `None` when it is fine, and always outside Linux.
///
/// Programs fix it before any thread starts (setting an environment variable is not
/// thread-safe), e.g. by pointing it at a fresh private temporary folder; the `blueshift`
/// CLI does so first thing in `main`.
#[must_use]
pub fn runtime_dir_problem() -> Option<&'static str> {
    if !cfg!(target_os = "linux") {
        return None;
    }
    let Some(dir) = std::env::var_os("XDG_RUNTIME_DIR").filter(|d| !d.is_empty()) else {
        return Some("not set");
    };
    let dir = std::path::Path::new(&dir);
    if !dir.is_absolute() {
        return Some("not an absolute path");
    }
    let Ok(meta) = std::fs::metadata(dir) else {
        return Some("does not exist");
    };
    if !meta.is_dir() {
        return Some("not a folder");
    }
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        if meta.mode() & 0o077 != 0 {
            return Some("not private (mode is not 0700)");
        }
        // /proc/self belongs to the process's effective user.
        if let Ok(me) = std::fs::metadata("/proc/self")
            && me.uid() != meta.uid()
        {
            return Some("owned by another user");
        }
    }
    None
}

fn backends() -> wgpu::Backends {
    wgpu::Backends::from_env().unwrap_or(wgpu::Backends::PRIMARY)
}

fn new_instance() -> wgpu::Instance {
    let mut desc = wgpu::InstanceDescriptor::new_without_display_handle();
    desc.backends = backends();
    wgpu::Instance::new(desc)
}

/// Lists every adapter wgpu finds (Vulkan / Metal / DX12, or `WGPU_BACKEND`).
pub fn list_adapters() -> Vec<AdapterSummary> {
    let instance = new_instance();
    let adapters = pollster::block_on(instance.enumerate_adapters(backends()));
    adapters.iter().map(|a| summary(&a.get_info())).collect()
}

/// Picks the adapter for `choice` among `adapters`; returns its index.
fn pick(infos: &[wgpu::AdapterInfo], choice: &AdapterChoice) -> Option<usize> {
    let mut order: Vec<usize> = (0..infos.len()).collect();
    // Stable: hardware first by rank, then enumeration order.
    order.sort_by_key(|&i| hardware_rank(infos[i].device_type));
    match choice {
        AdapterChoice::Auto => order.first().copied(),
        AdapterChoice::Hardware => order.into_iter().find(|&i| is_hardware(&infos[i])),
        AdapterChoice::Software => order.into_iter().find(|&i| !is_hardware(&infos[i])),
        AdapterChoice::Name(n) => {
            let n = n.to_lowercase();
            order
                .into_iter()
                .find(|&i| infos[i].name.to_lowercase().contains(&n))
        }
    }
}

/// Errors recorded outside error scopes (uncaptured errors, device loss).
#[derive(Debug, Default)]
struct ErrorSink {
    uncaptured: Mutex<Vec<String>>,
    lost: Mutex<Option<String>>,
}

/// A wgpu device and queue with the adapter's report, error capture and helpers.
#[derive(Debug)]
pub struct GpuContext {
    adapter: wgpu::Adapter,
    device: wgpu::Device,
    queue: wgpu::Queue,
    info: wgpu::AdapterInfo,
    sink: Arc<ErrorSink>,
    /// Compiled pipelines by (entry point, WGSL source): a pipeline is compiled once per
    /// context (the Doppler kernels take seconds on a software adapter).
    pipelines: Mutex<PipelineCache>,
    /// Largest brick pool, bytes, set by [`GpuContext::set_pool_limit`] (0: the device's).
    pool_limit: std::sync::atomic::AtomicU64,
}

type PipelineCache = std::collections::HashMap<(String, String), wgpu::ComputePipeline>;

/// Workgroup size (x) that the crate's 1-D shaders use.
pub const WORKGROUP_1D: u32 = 64;
/// Workgroup size (x and y) that the crate's 2-D image shaders use.
pub const WORKGROUP_2D: u32 = 8;

/// One compute dispatch for [`GpuContext::run_passes`].
#[derive(Debug)]
pub struct Pass<'a> {
    /// The pipeline.
    pub pipeline: &'a wgpu::ComputePipeline,
    /// Bind groups, bound at indices 0, 1, ...
    pub bind_groups: &'a [&'a wgpu::BindGroup],
    /// Workgroup counts (x, y, z).
    pub workgroups: [u32; 3],
}

impl GpuContext {
    /// Picks an adapter as `options` says and creates a device on it, requesting
    /// `SHADER_F16`, `SHADER_F64` and `TIMESTAMP_QUERY` where available and the adapter's
    /// own limits.
    pub fn new(options: GpuOptions) -> Result<Self> {
        let choice = options.effective_choice();
        let instance = new_instance();
        let adapters = pollster::block_on(instance.enumerate_adapters(backends()));
        let infos: Vec<wgpu::AdapterInfo> = adapters.iter().map(|a| a.get_info()).collect();
        let Some(index) = pick(&infos, &choice) else {
            let found = if infos.is_empty() {
                "wgpu found no adapter at all (install a Vulkan driver, e.g. Debian's \
                 mesa-vulkan-drivers for lavapipe)"
                    .to_string()
            } else {
                let names: Vec<String> = infos
                    .iter()
                    .map(|i| format!("{} ({:?}, {:?})", i.name, i.backend, i.device_type))
                    .collect();
                format!("adapters present: {}", names.join("; "))
            };
            return Err(Error::NoAdapter(format!("none matches {choice}; {found}")));
        };
        let adapter = adapters
            .into_iter()
            .nth(index)
            .ok_or_else(|| Error::NoAdapter("adapter list changed".into()))?;
        let info = infos[index].clone();
        let wanted = wgpu::Features::SHADER_F16
            | wgpu::Features::SHADER_F64
            | wgpu::Features::TIMESTAMP_QUERY;
        let features = adapter.features() & wanted;
        let limits = adapter.limits();
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("blueshift-gpu"),
            required_features: features,
            required_limits: limits,
            ..Default::default()
        }))
        .map_err(|e| Error::RequestDevice(format!("{} ({:?}): {e}", info.name, info.backend)))?;
        let sink = Arc::new(ErrorSink::default());
        let s = Arc::clone(&sink);
        device.on_uncaptured_error(Arc::new(move |err: wgpu::Error| {
            if let Ok(mut v) = s.uncaptured.lock() {
                v.push(err.to_string());
            }
        }));
        let s = Arc::clone(&sink);
        device.set_device_lost_callback(move |reason, msg| {
            if let Ok(mut l) = s.lost.lock() {
                *l = Some(format!("{reason:?}: {msg}"));
            }
        });
        Ok(GpuContext {
            adapter,
            device,
            queue,
            info,
            sink,
            pipelines: Mutex::new(PipelineCache::new()),
            pool_limit: std::sync::atomic::AtomicU64::new(0),
        })
    }

    /// One context per process, created on first use with [`GpuOptions::default`]
    /// (environment variable, else `auto`). The error is kept as text and returned as
    /// [`Error::NoAdapter`] / [`Error::RequestDevice`] on every call.
    pub fn shared() -> Result<&'static GpuContext> {
        static SHARED: OnceLock<std::result::Result<GpuContext, String>> = OnceLock::new();
        match SHARED.get_or_init(|| {
            GpuContext::new(GpuOptions::default()).map_err(|e| match e {
                Error::NoAdapter(m) => m,
                other => other.to_string(),
            })
        }) {
            Ok(ctx) => Ok(ctx),
            Err(msg) => Err(Error::NoAdapter(msg.clone())),
        }
    }

    /// The wgpu device.
    pub fn device(&self) -> &wgpu::Device {
        &self.device
    }

    /// The wgpu queue.
    pub fn queue(&self) -> &wgpu::Queue {
        &self.queue
    }

    /// The wgpu adapter.
    pub fn adapter(&self) -> &wgpu::Adapter {
        &self.adapter
    }

    /// The adapter's description.
    pub fn info(&self) -> &wgpu::AdapterInfo {
        &self.info
    }

    /// The device limits (equal to the adapter's).
    pub fn limits(&self) -> wgpu::Limits {
        self.device.limits()
    }

    /// Whether the adapter is a hardware GPU (not a software one like lavapipe).
    pub fn is_hardware(&self) -> bool {
        is_hardware(&self.info)
    }

    /// Whether `SHADER_F16` is enabled (WGSL `enable f16;`).
    pub fn has_f16(&self) -> bool {
        self.device.features().contains(wgpu::Features::SHADER_F16)
    }

    /// Whether `SHADER_F64` is enabled (WGSL `f64`).
    pub fn has_f64(&self) -> bool {
        self.device.features().contains(wgpu::Features::SHADER_F64)
    }

    /// Whether `TIMESTAMP_QUERY` is enabled.
    pub fn has_timestamps(&self) -> bool {
        self.device
            .features()
            .contains(wgpu::Features::TIMESTAMP_QUERY)
    }

    /// What the context got: adapter, backend, features and compute limits.
    pub fn report(&self) -> GpuReport {
        let l = self.device.limits();
        let features = self.device.features();
        let limits: Vec<(String, u64)> = vec![
            ("max_buffer_size".into(), l.max_buffer_size),
            (
                "max_storage_buffer_binding_size".into(),
                l.max_storage_buffer_binding_size,
            ),
            (
                "max_uniform_buffer_binding_size".into(),
                l.max_uniform_buffer_binding_size,
            ),
            (
                "max_storage_buffers_per_shader_stage".into(),
                l.max_storage_buffers_per_shader_stage.into(),
            ),
            ("max_bind_groups".into(), l.max_bind_groups.into()),
            (
                "max_texture_dimension_2d".into(),
                l.max_texture_dimension_2d.into(),
            ),
            (
                "max_texture_dimension_3d".into(),
                l.max_texture_dimension_3d.into(),
            ),
            (
                "max_compute_workgroups_per_dimension".into(),
                l.max_compute_workgroups_per_dimension.into(),
            ),
            (
                "max_compute_invocations_per_workgroup".into(),
                l.max_compute_invocations_per_workgroup.into(),
            ),
            (
                "max_compute_workgroup_size_x".into(),
                l.max_compute_workgroup_size_x.into(),
            ),
            (
                "max_compute_workgroup_size_y".into(),
                l.max_compute_workgroup_size_y.into(),
            ),
            (
                "max_compute_workgroup_size_z".into(),
                l.max_compute_workgroup_size_z.into(),
            ),
            (
                "max_compute_workgroup_storage_size".into(),
                l.max_compute_workgroup_storage_size.into(),
            ),
        ];
        GpuReport {
            name: self.info.name.clone(),
            backend: format!("{:?}", self.info.backend),
            device_type: format!("{:?}", self.info.device_type),
            hardware: self.is_hardware(),
            vendor: self.info.vendor,
            device: self.info.device,
            driver: self.info.driver.clone(),
            driver_info: self.info.driver_info.clone(),
            features: features.iter_names().map(|(n, _)| n.to_string()).collect(),
            shader_f16: self.has_f16(),
            shader_f64: self.has_f64(),
            timestamp_query: self.has_timestamps(),
            limits,
        }
    }

    /// Returns the first error recorded outside error scopes (device lost, uncaptured).
    pub fn check_device(&self) -> Result<()> {
        if let Ok(l) = self.sink.lost.lock()
            && let Some(msg) = l.as_ref()
        {
            return Err(Error::DeviceLost(msg.clone()));
        }
        if let Ok(mut v) = self.sink.uncaptured.lock()
            && !v.is_empty()
        {
            let msg = v.join("; ");
            v.clear();
            return Err(Error::Validation(msg));
        }
        Ok(())
    }

    /// Runs `f` inside out-of-memory, validation and internal error scopes and returns the
    /// first error caught (then any recorded device loss), else `f`'s value.
    pub fn scoped<T>(&self, f: impl FnOnce() -> T) -> Result<T> {
        let oom = self.device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
        let val = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let int = self.device.push_error_scope(wgpu::ErrorFilter::Internal);
        let out = f();
        let e_int = pollster::block_on(int.pop());
        let e_val = pollster::block_on(val.pop());
        let e_oom = pollster::block_on(oom.pop());
        if let Some(e) = [e_oom, e_val, e_int].into_iter().flatten().next() {
            // A lost device makes every call a validation error: let its callback run and
            // report the loss itself.
            let _ = self.device.poll(wgpu::PollType::Poll);
            self.check_device()?;
            return Err(Error::from_wgpu(&e));
        }
        self.check_device()?;
        Ok(out)
    }

    /// Compiles `wgsl` and creates a compute pipeline for `entry` with an automatic layout,
    /// once per context: a later call with the same source and entry point returns the same
    /// pipeline. A shader error is [`Error::Validation`] naming the label.
    pub fn compute_pipeline(
        &self,
        label: &str,
        wgsl: &str,
        entry: &str,
    ) -> Result<wgpu::ComputePipeline> {
        self.check_device()?;
        let key = (entry.to_string(), wgsl.to_string());
        if let Some(p) = self
            .pipelines
            .lock()
            .ok()
            .and_then(|c| c.get(&key).cloned())
        {
            return Ok(p);
        }
        let pipeline = self.compile_pipeline(label, wgsl, entry)?;
        if let Ok(mut c) = self.pipelines.lock() {
            c.insert(key, pipeline.clone());
        }
        Ok(pipeline)
    }

    /// Pipelines compiled so far and kept by [`GpuContext::compute_pipeline`].
    pub fn cached_pipelines(&self) -> usize {
        self.pipelines.lock().map_or(0, |c| c.len())
    }

    fn compile_pipeline(
        &self,
        label: &str,
        wgsl: &str,
        entry: &str,
    ) -> Result<wgpu::ComputePipeline> {
        self.scoped(|| {
            let module = self
                .device
                .create_shader_module(wgpu::ShaderModuleDescriptor {
                    label: Some(label),
                    source: wgpu::ShaderSource::Wgsl(wgsl.into()),
                });
            self.device
                .create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                    label: Some(label),
                    layout: None,
                    module: &module,
                    entry_point: Some(entry),
                    compilation_options: Default::default(),
                    cache: None,
                })
        })
        .map_err(|e| match e {
            Error::Validation(m) => Error::Validation(format!("pipeline {label}: {m}")),
            other => other,
        })
    }

    /// Caps the device brick pool ([`crate::pool`]) at `bytes` (`None`: the device's own
    /// limits). Scenes uploaded afterwards use it; a pool never exceeds the device's limits.
    pub fn set_pool_limit(&self, bytes: Option<u64>) {
        self.pool_limit
            .store(bytes.unwrap_or(0), std::sync::atomic::Ordering::Relaxed);
    }

    /// Bytes a brick pool may take: the least of `max_buffer_size`,
    /// `max_storage_buffer_binding_size` and the [`GpuContext::set_pool_limit`] cap.
    #[must_use]
    pub fn pool_capacity_bytes(&self) -> u64 {
        let l = self.device.limits();
        let device = l.max_buffer_size.min(l.max_storage_buffer_binding_size);
        match self.pool_limit.load(std::sync::atomic::Ordering::Relaxed) {
            0 => device,
            cap => cap.min(device),
        }
    }

    /// Checks a storage buffer of `bytes` bytes against `max_buffer_size` and
    /// `max_storage_buffer_binding_size`.
    pub fn check_storage_size(&self, what: &str, bytes: u64) -> Result<()> {
        let l = self.device.limits();
        if bytes > l.max_buffer_size {
            return Err(Error::LimitExceeded {
                what: what.into(),
                limit: "max_buffer_size",
                requested: bytes,
                max: l.max_buffer_size,
            });
        }
        if bytes > l.max_storage_buffer_binding_size {
            return Err(Error::LimitExceeded {
                what: what.into(),
                limit: "max_storage_buffer_binding_size",
                requested: bytes,
                max: l.max_storage_buffer_binding_size,
            });
        }
        Ok(())
    }

    /// A storage buffer (read-write in shaders, copyable) holding `data`; at least 4 bytes
    /// (an empty slice gives one zero word). Limits are checked before creation.
    pub fn storage_buffer<T: Pod>(&self, label: &str, data: &[T]) -> Result<wgpu::Buffer> {
        let bytes: &[u8] = bytemuck::cast_slice(data);
        self.check_storage_size(label, bytes.len() as u64)?;
        self.buffer_with(
            label,
            bytes,
            wgpu::BufferUsages::STORAGE
                | wgpu::BufferUsages::COPY_SRC
                | wgpu::BufferUsages::COPY_DST,
        )
    }

    /// A buffer of `usage` (plus `COPY_DST`) holding `bytes`, padded to a multiple of 4 (at
    /// least 4 bytes). Created unmapped and filled through the queue: wgpu's
    /// `create_buffer_init` panics when the device is lost, this returns the error.
    fn buffer_with(
        &self,
        label: &str,
        bytes: &[u8],
        usage: wgpu::BufferUsages,
    ) -> Result<wgpu::Buffer> {
        self.check_device()?;
        let size = (bytes.len() as u64).max(4).div_ceil(4) * 4;
        self.scoped(|| {
            let buffer = self.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size,
                usage: usage | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            });
            if !bytes.is_empty() {
                if bytes.len().is_multiple_of(4) {
                    self.queue.write_buffer(&buffer, 0, bytes);
                } else {
                    let mut padded = bytes.to_vec();
                    padded.resize(size as usize, 0);
                    self.queue.write_buffer(&buffer, 0, &padded);
                }
            }
            buffer
        })
    }

    /// A zero-filled storage buffer of `bytes` bytes (rounded up to a multiple of 4, at
    /// least 4). Limits are checked before creation, so an absurd size allocates nothing.
    pub fn storage_buffer_zeroed(&self, label: &str, bytes: u64) -> Result<wgpu::Buffer> {
        let size = bytes.max(4).div_ceil(4) * 4;
        self.check_storage_size(label, size)?;
        self.check_device()?;
        self.scoped(|| {
            self.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size,
                usage: wgpu::BufferUsages::STORAGE
                    | wgpu::BufferUsages::COPY_SRC
                    | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            })
        })
    }

    /// A uniform buffer holding `value` (checked against `max_uniform_buffer_binding_size`).
    pub fn uniform_buffer<T: Pod>(&self, label: &str, value: &T) -> Result<wgpu::Buffer> {
        let bytes: &[u8] = bytemuck::bytes_of(value);
        let l = self.device.limits();
        if bytes.len() as u64 > l.max_uniform_buffer_binding_size {
            return Err(Error::LimitExceeded {
                what: label.into(),
                limit: "max_uniform_buffer_binding_size",
                requested: bytes.len() as u64,
                max: l.max_uniform_buffer_binding_size,
            });
        }
        self.buffer_with(label, bytes, wgpu::BufferUsages::UNIFORM)
    }

    /// A bind group for `pipeline`'s group `group`, binding `buffers[i]` (whole) at binding
    /// `i`.
    pub fn bind_group(
        &self,
        pipeline: &wgpu::ComputePipeline,
        group: u32,
        buffers: &[&wgpu::Buffer],
    ) -> Result<wgpu::BindGroup> {
        self.scoped(|| {
            let layout = pipeline.get_bind_group_layout(group);
            let entries: Vec<wgpu::BindGroupEntry<'_>> = buffers
                .iter()
                .enumerate()
                .map(|(i, b)| wgpu::BindGroupEntry {
                    binding: i as u32,
                    resource: b.as_entire_binding(),
                })
                .collect();
            self.device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: None,
                layout: &layout,
                entries: &entries,
            })
        })
    }

    /// Workgroup counts covering `n` invocations with groups of `size`, checked against
    /// `max_compute_workgroups_per_dimension`.
    pub fn groups(&self, what: &str, n: u32, size: u32) -> Result<u32> {
        let g = n.div_ceil(size.max(1)).max(1);
        let max = self.device.limits().max_compute_workgroups_per_dimension;
        if g > max {
            return Err(Error::LimitExceeded {
                what: what.into(),
                limit: "max_compute_workgroups_per_dimension",
                requested: g.into(),
                max: max.into(),
            });
        }
        Ok(g)
    }

    /// Encodes `passes` in order (one compute pass each), submits and waits for completion.
    pub fn run_passes(&self, passes: &[Pass<'_>]) -> Result<()> {
        self.scoped(|| {
            let mut enc = self
                .device
                .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: None });
            for p in passes {
                let mut cp = enc.begin_compute_pass(&wgpu::ComputePassDescriptor::default());
                cp.set_pipeline(p.pipeline);
                for (i, bg) in p.bind_groups.iter().enumerate() {
                    cp.set_bind_group(i as u32, Some(*bg), &[]);
                }
                cp.dispatch_workgroups(p.workgroups[0], p.workgroups[1], p.workgroups[2]);
            }
            self.queue.submit([enc.finish()]);
        })?;
        self.wait()
    }

    /// Runs one dispatch of `pipeline` with `bind_group` at index 0.
    pub fn dispatch(
        &self,
        pipeline: &wgpu::ComputePipeline,
        bind_group: &wgpu::BindGroup,
        workgroups: [u32; 3],
    ) -> Result<()> {
        self.run_passes(&[Pass {
            pipeline,
            bind_groups: &[bind_group],
            workgroups,
        }])
    }

    /// Blocks until the queue is idle; device loss is an error.
    pub fn wait(&self) -> Result<()> {
        self.device
            .poll(wgpu::PollType::wait_indefinitely())
            .map_err(|e| Error::Poll(e.to_string()))?;
        self.check_device()
    }

    /// Writes `data` into `buffer` at offset 0 (the buffer must be large enough).
    pub fn write_buffer<T: Pod>(&self, buffer: &wgpu::Buffer, data: &[T]) -> Result<()> {
        let bytes: &[u8] = bytemuck::cast_slice(data);
        if bytes.len() as u64 > buffer.size() {
            return Err(Error::InvalidInput(format!(
                "writing {} bytes into a buffer of {}",
                bytes.len(),
                buffer.size()
            )));
        }
        self.scoped(|| self.queue.write_buffer(buffer, 0, bytes))
    }

    /// Copies the first `bytes` bytes (a multiple of 4) of `from` into `to` on the device and
    /// waits for it.
    pub fn copy_buffer(&self, from: &wgpu::Buffer, to: &wgpu::Buffer, bytes: u64) -> Result<()> {
        if !bytes.is_multiple_of(4) || bytes > from.size() || bytes > to.size() {
            return Err(Error::InvalidInput(format!(
                "copying {bytes} bytes between buffers of {} and {}",
                from.size(),
                to.size()
            )));
        }
        self.scoped(|| {
            let mut enc = self
                .device
                .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: None });
            enc.copy_buffer_to_buffer(from, 0, to, 0, bytes);
            self.queue.submit([enc.finish()]);
        })?;
        self.wait()
    }

    /// Copies the first `count` elements of `buffer` back to the host.
    pub fn read_buffer<T: Pod>(&self, buffer: &wgpu::Buffer, count: usize) -> Result<Vec<T>> {
        let bytes = (count as u64)
            .checked_mul(std::mem::size_of::<T>() as u64)
            .ok_or_else(|| Error::InvalidInput("readback size overflows".into()))?;
        if bytes > buffer.size() {
            return Err(Error::InvalidInput(format!(
                "reading {bytes} bytes from a buffer of {}",
                buffer.size()
            )));
        }
        if bytes == 0 {
            return Ok(Vec::new());
        }
        // Copy sizes must be multiples of 4.
        let padded = bytes.div_ceil(4) * 4;
        let padded = padded.min(buffer.size());
        let staging = self.scoped(|| {
            let staging = self.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("readback"),
                size: padded,
                usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            });
            let mut enc = self
                .device
                .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: None });
            enc.copy_buffer_to_buffer(buffer, 0, &staging, 0, padded);
            self.queue.submit([enc.finish()]);
            staging
        })?;
        let slot: Arc<Mutex<Option<std::result::Result<(), String>>>> = Arc::new(Mutex::new(None));
        let s = Arc::clone(&slot);
        staging.slice(..).map_async(wgpu::MapMode::Read, move |r| {
            if let Ok(mut g) = s.lock() {
                *g = Some(r.map_err(|e| e.to_string()));
            }
        });
        self.wait()?;
        // Another thread polling the same device may be the one that runs the callback
        // (after our poll returned): poll again until it has run, for at most ten seconds.
        let start = std::time::Instant::now();
        let status = loop {
            let s = slot
                .lock()
                .map_err(|_| Error::Map("poisoned".into()))?
                .take();
            if s.is_some() || start.elapsed() > std::time::Duration::from_secs(10) {
                break s;
            }
            std::thread::yield_now();
            self.wait()?;
        };
        match status {
            Some(Ok(())) => {}
            Some(Err(m)) => return Err(Error::Map(m)),
            None => return Err(Error::Map("the map callback never ran".into())),
        }
        let out = {
            let view = staging
                .slice(..)
                .get_mapped_range()
                .map_err(|e| Error::Map(e.to_string()))?;
            let mut v: Vec<T> = vec![T::zeroed(); count];
            bytemuck::cast_slice_mut::<T, u8>(&mut v).copy_from_slice(&view[..bytes as usize]);
            v
        };
        staging.unmap();
        Ok(out)
    }
}

/// For tests: the shared context, or `None` after printing `SKIP: no wgpu adapter: <why>`
/// to stderr. With `BLUESHIFT_REQUIRE_GPU_TESTS=1` a missing adapter panics instead (tests
/// fail in CI rather than skip). A test hook: reached at this path only
/// (`blueshift_gpu::context::test_context`), not re-exported at the crate root.
#[doc(hidden)]
pub fn test_context() -> Option<&'static GpuContext> {
    match GpuContext::shared() {
        Ok(ctx) => Some(ctx),
        Err(e) => {
            let require = std::env::var(ENV_REQUIRE_GPU_TESTS)
                .map(|v| v == "1")
                .unwrap_or(false);
            assert!(!require, "{ENV_REQUIRE_GPU_TESTS}=1 but {e}");
            // Written to the stderr handle, not with eprintln!, so that the test harness's
            // output capture does not hide it.
            let msg = match &e {
                Error::NoAdapter(m) => m.clone(),
                other => other.to_string(),
            };
            let _ = std::io::Write::write_all(
                &mut std::io::stderr(),
                format!("SKIP: no wgpu adapter: {msg}\n").as_bytes(),
            );
            None
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn info(name: &str, t: wgpu::DeviceType) -> wgpu::AdapterInfo {
        let mut i = wgpu::AdapterInfo::new(t, wgpu::Backend::Vulkan);
        i.name = name.into();
        i
    }

    #[test]
    fn parse_devices() {
        assert_eq!("cpu".parse::<DeviceChoice>(), Ok(DeviceChoice::Cpu));
        assert_eq!(" GPU ".parse::<DeviceChoice>(), Ok(DeviceChoice::Gpu));
        assert_eq!("auto".parse::<DeviceChoice>(), Ok(DeviceChoice::Auto));
        assert!("tpu".parse::<DeviceChoice>().is_err());
        assert_eq!(DeviceChoice::Cpu.context().unwrap().map(|_| ()), None);
        assert_eq!(DeviceChoice::default(), DeviceChoice::Cpu);
        let limit = Error::LimitExceeded {
            what: "x".into(),
            limit: "max_buffer_size",
            requested: 2,
            max: 1,
        };
        assert!(DeviceChoice::Auto.falls_back_on(&limit));
        assert!(DeviceChoice::Auto.falls_back_on(&Error::Unsupported("x".into())));
        assert!(!DeviceChoice::Auto.falls_back_on(&Error::InvalidInput("x".into())));
        assert!(!DeviceChoice::Auto.falls_back_on(&Error::Validation("x".into())));
        assert!(!DeviceChoice::Gpu.falls_back_on(&limit));
    }

    #[test]
    fn parse_choices() {
        assert_eq!(AdapterChoice::parse(""), AdapterChoice::Auto);
        assert_eq!(AdapterChoice::parse(" Hardware "), AdapterChoice::Hardware);
        assert_eq!(AdapterChoice::parse("software"), AdapterChoice::Software);
        // The aliases the documentation promises ("lavapipe" is not in the adapter's name,
        // which is "llvmpipe (LLVM ...)", so it must not be taken as a name).
        assert_eq!(AdapterChoice::parse("gpu"), AdapterChoice::Hardware);
        assert_eq!(AdapterChoice::parse("hw"), AdapterChoice::Hardware);
        assert_eq!(AdapterChoice::parse("Lavapipe"), AdapterChoice::Software);
        assert_eq!(AdapterChoice::parse("sw"), AdapterChoice::Software);
        assert_eq!(AdapterChoice::parse("cpu"), AdapterChoice::Software);
        assert_eq!(
            AdapterChoice::parse("llvmpipe"),
            AdapterChoice::Name("llvmpipe".into())
        );
    }

    #[test]
    fn pick_prefers_hardware_and_honours_forcing() {
        let infos = vec![
            info("llvmpipe (LLVM 15)", wgpu::DeviceType::Cpu),
            info("Intel UHD", wgpu::DeviceType::IntegratedGpu),
            info("NVIDIA H100", wgpu::DeviceType::DiscreteGpu),
        ];
        assert_eq!(pick(&infos, &AdapterChoice::Auto), Some(2));
        assert_eq!(pick(&infos, &AdapterChoice::Hardware), Some(2));
        assert_eq!(pick(&infos, &AdapterChoice::Software), Some(0));
        assert_eq!(pick(&infos, &AdapterChoice::Name("intel".into())), Some(1));
        assert_eq!(pick(&infos, &AdapterChoice::Name("amd".into())), None);
        let sw = vec![info("llvmpipe", wgpu::DeviceType::Cpu)];
        assert_eq!(pick(&sw, &AdapterChoice::Auto), Some(0));
        assert_eq!(pick(&sw, &AdapterChoice::Hardware), None);
        assert_eq!(pick(&[], &AdapterChoice::Auto), None);
    }
}

/// The CLI's `--device cpu|gpu|auto`: which backend runs a job.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum DeviceChoice {
    /// The CPU reference (bit-reproducible; the default).
    #[default]
    Cpu,
    /// A GPU: any adapter wgpu finds (lavapipe included), or an error.
    Gpu,
    /// A hardware GPU when there is one (or the adapter that `BLUESHIFT_GPU` forces), else
    /// the CPU; a job the adapter cannot run (see [`DeviceChoice::falls_back_on`]) runs on
    /// the CPU too.
    Auto,
}

impl std::str::FromStr for DeviceChoice {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s.trim().to_ascii_lowercase().as_str() {
            "cpu" => Ok(DeviceChoice::Cpu),
            "gpu" => Ok(DeviceChoice::Gpu),
            "auto" => Ok(DeviceChoice::Auto),
            other => Err(format!("unknown device {other:?} (use cpu, gpu or auto)")),
        }
    }
}

impl std::fmt::Display for DeviceChoice {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            DeviceChoice::Cpu => "cpu",
            DeviceChoice::Gpu => "gpu",
            DeviceChoice::Auto => "auto",
        })
    }
}

impl DeviceChoice {
    /// The context to run on: `None` means the CPU. `gpu` returns the shared context
    /// ([`GpuContext::shared`], honouring `BLUESHIFT_GPU`) or its error; `auto` returns it
    /// when it is a hardware adapter (a software one would be slower than the CPU) or when
    /// `BLUESHIFT_GPU` forces an adapter (`hardware`, `software` or a name), else `None`.
    pub fn context(self) -> Result<Option<&'static GpuContext>> {
        match self {
            DeviceChoice::Cpu => Ok(None),
            DeviceChoice::Gpu => GpuContext::shared().map(Some),
            DeviceChoice::Auto => {
                let forced = AdapterChoice::from_env().is_some_and(|c| c != AdapterChoice::Auto);
                Ok(GpuContext::shared()
                    .ok()
                    .filter(|c| forced || c.is_hardware()))
            }
        }
    }

    /// Whether a GPU failure `err` lets this choice run the job on the CPU instead: `auto`
    /// does when the job does not fit or is not supported on the adapter
    /// ([`Error::LimitExceeded`], [`Error::Unsupported`], [`Error::OutOfMemory`]); `gpu`
    /// and `cpu` never do.
    #[must_use]
    pub fn falls_back_on(self, err: &Error) -> bool {
        self == DeviceChoice::Auto
            && matches!(
                err,
                Error::LimitExceeded { .. } | Error::Unsupported(_) | Error::OutOfMemory(_)
            )
    }
}
