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

#[test]
fn bricked_output_streams_every_component_and_matches_the_nrrd_voxels() {
    use blueshift_volume::ooc::BrickedFile;
    let dir = tempfile::tempdir().unwrap();
    let ok = |out: std::process::Output| {
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        )
    };
    ok(synth(&["galaxy", "g.nrrd", "--res", "24"], dir.path()));
    ok(synth(
        &["galaxy", "g.bsv", "--res", "24", "--brick", "8"],
        dir.path(),
    ));
    let nrrd = |name: &str| {
        read(dir.path().join(name)).unwrap().channels()[0]
            .grid
            .clone()
    };
    let bricked = |name: &str| {
        let f = BrickedFile::open(&dir.path().join(name), 8).unwrap();
        let AnyGrid::F32(g) = f.load_level(0, &Default::default()).unwrap() else {
            panic!("level 0 of {name} is f32")
        };
        (f.channel_name().to_string(), g)
    };
    for (n, b, channel) in [
        ("g.nrrd", "g.bsv", "hi_density"),
        ("g_he_density.nrrd", "g_he_density.bsv", "he_density"),
        (
            "g_temperature_k.nrrd",
            "g_temperature_k.bsv",
            "temperature_k",
        ),
    ] {
        let AnyGrid::F32(want) = nrrd(n) else {
            panic!("{n} is f32")
        };
        let (name, got) = bricked(b);
        assert_eq!(name, channel);
        assert_eq!(got, want, "{b}");
    }
    let AnyGrid::Vec3(v) = nrrd("g_velocity_m_per_s.nrrd") else {
        panic!("velocity is a vector")
    };
    for (a, axis) in ["x", "y", "z"].into_iter().enumerate() {
        let (name, got) = bricked(&format!("g_velocity_m_per_s_{axis}.bsv"));
        assert_eq!(name, format!("velocity_m_per_s_{axis}"));
        let want: Vec<f32> = v.data().iter().map(|p| p[a]).collect();
        assert_eq!(got.data(), &want[..], "component {axis}");
    }
    // One channel only, and the analytic Marschner-Lobb centre value in a bricked file.
    ok(synth(
        &[
            "galaxy",
            "only.bsv",
            "--res",
            "16",
            "--channel",
            "dust_density",
        ],
        dir.path(),
    ));
    assert_eq!(bricked("only.bsv").0, "dust_density");
    assert!(!dir.path().join("only_he_density.bsv").exists());
    ok(synth(
        &["marschner-lobb", "ml.bsv", "--res", "33"],
        dir.path(),
    ));
    let (_, ml) = bricked("ml.bsv");
    let centre = ml.data()[16 + 33 * (16 + 33 * 16)];
    let want = blueshift_volume::synth::marschner_lobb_at(Vec3::ZERO);
    assert!((centre - want).abs() < 1e-6, "{centre} vs {want}");
    let bad = synth(&["galaxy", "z.bsv", "--gzip"], dir.path());
    assert!(!bad.status.success());
}

/// Every channel written beside an Open SciVis raw name gets such a name, with its own
/// size, components and type, so each reads back by its name alone and holds the voxels the
/// NRRD output holds.
#[test]
fn extra_raw_channels_get_open_scivis_names_that_read_back() {
    let dir = tempfile::tempdir().unwrap();
    for out in ["g.nrrd", "g_8x8x4_float32.raw"] {
        let o = synth(&["galaxy", out, "--res", "8"], dir.path());
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    }
    for (nrrd, raw) in [
        ("g.nrrd", "g_8x8x4_float32.raw"),
        ("g_he_density.nrrd", "g_he_density_8x8x4_float32.raw"),
        ("g_temperature_k.nrrd", "g_temperature_k_8x8x4_float32.raw"),
        (
            "g_velocity_m_per_s.nrrd",
            "g_velocity_m_per_s_8x8x4x3_float32.raw",
        ),
    ] {
        let want = read(dir.path().join(nrrd)).unwrap().channels()[0]
            .grid
            .clone();
        let mut got = read(dir.path().join(raw)).unwrap().channels()[0]
            .grid
            .clone();
        // A raw file holds no geometry: compare the voxels.
        got.set_geometry(*want.geometry()).unwrap();
        assert_eq!(got, want, "{raw}");
    }
}

/// A vector channel picked alone streams to OUT-stem_x/_y/_z.bsv, the files `convert`
/// writes from the same channel's NRRD, and no component lands at OUT itself.
#[test]
fn a_vector_channel_alone_streams_to_the_files_convert_writes() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let ok = |o: std::process::Output| {
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    };
    let v = [
        "--res",
        "8",
        "--channel",
        "velocity_m_per_s",
        "--brick",
        "4",
    ];
    let mut a = vec!["galaxy", "s.bsv"];
    a.extend(v);
    ok(synth(&a, d));
    let mut a = vec!["galaxy", "v.nrrd"];
    a.extend(&v[..4]);
    ok(synth(&a, d));
    ok(std::process::Command::new(env!("CARGO_BIN_EXE_blueshift"))
        .args(["convert", "v.nrrd", "c.bsv", "--brick", "4"])
        .current_dir(d)
        .output()
        .unwrap());
    assert!(!d.join("s.bsv").exists());
    for axis in ["x", "y", "z"] {
        let s = std::fs::read(d.join(format!("s_{axis}.bsv"))).unwrap();
        let c = std::fs::read(d.join(format!("c_{axis}.bsv"))).unwrap();
        assert_eq!(s.len(), c.len(), "{axis}");
        let load = |name: String| {
            let f = blueshift_volume::ooc::BrickedFile::open(&d.join(name), 8).unwrap();
            f.load_level(0, &Default::default()).unwrap()
        };
        assert_eq!(
            load(format!("s_{axis}.bsv")),
            load(format!("c_{axis}.bsv")),
            "{axis}"
        );
    }
}
