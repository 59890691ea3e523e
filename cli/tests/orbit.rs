//! `--orbit N[:DEG]` (a camera path) from the outside: one frame per angle, frame 0 the
//! plain render's bytes, half a turn the view from behind (the preset `--view -z`, and for
//! an emission-only medium at rest the mirror image of the front view), bad paths refused
//! in one line with nothing written.

use std::path::Path;
use std::process::{Command, Output};

mod common;

fn blueshift(dir: &Path, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_blueshift"))
        .args(args)
        .current_dir(dir)
        .output()
        .unwrap()
}

/// The galaxy, emission only, at rest (no Doppler shift), seen orthographically.
const DOPPLER: [&str; 15] = [
    "doppler",
    "--res",
    "24",
    "--width",
    "20",
    "--height",
    "16",
    "--velocity-factor",
    "0",
    "--absorption-factor",
    "0",
    "--exr-space",
    "xyz",
    "--device",
    "cpu",
];

fn ok(o: &Output) {
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

#[test]
fn half_an_orbit_is_the_view_from_behind() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let run = |extra: &[&str]| {
        let mut a = DOPPLER.to_vec();
        a.extend(extra);
        ok(&blueshift(d, &a));
    };
    run(&["--view", "z", "--orbit", "4", "--out", "o.exr"]);
    run(&["--view", "z", "--out", "front.exr"]);
    run(&["--view", "-z", "--out", "back.exr"]);
    for k in 0..4 {
        for ext in ["exr", "png"] {
            assert!(
                d.join(format!("o_{k:04}.{ext}")).is_file(),
                "frame {k} {ext}"
            );
        }
    }
    assert!(!d.join("o.exr").exists());
    assert_eq!(
        std::fs::read(d.join("o_0000.exr")).unwrap(),
        std::fs::read(d.join("front.exr")).unwrap()
    );
    let front = common::read_exr(&d.join("front.exr"));
    let back = common::read_exr(&d.join("back.exr"));
    let half = common::read_exr(&d.join("o_0002.exr"));
    let quarter = common::read_exr(&d.join("o_0001.exr"));
    let peak = front.as_raw().iter().fold(0.0f32, |m, &v| m.max(v));
    assert!(peak > 0.0);
    // Half a turn about +y puts the eye on -z with +y up: the -z preset's camera.
    let worst = half
        .as_raw()
        .iter()
        .zip(back.as_raw())
        .map(|(a, b)| (a - b).abs())
        .fold(0.0f32, f32::max);
    assert!(
        worst <= 1e-4 * peak,
        "half turn against --view -z: {worst} of {peak}"
    );
    // Emission only, at rest: the same line integrals, left and right swapped.
    let (w, h) = front.dimensions();
    let (mut diff, mut sum) = (0.0f64, 0.0f64);
    for y in 0..h {
        for x in 0..w {
            let a = front.get_pixel(x, y).0;
            let b = half.get_pixel(w - 1 - x, y).0;
            diff += f64::from((a[1] - b[1]).abs());
            sum += f64::from(a[1]);
        }
    }
    assert!(diff <= 0.02 * sum, "mirror: {diff} of {sum}");
    // A quarter turn sees the disc from its side: a different picture.
    assert_ne!(quarter.as_raw(), front.as_raw());
}

#[test]
fn render_orbit_frames_and_bad_paths() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let base = [
        "render",
        "--synth",
        "three-cubes",
        "--res",
        "12",
        "--tf",
        "builtin:viridis",
        "--width",
        "12",
        "--height",
        "12",
        "--spp",
        "2",
        "--device",
        "cpu",
    ];
    let mut a = base.to_vec();
    a.extend(["--orbit", "3:90", "--out", "r.exr"]);
    ok(&blueshift(d, &a));
    let mut a = base.to_vec();
    a.extend(["--out", "plain.exr"]);
    ok(&blueshift(d, &a));
    assert_eq!(
        std::fs::read(d.join("r_0000.exr")).unwrap(),
        std::fs::read(d.join("plain.exr")).unwrap()
    );
    assert_ne!(
        std::fs::read(d.join("r_0001.exr")).unwrap(),
        std::fs::read(d.join("r_0000.exr")).unwrap()
    );
    assert!(d.join("r_0002.exr").is_file() && !d.join("r_0003.exr").exists());
    for bad in [
        vec!["--orbit", "0"],
        vec!["--orbit", "4:nan"],
        vec!["--orbit", "x"],
        vec!["--orbit", "4", "--ramp", "0:0.5:3"],
    ] {
        let mut a = base.to_vec();
        a.extend(bad.iter().copied());
        a.extend(["--out", "bad.exr"]);
        let o = blueshift(d, &a);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{bad:?}");
        assert_eq!(err.trim().lines().count(), 1, "{bad:?}: {err}");
        assert!(err.contains("--orbit"), "{bad:?}: {err}");
    }
    assert!(
        std::fs::read_dir(d)
            .unwrap()
            .all(|e| { !e.unwrap().file_name().to_string_lossy().starts_with("bad") })
    );
}

/// An output of a later frame that is the input stops the run before frame 0 is written:
/// no partial sequence, the input untouched.
#[test]
fn an_orbit_whose_later_frame_is_the_input_writes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    ok(&blueshift(
        d,
        &["synth", "marschner-lobb", "--res", "10", "r_0001.nrrd"],
    ));
    let before = std::fs::read(d.join("r_0001.nrrd")).unwrap();
    let o = blueshift(
        d,
        &[
            "render",
            "--volume",
            "r_0001.nrrd",
            "--tf",
            "builtin:viridis",
            "--width",
            "8",
            "--height",
            "8",
            "--spp",
            "1",
            "--device",
            "cpu",
            "--orbit",
            "3",
            "--out",
            "r.nrrd",
        ],
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "{err}");
    assert!(
        err.contains("r_0001.nrrd") && err.contains("input"),
        "{err}"
    );
    assert_eq!(std::fs::read(d.join("r_0001.nrrd")).unwrap(), before);
    assert!(!d.join("r_0000.nrrd").exists() && !d.join("r_0002.nrrd").exists());
    // A series whose frame 1 output (r_0001.nrrd) is a snapshot: refused before frame 0.
    let o = blueshift(
        d,
        &[
            "render",
            "--series",
            "r_0001.nrrd",
            "r_0001.nrrd",
            "--tf",
            "builtin:viridis",
            "--width",
            "8",
            "--height",
            "8",
            "--device",
            "cpu",
            "--out",
            "r.nrrd",
        ],
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "{err}");
    assert!(err.contains("it is the input file"), "{err}");
    assert_eq!(std::fs::read(d.join("r_0001.nrrd")).unwrap(), before);
    assert!(!d.join("r_0000.nrrd").exists());
}
