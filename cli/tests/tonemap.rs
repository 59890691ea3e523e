//! `blueshift tonemap` end to end.

use std::process::Command;

fn blueshift() -> Command {
    Command::new(env!("CARGO_BIN_EXE_blueshift"))
}

fn write_pfm(path: &std::path::Path, w: usize, h: usize, f: impl Fn(usize, usize) -> f32) {
    let mut bytes = format!("PF\n{w} {h}\n-1.0\n").into_bytes();
    for y in (0..h).rev() {
        for x in 0..w {
            let v = f(x, y);
            for c in [1.1f32, 1.0, 0.8] {
                bytes.extend_from_slice(&(v * c).to_le_bytes());
            }
        }
    }
    std::fs::write(path, bytes).unwrap();
}

#[test]
fn every_operator_writes_a_png_and_prints_the_dynamic_range() {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("in.pfm");
    // Luminance 1e-2 .. 1e2: dynamic range 1e4.
    write_pfm(&input, 64, 40, |x, _| {
        10f32.powf(x as f32 / 63.0 * 4.0 - 2.0)
    });
    for op in [
        "drago",
        "reinhard",
        "reinhard-local",
        "durand",
        "fattal",
        "linear",
    ] {
        let out = dir.path().join(format!("{op}.png"));
        let o = blueshift()
            .args([
                "tonemap",
                input.to_str().unwrap(),
                "--op",
                op,
                "--out",
                out.to_str().unwrap(),
            ])
            .output()
            .unwrap();
        assert!(
            o.status.success(),
            "{op}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        let text = String::from_utf8_lossy(&o.stdout);
        assert!(text.contains("4.00 orders of magnitude"), "{op}: {text}");
        let img = image::open(&out).unwrap();
        assert_eq!((img.width(), img.height()), (64, 40));
    }
}

#[test]
fn roi_exposure_series_pseudocolor_and_json() {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("in.pfm");
    write_pfm(&input, 32, 32, |x, y| 0.01 + (x * y) as f32);
    let inp = input.to_str().unwrap();
    let out = dir.path().join("roi.png");
    let o = blueshift()
        .args([
            "tonemap",
            inp,
            "--op",
            "drago",
            "--roi",
            "5,5,4",
            "--depth",
            "16",
            "--out",
            out.to_str().unwrap(),
        ])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(image::open(&out).unwrap().color(), image::ColorType::Rgb16);
    let out = dir.path().join("series.png");
    let o = blueshift()
        .args([
            "tonemap",
            inp,
            "--exposure-series",
            "3",
            "--out",
            out.to_str().unwrap(),
        ])
        .output()
        .unwrap();
    assert!(o.status.success());
    for i in 0..3 {
        assert!(dir.path().join(format!("series-{i:02}.png")).exists());
    }
    let out = dir.path().join("pc.png");
    let o = blueshift()
        .args([
            "tonemap",
            inp,
            "--pseudocolor",
            "--json",
            "--out",
            out.to_str().unwrap(),
        ])
        .output()
        .unwrap();
    assert!(o.status.success());
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["operator"], "pseudocolor");
    assert!(image::open(&out).unwrap().width() > 32);
}

#[test]
fn bad_input_fails_with_one_line_and_leaves_no_output() {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("bad.exr");
    std::fs::write(&input, [0x76, 0x2f, 0x31, 0x01, 2, 0, 0, 0, b'x']).unwrap();
    let out = dir.path().join("out.png");
    let o = blueshift()
        .args([
            "tonemap",
            input.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(1));
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    assert!(!out.exists());
    assert_eq!(
        std::fs::read_dir(dir.path()).unwrap().count(),
        1,
        "a temporary file was left"
    );
    let good = dir.path().join("g.pfm");
    write_pfm(&good, 4, 4, |_, _| 1.0);
    let o = blueshift()
        .args([
            "tonemap",
            good.to_str().unwrap(),
            "--op",
            "drago",
            "--bias",
            "2",
            "--out",
            out.to_str().unwrap(),
        ])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&o.stderr).contains("bias"));
}

