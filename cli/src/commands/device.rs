//! `--device cpu|gpu|auto`: where a verb computes. `cpu` (the default) is bit-reproducible;
//! `gpu` insists on a wgpu adapter (a hardware GPU, else lavapipe; `BLUESHIFT_GPU` forces
//! one) and fails if there is none; `auto` takes a hardware GPU when one is present and the
//! CPU otherwise (a software adapter is slower than the CPU code).

use anyhow::{Context, Result};
use blueshift_gpu::GpuContext;

/// The `--device` values.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum DeviceArg {
    /// The CPU code (bit-reproducible on any thread count).
    #[default]
    Cpu,
    /// A wgpu adapter, or an error.
    Gpu,
    /// A hardware GPU when present, else the CPU.
    Auto,
}

/// The GPU context to use for `choice`, or `None` for the CPU.
pub fn gpu_for(choice: DeviceArg) -> Result<Option<&'static GpuContext>> {
    match choice {
        DeviceArg::Cpu => Ok(None),
        DeviceArg::Gpu => GpuContext::shared().map(Some).context("--device gpu"),
        DeviceArg::Auto => Ok(GpuContext::shared().ok().filter(|c| c.is_hardware())),
    }
}
