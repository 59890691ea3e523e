//! `blueshift tf`: run the binary on real inputs and check its outputs.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn blueshift(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_blueshift"))
        .args(args)
        .output()
        .expect("run blueshift")
}

fn okubo_weiss() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../tfedit/tests/data/paraview/OkuboWeiss.json")
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

#[test]
fn lut_writes_n_by_1_rgba_float_exr_with_entry_i_at_min_plus_i_step() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("grey.exr");
    let o = blueshift(&["tf", "lut", "builtin:grey", "--entries", "256", "--out", out.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    let img = image::open(&out).unwrap().into_rgba32f();
    assert_eq!(img.dimensions(), (256, 1));
    // The grey map is black to white with a 0-to-1 opacity ramp over [0, 1], so entry i is
    // i / 255 in every channel.
    for i in [0u32, 1, 100, 254, 255] {
        let p = img.get_pixel(i, 0).0;
        for c in p {
            assert!((c - i as f32 / 255.0).abs() < 1e-6, "entry {i}: {p:?}");
        }
    }
}

#[test]
fn lut_encode_2d_writes_rows_with_duplicated_neighbours() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("lut2d.exr");
    let o = blueshift(&[
        "tf", "lut", "builtin:grey", "--entries", "100", "--encode-2d", "--max-texture", "16",
        "--out", out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let img = image::open(&out).unwrap().into_rgba32f();
    // n = 14 entries per row, 100 / 14 -> 8 rows of 16 texels.
    assert_eq!(img.dimensions(), (16, 8));
    let entry = |i: u32| i as f32 / 99.0;
    // Row 1: texel 0 is entry 13, texels 1..=14 entries 14..=27, texel 15 entry 28.
    assert!((img.get_pixel(0, 1).0[0] - entry(13)).abs() < 1e-6);
    assert!((img.get_pixel(1, 1).0[0] - entry(14)).abs() < 1e-6);
    assert!((img.get_pixel(15, 1).0[0] - entry(28)).abs() < 1e-6);
}

#[test]
fn paraview_import_then_export_keeps_the_opacity_points() {
    let dir = tempfile::tempdir().unwrap();
    let json = dir.path().join("okubo.json");
    let o = blueshift(&["tf", "import-paraview", okubo_weiss().to_str().unwrap(), "--out", json.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    let tf: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(tf["format"], "blueshift-transfer-function");
    assert_eq!(tf["opacity"].as_array().unwrap().len(), 3);
    assert_eq!(tf["opacity"][1]["alpha"], 0.0);
    let o = blueshift(&["tf", "export-paraview", json.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    let pv: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let points: Vec<f64> = pv[0]["Points"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
    assert_eq!(points, vec![0.0, 1.0, 0.5, 0.0, 1.0, 0.0, 0.5, 0.0, 2.0, 1.0, 0.5, 0.0]);
    assert_eq!(pv[0]["Name"], "OkuboWeiss");
    // The ParaView file itself is accepted wherever a transfer function is expected.
    let out = dir.path().join("okubo.exr");
    let o = blueshift(&["tf", "lut", okubo_weiss().to_str().unwrap(), "--entries", "3", "--out", out.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    let img = image::open(&out).unwrap().into_rgba32f();
    assert_eq!([img.get_pixel(0, 0).0[3], img.get_pixel(1, 0).0[3], img.get_pixel(2, 0).0[3]], [1.0, 0.0, 1.0]);
}

#[test]
fn show_draws_the_editor_view_with_focus_and_log_alpha() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("tf.png");
    let o = blueshift(&[
        "tf", "show", okubo_weiss().to_str().unwrap(), "--out", out.to_str().unwrap(),
        "--focus", "0.5:0.2:3", "--focus", "1.5:0.1:2:0.02", "--log-alpha",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let img = image::open(&out).unwrap();
    assert_eq!((img.width(), img.height()), (1024, 512));
}

#[test]
fn bad_input_gives_one_line_errors_and_no_output_file() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("x.png");
    let outs = out.to_str().unwrap();
    let bad_tf = dir.path().join("bad.json");
    std::fs::write(&bad_tf, "[{\"Name\": \"b\", \"RGBPoints\": [0, 0, 0, 0, 1, 1, 1, 1], \"Points\": [0, 0, 0.5, 0, 1, 2, 0.5, 0]}]").unwrap();
    let exr = dir.path().join("x.exr");
    let exrs = exr.to_str().unwrap();
    let cases: Vec<(Vec<&str>, &str)> = vec![
        (vec!["tf", "show", "builtin:grey", "--out", outs, "--focus", "0.5:0.5:10"], "M_min"),
        (vec!["tf", "show", "builtin:grey", "--out", outs, "--focus", "0.5:abc:2"], "not a number"),
        (vec!["tf", "show", "builtin:grey", "--out", outs, "--focus", "0.3:0.2:2", "--focus", "0.4:0.2:2"], "overlap"),
        (vec!["tf", "show", bad_tf.to_str().unwrap(), "--out", outs], "Points point 1"),
        (vec!["tf", "show", "builtin:nope", "--out", outs], "no built-in"),
        (vec!["tf", "lut", "builtin:grey", "--entries", "16", "--out", outs], "exr"),
        (vec!["tf", "lut", "builtin:grey", "--entries", "1", "--out", exrs], "entries"),
        (vec!["tf", "lut", "builtin:grey", "--entries", "99999999999", "--out", exrs], "entries"),
        (vec!["tf", "import-paraview", "/nonexistent.json"], "/nonexistent.json"),
    ];
    for (args, needle) in cases {
        let o = blueshift(&args);
        let err = stderr(&o);
        assert_eq!(o.status.code(), Some(1), "{args:?}: {err}");
        assert!(err.contains(needle), "{args:?}: {err:?} lacks {needle:?}");
        assert_eq!(err.trim_end().lines().count(), 1, "{args:?}: {err:?}");
    }
    assert!(!out.exists() && !exr.exists());
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1, "stray files left behind");
}
