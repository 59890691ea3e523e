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
