//! Loads a volume (any supported format), prints its channels, samples it, builds
//! macrocells and walks a ray through them, then bricks it into an out-of-core file.
//!
//! `cargo run -p blueshift-volume --example inspect -- [FILE]`
//! (defaults to the committed headsq crop).

use blueshift_volume::ooc::{self, BrickLayout, BrickedFile, GridSource, Sampler};
use blueshift_volume::{AnyGrid, Macrocells};
use glam::Vec3;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let path = std::env::args().nth(1).unwrap_or_else(|| {
        concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/valid/headsq_crop_gzip.nrrd").to_string()
    });
    let vol = blueshift_volume::read(&path)?;
    let g = vol.geometry();
    println!("{path}: dims {:?}, spacing {}, origin {}", g.dims, g.spacing, g.origin);
    for c in vol.channels() {
        println!("  channel '{}': {} in memory, {:?} on disk, range {:?}", c.name, c.grid.scalar_type().name(), c.stored_as, c.grid.finite_range());
    }
    let (lo, hi) = g.world_bounds();
    let centre = (lo + hi) / 2.0;
    let first = &vol.channels()[0].grid;
    println!("trilinear sample at the centre {centre}: {}", first.sample_scalar_index(g.world_to_index(centre)));

    let cells = Macrocells::build_any(first, 4)?;
    println!("macrocells (k = 4): {:?}", cells.dims());
    for iv in cells.intervals(lo - Vec3::ONE, (hi - lo).normalize(), 0.0..f32::INFINITY).take(5) {
        println!("  t {:8.3} .. {:8.3}: values {:?}", iv.t.start, iv.t.end, iv.value);
    }

    if let AnyGrid::F32(grid) = first {
        let out = std::env::temp_dir().join("blueshift-inspect.bsv");
        ooc::convert(&mut GridSource(grid), &out, "scalars", BrickLayout { brick: 8, apron: 1 }, &mut |_, _| {})?;
        let file = BrickedFile::open(&out, 16)?;
        let l0 = file.level(0)?;
        println!(
            "bricked file: {} levels; out-of-core sample at the centre {}",
            file.levels(),
            l0.sample_world(centre)?
        );
        std::fs::remove_file(out)?;
    }
    Ok(())
}
