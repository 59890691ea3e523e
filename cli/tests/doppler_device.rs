//! `blueshift doppler --device`: the GPU renders the CPU's XYZ image through the CLI (per
//! pixel within the f32 tolerance of `gpu/tests/doppler.rs`, absorption and line broadening
//! included), what the GPU lacks (spectral cubes) is refused on `gpu` with one line and no
//! output, and `auto` falls back to the CPU.

use std::path::Path;
use std::process::{Command, Output};

mod common;
use common::{gpu_ok, read_exr};

fn doppler(args: &[&str], dir: &Path) -> Output {
    Command::new(env!("CARGO_BIN_EXE_blueshift"))
        .arg("doppler")
        .args(args)
        .current_dir(dir)
        .output()
        .unwrap()
}

const COMMON: [&str; 10] = [
    "--synth",
    "shell",
    "--res",
    "16",
    "--width",
    "16",
    "--height",
    "16",
    "--velocity-factor",
    "10",
];

fn run(dir: &Path, extra: &[&str], out: &str, device: &str) -> Output {
    let mut a = COMMON.to_vec();
    a.extend_from_slice(extra);
    a.extend(["--device", device, "--out", out]);
    doppler(&a, dir)
}

#[test]
fn gpu_image_matches_the_cpu_image() {
    let dir = tempfile::tempdir().unwrap();
    let c = run(dir.path(), &[], "cpu.exr", "cpu");
    assert!(c.status.success(), "{}", String::from_utf8_lossy(&c.stderr));
    assert!(String::from_utf8_lossy(&c.stderr).contains("on the cpu"));
    let g = run(dir.path(), &[], "gpu.exr", "gpu");
    if !gpu_ok("doppler", &g) {
        return;
    }
    assert!(String::from_utf8_lossy(&g.stderr).contains("on the gpu"));
    let (a, b) = (
        read_exr(&dir.path().join("cpu.exr")),
        read_exr(&dir.path().join("gpu.exr")),
    );
    let max = a
        .pixels()
        .flat_map(|p| p.0[..3].to_vec())
        .fold(0.0f32, f32::max);
    assert!(max > 0.0);
    for (p, q) in a.pixels().zip(b.pixels()) {
        for k in 0..3 {
            let tol = 2e-3 * p.0[k].abs() + 1e-5 * max;
            assert!((p.0[k] - q.0[k]).abs() <= tol, "{:?} vs {:?}", p.0, q.0);
        }
    }
    assert!(dir.path().join("gpu.png").exists());
}

#[test]
fn unsupported_settings_are_refused_on_gpu_and_fall_back_on_auto() {
    let dir = tempfile::tempdir().unwrap();
    // Spectral cubes stay on the CPU: refused on gpu (one line, no output), run on auto.
    let cube = dir.path().join("c.fits");
    let extra = [
        "--cube",
        cube.to_str().unwrap(),
        "--line",
        "Halpha",
        "--velocity-bins",
        "-400:400:8",
    ];
    let o = run(dir.path(), &extra, "refused.exr", "gpu");
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("--device gpu") && err.contains("cubes"),
        "{err}"
    );
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    assert!(!cube.exists());
    let o = run(dir.path(), &extra, "auto.exr", "auto");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(cube.exists());
    // Absorption (banded and piecewise linear) and line broadening (with and without
    // absorption) are on the GPU too, and agree with the CPU.
    for (i, absorbing) in [
        &["--integrator", "banded-ec:100", "--absorption-factor", "50"][..],
        &["--absorption-factor", "2"][..],
        &["--line-sigma", "50"][..],
        &["--line-sigma", "50", "--absorption-factor", "2"][..],
    ]
    .into_iter()
    .enumerate()
    {
        let c = run(dir.path(), absorbing, "bc.exr", "cpu");
        assert!(c.status.success(), "{}", String::from_utf8_lossy(&c.stderr));
        let g = run(dir.path(), absorbing, "bg.exr", "gpu");
        if !gpu_ok("doppler", &g) {
            continue;
        }
        assert!(String::from_utf8_lossy(&g.stderr).contains("on the gpu"));
        let (a, b) = (
            read_exr(&dir.path().join("bc.exr")),
            read_exr(&dir.path().join("bg.exr")),
        );
        let max = a
            .pixels()
            .flat_map(|p| p.0[..3].to_vec())
            .fold(0.0f32, f32::max);
        assert!(max > 0.0);
        for (p, q) in a.pixels().zip(b.pixels()) {
            for k in 0..3 {
                let tol = 2e-3 * p.0[k].abs() + 1e-5 * max;
                assert!(
                    (p.0[k] - q.0[k]).abs() <= tol,
                    "case {i}: {:?} vs {:?}",
                    p.0,
                    q.0
                );
            }
        }
    }
    let o = run(dir.path(), &[], "x.exr", "quantum");
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("unknown device"));
}

