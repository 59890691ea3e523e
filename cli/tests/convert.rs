//! `blueshift convert` between formats and into the bricked layout.

use std::path::{Path, PathBuf};
use std::process::Command;

use blueshift_volume::ooc::{BrickedFile, Sampler};
use blueshift_volume::{AnyGrid, DiskType, read};
use glam::Vec3;

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../volume/tests/data")
        .join(name)
}

fn run(args: &[&std::ffi::OsStr]) -> std::process::Output {
    let out = Command::new(env!("CARGO_BIN_EXE_blueshift"))
        .args(args)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{:?}: {}",
        args,
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

fn reference() -> Vec<f32> {
    let raw = std::fs::read(data("valid/headsq_crop_16x16x8_int16.raw")).unwrap();
    raw.chunks_exact(2)
        .map(|c| f32::from(i16::from_le_bytes([c[0], c[1]])))
        .collect()
}

#[test]
fn mha_to_nrrd_keeps_int16_spacing_and_values() {
    let dir = tempfile::tempdir().unwrap();
    for (name, extra) in [
        ("a.nrrd", None),
        ("b.nrrd", Some("--gzip")),
        ("c.nhdr", None),
    ] {
        let out = dir.path().join(name);
        let input = data("valid/headsq_crop.mha");
        let mut args: Vec<&std::ffi::OsStr> =
            vec!["convert".as_ref(), input.as_os_str(), out.as_os_str()];
        if let Some(e) = extra {
            args.push(e.as_ref());
        }
        run(&args);
        let v = read(&out).unwrap();
        assert_eq!(v.channels()[0].stored_as, Some(DiskType::I16), "{name}");
        assert!(
            (v.geometry().spacing - Vec3::new(3.2, 3.2, 1.5))
                .abs()
                .max_element()
                < 1e-6
        );
        assert_eq!(v.channels()[0].grid.to_f32_vec(), reference(), "{name}");
    }
    // --type and --spacing override.
    let out = dir.path().join("f.nrrd");
    run(&[
        "convert".as_ref(),
        data("valid/headsq_crop_be.nrrd").as_os_str(),
        out.as_os_str(),
        "--type".as_ref(),
        "float32".as_ref(),
        "--spacing".as_ref(),
        "1,2,3".as_ref(),
    ]);
    let v = read(&out).unwrap();
    assert_eq!(v.channels()[0].stored_as, Some(DiskType::F32));
    assert_eq!(v.geometry().spacing, Vec3::new(1.0, 2.0, 3.0));
    assert_eq!(v.channels()[0].grid.to_f32_vec(), reference());
}

#[test]
fn vtk_with_vectors_writes_one_nrrd_per_channel() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("car.nrrd");
    run(&[
        "convert".as_ref(),
        data("valid/carotid_crop_binary.vtk").as_os_str(),
        out.as_os_str(),
    ]);
    let vec_ref: Vec<f32> = std::fs::read(data("valid/carotid_crop_vectors_8x8x6x3_float32.raw"))
        .unwrap()
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect();
    let v = read(dir.path().join("car_vectors.nrrd")).unwrap();
    let AnyGrid::Vec3(g) = &v.channels()[0].grid else {
        panic!("vectors expected")
    };
    let got: Vec<f32> = g.data().iter().flat_map(|v| v.to_array()).collect();
    assert_eq!(got, vec_ref);
    assert_eq!(
        read(&out).unwrap().geometry().origin,
        Vec3::new(130.0, 100.0, 21.0)
    );
    // A .bsv holds one channel: the one converted and the others are named on stderr.
    let o = run(&[
        "convert".as_ref(),
        data("valid/carotid_crop_binary.vtk").as_os_str(),
        dir.path().join("car.bsv").as_os_str(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("a .bsv file holds one") && err.contains("--channel"),
        "{err}"
    );
}

#[test]
fn convert_to_bricked_file_samples_like_the_input() {
    let dir = tempfile::tempdir().unwrap();
    // Streamed from a detached raw NRRD and decompressed slice by slice from a gzip NRRD:
    // the same file.
    let a = dir.path().join("a.bsv");
    let b = dir.path().join("b.bsv");
    run(&[
        "convert".as_ref(),
        data("valid/headsq_crop.nhdr").as_os_str(),
        a.as_os_str(),
        "--brick".as_ref(),
        "4".as_ref(),
    ]);
    run(&[
        "convert".as_ref(),
        data("valid/headsq_crop_gzip.nrrd").as_os_str(),
        b.as_os_str(),
        "--brick".as_ref(),
        "4".as_ref(),
        "--spacing".as_ref(),
        "3.2,3.2,1.5".as_ref(),
    ]);
    let input = read(data("valid/headsq_crop.nhdr")).unwrap();
    let AnyGrid::F32(g) = &input.channels()[0].grid else {
        panic!("int16 loads as f32")
    };
    for path in [&a, &b] {
        let f = BrickedFile::open(path, 8).unwrap();
        assert!(
            f.levels() >= 3,
            "16x16x8 with 4^3 bricks needs levels down to 4^3"
        );
        let l0 = f.level(0).unwrap();
        for p in [
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(3.5, 7.25, 2.5),
            Vec3::new(15.0, 15.0, 7.0),
            Vec3::new(8.1, 0.9, 6.6),
        ] {
            assert_eq!(
                l0.sample_index(p).unwrap(),
                g.sample_trilinear_index(p),
                "{} at {p}",
                path.display()
            );
        }
    }
    // info reads the bricked file back.
    let out = run(&["info".as_ref(), a.as_os_str(), "--json".as_ref()]);
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["dims"], serde_json::json!([16, 16, 8]));
    assert_eq!(
        v["levels"],
        serde_json::json!([[16, 16, 8], [8, 8, 4], [4, 4, 2]])
    );
}

#[test]
fn bad_output_extension_and_bad_input_fail_cleanly_without_output() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("x.png");
    let o = Command::new(env!("CARGO_BIN_EXE_blueshift"))
        .args([
            "convert".as_ref(),
            data("valid/headsq_crop.mha").as_os_str(),
            out.as_os_str(),
        ])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(1));
    let out = dir.path().join("x.nrrd");
    let o = Command::new(env!("CARGO_BIN_EXE_blueshift"))
        .args([
            "convert".as_ref(),
            data("invalid/truncated_data.nrrd").as_os_str(),
            out.as_os_str(),
        ])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(1));
    assert!(!out.exists(), "no output file on failure");
    assert_eq!(
        std::fs::read_dir(dir.path()).unwrap().count(),
        0,
        "no temporary files left behind"
    );
}

