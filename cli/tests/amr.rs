//! AMR output from the command line: `info` on Enzo and Athena++ files, `convert` to the
//! uniform grid of a level (checked against yt's covering grid of the real snapshot), and
//! a Doppler render of the AMR scene file, on the CPU and through the GPU's brick pool (each
//! region at its own refinement level).

use std::path::{Path, PathBuf};
use std::process::Command;

mod common;

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn enzo() -> PathBuf {
    root().join("../shared/data/enzo-moving7/original/moving7_0010")
}

fn blueshift(args: &[&std::ffi::OsStr]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_blueshift"))
        .args(args)
        .output()
        .unwrap()
}

fn ok(out: &std::process::Output) {
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

#[test]
fn info_lists_levels_blocks_fields_and_units() {
    let out = blueshift(&["info".as_ref(), enzo().as_os_str()]);
    ok(&out);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        text.contains("Enzo AMR, 10 blocks, 8 levels (ratio 2), root grid 16x16x16"),
        "{text}"
    );
    assert!(text.contains("level 7: 1 blocks, 800 cells"), "{text}");
    assert!(text.contains("field Density [g/cm3]"), "{text}");
    assert!(text.contains("field x-velocity [cm/s]"), "{text}");
    assert!(text.contains("redshift 9.991028"), "{text}");
    let out = blueshift(&["info".as_ref(), enzo().as_os_str(), "--json".as_ref()]);
    ok(&out);
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["code"], "Enzo");
    assert_eq!(v["blocks"], 10);
    assert_eq!(
        v["levels"][7]["uniform_dims"],
        serde_json::json!([2048, 2048, 2048])
    );
    let athena = root().join("volume/tests/data/amr/athena2.athdf");
    let out = blueshift(&["info".as_ref(), athena.as_os_str(), "--json".as_ref()]);
    ok(&out);
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["code"], "Athena++");
    assert_eq!(v["levels"][1]["blocks"], 8);
    let names: Vec<&str> = v["fields"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| f["name"].as_str().unwrap())
        .collect();
    assert_eq!(names, ["rho", "press", "vel1", "vel2", "vel3"]);
}

/// `convert --level 2` writes yt's covering grid: the same cells as the 64^3 file yt made.
#[test]
fn convert_writes_the_covering_grid_of_a_level() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("rho.nrrd");
    let r = blueshift(&[
        "convert".as_ref(),
        enzo().as_os_str(),
        out.as_os_str(),
        "--level".as_ref(),
        "2".as_ref(),
        "--channel".as_ref(),
        "Density".as_ref(),
    ]);
    ok(&r);
    let vol = blueshift_volume::read(&out).unwrap();
    let ours = vol.channels()[0].grid.to_f32_vec();
    let yt: Vec<f32> =
        std::fs::read(root().join("../shared/data/enzo-moving7/density_gcm3_64x64x64_f32le.raw"))
            .unwrap()
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect();
    assert_eq!(ours.len(), yt.len());
    for (a, b) in ours.iter().zip(&yt) {
        assert!((a / b - 1.0).abs() < 5e-7, "{a} vs {b}");
    }
    // No --level: one line naming the levels, nothing written.
    let none = dir.path().join("none.nrrd");
    let r = blueshift(&["convert".as_ref(), enzo().as_os_str(), none.as_os_str()]);
    assert!(!r.status.success());
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    assert!(err.contains("7 (2048x2048x2048)"), "{err}");
    assert!(!none.exists());
    // A level the budget cannot hold is refused before anything is read.
    let r = blueshift(&[
        "convert".as_ref(),
        enzo().as_os_str(),
        none.as_os_str(),
        "--level".as_ref(),
        "7".as_ref(),
        "--max-memory".as_ref(),
        "1G".as_ref(),
    ]);
    assert!(!r.status.success());
    assert!(!none.exists());
}

/// The AMR scene renders from the command line (the level the view needs by default).
#[test]
fn doppler_renders_the_amr_scene() {
    let dir = tempfile::tempdir().unwrap();
    let exr = dir.path().join("enzo.exr");
    let png = dir.path().join("enzo.png");
    let r = blueshift(&[
        "doppler".as_ref(),
        "--scene".as_ref(),
        root().join("scenes/enzo-moving7-amr.json").as_os_str(),
        "--width".as_ref(),
        "32".as_ref(),
        "--height".as_ref(),
        "32".as_ref(),
        "--species".as_ref(),
        "H I".as_ref(),
        "--out".as_ref(),
        exr.as_os_str(),
    ]);
    ok(&r);
    let img = image::open(&png).unwrap().to_rgb8();
    assert_eq!(img.dimensions(), (32, 32));
    assert!(img.pixels().any(|p| p.0.iter().any(|&c| c > 0)));
}

/// The AMR scene on the GPU: the pool holds each refinement level's sampled bricks (the
/// regions' levels of the hierarchy) and renders the CPU's image, within the f32 tolerance
/// of tests/doppler_device.rs.
#[test]
fn the_amr_scene_renders_on_the_gpu_as_on_the_cpu() {
    let dir = tempfile::tempdir().unwrap();
    let run = |device: &str| {
        let exr = dir.path().join(format!("{device}.exr"));
        let r = Command::new(env!("CARGO_BIN_EXE_blueshift"))
            .args(["doppler", "--scene"])
            .arg(root().join("scenes/enzo-moving7-amr.json"))
            .args([
                "--width", "64", "--height", "64", "--device", device, "--out",
            ])
            .arg(&exr)
            .env("BLUESHIFT_GPU", "software")
            .output()
            .unwrap();
        (r, exr)
    };
    let (c, cpu) = run("cpu");
    ok(&c);
    let (g, gpu) = run("gpu");
    if !common::gpu_ok("doppler", &g) {
        return;
    }
    let log = String::from_utf8_lossy(&g.stderr);
    assert!(log.contains("levels per brick"), "{log}");
    common::close_doppler(&cpu, &gpu);
}
