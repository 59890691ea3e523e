//! `blueshift render --device`: the GPU renders the CPU's picture through the CLI (the
//! marcher per pixel, tracking by image mean), CPU-only options are refused on `gpu`, and
//! `cpu` stays the default.

use std::path::Path;
use std::process::{Command, Output};

mod common;
use common::{gpu_ok, read_exr};

fn blueshift(args: &[&str], dir: &Path) -> Output {
    Command::new(env!("CARGO_BIN_EXE_blueshift"))
        .arg("render")
        .args(args)
        .current_dir(dir)
        .output()
        .unwrap()
}

const COMMON: [&str; 16] = [
    "--synth",
    "three-cubes",
    "--res",
    "16",
    "--tf",
    "builtin:viridis",
    "--width",
    "16",
    "--height",
    "12",
    "--density-scale",
    "3",
    "--seed",
    "3",
    "--background",
    "0.1,0.1,0.2",
];

fn run(dir: &Path, extra: &[&str], out: &str, device: &str) -> Output {
    let mut a = COMMON.to_vec();
    a.extend_from_slice(extra);
    a.extend(["--device", device, "--out", out]);
    blueshift(&a, dir)
}

#[test]
fn the_gpu_marcher_matches_the_cpu_per_pixel() {
    let dir = tempfile::tempdir().unwrap();
    let m = ["--method", "marcher", "--spp", "1"];
    let cpu = run(dir.path(), &m, "cpu.exr", "cpu");
    assert!(
        cpu.status.success(),
        "{}",
        String::from_utf8_lossy(&cpu.stderr)
    );
    if !gpu_ok("render", &run(dir.path(), &m, "gpu.exr", "gpu")) {
        return;
    }
    let a = read_exr(&dir.path().join("cpu.exr"));
    let b = read_exr(&dir.path().join("gpu.exr"));
    assert_eq!(a.dimensions(), b.dimensions());
    // Lookup-table transfer functions on the device: 1e-3 per pixel (see gpu::tracking).
    let d = a
        .as_raw()
        .iter()
        .zip(b.as_raw())
        .map(|(x, y)| (x - y).abs())
        .fold(0.0f32, f32::max);
    assert!(d <= 1e-3, "max |gpu - cpu| = {d}");
    assert!(a.pixels().any(|p| p.0[3] > 0.1));
}

#[test]
fn gpu_tracking_agrees_with_the_cpu_in_the_mean_and_reports_json() {
    let dir = tempfile::tempdir().unwrap();
    let m = ["--method", "mdwt-1dda", "--spp", "32", "--json"];
    let cpu = run(dir.path(), &m, "cpu.exr", "cpu");
    assert!(cpu.status.success());
    let v: serde_json::Value = serde_json::from_slice(&cpu.stdout).unwrap();
    assert_eq!(v["device"], "cpu");
    let g = run(dir.path(), &m, "gpu.exr", "gpu");
    if !gpu_ok("render", &g) {
        return;
    }
    let v: serde_json::Value = serde_json::from_slice(&g.stdout).unwrap();
    assert_eq!(v["device"], "gpu");
    assert!(!v["adapter"].as_str().unwrap().is_empty());
    assert_eq!(v["spp"], 32);
    let a = read_exr(&dir.path().join("cpu.exr"));
    let b = read_exr(&dir.path().join("gpu.exr"));
    let mean = |i: &image::Rgba32FImage| {
        i.as_raw().iter().map(|v| f64::from(*v)).sum::<f64>() / i.as_raw().len() as f64
    };
    // Same seed and counter-based numbers: the image means agree far within their noise.
    let (ma, mb) = (mean(&a), mean(&b));
    assert!((ma - mb).abs() < 0.01 * ma.abs().max(0.05), "{ma} vs {mb}");
}

#[test]
fn cpu_only_options_are_refused_on_the_gpu_and_bad_values_on_any() {
    let dir = tempfile::tempdir().unwrap();
    let out = run(dir.path(), &["--heatmap", "steps"], "x.exr", "gpu");
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("CPU-only") || err.contains("no wgpu adapter"),
        "{err}"
    );
    assert!(!dir.path().join("x.exr").exists());
    let out = run(dir.path(), &[], "y.exr", "tpu");
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("--device"));
    // auto on a machine without a hardware GPU renders on the CPU, and always succeeds.
    let out = run(dir.path(), &["--spp", "1", "--json"], "z.exr", "auto");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}