/// `--device auto` with the adapter `BLUESHIFT_GPU` forces (lavapipe here) tone-maps on the
/// CPU what the adapter cannot: Fattal's width^2 DCT matrix of a 6000-pixel-wide image is
/// over `max_storage_buffer_binding_size` (128 MiB on lavapipe), so `gpu` fails with one
/// line naming the limit and writes nothing, and `auto` notes it and writes the CPU's image
/// bit for bit.
#[test]
fn auto_tone_maps_on_the_cpu_what_the_adapter_cannot() {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("wide.pfm");
    write_pfm(&input, 6000, 3, |x, y| {
        0.01 + ((x * 7 + y * 13) % 97) as f32 * 0.1
    });
    let run = |device: &str, out: &std::path::Path| {
        blueshift()
            .env("BLUESHIFT_GPU", "software")
            .arg("tonemap")
            .arg(&input)
            .args(["--op", "fattal", "--device", device, "--out"])
            .arg(out)
            .output()
            .unwrap()
    };
    let cpu = dir.path().join("cpu.pfm");
    let o = run("cpu", &cpu);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let gpu = dir.path().join("gpu.pfm");
    let g = run("gpu", &gpu);
    let gerr = String::from_utf8_lossy(&g.stderr).to_string();
    let auto = dir.path().join("auto.pfm");
    let a = run("auto", &auto);
    let aerr = String::from_utf8_lossy(&a.stderr);
    assert!(a.status.success(), "{aerr}");
    // Whatever the adapter, auto's image is the CPU's when the GPU did not run it.
    if !g.status.success() {
        assert_eq!(
            std::fs::read(&cpu).unwrap(),
            std::fs::read(&auto).unwrap(),
            "auto did not write the CPU's image"
        );
        assert!(
            !gpu.exists(),
            "a failed --device gpu left {}",
            gpu.display()
        );
        assert_eq!(gerr.trim().lines().count(), 1, "{gerr}");
        if gerr.contains("no wgpu adapter") {
            let require = std::env::var("BLUESHIFT_REQUIRE_GPU_TESTS").is_ok_and(|v| v == "1");
            assert!(!require, "{gerr}");
            eprintln!("SKIP: no software wgpu adapter: {gerr}");
            return;
        }
        assert!(gerr.contains("max_storage_buffer_binding_size"), "{gerr}");
        // auto tried the forced adapter and fell back.
        assert!(
            aerr.contains("--device auto") && aerr.contains("on the CPU"),
            "{aerr}"
        );
    }
}