/// A long thin volume in bricks of its length: one brick of 1002^3 floats (4.0 GB) for
/// 4,000 voxels. Refused up front within `--max-memory` (it aborted on a failed
/// allocation before, leaving a 4 GB temporary file), converted with smaller bricks.
#[test]
fn a_conversion_that_would_exceed_max_memory_is_refused_in_one_line() {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("thin_1000x2x2_float32.raw");
    let vals: Vec<u8> = (0..4000u32)
        .flat_map(|i| (i as f32).to_le_bytes())
        .collect();
    std::fs::write(&input, &vals).unwrap();
    let out = dir.path().join("thin.bsv");
    let o = Command::new(env!("CARGO_BIN_EXE_blueshift"))
        .args(["--max-memory", "1G", "convert"])
        .arg(&input)
        .arg(&out)
        .args(["--brick", "1000"])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(1));
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    assert!(
        err.contains("needs") && err.contains("--max-memory") && err.contains("brick"),
        "{err}"
    );
    let left: Vec<_> = std::fs::read_dir(dir.path()).unwrap().collect();
    assert_eq!(left.len(), 1, "only the input: {left:?}");
    run(&[
        "--max-memory".as_ref(),
        "1G".as_ref(),
        "convert".as_ref(),
        input.as_os_str(),
        out.as_os_str(),
        "--brick".as_ref(),
        "8".as_ref(),
    ]);
    let back = level0(&out);
    let want: Vec<f32> = (0..4000).map(|i| i as f32).collect();
    assert_eq!(back, want);
}

fn level0(path: &Path) -> Vec<f32> {
    let f = BrickedFile::open(path, 8).unwrap();
    let g = f
        .load_level(0, &blueshift_volume::Limits::default())
        .unwrap();
    let n = g.geometry().voxel_count();
    (0..n).map(|i| g.scalar_at(i)).collect()
}

