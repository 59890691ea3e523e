//! `blueshift doppler --cube` from outside: FITS + NRRD + moment maps, bad input.

use std::process::Command;

fn blueshift(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_blueshift"))
        .args(args)
        .output()
        .unwrap()
}

const BASE: [&str; 11] = [
    "doppler",
    "--synth",
    "shell",
    "--res",
    "24",
    "--species",
    "H",
    "--width",
    "24",
    "--height",
    "24",
];

/// The shell seen from +z: the cube has the FITS size the standard prescribes, moment 1 is
/// receding (> 0) on the +x side and approaching on the -x side, within +-350 km/s.
#[test]
fn shell_cube_with_moments() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("shell.fits");
    let mut a: Vec<&str> = BASE.to_vec();
    let o = out.to_str().unwrap();
    a.extend([
        "--cube",
        o,
        "--line",
        "Halpha",
        "--velocity-bins",
        "-400:400:32",
        "--axis",
        "z",
        "--moments",
        "--line-sigma",
        "15",
    ]);
    let r = blueshift(&a);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let bytes = std::fs::read(&out).unwrap();
    let header = (bytes.len() - (24 * 24 * 32 * 4usize).div_ceil(2880) * 2880) % 2880;
    assert_eq!(bytes.len() % 2880, 0);
    assert_eq!(header, 0);
    assert!(bytes.starts_with(b"SIMPLE  =                    T"));
    for name in ["mom0", "mom1", "mom2"] {
        for ext in ["exr", "png"] {
            assert!(
                dir.path().join(format!("shell_{name}.{ext}")).exists(),
                "{name}.{ext}"
            );
        }
    }
    assert!(dir.path().join("shell.nrrd").exists());
    let m1 = image::open(dir.path().join("shell_mom1.exr"))
        .unwrap()
        .into_rgba32f();
    let (left, right) = (m1.get_pixel(5, 12)[0], m1.get_pixel(18, 12)[0]);
    assert!(left < -50.0 && right > 50.0, "moment 1 {left} {right} km/s");
    assert!(left > -350.0 && right < 350.0);
}

#[test]
fn bad_cube_input_exits_1_without_files() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("bad.fits");
    let o = out.to_str().unwrap();
    for extra in [
        vec!["--line", "H-alpha", "--velocity-bins", "100:100:8"],
        vec!["--line", "H-alpha", "--velocity-bins", "100:-100:8"],
        vec!["--line", "H-alpha", "--velocity-bins", "-100:100:0"],
        vec!["--line", "900", "--velocity-bins", "-100:100:8"],
        vec!["--line", "OIII", "--velocity-bins", "-100:100:8"],
        vec!["--velocity-bins", "-100:100:8"],
        vec!["--line", "H-alpha"],
        vec![
            "--line",
            "H-alpha",
            "--velocity-bins",
            "-100:100:8",
            "--axis",
            "w",
        ],
        vec![
            "--line",
            "H-alpha",
            "--velocity-bins",
            "-100:100:8",
            "--normal",
            "0,0,0",
        ],
        // The shell has no temperature field.
        vec![
            "--line",
            "H-alpha",
            "--velocity-bins",
            "-100:100:8",
            "--thermal",
        ],
    ] {
        let mut a: Vec<&str> = BASE.to_vec();
        a.extend(["--cube", o]);
        a.extend(extra.iter().copied());
        let r = blueshift(&a);
        assert_eq!(r.status.code(), Some(1), "{extra:?}");
        assert!(!String::from_utf8_lossy(&r.stderr).trim().is_empty());
        let left: Vec<_> = std::fs::read_dir(dir.path()).unwrap().collect();
        assert!(left.is_empty(), "{extra:?} left files");
    }
}

/// `--mask 50%`: moments 1 and 2 are NaN exactly where moment 0 is below half its peak;
/// without it those faint pixels have a (noisy) finite moment 1.
#[test]
fn mask_blanks_moments_1_and_2_of_faint_pixels() {
    let dir = tempfile::tempdir().unwrap();
    let read = |p: &std::path::Path| -> Vec<f32> {
        image::open(p)
            .unwrap()
            .into_rgba32f()
            .pixels()
            .map(|p| p[0])
            .collect()
    };
    let mut runs = Vec::new();
    for (stem, mask) in [("plain", None), ("masked", Some("50%"))] {
        let out = dir.path().join(format!("{stem}.fits"));
        let mut a: Vec<&str> = BASE.to_vec();
        a.extend([
            "--cube",
            out.to_str().unwrap(),
            "--line",
            "Halpha",
            "--velocity-bins",
            "-400:400:32",
            "--axis",
            "z",
            "--moments",
            "--line-sigma",
            "15",
        ]);
        if let Some(m) = mask {
            a.extend(["--mask", m]);
        }
        let r = blueshift(&a);
        assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
        let m = |k: &str| read(&dir.path().join(format!("{stem}_{k}.exr")));
        runs.push((m("mom0"), m("mom1"), m("mom2")));
    }
    let (m0, plain1, _) = &runs[0];
    let (m0_masked, m1, m2) = &runs[1];
    assert_eq!(m0, m0_masked, "moment 0 is never masked");
    let peak = m0.iter().copied().fold(0.0f32, f32::max);
    let faint = m0.iter().filter(|&&v| v > 0.0 && v < 0.5 * peak).count();
    assert!(faint > 0, "the shell has faint pixels");
    for i in 0..m0.len() {
        let below = m0[i] < 0.5 * peak;
        assert_eq!(
            m1[i].is_nan(),
            below,
            "pixel {i}: m0 {} m1 {}",
            m0[i],
            m1[i]
        );
        assert_eq!(m2[i].is_nan(), below, "pixel {i}");
        if m0[i] > 0.0 {
            assert!(plain1[i].is_finite());
        }
    }
    // A bad threshold is a user error.
    let out = dir.path().join("bad.fits");
    let mut a: Vec<&str> = BASE.to_vec();
    a.extend([
        "--cube",
        out.to_str().unwrap(),
        "--line",
        "Halpha",
        "--velocity-bins",
        "-400:400:8",
        "--moments",
        "--mask",
        "lots",
    ]);
    assert_eq!(blueshift(&a).status.code(), Some(1));
    assert!(!out.exists());
}

