//! `blueshift info` on real crops, as text and JSON, and on malformed files.

use std::path::{Path, PathBuf};
use std::process::Command;

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../volume/tests/data")
        .join(name)
}

fn blueshift(args: &[&std::ffi::OsStr]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_blueshift"))
        .args(args)
        .output()
        .unwrap()
}

#[test]
fn info_json_reports_dims_spacing_type_and_range_of_the_headsq_crop() {
    let out = blueshift(&[
        "info".as_ref(),
        data("valid/headsq_crop_gzip.nrrd").as_os_str(),
        "--json".as_ref(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["dims"], serde_json::json!([16, 16, 8]));
    let sp: Vec<f64> = v["spacing"]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect();
    assert!(
        (sp[0] - 3.2).abs() < 1e-6 && (sp[2] - 1.5).abs() < 1e-6,
        "{sp:?}"
    );
    assert_eq!(v["type"], "int16");
    // Independent truth: the reference raw file's min and max.
    let raw = std::fs::read(data("valid/headsq_crop_16x16x8_int16.raw")).unwrap();
    let vals: Vec<i16> = raw
        .chunks_exact(2)
        .map(|c| i16::from_le_bytes([c[0], c[1]]))
        .collect();
    assert_eq!(
        v["min"].as_f64().unwrap(),
        f64::from(*vals.iter().min().unwrap())
    );
    assert_eq!(
        v["max"].as_f64().unwrap(),
        f64::from(*vals.iter().max().unwrap())
    );
    let counts: u64 = v["channels"][0]["histogram"]["counts"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c.as_u64().unwrap())
        .sum();
    assert_eq!(counts, 16 * 16 * 8, "the histogram counts every voxel");
}

#[test]
fn info_text_lists_both_channels_of_a_vtk_file() {
    let out = blueshift(&[
        "info".as_ref(),
        data("valid/carotid_crop_binary.vtk").as_os_str(),
    ]);
    assert!(out.status.success());
    let text = String::from_utf8(out.stdout).unwrap();
    assert!(text.contains("dims: 8 x 8 x 6"), "{text}");
    assert!(
        text.contains("channel 'scalars'") && text.contains("channel 'vectors'"),
        "{text}"
    );
}

#[test]
fn malformed_files_give_one_line_errors_and_nonzero_exit() {
    let dir = data("invalid");
    let mut n = 0;
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        let out = blueshift(&["info".as_ref(), p.as_os_str()]);
        assert_eq!(out.status.code(), Some(1), "{}", p.display());
        let err = String::from_utf8(out.stderr).unwrap();
        assert_eq!(
            err.trim_end().lines().count(),
            1,
            "one line for {}: {err}",
            p.display()
        );
        assert!(
            err.starts_with("blueshift: ") && !err.contains("panicked"),
            "{err}"
        );
        n += 1;
    }
    assert!(n >= 25);
    let out = blueshift(&["info".as_ref(), "/nonexistent/file.nrrd".as_ref()]);
    assert_eq!(out.status.code(), Some(1));
}
