//! An output larger than the disk, in a test binary of its own: reserving its blocks fills
//! the disk until the reservation fails, and tests writing files at the same moment in the
//! same binary (cargo runs one test binary at a time) would see the disk full.

use blueshift_volume::ooc::{self, BrickLayout};
use blueshift_volume::{Geometry, MemoryBudget};

/// An output the disk cannot hold (about 11 TiB of bricks, under ext4's 16 TiB file limit,
/// so that only reserving its blocks can tell) is refused before a single slice is read,
/// and leaves no file behind. (On a disk with that much room, the source's error at its
/// second slice ends the conversion instead, and the test fails.)
#[cfg(target_os = "linux")]
#[test]
fn an_output_larger_than_the_disk_is_refused_before_any_read() {
    struct Counting(Geometry, usize);
    impl ooc::SlabSource for Counting {
        fn geometry(&self) -> Geometry {
            self.0
        }
        fn read_slice(&mut self, _z: usize, out: &mut [f32]) -> blueshift_volume::Result<()> {
            self.1 += 1;
            if self.1 > 1 {
                return Err(blueshift_volume::Error::Invalid("enough".into()));
            }
            out.fill(1.0);
            Ok(())
        }
    }
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("huge.bsv");
    let mut src = Counting(Geometry::unit([1 << 13, 1 << 13, 1 << 15]), 0);
    // Memory unchecked: its 8192^2 slices need more than this machine's budget, and the
    // disk is what this test is about.
    let r = ooc::convert_within(
        &mut src,
        &out,
        "d",
        BrickLayout::default(),
        &MemoryBudget::unlimited(),
        &mut |_, _| {},
    );
    assert!(matches!(r, Err(blueshift_volume::Error::Io(_))), "{r:?}");
    assert_eq!(src.1, 0, "slices read before the space was reserved");
    let left: Vec<_> = std::fs::read_dir(dir.path()).unwrap().collect();
    assert!(left.is_empty(), "{left:?}");
}