/// `.bsv` output: a vector field becomes three files of its components; `--type uint8`
/// stores what NRRD output with `--type uint8` stores; `--gzip` and types a `.bsv` cannot
/// hold are refused with one line and no file; `info` over `--max-memory` describes a coarser
/// level.
#[test]
fn bricked_output_takes_vectors_and_types_and_refuses_what_it_cannot_do() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("car.bsv");
    run(&[
        "convert".as_ref(),
        data("valid/carotid_crop_binary.vtk").as_os_str(),
        out.as_os_str(),
        "--channel".as_ref(),
        "vectors".as_ref(),
        "--brick".as_ref(),
        "4".as_ref(),
    ]);
    let vec_ref: Vec<f32> = std::fs::read(data("valid/carotid_crop_vectors_8x8x6x3_float32.raw"))
        .unwrap()
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect();
    assert!(
        !out.exists(),
        "a vector field writes one file per component"
    );
    for (c, axis) in ["x", "y", "z"].iter().enumerate() {
        let got = level0(&dir.path().join(format!("car_{axis}.bsv")));
        let want: Vec<f32> = vec_ref.iter().skip(c).step_by(3).copied().collect();
        assert_eq!(got, want, "component {axis}");
    }
    // uint8: rounded and saturated as NRRD output rounds them.
    let input = data("valid/headsq_crop.nhdr");
    let (u8_bsv, u8_nrrd) = (dir.path().join("u8.bsv"), dir.path().join("u8.nrrd"));
    for out in [&u8_bsv, &u8_nrrd] {
        run(&[
            "convert".as_ref(),
            input.as_os_str(),
            out.as_os_str(),
            "--type".as_ref(),
            "uint8".as_ref(),
            "--brick".as_ref(),
            "4".as_ref(),
        ]);
    }
    let want = read(&u8_nrrd).unwrap().channels()[0].grid.to_f32_vec();
    // The input runs from 98 to 3517: most values saturate.
    assert!(want.contains(&255.0) && want.iter().any(|&v| v < 255.0));
    assert_eq!(level0(&u8_bsv), want);
    let stored = BrickedFile::open(&u8_bsv, 8)
        .unwrap()
        .load_level(0, &blueshift_volume::Limits::default())
        .unwrap();
    assert!(matches!(stored, AnyGrid::U8(_)), "stored as uint8");
    let refused = |extra: &[&str], needle: &str| {
        let out = dir.path().join("no.bsv");
        let o = Command::new(env!("CARGO_BIN_EXE_blueshift"))
            .args(["convert".as_ref(), input.as_os_str(), out.as_os_str()])
            .args(extra)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{extra:?}: {err}");
        assert!(
            err.contains(needle) && err.trim().lines().count() == 1,
            "{err}"
        );
        assert!(!out.exists());
    };
    refused(&["--gzip"], "--gzip");
    refused(&["--type", "int16"], "--type int16");
    // A .raw output is not compressed either.
    let raw = dir.path().join("no_8x8x8_uint8.raw");
    let o = Command::new(env!("CARGO_BIN_EXE_blueshift"))
        .args([
            "convert".as_ref(),
            input.as_os_str(),
            raw.as_os_str(),
            "--gzip".as_ref(),
        ])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&o.stderr).contains("a .raw file is stored raw"));
    assert!(!raw.exists());
    let o = Command::new(env!("CARGO_BIN_EXE_blueshift"))
        .args(["--max-memory", "1K", "info"])
        .arg(&u8_bsv)
        .output()
        .unwrap();
    // Level 0 does not fit: a coarser level's statistics, said so.
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(0), "{err}");
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(
        text.contains("the finest level within --max-memory"),
        "{text}"
    );
}

