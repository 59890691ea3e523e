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