/// A scene file's `cube` units become the FITS BUNIT and the sky axes' CUNIT / CDELT;
/// `--bunit` overrides the file.
#[test]
fn scene_file_cube_units_label_the_fits() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let n = 8usize;
    let mut b = format!(
        "NRRD0004\ntype: float\ndimension: 3\nsizes: {n} {n} {n}\nendian: little\nencoding: raw\n\n"
    )
    .into_bytes();
    for _ in 0..n * n * n {
        b.extend_from_slice(&2.0f32.to_le_bytes());
    }
    std::fs::write(d.join("h.nrrd"), b).unwrap();
    let scene = r#"{"species": [{"name": "hydrogen", "lines": "H",
        "density": {"file": "h.nrrd", "unit": "cm-3"}}],
        "cube": {"bunit": "cm-2", "world_unit": "cm:3e18"}}"#;
    std::fs::write(d.join("scene.json"), scene).unwrap();
    let s = d.join("scene.json");
    let header = |extra: &[&str]| -> String {
        let out = d.join("c.fits");
        let mut a = vec![
            "doppler",
            "--scene",
            s.to_str().unwrap(),
            "--width",
            "8",
            "--height",
            "8",
            "--axis",
            "z",
            "--cube",
            out.to_str().unwrap(),
            "--line",
            "Halpha",
            "--velocity-bins",
            "-100:100:4",
        ];
        a.extend_from_slice(extra);
        let r = blueshift(&a);
        assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
        let bytes = std::fs::read(&out).unwrap();
        String::from_utf8_lossy(&bytes[..2880]).into_owned()
    };
    let cards = |h: &str, key: &str| -> String {
        (0..h.len() / 80)
            .map(|i| &h[i * 80..i * 80 + 80])
            .find(|c| c.starts_with(&format!("{key:<8}=")))
            .unwrap_or_else(|| panic!("no {key}"))[10..]
            .split('/')
            .next()
            .unwrap()
            .trim()
            .to_owned()
    };
    let h = header(&[]);
    assert_eq!(cards(&h, "BUNIT"), "'cm-2    '");
    assert_eq!(cards(&h, "CUNIT1"), "'cm      '");
    // 8 voxel centres span 7 spacings (1 world unit each), framed by 8 pixels seen from +z:
    // 7/8 world unit per pixel, 3e18 cm per world unit.
    let cdelt: f64 = cards(&h, "CDELT1").parse().unwrap();
    assert!((cdelt / (3e18 * 7.0 / 8.0) - 1.0).abs() < 1e-6, "{cdelt}");
    let h = header(&["--bunit", "K km s-1"]);
    assert_eq!(cards(&h, "BUNIT"), "'K km s-1'");
}

/// An image or a cube beyond `--max-memory` is refused in one line, before the scene is
/// loaded, and nothing is written (a 512x512x1000 cube is 1 GB of f32, 3 GB with its FITS
/// and NRRD copies).
#[test]
fn images_and_cubes_beyond_the_memory_budget_are_refused_before_work() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let cube = d.join("big.fits");
    let image = d.join("big.exr");
    for (args, needle) in [
        (
            vec![
                "--max-memory",
                "300M",
                "doppler",
                "--res",
                "16",
                "--width",
                "512",
                "--height",
                "512",
                "--line",
                "H-alpha",
                "--velocity-bins",
                "-100:100:1000",
                "--cube",
                cube.to_str().unwrap(),
            ],
            "this cube (512x512x1000 channels",
        ),
        (
            vec![
                "--max-memory",
                "50M",
                "doppler",
                "--res",
                "16",
                "--width",
                "4096",
                "--height",
                "4096",
                "--out",
                image.to_str().unwrap(),
            ],
            "this image (4096x4096",
        ),
    ] {
        let o = blueshift(&args);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{err}");
        assert!(
            err.contains(needle) && err.contains("--max-memory"),
            "{err}"
        );
        assert_eq!(err.trim().lines().count(), 1, "{err}");
    }
    assert_eq!(std::fs::read_dir(d).unwrap().count(), 0);
}
