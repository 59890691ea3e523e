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
    assert!(demo.join("spectra.png").exists() && demo.join("demo.png").exists());
}

/// Pixels of exactly `rgb` inside the rectangle `[x0, x1) x [y0, y1)`.
fn count_colour(img: &image::RgbImage, rgb: [u8; 3], x0: u32, x1: u32, y0: u32, y1: u32) -> usize {
    let mut n = 0;
    for y in y0..y1.min(img.height()) {
        for x in x0..x1.min(img.width()) {
            n += usize::from(img.get_pixel(x, y).0 == rgb);
        }
    }
    n
}

#[test]
fn demo_figure_has_images_marks_and_spectra_under_them() {
    let dir = tempfile::tempdir().unwrap();
    let demo = dir.path().join("demo");
    let o = blueshift(&[
        "demo",
        demo.to_str().unwrap(),
        "--size",
        "32",
        "--res",
        "16",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let fig = image::open(demo.join("demo.png")).unwrap().to_rgb8();
    // Layout: 900 wide; three panels (Doppler on, off, velocity) of the 32-pixel images shown
    // 6x (192 pixels) from y = 34 at x = 20, 236, 452, the keys under them, the plot below.
    assert_eq!(fig.width(), 900);
    let (top, bottom) = (34, 34 + 192 + 66 + 14);
    assert_eq!(fig.height(), bottom + 400);
    // Both true-colour panels hold the rendered galaxy: the side-by-side PNG's pixels, enlarged.
    let sbs = image::open(demo.join("side_by_side.png"))
        .unwrap()
        .to_rgb8();
    let (lx, rx) = (20, 236);
    for (x0, off) in [(lx, 0u32), (rx, 32)] {
        let (sx, sy) = (3u32, 3u32);
        assert_eq!(
            fig.get_pixel(x0 + sx * 6 + 1, top + sy * 6 + 1),
            sbs.get_pixel(off + sx, sy)
        );
    }
    // The picks (8,16), (16,16), (24,16) are ringed in the plot's colours in both images,
    // and each colour also draws a curve in the plot under the images.
    let colours = [[31, 119, 180], [214, 39, 40], [44, 160, 44]];
    for (k, c) in colours.iter().enumerate() {
        let px = 8 + 8 * k as u32;
        for x0 in [lx, rx] {
            let (cx, cy) = (x0 + px * 6 + 3, top + 16 * 6 + 3);
            assert!(
                count_colour(&fig, *c, cx - 10, cx + 11, cy - 10, cy + 11) > 10,
                "no ring of colour {c:?} at pick {k}"
            );
        }
        assert!(
            count_colour(&fig, *c, 0, 900, bottom, fig.height()) > 100,
            "no curve of colour {c:?} in the plot"
        );
    }
}

#[test]
fn trace_writes_small_multiples_matching_the_pick() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("g.exr");
    let o = blueshift(&[
        "doppler",
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
        "--pick",
        "4,8",
        "--trace",
        "4,8",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let csv = std::fs::read_to_string(dir.path().join("g_trace_4_8.csv")).unwrap();
    let rows: Vec<Vec<f64>> = csv
        .lines()
        .skip(1)
        .map(|l| l.split(',').map(|v| v.parse().unwrap()).collect())
        .collect();
    let steps = rows.iter().map(|r| r[0] as usize).max().unwrap() + 1;
    assert!(steps > 12, "{steps} steps");
    // More than 12 steps: 12 panels in a 4 x 3 grid of 300 x 230 under a 60-pixel title.
    let png = image::open(dir.path().join("g_trace_4_8.png")).unwrap();
    assert_eq!((png.width(), png.height()), (1200, 60 + 3 * 230));
    // The animation: one frame per step (up to 120), the final one held longer, and the
    // spectrum visibly growing between the first and the last frame.
    use image::AnimationDecoder;
    let gif = std::fs::File::open(dir.path().join("g_trace_4_8.gif")).unwrap();
    let frames = image::codecs::gif::GifDecoder::new(std::io::BufReader::new(gif))
        .unwrap()
        .into_frames()
        .collect_frames()
        .unwrap();
    assert_eq!(frames.len(), steps.min(120));
    let ms = |f: &image::Frame| {
        let (n, d) = f.delay().numer_denom_ms();
        n / d
    };
    assert!(ms(frames.last().unwrap()) > ms(&frames[0]));
    assert_eq!(frames[0].buffer().dimensions(), (640, 400));
    let differing = frames[0]
        .buffer()
        .pixels()
        .zip(frames.last().unwrap().buffer().pixels())
        .filter(|(a, b)| a != b)
        .count();
    assert!(differing > 500, "{differing} pixels differ");
    // Steps run back to front: the depth (distance from the ray's entry on the camera side)
    // falls to 0 at the last step, which is the picked pixel's final spectrum.
    let t_of = |s: usize| rows.iter().find(|r| r[0] as usize == s).unwrap()[1];
    assert!(t_of(0) > t_of(steps / 2) && t_of(steps / 2) > t_of(steps - 1));
    assert_eq!(t_of(steps - 1), 0.0);
    let pick = std::fs::read_to_string(dir.path().join("g_pick_4_8.csv")).unwrap();
    let pick: Vec<(f64, f64)> = pick
        .lines()
        .skip(1)
        .map(|l| {
            let (a, b) = l.split_once(',').unwrap();
            (a.parse().unwrap(), b.parse().unwrap())
        })
        .collect();
    let mut compared = 0;
    for r in rows.iter().filter(|r| r[0] as usize == steps - 1) {
        let (l, v) = (r[3], r[4]);
        let p = pick.iter().find(|p| (p.0 - l).abs() < 1e-9).unwrap().1;
        assert!(
            (p - v).abs() <= 1e-9 * p.abs().max(1e-30),
            "{l}: {p} vs {v}"
        );
        compared += 1;
    }
    assert!(compared > 100);
}

#[test]
fn tonemap_operators_compress_what_the_clamp_saturates() {
    let dir = tempfile::tempdir().unwrap();
    let saturated = |tonemap: &str, exposure: &str| -> (usize, usize) {
        let out = dir.path().join(format!("t_{tonemap}.exr"));
        let o = blueshift(&[
            "doppler",
            "--synth",
            "galaxy",
            "--res",
            "16",
            "--width",
            "24",
            "--height",
            "24",
            "--exposure-scale",
            exposure,
            "--tonemap",
            tonemap,
            "--out",
            out.to_str().unwrap(),
        ]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let png = image::open(out.with_extension("png")).unwrap().to_rgb8();
        let full = png.pixels().filter(|p| p.0.contains(&255)).count();
        let lit = png.pixels().filter(|p| p.0.iter().any(|&c| c > 0)).count();
        (full, lit)
    };
    // p50: half the lit pixels are brighter than Y = 1, so the clamp saturates many.
    let (clamped, lit) = saturated("none", "p50");
    assert!(clamped > 10 && lit > clamped);
    for op in ["reinhard", "drago"] {
        let (n, _) = saturated(op, "p50");
        assert!(n < clamped, "{op}: {n} saturated vs {clamped} clamped");
    }
    // Per-pixel luminance (Fig. 4a) works too; bad names are refused without output.
    let (_, lit_pp) = saturated("none", "per-pixel");
    assert!(lit_pp > 0);
    for (tm, ex) in [
        ("gamma", "p99"),
        ("none", "p101"),
        ("none", "-1"),
        ("none", "bright"),
    ] {
        let out = dir.path().join("bad.exr");
        let o = blueshift(&[
            "doppler",
            "--synth",
            "shell",
            "--res",
            "8",
            "--width",
            "8",
            "--height",
            "8",
            "--tonemap",
            tm,
            "--exposure-scale",
            ex,
            "--out",
            out.to_str().unwrap(),
        ]);
        assert_eq!(o.status.code(), Some(1), "{tm} {ex}");
        assert!(!out.exists() && !out.with_extension("png").exists());
    }
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
    // v_z = +300 km/s moves towards the default observer at +z (yt's view): blue-shifted.
    for (vf, want) in [("1", 656.279 * (1.0 - 300.0 / c)), ("0", 656.279)] {
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

#[test]
fn progressive_bricked_scene_reports_each_level_and_ends_on_the_exact_image() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let synth = blueshift(&[
        "synth",
        "hydrogen-shell",
        d.join("s.bsv").to_str().unwrap(),
        "--res",
        "32",
        "--brick",
        "8",
    ]);
    assert!(
        synth.status.success(),
        "{}",
        String::from_utf8_lossy(&synth.stderr)
    );
    let scene = r#"{"velocity": {"files": ["s_velocity_m_per_s_x.bsv",
            "s_velocity_m_per_s_y.bsv", "s_velocity_m_per_s_z.bsv"]},
        "species": [{"name": "hydrogen", "lines": "H", "density": {"file": "s.bsv"}}]}"#;
    std::fs::write(d.join("scene.json"), scene).unwrap();
    let s = d.join("scene.json");
    let run = |out: &str, extra: &[&str]| {
        let out = d.join(out);
        let mut args = vec![
            "doppler",
            "--scene",
            s.to_str().unwrap(),
            "--width",
            "16",
            "--height",
            "16",
            "--out",
            out.to_str().unwrap(),
        ];
        args.extend_from_slice(extra);
        let o = blueshift(&args);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        (
            std::fs::read(out).unwrap(),
            String::from_utf8_lossy(&o.stderr).to_string(),
        )
    };
    let (exact, _) = run("exact.exr", &[]);
    let (prog, log) = run("prog.exr", &["--progressive"]);
    // 32^3 in bricks of 8: levels 32, 16, 8 per edge; coarsest first.
    let levels: Vec<&str> = log
        .lines()
        .filter(|l| l.starts_with("progressive:"))
        .collect();
    assert_eq!(levels.len(), 3, "{log}");
    assert!(levels[0].contains("pass 1, level 2 (8x8x8)"), "{log}");
    assert!(levels[2].contains("pass 3, level 0 (32x32x32)"), "{log}");
    assert_eq!(prog, exact, "the last pass is the exact image");
    let (one, log1) = run("one.exr", &["--progressive", "--lod", "1"]);
    assert_eq!(
        log1.lines()
            .filter(|l| l.starts_with("progressive:"))
            .count(),
        2
    );
    let (lod1, _) = run("lod1.exr", &["--lod", "1"]);
    assert_eq!(one, lod1);
    // Brick by brick: the coarsest level, images over what has loaded, the exact image.
    let (bricks, logb) = run("bricks.exr", &["--progressive", "bricks"]);
    let steps: Vec<&str> = logb
        .lines()
        .filter(|l| l.starts_with("progressive:"))
        .collect();
    assert!(steps.len() >= 2, "{logb}");
    assert!(steps[0].contains("pass 1, level 2 (8x8x8)"), "{logb}");
    for s in &steps[1..steps.len() - 1] {
        assert!(s.contains("and finer where loaded"), "{logb}");
    }
    assert!(
        steps[steps.len() - 1].contains("level 0 (32x32x32)"),
        "{logb}"
    );
    assert_eq!(bricks, exact, "the last image is the exact one");
    let o = blueshift(&[
        "doppler",
        "--scene",
        s.to_str().unwrap(),
        "--progressive",
        "tiles",
        "--out",
        d.join("t.exr").to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("levels or bricks"));
    assert!(!d.join("t.exr").exists());
    // A scene in memory has no levels.
    let o = blueshift(&[
        "doppler",
        "--synth",
        "shell",
        "--res",
        "8",
        "--progressive",
        "--out",
        d.join("x.exr").to_str().unwrap(),
    ]);
    assert!(!o.status.success());
}
