//! `Field::read_block` / `VectorField::read_block` (the blocks a device brick pool holds)
//! against direct clamped indexing of the grid: dense, bricked through a cache smaller than
//! the blocks' bricks, and vector components, at interior, edge and corner positions.

use blueshift_volume::ooc::{self, BrickLayout, BrickedFile, GridSource};
use blueshift_volume::{AnyGrid, BrickCache, Field, Geometry, Grid, VectorField};
use glam::Vec3;

fn grid(dims: [usize; 3]) -> Grid<f32> {
    Grid::from_fn(Geometry::unit(dims), |x, y, z| {
        (x * 10_000 + y * 100 + z) as f32 + 0.25
    })
    .unwrap()
}

/// Voxel `min(lo + l, n - 1)` of `g` per axis, `edge^3` of them, x fastest.
fn clamped(g: &Grid<f32>, lo: [usize; 3], edge: usize) -> Vec<f32> {
    let n = g.dims();
    let mut out = Vec::new();
    for z in 0..edge {
        for y in 0..edge {
            for x in 0..edge {
                let v = [x, y, z];
                let at = [0, 1, 2].map(|a| (lo[a] + v[a]).min(n[a] - 1));
                out.push(g.get(at[0], at[1], at[2]).unwrap());
            }
        }
    }
    out
}

#[test]
fn blocks_equal_clamped_indexing_dense_bricked_and_vector() {
    let dims = [21, 13, 10];
    let g = grid(dims);
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("g.bsv");
    ooc::convert(
        &mut GridSource(&g),
        &p,
        "g",
        BrickLayout { brick: 4, apron: 1 },
        &mut |_, _| {},
    )
    .unwrap();
    // Two bricks of 6^3 f32: every block crosses more bricks than the cache holds.
    let f = BrickedFile::open_with_cache(&p, BrickCache::new(2 * 6 * 6 * 6 * 4)).unwrap();
    let bricked = Field::from(f.field(0).unwrap());
    let dense = Field::from(AnyGrid::F32(g.clone()));
    let vector = VectorField::from(
        Grid::from_fn(Geometry::unit(dims), |x, y, z| {
            Vec3::new(x as f32, -(y as f32), 0.5 * z as f32)
        })
        .unwrap(),
    );
    for lo in [[0, 0, 0], [3, 5, 2], [16, 8, 6], [20, 12, 9], [7, 0, 9]] {
        for edge in [1, 5, 9] {
            let want = clamped(&g, lo, edge);
            let mut got = vec![0.0; edge * edge * edge];
            dense.read_block(lo, edge, &mut got).unwrap();
            assert_eq!(got, want, "dense at {lo:?} edge {edge}");
            got.fill(-1.0);
            bricked.read_block(lo, edge, &mut got).unwrap();
            assert_eq!(got, want, "bricked at {lo:?} edge {edge}");
            for axis in 0..3 {
                vector.read_block(axis, lo, edge, &mut got).unwrap();
                let comp: Vec<f32> = (0..edge * edge * edge)
                    .map(|i| {
                        let l = [i % edge, (i / edge) % edge, i / (edge * edge)];
                        let at = [0, 1, 2].map(|a| (lo[a] + l[a]).min(dims[a] - 1));
                        [at[0] as f32, -(at[1] as f32), 0.5 * at[2] as f32][axis]
                    })
                    .collect();
                assert_eq!(got, comp, "vector {axis} at {lo:?} edge {edge}");
            }
        }
    }
    // Requests outside the grid or of the wrong size are errors, not panics.
    let mut out = vec![0.0; 8];
    assert!(dense.read_block([21, 0, 0], 2, &mut out).is_err());
    assert!(bricked.read_block([0, 0, 0], 3, &mut out).is_err());
    assert!(vector.read_block(3, [0, 0, 0], 2, &mut out).is_err());
    assert!(dense.read_block([0, 0, 0], 0, &mut []).is_err());
}
