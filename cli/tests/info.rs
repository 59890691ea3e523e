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

#[test]
fn raw_input_layout_can_come_from_arguments() {
    let dir = tempfile::tempdir().unwrap();
    let bin = dir.path().join("crop.bin");
    std::fs::copy(data("valid/headsq_crop_16x16x8_int16.raw"), &bin).unwrap();
    // Without a layout the file cannot be read.
    assert_eq!(
        blueshift(&["info".as_ref(), bin.as_os_str()]).status.code(),
        Some(1)
    );
    let out = blueshift(&[
        "info".as_ref(),
        bin.as_os_str(),
        "--json".as_ref(),
        "--raw-dims".as_ref(),
        "16,16,8".as_ref(),
        "--raw-type".as_ref(),
        "int16".as_ref(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["dims"], serde_json::json!([16, 16, 8]));
    assert_eq!(v["type"], "int16");
    // A declared size larger than the file is refused.
    let out = blueshift(&[
        "info".as_ref(),
        bin.as_os_str(),
        "--raw-dims".as_ref(),
        "16,16,9".as_ref(),
        "--raw-type".as_ref(),
        "int16".as_ref(),
    ]);
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stderr).contains("file holds"));
}

/// `info` reads back the FITS cube `doppler --cube` writes: the dimensions, the WCS the
/// flags asked for (channel centres from -400 km/s in 25 km/s steps, sky axes in cm) and
/// BUNIT; a truncated or non-FITS file is a one-line error with exit code 1.
#[test]
fn info_reads_the_fits_cubes_the_tool_writes() {
    let dir = tempfile::tempdir().unwrap();
    let fits = dir.path().join("cube.fits");
    let out = Command::new(env!("CARGO_BIN_EXE_blueshift"))
        .args([
            "doppler",
            "--synth",
            "shell",
            "--res",
            "16",
            "--species",
            "H",
            "--width",
            "20",
            "--height",
            "12",
            "--line",
            "H-alpha",
            "--velocity-bins",
            "-400:400:32",
            "--bunit",
            "erg/s/cm2",
            "--world-unit",
            "cm:2",
            "--cube",
        ])
        .arg(&fits)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let out = Command::new(env!("CARGO_BIN_EXE_blueshift"))
        .arg("info")
        .arg(&fits)
        .arg("--json")
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["format"], "fits");
    assert_eq!(v["bitpix"], -32);
    assert_eq!(v["dims"], serde_json::json!([20, 12, 32]));
    assert_eq!(v["bunit"], "erg/s/cm2");
    let ax = &v["axes"];
    assert_eq!(ax[0]["ctype"], "LINEAR");
    assert_eq!(ax[0]["cunit"], "cm");
    assert_eq!(ax[0]["crpix"], 10.5);
    assert_eq!(ax[1]["crpix"], 6.5);
    assert_eq!(ax[2]["ctype"], "VRAD");
    assert_eq!(ax[2]["cunit"], "m/s");
    assert_eq!(ax[2]["crpix"], 1.0);
    let close = |a: &serde_json::Value, b: f64| (a.as_f64().unwrap() - b).abs() <= 1e-9 * b.abs();
    assert!(close(&ax[2]["crval"], -387_500.0), "{}", ax[2]["crval"]);
    assert!(close(&ax[2]["cdelt"], 25_000.0), "{}", ax[2]["cdelt"]);
    let rest = v["restwav_m"].as_f64().unwrap();
    assert!((656.2e-9..656.3e-9).contains(&rest), "{rest}");
    assert!(v["max"].as_f64().unwrap() > 0.0);
    // Text output names the same WCS.
    let out = Command::new(env!("CARGO_BIN_EXE_blueshift"))
        .arg("info")
        .arg(&fits)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("dims: 20 x 12 x 32"), "{text}");
    assert!(text.contains("axis 3: VRAD"), "{text}");
    assert!(text.contains("BUNIT: erg/s/cm2"), "{text}");

    // Malformed: the data cut short, and a text file named .fits.
    let bytes = std::fs::read(&fits).unwrap();
    let cut = dir.path().join("cut.fits");
    std::fs::write(&cut, &bytes[..2880 + 100]).unwrap();
    let junk = dir.path().join("junk.fits");
    std::fs::write(&junk, "not a FITS file\n".repeat(300)).unwrap();
    for (p, why) in [(&cut, "data"), (&junk, "SIMPLE")] {
        let out = Command::new(env!("CARGO_BIN_EXE_blueshift"))
            .arg("info")
            .arg(p)
            .output()
            .unwrap();
        assert_eq!(out.status.code(), Some(1));
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(err.trim().lines().count(), 1, "{err}");
        assert!(err.contains("malformed FITS") && err.contains(why), "{err}");
    }
}
