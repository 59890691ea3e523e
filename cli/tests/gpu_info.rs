//! `blueshift gpu-info`: reports the adapter (lavapipe in CI) or fails with a one-line error.

use std::process::Command;

fn require() -> bool {
    std::env::var("BLUESHIFT_REQUIRE_GPU_TESTS").is_ok_and(|v| v == "1")
}

#[test]
fn gpu_info_json_reports_adapter_and_limits() {
    let out = Command::new(env!("CARGO_BIN_EXE_blueshift"))
        .args(["gpu-info", "--json", "--check", "--all"])
        .output()
        .unwrap();
    if !out.status.success() {
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!require(), "gpu-info failed: {err}");
        assert!(err.contains("no wgpu adapter"), "{err}");
        eprintln!("SKIP: no wgpu adapter: {err}");
        return;
    }
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert!(!v["name"].as_str().unwrap().is_empty());
    assert!(
        v["limits"]["max_storage_buffer_binding_size"]
            .as_u64()
            .unwrap()
            > 0
    );
    assert_eq!(v["check"], serde_json::json!(true));
    assert!(!v["adapters"].as_array().unwrap().is_empty());
}

#[test]
fn gpu_info_with_an_unknown_adapter_fails_cleanly() {
    let out = Command::new(env!("CARGO_BIN_EXE_blueshift"))
        .args(["gpu-info", "--adapter", "no-such-adapter-xyz"])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("no wgpu adapter"), "{err}");
    assert_eq!(err.trim().lines().count(), 1, "{err}");
}

fn blueshift(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_blueshift"))
        .args(args)
        .output()
        .unwrap()
}

fn read_exr(p: &std::path::Path) -> image::Rgb32FImage {
    image::open(p).unwrap().to_rgb32f()
}

/// Whether a wgpu adapter exists (asks `gpu-info`); prints SKIP otherwise.
fn have_gpu() -> bool {
    let out = blueshift(&["gpu-info"]);
    if out.status.success() {
        return true;
    }
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!require(), "no adapter: {err}");
    eprintln!("SKIP: no wgpu adapter: {err}");
    false
}

fn max_rel_diff(a: &image::Rgb32FImage, b: &image::Rgb32FImage) -> f32 {
    assert_eq!(a.dimensions(), b.dimensions());
    a.pixels()
        .zip(b.pixels())
        .map(|(p, q)| {
            let peak = p.0.iter().fold(1e-3f32, |m, v| m.max(v.abs()));
            (0..3)
                .map(|i| (p.0[i] - q.0[i]).abs() / peak)
                .fold(0.0, f32::max)
        })
        .fold(0.0, f32::max)
}

#[test]
fn relativity_and_tonemap_on_the_gpu_match_the_cpu() {
    if !have_gpu() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let p = |n: &str| dir.path().join(n);
    let common = [
        "relativity",
        "--synth",
        "checker",
        "--beta",
        "0.7",
        "--width",
        "48",
        "--height",
        "32",
    ];
    for dev in ["cpu", "gpu"] {
        let out_name = format!("rel_{dev}.exr");
        let mut args: Vec<&str> = common.to_vec();
        let out = p(&out_name);
        let out_s = out.to_str().unwrap().to_string();
        args.extend(["--device", dev, "--out", &out_s]);
        let o = blueshift(&args);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    }
    let (c, g) = (read_exr(&p("rel_cpu.exr")), read_exr(&p("rel_gpu.exr")));
    // The checker has edges: compare the fraction of agreeing pixels.
    let agree = c
        .pixels()
        .zip(g.pixels())
        .filter(|(a, b)| {
            let peak = a.0.iter().fold(1e-3f32, |m, v| m.max(v.abs()));
            (0..3).all(|i| (a.0[i] - b.0[i]).abs() <= 2e-3 * peak)
        })
        .count();
    assert!(
        agree as f64 >= 0.99 * f64::from(c.width() * c.height()),
        "{agree}"
    );

    // Tone-map the CPU render with each operator that has a GPU version.
    let input = p("rel_cpu.exr");
    let input = input.to_str().unwrap();
    for op in ["drago", "reinhard", "reinhard-local", "durand", "linear"] {
        let mut imgs = Vec::new();
        for dev in ["cpu", "gpu"] {
            let out = p(&format!("tm_{op}_{dev}.exr"));
            let o = blueshift(&[
                "tonemap",
                input,
                "--op",
                op,
                "--device",
                dev,
                "--out",
                out.to_str().unwrap(),
            ]);
            assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
            imgs.push(read_exr(&out));
        }
        let d = max_rel_diff(&imgs[0], &imgs[1]);
        assert!(d < 1e-3, "{op}: GPU differs from CPU by {d}");
    }
}