/// `info` on a `.bsv` whose level 0 exceeds `--max-memory` gives the statistics of the finest
/// level that fits, says which, and keeps the file's own dimensions and type. The levels
/// average 2 x 2 x 2 blocks, so for even dimensions their mean is level 0's.
#[test]
fn info_of_a_bricked_file_over_max_memory_describes_a_coarser_level() {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("ramp_64x64x64_uint8.raw");
    let vals: Vec<u8> = (0..64 * 64 * 64u32)
        .map(|i| ((i % 64) * 3 + (i / 4096)) as u8)
        .collect();
    std::fs::write(&input, &vals).unwrap();
    let bsv = dir.path().join("ramp.bsv");
    run(&[
        "convert".as_ref(),
        input.as_os_str(),
        bsv.as_os_str(),
        "--brick".as_ref(),
        "16".as_ref(),
    ]);
    let info = |budget: &str| {
        let o = run(&[
            "--max-memory".as_ref(),
            budget.as_ref(),
            "info".as_ref(),
            bsv.as_os_str(),
            "--json".as_ref(),
        ]);
        serde_json::from_slice::<serde_json::Value>(&o.stdout).unwrap()
    };
    let whole = info("1G");
    assert!(whole.get("statistics_level").is_none(), "{whole}");
    // Level 0 in f32 and its sorted copy: 2 MiB; level 1: 256 KiB.
    let part = info("600K");
    assert_eq!(part["statistics_level"], 1, "{part}");
    assert_eq!(part["dims"], serde_json::json!([64, 64, 64]));
    assert_eq!(part["channels"][0]["type"], "uint8");
    assert_eq!(part["channels"][0]["finite_count"], 32 * 32 * 32);
    let mean = |v: &serde_json::Value| v["channels"][0]["mean"].as_f64().unwrap();
    let want = vals.iter().map(|&v| f64::from(v)).sum::<f64>() / vals.len() as f64;
    assert!((mean(&whole) - want).abs() < 1e-9, "{}", mean(&whole));
    assert!((mean(&part) - want).abs() < 1e-4, "{}", mean(&part));
    // Nothing fits: the read's error, naming the setting.
    let o = Command::new(env!("CARGO_BIN_EXE_blueshift"))
        .args(["--max-memory", "1K", "info"])
        .arg(&bsv)
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&o.stderr).contains("--max-memory"));
}

/// Cubic bricks pad a thin volume: `convert` says so after writing, with the file's real
/// size and a brick edge that writes a smaller file (checked by converting with it).
#[test]
fn a_thin_volume_gets_a_note_on_its_padding_with_a_smaller_brick() {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("slice_512x512x1_uint8.raw");
    let vals: Vec<u8> = (0..512 * 512u32).map(|i| (i % 253) as u8).collect();
    std::fs::write(&input, &vals).unwrap();
    let out = dir.path().join("slice.bsv");
    let o = run(&["convert".as_ref(), input.as_os_str(), out.as_os_str()]);
    let err = String::from_utf8_lossy(&o.stderr);
    let note = err
        .lines()
        .find(|l| l.starts_with("note: bricks of edge 64"))
        .unwrap_or_else(|| panic!("no note: {err}"));
    assert!(note.contains("bricks are cubes"), "{note}");
    let len = std::fs::metadata(&out).unwrap().len();
    let fmt = blueshift_volume::budget::format_bytes;
    assert!(
        note.contains(&format!("volume {},", fmt(len))),
        "{note} ({len} bytes)"
    );
    let (_, tail) = note.split_once("--brick ").expect("a smaller brick named");
    let brick: String = tail.chars().take_while(char::is_ascii_digit).collect();
    let smaller = dir.path().join("smaller.bsv");
    run(&[
        "convert".as_ref(),
        input.as_os_str(),
        smaller.as_os_str(),
        "--brick".as_ref(),
        brick.as_ref(),
    ]);
    let small_len = std::fs::metadata(&smaller).unwrap().len();
    assert!(small_len < len / 4, "{small_len} vs {len}");
    assert!(
        note.ends_with(&format!("writes {}", fmt(small_len))),
        "{note}"
    );
    assert_eq!(level0(&smaller), level0(&out));
    // A cube-shaped volume gets no note.
    let cube = dir.path().join("c_64x64x64_uint8.raw");
    std::fs::write(&cube, vec![7u8; 64 * 64 * 64]).unwrap();
    let o = run(&[
        "convert".as_ref(),
        cube.as_os_str(),
        dir.path().join("c.bsv").as_os_str(),
    ]);
    assert!(!String::from_utf8_lossy(&o.stderr).contains("note:"));
    // Tiny bricks on a cube (of more than 1 MiB, below which no note is given): their 1-voxel
    // apron (4^3 values for 2^3 voxels) is the cause, and is named as such.
    let cube = dir.path().join("c_104x104x104_uint8.raw");
    std::fs::write(&cube, vec![7u8; 104 * 104 * 104]).unwrap();
    let o = run(&[
        "convert".as_ref(),
        cube.as_os_str(),
        dir.path().join("c2.bsv").as_os_str(),
        "--brick".as_ref(),
        "2".as_ref(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("note: bricks of edge 2")
            && err.contains("apron around its 2^3 voxels, 4^3 values (8.0 times)"),
        "{err}"
    );
}
