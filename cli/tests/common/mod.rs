//! Helpers shared by the CLI's `--device` tests.
#![allow(dead_code)] // each test binary uses some of the helpers

use std::path::Path;
use std::process::Output;

/// True when `BLUESHIFT_REQUIRE_GPU_TESTS=1`: a missing adapter fails instead of skipping.
pub fn require() -> bool {
    std::env::var("BLUESHIFT_REQUIRE_GPU_TESTS").is_ok_and(|v| v == "1")
}

/// `false` (after a SKIP line) when a `--device gpu` run of `verb` failed for want of an
/// adapter; any other failure (or a missing adapter under [`require`]) fails the test.
pub fn gpu_ok(verb: &str, out: &Output) -> bool {
    if out.status.success() {
        return true;
    }
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!require(), "{verb} --device gpu failed: {err}");
    assert!(err.contains("no wgpu adapter"), "{err}");
    eprintln!("SKIP: no wgpu adapter: {err}");
    false
}

/// An EXR as f32 RGBA.
pub fn read_exr(p: &Path) -> image::Rgba32FImage {
    image::open(p).unwrap().to_rgba32f()
}

/// Asserts that two Doppler EXR images agree within the f32 GPU tolerance of
/// tests/doppler_device.rs: per sample `2e-3 |a| + 1e-5 max(a)`, over RGB.
pub fn close_doppler(a: &Path, b: &Path) {
    let (a, b) = (read_exr(a), read_exr(b));
    let max = a
        .pixels()
        .flat_map(|p| p.0[..3].to_vec())
        .fold(0.0f32, f32::max);
    assert!(max > 0.0, "a black image");
    for (p, q) in a.pixels().zip(b.pixels()) {
        for k in 0..3 {
            let tol = 2e-3 * p.0[k].abs() + 1e-5 * max;
            assert!((p.0[k] - q.0[k]).abs() <= tol, "{:?} vs {:?}", p.0, q.0);
        }
    }
}

/// Runs `cmd` (stdin closed), killing it after `limit_s` seconds so a test never hangs:
/// the output, and whether it finished in time.
#[allow(dead_code)]
pub fn output_within(cmd: &mut std::process::Command, limit_s: u64) -> (Output, bool) {
    use std::process::Stdio;
    let mut child = cmd
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn");
    let start = std::time::Instant::now();
    let mut in_time = true;
    while child.try_wait().expect("wait").is_none() {
        if start.elapsed().as_secs() >= limit_s {
            let _ = child.kill();
            in_time = false;
            break;
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    (child.wait_with_output().expect("output"), in_time)
}
