//! Resource limits: the memory budget and inputs that are not regular files.

use std::time::Duration;

use blueshift_volume::budget::{MemoryBudget, grid_bytes};
use blueshift_volume::ooc::BrickLayout;
use blueshift_volume::{Error, synth};

#[test]
fn synth_checks_its_estimate_against_the_budget() {
    let budget = MemoryBudget::new(64 << 20, "--max-memory");
    let err = synth::by_name_within("turbulence", 2048, 1, &budget).unwrap_err();
    assert!(matches!(err, Error::Budget(ref e) if e.needed == grid_bytes([2048; 3], 4, 1)));
    let msg = err.to_string();
    assert!(
        msg.contains("needs 34.4 GB") && msg.contains("(--max-memory)"),
        "{msg}"
    );
    let v = synth::by_name_within("turbulence", 8, 1, &budget).unwrap();
    assert_eq!(v.geometry().dims, [8, 8, 8]);
}

#[test]
fn a_fifo_data_file_is_refused_promptly() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path().to_path_buf();
    assert!(
        std::process::Command::new("mkfifo")
            .arg(d.join("data.raw"))
            .status()
            .unwrap()
            .success()
    );
    std::fs::write(
        d.join("v.nhdr"),
        "NRRD0004\ntype: float\ndimension: 3\nsizes: 4 4 4\nencoding: raw\nendian: little\ndata file: data.raw\n",
    )
    .unwrap();
    let (tx, rx) = std::sync::mpsc::channel();
    let p = d.join("v.nhdr");
    let fifo = d.join("data.raw");
    std::thread::spawn(move || {
        let a = blueshift_volume::read(&p)
            .map(|_| ())
            .map_err(|e| e.to_string());
        let b = blueshift_volume::read(&fifo)
            .map(|_| ())
            .map_err(|e| e.to_string());
        let _ = tx.send((a, b));
    });
    // A blocked open would never answer; the guard is generous.
    let (a, b) = rx
        .recv_timeout(Duration::from_secs(30))
        .expect("the read blocked");
    for r in [a, b] {
        let msg = r.unwrap_err();
        assert!(msg.contains("not a regular file (a FIFO)"), "{msg}");
    }
}

#[test]
fn a_brick_edge_is_capped_at_the_volume() {
    let l = BrickLayout {
        brick: 1024,
        apron: 1,
    };
    assert_eq!(l.fitted([16, 16, 16]).brick, 16);
    assert_eq!(l.fitted([15, 3, 2]).brick, 16);
    assert_eq!(l.fitted([4096, 16, 16]).brick, 1024);
    assert_eq!(BrickLayout::default().fitted([1, 1, 1]).brick, 2);
}

/// The files in `dir`, sorted.
fn listing(dir: &std::path::Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

#[test]
fn a_conversion_over_the_budget_is_refused_before_any_file_is_made() {
    use blueshift_volume::ooc::{self, GridSource};
    use blueshift_volume::{Geometry, Grid, ScalarType};
    // A long thin volume in bricks of 1000: its one brick of 1002^3 floats (4.0 GB) holds
    // 4,000 voxels. The fitted brick stays 1000 (the volume's longest axis).
    let dims = [1000, 2, 2];
    let g = Grid::<f32>::from_fn(Geometry::unit(dims), |x, y, z| (x + y + z) as f32).unwrap();
    let layout = BrickLayout {
        brick: 1000,
        apron: 1,
    };
    let one_brick = 1002u64.pow(3) * 4;
    let need = ooc::conversion_bytes(dims, layout, &[ScalarType::F32]);
    assert!(need >= one_brick, "{need} < {one_brick}");
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("thin.bsv");
    let budget = MemoryBudget::new(1 << 30, "--max-memory");
    let err = ooc::convert_within(
        &mut GridSource(&g),
        &out,
        "d",
        layout,
        &budget,
        &mut |_, _| {},
    )
    .unwrap_err();
    assert!(
        matches!(err, Error::Budget(ref e) if e.needed == need && e.budget == 1 << 30),
        "{err}"
    );
    let msg = err.to_string();
    assert!(
        msg.contains("1000x2x2") && msg.contains("(--max-memory)"),
        "{msg}"
    );
    assert!(listing(dir.path()).is_empty(), "{:?}", listing(dir.path()));
    // Bricks of 8 fit: the same budget converts it, and the file reads back.
    let small = BrickLayout { brick: 8, apron: 1 };
    assert!(ooc::conversion_bytes(dims, small, &[ScalarType::F32]) < 1 << 20);
    ooc::convert_within(
        &mut GridSource(&g),
        &out,
        "d",
        small,
        &budget,
        &mut |_, _| {},
    )
    .unwrap();
    assert_eq!(listing(dir.path()), ["thin.bsv"]);
    let back = ooc::BrickedFile::open(&out, 4).unwrap();
    assert_eq!(back.geometries()[0].dims, dims);
}

#[test]
fn the_conversion_estimate_covers_the_slices_and_bricks_it_must_hold() {
    use blueshift_volume::ScalarType;
    use blueshift_volume::ooc;
    // Lower bounds from the layout alone: a window of at least the stored edge of level-0
    // slices (each a whole slice of f32) and a row of bricks of level 0 at once.
    let layout = BrickLayout::default();
    let s = layout.stored_edge() as u64;
    for (dims, ty, bytes) in [
        ([256, 256, 256], ScalarType::F32, 4u64),
        ([300, 200, 100], ScalarType::U8, 1),
        ([65, 64, 3], ScalarType::U16, 2),
    ] {
        let need = ooc::conversion_bytes(dims, layout, &[ty]);
        let nz = (dims[2] as u64).min(s);
        let slices = nz * (dims[0] * dims[1]) as u64 * 4;
        let row = dims[0].div_ceil(layout.brick) as u64 * s.pow(3) * bytes;
        assert!(need >= slices + row, "{dims:?}: {need} < {}", slices + row);
        // Two channels hold two windows.
        assert!(ooc::conversion_bytes(dims, layout, &[ty, ty]) >= need + slices);
    }
}
