//! `blueshift synth`: one NRRD per channel, deterministic by seed.

use std::process::Command;

use blueshift_volume::{AnyGrid, read};
use glam::Vec3;

fn synth(args: &[&str], dir: &std::path::Path) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_blueshift"))
        .arg("synth")
        .args(args)
        .current_dir(dir)
        .output()
        .unwrap()
}

#[test]
fn galaxy_writes_one_nrrd_per_channel() {
    let dir = tempfile::tempdir().unwrap();
    let out = synth(&["galaxy", "g.nrrd", "--res", "16"], dir.path());
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    for f in [
        "g.nrrd",
        "g_he_density.nrrd",
        "g_c_density.nrrd",
        "g_dust_density.nrrd",
        "g_temperature_k.nrrd",
        "g_velocity_m_per_s.nrrd",
    ] {
        assert!(dir.path().join(f).exists(), "{f}");
    }
    let v = read(dir.path().join("g_velocity_m_per_s.nrrd")).unwrap();
    assert_eq!(v.geometry().dims, [16, 16, 8]);
    assert!(matches!(v.channels()[0].grid, AnyGrid::Vec3(_)));
}

#[test]
fn same_seed_same_bytes_other_seed_other_bytes() {
    let dir = tempfile::tempdir().unwrap();
    for (f, seed) in [("a.nrrd", "3"), ("b.nrrd", "3"), ("c.nrrd", "4")] {
        assert!(
            synth(
                &["turbulence", f, "--res", "12", "--seed", seed],
                dir.path()
            )
            .status
            .success()
        );
    }
    let r = |f: &str| std::fs::read(dir.path().join(f)).unwrap();
    assert_eq!(r("a.nrrd"), r("b.nrrd"));
    assert_ne!(r("a.nrrd"), r("c.nrrd"));
}

#[test]
fn marschner_lobb_file_holds_the_analytic_centre_value() {
    let dir = tempfile::tempdir().unwrap();
    assert!(
        synth(&["marschner-lobb", "ml.nrrd", "--res", "21"], dir.path())
            .status
            .success()
    );
    let v = read(dir.path().join("ml.nrrd")).unwrap();
    let AnyGrid::F32(g) = &v.channels()[0].grid else {
        panic!()
    };
    // ρ(0, 0, 0) = 0.6 for f_M = 6, α = 0.25; the world origin is the grid centre.
    assert!((g.sample_trilinear(Vec3::ZERO) - 0.6).abs() < 1e-5);
}

#[test]
fn unknown_dataset_and_bad_resolution_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    assert!(!synth(&["nebula", "x.nrrd"], dir.path()).status.success());
    let o = synth(&["galaxy", "x.nrrd", "--res", "1"], dir.path());
    assert_eq!(o.status.code(), Some(1));
    assert!(!dir.path().join("x.nrrd").exists());
}