/// `--gpu-precision`: f64 (where the adapter has SHADER_F64, as lavapipe does) writes the
/// CPU's image to within the EXR's own f32 rounding, f32 within its stated 2e-3, auto names
/// what it took, and a bad value is refused by clap with the accepted values.
#[test]
fn the_gpu_precision_flag_picks_the_kernels() {
    let dir = tempfile::tempdir().unwrap();
    let extra = ["--absorption-factor", "2", "--merge-tol", "0"];
    let c = run(dir.path(), &extra, "pc.exr", "cpu");
    assert!(c.status.success(), "{}", String::from_utf8_lossy(&c.stderr));
    let a = read_exr(&dir.path().join("pc.exr"));
    let max = a
        .pixels()
        .flat_map(|p| p.0[..3].to_vec())
        .fold(0.0f32, f32::max);
    assert!(max > 0.0);
    let worst = |b: &image::Rgba32FImage| {
        a.pixels()
            .zip(b.pixels())
            .flat_map(|(p, q)| {
                (0..3).map(move |k| (p.0[k] - q.0[k]).abs() / (p.0[k].abs() + 1e-6 * max))
            })
            .fold(0.0f32, f32::max)
    };
    let mut x = extra.to_vec();
    x.extend(["--gpu-precision", "f64"]);
    let g = run(dir.path(), &x, "p64.exr", "gpu");
    if !gpu_ok("doppler", &g) {
        return;
    }
    let out = String::from_utf8_lossy(&g.stderr);
    if g.status.success() && out.contains("gpu (f64)") {
        let w = worst(&read_exr(&dir.path().join("p64.exr")));
        eprintln!("--gpu-precision f64: worst relative difference {w:e}");
        // The same f64 sums, written as f32: at most an f32 rounding apart.
        assert!(w <= 2e-7, "{w}");
    }
    x.truncate(extra.len());
    x.extend(["--gpu-precision", "f32"]);
    let g = run(dir.path(), &x, "p32.exr", "gpu");
    assert!(g.status.success(), "{}", String::from_utf8_lossy(&g.stderr));
    assert!(String::from_utf8_lossy(&g.stderr).contains("gpu (f32)"));
    let w = worst(&read_exr(&dir.path().join("p32.exr")));
    eprintln!("--gpu-precision f32: worst relative difference {w:e}");
    assert!(w <= 2e-3 && w > 0.0, "{w}");
    x.truncate(extra.len());
    x.extend(["--gpu-precision", "f16"]);
    let o = run(dir.path(), &x, "bad.exr", "gpu");
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("auto, f32 or f64"), "{err}");
    assert!(!dir.path().join("bad.exr").exists());
}

/// Work beyond lavapipe's loop limit (a banded render of 200,000 bands: one pass per pixel)
/// is refused on `gpu` with one line naming the limit and no output, and `auto` with the
/// adapter `BLUESHIFT_GPU` forces renders it on the CPU: the same EXR bytes as `--device cpu`
/// (the EXR is written block after block, so equal images are equal files).
#[test]
fn auto_falls_back_to_the_cpu_where_the_adapter_cannot_run_it() {
    let dir = tempfile::tempdir().unwrap();
    let go = |device: &str, out: &str| {
        let mut a = COMMON[..4].to_vec();
        a.extend([
            "--width",
            "2",
            "--height",
            "2",
            "--integrator",
            "banded-ec:200000",
            "--device",
            device,
            "--out",
            out,
        ]);
        Command::new(env!("CARGO_BIN_EXE_blueshift"))
            .arg("doppler")
            .args(&a)
            .env("BLUESHIFT_GPU", "software")
            .current_dir(dir.path())
            .output()
            .unwrap()
    };
    let c = go("cpu", "c.exr");
    assert!(c.status.success(), "{}", String::from_utf8_lossy(&c.stderr));
    let g = go("gpu", "g.exr");
    if g.status.success() {
        // An adapter without lavapipe's limit renders it.
        return;
    }
    let err = String::from_utf8_lossy(&g.stderr);
    if err.contains("no wgpu adapter") {
        assert!(!common::require(), "{err}");
        eprintln!("SKIP: no wgpu adapter: {err}");
        return;
    }
    assert!(err.contains("loop limit"), "{err}");
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    assert!(!dir.path().join("g.exr").exists());
    let a = go("auto", "a.exr");
    assert!(a.status.success(), "{}", String::from_utf8_lossy(&a.stderr));
    assert!(String::from_utf8_lossy(&a.stderr).contains("on the cpu"));
    assert!(String::from_utf8_lossy(&a.stderr).contains("rendering on the CPU"));
    assert_eq!(
        std::fs::read(dir.path().join("c.exr")).unwrap(),
        std::fs::read(dir.path().join("a.exr")).unwrap()
    );
}
