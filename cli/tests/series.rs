//! `--series PATH...` (a time series of snapshots) from the outside: frame k is the render
//! of snapshot k on its own, byte for byte, written as STEM_kkkk.EXT; different snapshots
//! give different frames; a missing snapshot or two sequences at once are refused in one
//! line with nothing written.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn blueshift(dir: &Path, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_blueshift"))
        .args(args)
        .current_dir(dir)
        .output()
        .unwrap()
}

fn ok(o: &Output) {
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

fn bytes(p: PathBuf) -> Vec<u8> {
    std::fs::read(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()))
}

const RENDER: [&str; 13] = [
    "render",
    "--tf",
    "builtin:inferno",
    "--tf-range",
    "0:1",
    "--method",
    "marcher",
    "--width",
    "24",
    "--height",
    "20",
    "--device",
    "cpu",
];

#[test]
fn a_volume_series_renders_each_snapshot_as_its_own_frame() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // Three snapshots: the same turbulence at three seeds.
    for s in 1..=3 {
        ok(&blueshift(
            d,
            &[
                "synth",
                "turbulence",
                &format!("t{s}.nrrd"),
                "--res",
                "16",
                "--seed",
                &s.to_string(),
            ],
        ));
    }
    let run = |extra: &[&str]| {
        let mut a = RENDER.to_vec();
        a.extend(extra);
        blueshift(d, &a)
    };
    ok(&run(&[
        "--series", "t1.nrrd", "t2.nrrd", "t3.nrrd", "--out", "s.exr",
    ]));
    assert!(!d.join("s.exr").exists());
    for s in 1..=3 {
        ok(&run(&[
            "--volume",
            &format!("t{s}.nrrd"),
            "--out",
            &format!("one{s}.exr"),
        ]));
        let k = s - 1;
        assert_eq!(
            bytes(d.join(format!("s_{k:04}.exr"))),
            bytes(d.join(format!("one{s}.exr"))),
            "frame {k}"
        );
    }
    assert_ne!(bytes(d.join("s_0000.exr")), bytes(d.join("s_0001.exr")));

    // Refusals: nothing written.
    let bad = run(&["--series", "t1.nrrd", "missing.nrrd", "--out", "m.exr"]);
    assert!(!bad.status.success());
    let err = String::from_utf8_lossy(&bad.stderr);
    assert!(err.contains("missing.nrrd"), "{err}");
    assert!(!d.join("m_0000.exr").exists());
    let bad = run(&["--series", "t1.nrrd", "--orbit", "3", "--out", "b.exr"]);
    assert!(!bad.status.success());
    let err = String::from_utf8_lossy(&bad.stderr);
    assert!(err.contains("one of --series, --orbit and --ramp"), "{err}");
    assert!(!d.join("b_0000.exr").exists());
}

#[test]
fn a_scene_series_of_doppler_snapshots_renders_each_scene() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let data = root.join("../shared/data/enzo-moving7");
    let scene = std::fs::read_to_string(root.join("scenes/enzo-moving7.json")).unwrap();
    let scene = scene.replace(
        "\"../../shared/data/enzo-moving7\"",
        &format!("{:?}", data.to_str().unwrap()),
    );
    // Two snapshots of the scene: as it is, and with the gas twice as fast.
    std::fs::write(d.join("a.json"), &scene).unwrap();
    std::fs::write(
        d.join("b.json"),
        scene.replace("\"velocity\": 1,", "\"velocity\": 2,"),
    )
    .unwrap();
    let run = |extra: &[&str]| {
        let mut a = vec![
            "doppler", "--width", "16", "--height", "12", "--device", "cpu",
        ];
        a.extend(extra);
        blueshift(d, &a)
    };
    ok(&run(&["--series", "a.json", "b.json", "--out", "s.exr"]));
    for (k, s) in ["a", "b"].into_iter().enumerate() {
        ok(&run(&[
            "--scene",
            &format!("{s}.json"),
            "--out",
            &format!("{s}.exr"),
        ]));
        assert_eq!(
            bytes(d.join(format!("s_{k:04}.exr"))),
            bytes(d.join(format!("{s}.exr"))),
            "frame {k}"
        );
    }
    assert_ne!(bytes(d.join("s_0000.exr")), bytes(d.join("s_0001.exr")));
}
