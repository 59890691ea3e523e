//! A moving observer from the outside (`doppler` and `render` with `--observer-velocity`,
//! `--beta`/`--direction`, `--ramp`, `--searchlight`): at rest the same bytes, ramps write
//! one frame per speed, bad speeds are one-line errors that write nothing.

use std::process::Command;

fn blueshift() -> Command {
    Command::new(env!("CARGO_BIN_EXE_blueshift"))
}

fn doppler(dir: &std::path::Path, out: &str, extra: &[&str]) -> std::process::Output {
    blueshift()
        .args(["doppler", "--res", "24", "--width", "24", "--height", "20"])
        .args(extra)
        .arg("--out")
        .arg(dir.join(out))
        .output()
        .unwrap()
}

#[test]
fn speed_zero_writes_the_same_bytes_as_no_observer() {
    let dir = tempfile::tempdir().unwrap();
    let a = doppler(dir.path(), "a.exr", &[]);
    assert!(a.status.success(), "{}", String::from_utf8_lossy(&a.stderr));
    let b = doppler(
        dir.path(),
        "b.exr",
        &["--beta", "0", "--direction", "1,0,0"],
    );
    assert!(b.status.success(), "{}", String::from_utf8_lossy(&b.stderr));
    let c = doppler(dir.path(), "c.exr", &["--beta", "0.3"]);
    assert!(c.status.success(), "{}", String::from_utf8_lossy(&c.stderr));
    let read = |n: &str| std::fs::read(dir.path().join(n)).unwrap();
    assert_eq!(read("a.exr"), read("b.exr"));
    assert_eq!(read("a.png"), read("b.png"));
    assert_ne!(read("a.exr"), read("c.exr"));
}

#[test]
fn a_ramp_writes_one_frame_per_speed() {
    let dir = tempfile::tempdir().unwrap();
    let out = doppler(dir.path(), "fly.exr", &["--ramp", "0:0.4:3", "--fov", "40"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    for k in 0..3 {
        for ext in ["exr", "png"] {
            let p = dir.path().join(format!("fly_{k:04}.{ext}"));
            assert!(p.is_file(), "{}", p.display());
        }
    }
    assert!(!dir.path().join("fly.exr").exists());
    let render = blueshift()
        .args(["render", "--synth", "three-cubes", "--res", "16"])
        .args(["--tf", "builtin:viridis", "--width", "16", "--height", "16"])
        .args(["--spp", "1", "--ramp", "0.1:0.2:2", "--searchlight"])
        .arg("--out")
        .arg(dir.path().join("cubes.exr"))
        .output()
        .unwrap();
    assert!(
        render.status.success(),
        "{}",
        String::from_utf8_lossy(&render.stderr)
    );
    assert!(dir.path().join("cubes_0000.exr").is_file());
    assert!(dir.path().join("cubes_0001.exr").is_file());
}

#[test]
fn impossible_speeds_are_one_line_errors_that_write_nothing() {
    let dir = tempfile::tempdir().unwrap();
    for extra in [
        &["--beta", "1"][..],
        &["--beta", "-1.5"],
        &["--observer-velocity", "0.6,0.6,0.6"],
        &["--observer-velocity", "0.1,nan,0"],
        &["--beta", "0.5", "--direction", "0,0,0"],
        &["--direction", "1,0,0"],
        &["--ramp", "0:1:3"],
    ] {
        let out = doppler(dir.path(), "bad.exr", extra);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{extra:?}: {err}");
        assert_eq!(err.trim().lines().count(), 1, "{extra:?}: {err}");
        assert!(!dir.path().join("bad.exr").exists(), "{extra:?}");
    }
    let out = blueshift()
        .args(["render", "--synth", "three-cubes", "--res", "8"])
        .args(["--tf", "builtin:viridis", "--searchlight"])
        .arg("--out")
        .arg(dir.path().join("s.exr"))
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stderr).contains("--searchlight needs"));
}

/// A Doppler scene file's `observer_velocity` is the same observer as the flags: the scene
/// with `[0, 0, -0.2]` renders the bytes `--beta 0.2` (along the default view, -z) does.
#[test]
fn a_scene_file_observer_equals_the_flags() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let out = blueshift()
        .args(["synth", "hydrogen-shell", "--res", "16"])
        .arg(d.join("shell.nrrd"))
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let scene = |observer: &str| {
        format!(
            r#"{{ "velocity": {{ "file": "shell_velocity_m_per_s.nrrd" }},
                 "species": [{{ "name": "H", "lines": "H",
                               "density": {{ "file": "shell.nrrd" }} }}]
                 {observer} }}"#
        )
    };
    std::fs::write(
        d.join("moving.json"),
        scene(r#", "observer_velocity": [0, 0, -0.2]"#),
    )
    .unwrap();
    std::fs::write(d.join("still.json"), scene("")).unwrap();
    let run = |scene: &str, extra: &[&str], out: &str| {
        let o = blueshift()
            .args(["doppler", "--width", "16", "--height", "16", "--scene"])
            .arg(d.join(scene))
            .args(extra)
            .arg("--out")
            .arg(d.join(out))
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        std::fs::read(d.join(out)).unwrap()
    };
    let from_file = run("moving.json", &[], "a.exr");
    let from_flag = run("still.json", &["--beta", "0.2"], "b.exr");
    let at_rest = run("still.json", &[], "c.exr");
    assert_eq!(from_file, from_flag);
    assert_ne!(from_file, at_rest);
}
