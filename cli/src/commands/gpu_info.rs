//! `blueshift gpu-info [--json] [--adapter auto|hardware|software|NAME] [--all] [--check]`:
//! the wgpu adapter blueshift would use, its backend, features and limits.

use anyhow::{Context, Result};
use blueshift_gpu::{AdapterChoice, GpuContext, GpuOptions, list_adapters};

/// Arguments of `blueshift gpu-info`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Print JSON instead of text.
    #[arg(long)]
    pub json: bool,
    /// Adapter to pick: auto (hardware first, else software), hardware, software
    /// (lavapipe) or a substring of the adapter name. Default: $BLUESHIFT_GPU, else auto.
    #[arg(long)]
    pub adapter: Option<String>,
    /// Also list every adapter wgpu finds.
    #[arg(long)]
    pub all: bool,
    /// Run a small compute kernel and check its result against the CPU.
    #[arg(long)]
    pub check: bool,
}

/// Runs `blueshift gpu-info`.
pub fn run(args: Args) -> Result<()> {
    let options = GpuOptions {
        adapter: args.adapter.as_deref().map(AdapterChoice::parse),
    };
    let choice = options.effective_choice();
    let ctx = GpuContext::new(options).context("gpu-info")?;
    let report = ctx.report();
    let check = if args.check {
        let x: Vec<f32> = (0..4096).map(|i| i as f32 * 0.5).collect();
        let y = blueshift_gpu::scale(&ctx, &x, 2.0, 1.0).context("gpu-info --check")?;
        let ok = x.iter().zip(&y).all(|(a, b)| *b == 2.0 * a + 1.0);
        if !ok {
            anyhow::bail!("gpu-info --check: the GPU result differs from the CPU");
        }
        Some(ok)
    } else {
        None
    };
    let all = args.all.then(list_adapters);
    if args.json {
        let mut v = serde_json::to_value(&report)?;
        v["limits"] = serde_json::Value::Object(
            report
                .limits
                .iter()
                .map(|(k, n)| (k.clone(), serde_json::json!(n)))
                .collect(),
        );
        v["choice"] = serde_json::json!(choice.to_string());
        if let Some(c) = check {
            v["check"] = serde_json::json!(c);
        }
        if let Some(all) = &all {
            v["adapters"] = serde_json::to_value(all)?;
        }
        outln!("{}", serde_json::to_string_pretty(&v)?);
        return Ok(());
    }
    outln!("adapter:     {}", report.name);
    outln!("backend:     {}", report.backend);
    outln!(
        "type:        {} ({})",
        report.device_type,
        if report.hardware {
            "hardware"
        } else {
            "software"
        }
    );
    outln!("choice:      {choice}");
    outln!("driver:      {} {}", report.driver, report.driver_info);
    outln!("vendor/dev:  {:#06x}/{:#06x}", report.vendor, report.device);
    outln!(
        "shader f16:  {}   shader f64: {}   timestamps: {}",
        report.shader_f16,
        report.shader_f64,
        report.timestamp_query
    );
    outln!("features:    {}", report.features.join(", "));
    outln!("limits:");
    for (k, n) in &report.limits {
        outln!("  {k:<40} {n}");
    }
    if check.is_some() {
        outln!("check:       ok (a*x+b on 4096 values equals the CPU)");
    }
    if let Some(all) = all {
        outln!("all adapters:");
        for a in all {
            outln!("  {} ({}, {})", a.name, a.backend, a.device_type);
        }
    }
    Ok(())
}
