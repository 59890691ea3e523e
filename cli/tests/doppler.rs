//! `blueshift doppler` and `blueshift demo` from outside.

use std::path::Path;
use std::process::Command;

fn blueshift(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_blueshift"))
        .args(args)
        .output()
        .unwrap()
}

fn peak_nm(csv: &Path, lo: f64, hi: f64) -> f64 {
    let text = std::fs::read_to_string(csv).unwrap();
    let mut lines = text.lines();
    assert_eq!(lines.next(), Some("wavelength_nm,value"));
    let (mut best, mut at) = (0.0, 0.0);
    for l in lines {
        let (a, b) = l.split_once(',').unwrap();
        let (w, v): (f64, f64) = (a.parse().unwrap(), b.parse().unwrap());
        if (lo..hi).contains(&w) && v > best {
            best = v;
            at = w;
        }
    }
    assert!(best > 0.0);
    at
}

#[test]
fn shell_sides_are_blue_and_red_shifted_in_picked_spectra() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("shell.exr");
    let o = blueshift(&[
        "doppler",
        "--synth",
        "shell",
        "--res",
        "24",
        "--width",
        "32",
        "--height",
        "32",
        "--velocity-factor",
        "10",
        "--pick",
        "6,16",
        "--pick",
        "25,16",
        "--trace",
        "6,16",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(out.exists() && dir.path().join("shell.png").exists());
    // The camera looks along +z with +y up, so image x runs along -x in the world; the shell
    // spins about +y with v_z = -omega x: the left of the image (world x > 0) approaches.
    let left = peak_nm(&dir.path().join("shell_pick_6_16.csv"), 600.0, 720.0);
    let right = peak_nm(&dir.path().join("shell_pick_25_16.csv"), 600.0, 720.0);
    assert!(left < 656.28 - 2.0, "approaching side peak {left}");
    assert!(right > 656.28 + 2.0, "receding side peak {right}");
    let trace = std::fs::read_to_string(dir.path().join("shell_trace_6_16.csv")).unwrap();
    assert!(trace.starts_with("step,t,radial_velocity_m_per_s,wavelength_nm,value"));
    assert!(trace.lines().count() > 100);
    assert!(dir.path().join("shell_trace_6_16.png").exists());
}

#[test]
fn bad_input_is_refused_without_output() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("x.exr");
    let o = out.to_str().unwrap();
    for args in [
        vec!["--integrator", "banded:0"],
        vec!["--integrator", "spline"],
        vec!["--synth", "teapot"],
        vec!["--pick", "99,0"],
        vec!["--res", "100000"],
        vec!["--doppler", "galilean"],
        vec!["--velocity-factor", "NaN"],
        vec!["--width", "0"],
    ] {
        let mut a = vec![
            "doppler", "--synth", "shell", "--res", "8", "--width", "8", "--height", "8",
        ];
        a.extend(args.iter().copied());
        a.extend(["--out", o]);
        let r = blueshift(&a);
        assert_eq!(r.status.code(), Some(1), "{args:?}");
        assert!(!String::from_utf8_lossy(&r.stderr).is_empty());
        assert!(!out.exists(), "{args:?} left a file");
    }
}