/// Durand with a spatial sigma as large as the image: each bilateral-grid cell sums
/// (sigma_s / 4)^2 pixels, past lavapipe's loop limit (65535 per invocation batch, after
/// which loops stop silently; before the check `gpu` wrote an image up to 10x off and
/// exited 0). `gpu` must write the CPU's image within the stated tolerance or fail with one
/// line naming the loop limit and write nothing; `auto` with the adapter forced then writes
/// the CPU's image bit for bit.
#[test]
fn durand_past_the_loop_limit_is_refused_on_gpu_and_done_on_the_cpu_by_auto() {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("in.pfm");
    write_pfm(&input, 320, 240, |x, y| {
        10f32.powf(4.0 * (x as f32 / 320.0) - 1.0) * (1.2 + (y as f32 * 0.3).sin())
    });
    let run = |device: &str, out: &std::path::Path| {
        blueshift()
            .env("BLUESHIFT_GPU", "software")
            .arg("tonemap")
            .arg(&input)
            .args(["--op", "durand", "--sigma-s", "1280", "--device", device])
            .arg("--out")
            .arg(out)
            .output()
            .unwrap()
    };
    let cpu = dir.path().join("cpu.pfm");
    assert!(run("cpu", &cpu).status.success());
    let gpu = dir.path().join("gpu.pfm");
    let g = run("gpu", &gpu);
    let err = String::from_utf8_lossy(&g.stderr);
    let floats = |p: &std::path::Path| -> Vec<f32> {
        let b = std::fs::read(p).unwrap();
        // "PF\n320 240\n-1.0\n" then little-endian floats.
        let start = b.len() - 320 * 240 * 12;
        b[start..]
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect()
    };
    if g.status.success() {
        for (a, b) in floats(&cpu).iter().zip(&floats(&gpu)) {
            assert!((a - b).abs() <= 2e-4 * a.abs() + 1e-6, "cpu {a} gpu {b}");
        }
        return;
    }
    if err.contains("no wgpu adapter") {
        let require = std::env::var("BLUESHIFT_REQUIRE_GPU_TESTS").is_ok_and(|v| v == "1");
        assert!(!require, "{err}");
        eprintln!("SKIP: no software wgpu adapter: {err}");
        return;
    }
    assert_eq!(g.status.code(), Some(1), "{err}");
    assert!(err.contains("loop limit"), "{err}");
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    assert!(!gpu.exists());
    let auto = dir.path().join("auto.pfm");
    let a = run("auto", &auto);
    let aerr = String::from_utf8_lossy(&a.stderr);
    assert!(a.status.success(), "{aerr}");
    assert!(aerr.contains("--device auto"), "{aerr}");
    assert_eq!(std::fs::read(&cpu).unwrap(), std::fs::read(&auto).unwrap());
}

/// `--exposure` is stops for every operator: the local operators (which normalise their
/// input's scale away) get it on their display output, so +1 stop brightens Durand's and
/// Fattal's pictures instead of being ignored.
#[test]
fn exposure_stops_brighten_every_operator() {
    let dir = tempfile::tempdir().unwrap();
    let (w, h) = (48usize, 32usize);
    let mut pfm = format!("PF\n{w} {h}\n-1.0\n").into_bytes();
    for y in 0..h {
        for x in 0..w {
            let v = 10f32.powf(-2.0 + 4.0 * x as f32 / w as f32) * (1.0 + 0.2 * (y % 5) as f32);
            for c in [v, 0.7 * v, 0.4 * v] {
                pfm.extend_from_slice(&c.to_le_bytes());
            }
        }
    }
    let input = dir.path().join("ramp.pfm");
    std::fs::write(&input, pfm).unwrap();
    for op in ["durand", "fattal", "reinhard", "reinhard-local"] {
        let mean = |stops: &str| {
            let out = dir.path().join(format!("{op}{stops}.png"));
            let o = std::process::Command::new(env!("CARGO_BIN_EXE_blueshift"))
                .args([
                    "tonemap",
                    input.to_str().unwrap(),
                    "--op",
                    op,
                    "--exposure",
                    stops,
                ])
                .args(["--out", out.to_str().unwrap()])
                .output()
                .unwrap();
            assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
            let img = image::open(&out).unwrap().to_luma8();
            img.pixels().map(|p| f64::from(p.0[0])).sum::<f64>() / (w * h) as f64
        };
        let (m0, m1) = (mean("0"), mean("1"));
        assert!(m1 > m0 * 1.1, "{op}: +1 stop gave mean {m1} against {m0}");
    }
}

/// With stdout a pipe its reader has closed (`blueshift tonemap ... | head -0`), the image is
/// still written and the process exits 0 without a panic (std's `println!` panics there).
#[test]
fn a_closed_stdout_pipe_is_not_a_panic() {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("in.pfm");
    write_pfm(&input, 256, 256, |x, y| 0.01 + (x * y) as f32 / 100.0);
    let out = dir.path().join("o.png");
    let mut child = blueshift()
        .args(["tonemap", input.to_str().unwrap(), "--op", "fattal"])
        .args(["--json", "--out", out.to_str().unwrap()])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    // The reader closes before the tone mapping (tens of milliseconds) prints anything.
    drop(child.stdout.take());
    let o = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success() && !err.contains("panicked"), "{err}");
    assert_eq!(image::open(&out).unwrap().width(), 256);
    // A stdout that fails otherwise (a full disk) fails the run, in one line.
    if let Ok(full) = std::fs::OpenOptions::new().write(true).open("/dev/full") {
        let o = blueshift()
            .args([
                "tonemap",
                input.to_str().unwrap(),
                "--out",
                out.to_str().unwrap(),
            ])
            .stdout(full)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{err}");
        assert!(err.contains("cannot write to stdout"), "{err}");
    }
}