#[test]
fn device_auto_on_a_software_adapter_is_the_cpu_and_bad_devices_are_refused() {
    if !have_gpu() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let hdr = dir.path().join("in.exr");
    let o = blueshift(&[
        "relativity",
        "--synth",
        "checker",
        "--width",
        "24",
        "--height",
        "16",
        "--out",
        hdr.to_str().unwrap(),
    ]);
    assert!(o.status.success());
    let info = blueshift(&["gpu-info", "--json"]);
    let v: serde_json::Value = serde_json::from_slice(&info.stdout).unwrap();
    let hardware = v["hardware"].as_bool().unwrap();
    let mut outs = Vec::new();
    for dev in ["cpu", "auto", "gpu"] {
        let out = dir.path().join(format!("f_{dev}.exr"));
        let o = blueshift(&[
            "tonemap",
            hdr.to_str().unwrap(),
            "--op",
            "fattal",
            "--device",
            dev,
            "--out",
            out.to_str().unwrap(),
        ]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        outs.push(read_exr(&out));
    }
    if !hardware {
        // auto takes the CPU when the only adapter is a software one: bit-identical.
        assert_eq!(outs[0].as_raw(), outs[1].as_raw());
    }
    let d = max_rel_diff(&outs[0], &outs[2]);
    assert!(d < 1e-3, "fattal: GPU differs from CPU by {d}");
    let o = blueshift(&[
        "tonemap",
        hdr.to_str().unwrap(),
        "--device",
        "tpu",
        "--out",
        "x.png",
    ]);
    assert_eq!(o.status.code(), Some(1));
    let out = dir.path().join("r.exr");
    let o = blueshift(&[
        "relativity",
        "--synth",
        "checker",
        "--device",
        "quantum",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert_eq!(o.status.code(), Some(1));
    assert!(!out.exists());
}

/// The adapter aliases the documentation promises: `lavapipe` (and `software`) pick the
/// software adapter, `gpu` (and `hardware`) a hardware one, checked against the list of
/// adapters `--all` reports. `lavapipe` used to be taken as a name and fail, since the
/// adapter is called "llvmpipe (...)".
#[test]
fn adapter_aliases_pick_the_kind_they_name() {
    let all = blueshift(&["gpu-info", "--json", "--all"]);
    if !all.status.success() {
        let err = String::from_utf8_lossy(&all.stderr);
        assert!(!require(), "gpu-info failed: {err}");
        eprintln!("SKIP: no wgpu adapter: {err}");
        return;
    }
    let v: serde_json::Value = serde_json::from_slice(&all.stdout).unwrap();
    let kinds: Vec<&str> = v["adapters"]
        .as_array()
        .unwrap()
        .iter()
        .map(|a| a["device_type"].as_str().unwrap())
        .collect();
    let has_software = kinds.contains(&"Cpu");
    let has_hardware = kinds.iter().any(|k| *k != "Cpu");
    for (alias, want_hardware, present) in [
        ("lavapipe", false, has_software),
        ("software", false, has_software),
        ("gpu", true, has_hardware),
        ("hardware", true, has_hardware),
    ] {
        for via_env in [false, true] {
            let mut cmd = Command::new(env!("CARGO_BIN_EXE_blueshift"));
            cmd.args(["gpu-info", "--json"]);
            if via_env {
                cmd.env("BLUESHIFT_GPU", alias);
            } else {
                cmd.args(["--adapter", alias]).env_remove("BLUESHIFT_GPU");
            }
            let out = cmd.output().unwrap();
            let err = String::from_utf8_lossy(&out.stderr);
            if present {
                assert!(out.status.success(), "{alias} (env {via_env}): {err}");
                let r: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
                assert_eq!(r["hardware"], serde_json::json!(want_hardware), "{alias}");
            } else {
                assert_eq!(out.status.code(), Some(1), "{alias}: {err}");
                assert!(err.contains("no wgpu adapter"), "{alias}: {err}");
            }
        }
    }
}