#[test]
fn banded_and_pwl_agree_and_demo_writes_its_files() {
    let dir = tempfile::tempdir().unwrap();
    let read = |name: &str| {
        image::open(dir.path().join(name))
            .unwrap()
            .to_rgb32f()
            .into_raw()
    };
    for (name, integ) in [("p.exr", "pwl"), ("b.exr", "banded-ec:2000")] {
        let o = blueshift(&[
            "doppler",
            "--synth",
            "galaxy",
            "--res",
            "16",
            "--width",
            "12",
            "--height",
            "12",
            "--integrator",
            integ,
            "--out",
            dir.path().join(name).to_str().unwrap(),
        ]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    }
    let (p, b) = (read("p.exr"), read("b.exr"));
    let (mut num, mut den) = (0.0f64, 0.0f64);
    for (x, y) in p.iter().zip(&b) {
        num += f64::from(x - y).abs();
        den += f64::from(*x).abs();
    }
    assert!(den > 0.0 && num / den < 0.01, "relative L1 {}", num / den);
    let demo = dir.path().join("demo");
    let o = blueshift(&[
        "demo",
        demo.to_str().unwrap(),
        "--size",
        "24",
        "--res",
        "16",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let img = image::open(demo.join("side_by_side.png")).unwrap();
    assert_eq!((img.width(), img.height()), (48, 24));
    assert!(demo.join("spectra.png").exists());
}

/// A scene file of NRRDs written here: constant hydrogen moving away from the camera (+z)
/// at 300 km/s. The picked H-alpha peak sits at 656.279 (1 + 300 / c) nm; the factor flag
/// overrides the file's velocity factor; a bad scene is refused with exit code 1.
#[test]
fn scene_file_renders_with_units_and_flag_overrides() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let n = 8usize;
    let write = |name: &str, comps: usize, v: [f32; 3]| {
        let mut b = format!(
            "NRRD0004\ntype: float\ndimension: {}\nsizes: {}{n} {n} {n}\nendian: little\nencoding: raw\n\n",
            if comps == 3 { 4 } else { 3 },
            if comps == 3 { "3 " } else { "" }
        )
        .into_bytes();
        for _ in 0..n * n * n {
            for c in v.iter().take(comps) {
                b.extend_from_slice(&c.to_le_bytes());
            }
        }
        std::fs::write(d.join(name), b).unwrap();
    };
    write("h.nrrd", 1, [2.0, 0.0, 0.0]);
    write("v.nrrd", 3, [0.0, 0.0, 300.0]);
    let scene = r#"{"velocity": {"file": "v.nrrd", "unit": "km/s"},
        "species": [{"name": "hydrogen", "lines": "H", "density": {"file": "h.nrrd"}}],
        "factors": {"velocity": 1}}"#;
    std::fs::write(d.join("scene.json"), scene).unwrap();
    let s = d.join("scene.json");
    let s = s.to_str().unwrap();
    let c = 299_792.458;
    for (vf, want) in [("1", 656.279 * (1.0 + 300.0 / c)), ("0", 656.279)] {
        let out = d.join(format!("v{vf}.exr"));
        let o = blueshift(&[
            "doppler",
            "--scene",
            s,
            "--width",
            "8",
            "--height",
            "8",
            "--line-width",
            "0.02",
            "--velocity-factor",
            vf,
            "--pick",
            "4,4",
            "--out",
            out.to_str().unwrap(),
        ]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let peak = peak_nm(&d.join(format!("v{vf}_pick_4_4.csv")), 650.0, 662.0);
        assert!(
            (peak - want).abs() < 0.03,
            "velocity factor {vf}: peak {peak}, want {want}"
        );
    }
    // Bad scenes: an unknown unit, a part the scene lacks, --scene with --synth.
    std::fs::write(
        d.join("bad.json"),
        scene.replace("km/s", "parsec/fortnight"),
    )
    .unwrap();
    let bad = d.join("bad.json");
    for args in [
        vec!["--scene", bad.to_str().unwrap()],
        vec!["--scene", s, "--species", "oxygen"],
        vec!["--scene", s, "--synth", "shell"],
    ] {
        let out = d.join("never.exr");
        let mut all = vec!["doppler"];
        all.extend(args.iter().copied());
        all.extend(["--out", out.to_str().unwrap()]);
        let o = blueshift(&all);
        assert_eq!(o.status.code(), Some(1), "{args:?}");
        let msg = String::from_utf8_lossy(&o.stderr);
        assert!(!msg.trim().is_empty() && !msg.contains("panicked"), "{msg}");
        assert!(!out.exists());
    }
}