/// `--out -` writes the PNG to standard output (the summary then goes to stderr), `--format`
/// picks another format; a zero exposure step and an exposure series to stdout are refused.
#[test]
fn standard_output_takes_the_image_and_the_format_flag() {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("in.pfm");
    write_pfm(&input, 16, 8, |x, _| 0.1 + x as f32);
    let run = |extra: &[&str]| {
        blueshift()
            .args(["tonemap", input.to_str().unwrap()])
            .args(extra)
            .output()
            .unwrap()
    };
    let o = run(&["--out", "-"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let img = image::load_from_memory_with_format(&o.stdout, image::ImageFormat::Png).unwrap();
    assert_eq!((img.width(), img.height()), (16, 8));
    assert!(String::from_utf8_lossy(&o.stderr).contains("dynamic range"));
    let o = run(&["--out", "-", "--format", "exr"]);
    assert!(o.status.success());
    assert!(
        o.stdout.starts_with(&[0x76, 0x2f, 0x31, 0x01]),
        "OpenEXR magic"
    );
    for (extra, needle) in [
        (
            &["--out", "-", "--exposure-series", "2"][..],
            "one file per image",
        ),
        (
            &[
                "--out",
                "s.png",
                "--exposure-series",
                "3",
                "--stops-step",
                "0",
            ][..],
            "--stops-step 0",
        ),
        // Refused before any output name is made (4 billion of them would not fit).
        (
            &["--out", "s.png", "--exposure-series", "4294967295"][..],
            "1 to 64 images",
        ),
    ] {
        let o = run(extra);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{err}");
        assert!(
            err.contains(needle) && err.trim().lines().count() == 1,
            "{err}"
        );
    }
    assert!(!dir.path().join("s-00.png").exists());
    // An exposure series whose second image would be the input itself is refused, and the
    // input is left as it was.
    let named = dir.path().join("in-01.pfm");
    std::fs::copy(&input, &named).unwrap();
    let before = std::fs::read(&named).unwrap();
    let o = blueshift()
        .args(["tonemap", named.to_str().unwrap(), "--exposure-series", "3"])
        .args(["--out", dir.path().join("in.pfm").to_str().unwrap()])
        .output()
        .unwrap();
    assert_eq!(
        o.status.code(),
        Some(1),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert_eq!(std::fs::read(&named).unwrap(), before);
    assert!(!dir.path().join("in-00.pfm").exists());
    // A flat image spans no stops: its series (a zero step the tool chose) is still written.
    let flat = dir.path().join("flat.pfm");
    write_pfm(&flat, 4, 4, |_, _| 2.0);
    let series = dir.path().join("f.png");
    let o = blueshift()
        .args(["tonemap", flat.to_str().unwrap(), "--exposure-series", "3"])
        .args(["--out", series.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(dir.path().join("f-02.png").exists());
    // Fattal's display stretch has no range on a flat grey image: white, as Drago gives,
    // not black.
    for op in ["fattal", "drago"] {
        let png = dir.path().join(format!("flat_{op}.png"));
        let o = blueshift()
            .args(["tonemap", flat.to_str().unwrap(), "--op", op])
            .args(["--out", png.to_str().unwrap()])
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let img = image::open(&png).unwrap().to_rgb8();
        assert!(
            img.pixels().all(|p| p.0[1] > 240),
            "{op}: {:?}",
            img.get_pixel(0, 0)
        );
    }
}
