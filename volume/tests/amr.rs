//! AMR hierarchies read natively: the h5py-written Enzo and Athena++ files of
//! `tests/data/amr/make.py` read back cell by cell against the formula that made them, the
//! real Enzo snapshot's covering grid against yt's, the reconstruction's continuity across
//! levels, and the brick source every renderer samples.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use blueshift_volume::amr::{
    AmrField, AmrStats, Block, FieldInfo, Hierarchy, Region, is_amr, open_field_within,
};
use blueshift_volume::{BrickCache, BrickedField, Error, Field, Geometry, Grid, Limits};
use glam::{DVec3, Vec3};

fn data(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/amr")
        .join(rel)
}

fn enzo_snapshot() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/enzo-moving7")
}

/// The formula `make.py` stores at every leaf cell centre.
fn f(p: DVec3) -> f64 {
    1.0 + p.x + 2.0 * p.y + 3.0 * p.z + p.x * p.y * p.z
}

fn centre(h: &Hierarchy, b: &Block, c: [usize; 3]) -> DVec3 {
    let dx = h.cell_size(b.level);
    h.domain_lo
        + DVec3::new(
            (b.lo[0] + c[0] as i64) as f64 + 0.5,
            (b.lo[1] + c[1] as i64) as f64 + 0.5,
            (b.lo[2] + c[2] as i64) as f64 + 0.5,
        ) * dx
}

fn cells(b: &Block) -> impl Iterator<Item = [usize; 3]> + '_ {
    (0..b.dims[2])
        .flat_map(move |z| (0..b.dims[1]).flat_map(move |y| (0..b.dims[0]).map(move |x| [x, y, z])))
}

#[test]
fn enzo_two_levels_read_back_exactly_in_cgs() {
    let path = data("enzo2/amr2_0000");
    assert!(is_amr(&path));
    let h = Hierarchy::open(&path).unwrap();
    assert_eq!(h.code, "Enzo");
    assert_eq!(h.root_dims, [8, 8, 8]);
    assert_eq!(h.max_level(), 1);
    assert_eq!(
        h.blocks,
        vec![
            Block {
                level: 0,
                lo: [0, 0, 0],
                dims: [8, 8, 8]
            },
            Block {
                level: 1,
                lo: [4, 4, 4],
                dims: [8, 8, 8]
            },
        ]
    );
    let names: Vec<(&str, &str)> = h
        .fields
        .iter()
        .map(|f| (f.name.as_str(), f.unit.as_str()))
        .collect();
    assert_eq!(
        names,
        vec![
            ("Density", "g/cm3"),
            ("Temperature", "K"),
            ("x-velocity", "cm/s")
        ]
    );
    assert_eq!(h.length_unit_cm, Some(3e24));
    let rho = h.field("Density", &Limits::default()).unwrap();
    let vx = h.field("x-velocity", &Limits::default()).unwrap();
    let t = h.field("Temperature", &Limits::default()).unwrap();
    let mut leaves = 0;
    for (i, b) in h.blocks.iter().enumerate() {
        for (c, cell) in cells(b).enumerate() {
            let covered = b.level == 0 && cell.iter().all(|&x| (2..6).contains(&x));
            assert_eq!(rho.is_leaf(i, c), !covered, "block {i} cell {cell:?}");
            if covered {
                continue;
            }
            leaves += 1;
            let v = f64::from(f(centre(&h, b, cell)) as f32);
            // Code units times DensityUnits, LengthUnits / TimeUnits (as yt converts).
            assert_eq!(rho.block_values(i)[c], (v * 1e-27) as f32);
            let v10 = f64::from((10.0 * f(centre(&h, b, cell))) as f32);
            assert_eq!(vx.block_values(i)[c], (v10 * 3e9) as f32);
            assert_eq!(
                t.block_values(i)[c],
                (100.0 * f(centre(&h, b, cell))) as f32
            );
        }
    }
    assert_eq!(leaves, 8 * 8 * 8 - 4 * 4 * 4 + 8 * 8 * 8);
    assert!(h.field("Pressure", &Limits::default()).is_err());
}

#[test]
fn athena_two_levels_read_back_exactly() {
    let path = data("athena2.athdf");
    let h = Hierarchy::open(&path).unwrap();
    assert_eq!(h.code, "Athena++");
    assert_eq!(h.blocks.len(), 15);
    assert_eq!(h.blocks.iter().filter(|b| b.level == 1).count(), 8);
    assert_eq!(h.domain_lo, DVec3::splat(-1.0));
    let rho = h.field("rho", &Limits::default()).unwrap();
    let vel2 = h.field("vel2", &Limits::default()).unwrap();
    for (i, b) in h.blocks.iter().enumerate() {
        assert_eq!(b.dims, [4, 4, 4]);
        for (c, cell) in cells(b).enumerate() {
            // Refined blocks replace their parent: every stored cell is a leaf.
            assert!(rho.is_leaf(i, c));
            let p = centre(&h, b, cell);
            assert_eq!(
                rho.block_values(i)[c],
                f(p) as f32,
                "block {i} cell {cell:?}"
            );
            assert_eq!(vel2.block_values(i)[c], p.x as f32);
        }
    }
}

/// yt made the 64^3 files in shared/data with `covering_grid(level=2)` (SOURCE.md): ours
/// equals them on every cell, in yt's proper cgs units.
#[test]
fn enzo_covering_grid_equals_yts() {
    let dir = enzo_snapshot();
    let h = Hierarchy::open(&dir.join("original/moving7_0010")).unwrap();
    assert_eq!(h.max_level(), 7);
    assert_eq!(h.blocks.len(), 10);
    // yt's code length for this snapshot, proper cm.
    let l = h.length_unit_cm.unwrap();
    assert!((l / 5.614_902_697_595_324e23 - 1.0).abs() < 1e-12, "{l}");
    let read = |name: &str| -> Vec<f32> {
        let bytes = std::fs::read(dir.join(name)).unwrap();
        bytes
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes(c.try_into().unwrap()))
            .collect()
    };
    let limits = Limits::default();
    let check = |field: &str, scale: f64, want: &[f32], stride: usize, comp: usize| {
        let g = h
            .field(field, &limits)
            .unwrap()
            .covering_grid(2, &limits)
            .unwrap();
        assert_eq!(g.geometry().dims, [64, 64, 64]);
        let mut worst = 0.0f64;
        for (i, v) in g.data().iter().enumerate() {
            let ours = f64::from(*v) * scale;
            let theirs = f64::from(want[i * stride + comp]);
            worst = worst.max((ours - theirs).abs() / theirs.abs().max(1e-30));
        }
        // f32 values through two f64 unit conversions: a few ulps at most.
        assert!(worst < 5e-7, "{field}: worst relative difference {worst}");
    };
    check(
        "Density",
        1.0,
        &read("density_gcm3_64x64x64_f32le.raw"),
        1,
        0,
    );
    check(
        "Temperature",
        1.0,
        &read("temperature_K_64x64x64_f32le.raw"),
        1,
        0,
    );
    let v = read("velocity_kms_64x64x64x3_f32le.raw");
    check("x-velocity", 1e-5, &v, 3, 0);
    check("y-velocity", 1e-5, &v, 3, 1);
    check("z-velocity", 1e-5, &v, 3, 2);
    // The clump: the finest level holds densities far above the level-2 grid's peak.
    let rho = h.field("Density", &limits).unwrap();
    let code = 6.235_329_974_609_323_5e-27;
    let peak = rho
        .blocks()
        .iter()
        .enumerate()
        .flat_map(|(i, _)| rho.block_values(i).iter().copied())
        .fold(0.0f32, f32::max);
    assert!(
        (f64::from(peak) / code / 256_955.0 - 1.0).abs() < 1e-3,
        "{}",
        f64::from(peak) / code
    );
}

/// A two-level hierarchy of a smooth field built in memory.
fn smooth(g: impl Fn(DVec3) -> f64) -> (Hierarchy, AmrField) {
    let h = Hierarchy::new(
        DVec3::ZERO,
        DVec3::ONE,
        [8, 8, 8],
        2,
        vec![
            Block {
                level: 0,
                lo: [0, 0, 0],
                dims: [8, 8, 8],
            },
            Block {
                level: 1,
                lo: [4, 6, 2],
                dims: [6, 8, 10],
            },
        ],
    )
    .unwrap();
    let values = h
        .blocks
        .iter()
        .map(|b| cells(b).map(|c| g(centre(&h, b, c)) as f32).collect())
        .collect();
    let info = blueshift_volume::amr::FieldInfo {
        name: "g".into(),
        unit: "code".into(),
        to_unit: 1.0,
    };
    let f = AmrField::new(&h, info, values).unwrap();
    (h, f)
}

/// Across the level boundary the reconstruction has no seam: along lines crossing the
/// refined block's faces, neighbouring samples 1e-4 apart differ by no more than the
/// field's slope allows, and the whole line stays within the coarse level's interpolation
/// error of the analytic field. A per-block sampler (the finest block's own trilinear
/// interpolation, clamped at its faces) jumps there.
#[test]
fn reconstruction_is_continuous_across_levels() {
    let g = |p: DVec3| (3.0 * p.x).sin() + (2.0 * p.y).cos() + p.z * p.z;
    let (_, amr) = smooth(g);
    // |grad g| <= 3 + 2 + 2; second derivatives <= 9 + 4 + 2.
    let (slope, curv) = (7.0, 15.0);
    let h0 = 1.0 / 8.0;
    let bound = curv * h0 * h0 / 8.0 * 3.0 + 2e-6;
    let step = 1e-4;
    let mut worst_jump = 0.0f64;
    let mut worst_err = 0.0f64;
    for line in 0..40 {
        let t = f64::from(line) / 40.0;
        let a = DVec3::new(0.1 + 0.8 * t, 0.05, 0.3 + 0.4 * t);
        let b = DVec3::new(0.9 - 0.7 * t, 0.95, 0.7 - 0.3 * t);
        let n = ((b - a).length() / step) as usize;
        let mut prev: Option<f64> = None;
        for i in 0..=n {
            let p = a + (b - a) * (i as f64 / n as f64);
            let v = f64::from(amr.sample(p));
            worst_err = worst_err.max((v - g(p)).abs());
            if let Some(q) = prev {
                worst_jump = worst_jump.max(((v - q) / ((b - a).length() / n as f64)).abs());
            }
            prev = Some(v);
        }
    }
    assert!(
        worst_err < bound,
        "error {worst_err} above the interpolation bound {bound}"
    );
    // Float rounding of f32 values over a 1e-4 step adds ~1e-7 / 1e-4 = 1e-3 at most.
    assert!(
        worst_jump < 4.0 * slope,
        "largest slope between samples {worst_jump}"
    );
}

/// Inside one level the reconstruction is trilinear interpolation of the cell centres,
/// clamped at the domain's faces: a root-only hierarchy equals the dense grid's sampler.
#[test]
fn one_level_is_trilinear_interpolation() {
    let h = Hierarchy::new(
        DVec3::ZERO,
        DVec3::new(2.0, 1.0, 1.0),
        [8, 4, 4],
        2,
        vec![Block {
            level: 0,
            lo: [0, 0, 0],
            dims: [8, 4, 4],
        }],
    )
    .unwrap();
    let vals: Vec<f32> = (0..128).map(|i| ((i * 37) % 23) as f32).collect();
    let info = blueshift_volume::amr::FieldInfo {
        name: "v".into(),
        unit: "code".into(),
        to_unit: 1.0,
    };
    let amr = AmrField::new(&h, info, vec![vals.clone()]).unwrap();
    let geom = h.level_geometry(0);
    let dense = Grid::from_vec(geom, vals).unwrap();
    let mut rng = 12345u64;
    let mut next = || {
        rng = rng.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1);
        (rng >> 11) as f64 / (1u64 << 53) as f64
    };
    for _ in 0..2000 {
        let p = DVec3::new(2.0 * next(), next(), next());
        let want = dense.sample_trilinear_index(geom.world_to_index(p.as_vec3()));
        let got = amr.sample(p);
        assert!((got - want).abs() < 2e-5, "{p}: {got} vs {want}");
    }
}

/// The brick source: each brick region is sampled at the level of its own data (the refined
/// region at level 1, the rest at the root level), samples agree with the reconstruction,
/// and the stored macrocells bound every sample.
#[test]
fn brick_source_samples_the_reconstruction_at_native_levels() {
    let g = |p: DVec3| 2.0 + p.x - p.y + 0.5 * p.z;
    let (_, amr) = smooth(g);
    let amr = Arc::new(amr);
    let src = amr.source();
    assert_eq!(src.geometries().len(), 2);
    assert_eq!(src.geometries()[0].dims, [16, 16, 16]);
    let cache = BrickCache::new(64 << 20);
    let field = BrickedField::new(src, cache, 0).unwrap();
    // 16^3 at the finest level is one 32^3 brick: refined data inside, so level 0.
    assert_eq!(field.level_map().map(|m| m.histogram()), None);
    let f = Field::from(field.clone());
    let geom: Geometry = *f.geometry();
    let cells = f.macrocells(4).unwrap();
    let mut rng = 99u64;
    let mut next = || {
        rng = rng.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1);
        (rng >> 11) as f64 / (1u64 << 53) as f64
    };
    for _ in 0..3000 {
        let p = DVec3::new(next(), next(), next()) * 0.9 + 0.05;
        let idx = geom.world_to_index(p.as_vec3());
        let got = f.sample_scalar_index(idx);
        // A linear field: trilinear of the reconstruction's samples is the field where one
        // level holds all the voxels around p; at most the level mixing's small error.
        assert!(
            (f64::from(got) - g(p)).abs() < 0.05,
            "{p}: {got} vs {}",
            g(p)
        );
        let c = [0, 1, 2].map(|a| ((idx[a] as usize) / 4).min(cells.dims()[a] - 1));
        let (lo, hi) = cells.min_max(c);
        assert!(
            got >= lo - 1e-5 && got <= hi + 1e-5,
            "{got} outside [{lo}, {hi}]"
        );
    }
    // A larger hierarchy: regions of root cells only take the coarsest level.
    let h = Hierarchy::new(
        DVec3::ZERO,
        DVec3::ONE,
        [64, 64, 64],
        2,
        vec![
            Block {
                level: 0,
                lo: [0, 0, 0],
                dims: [64, 64, 64],
            },
            Block {
                level: 1,
                lo: [0, 0, 0],
                dims: [16, 16, 16],
            },
        ],
    )
    .unwrap();
    let values = h.blocks.iter().map(|b| vec![1.0f32; b.cells()]).collect();
    let info = blueshift_volume::amr::FieldInfo {
        name: "one".into(),
        unit: "code".into(),
        to_unit: 1.0,
    };
    let big = Arc::new(AmrField::new(&h, info, values).unwrap());
    let cache = BrickCache::new(64 << 20);
    let field = BrickedField::new(big.source(), cache.clone(), 0).unwrap();
    let hist = field.level_map().expect("regions").histogram();
    // 128^3 at level 1 = 4^3 bricks; the refined corner touches the first 1-2 per axis.
    assert_eq!(hist.iter().sum::<usize>(), 64);
    assert!(hist[0] >= 1 && hist[0] <= 8, "{hist:?}");
    assert!(hist[1] >= 56, "{hist:?}");
    assert_eq!(
        f64::from(Field::from(field).sample_scalar_index(Vec3::splat(100.0))),
        1.0
    );
}

#[test]
fn bad_amr_files_are_clean_errors() {
    let dir = tempfile::tempdir().unwrap();
    let src = data("enzo2");
    for name in ["amr2_0000", "amr2_0000.hierarchy", "amr2_0000.cpu0000"] {
        std::fs::copy(src.join(name), dir.path().join(name)).unwrap();
    }
    let p = dir.path().join("amr2_0000");
    // Truncated HDF5: opening or reading fails with an error, never a panic.
    let full = std::fs::read(src.join("amr2_0000.cpu0000")).unwrap();
    let whole = Hierarchy::open(&p)
        .unwrap()
        .field("Density", &Limits::default())
        .unwrap();
    for cut in (0..full.len()).step_by(97) {
        std::fs::write(dir.path().join("amr2_0000.cpu0000"), &full[..cut]).unwrap();
        let r = Hierarchy::open(&p).and_then(|h| h.field("Density", &Limits::default()));
        // A cut that spares the density's bytes still reads them right; others fail.
        if let Ok(f) = r {
            for i in 0..2 {
                assert_eq!(f.block_values(i), whole.block_values(i), "cut at {cut}");
            }
        }
        if cut < full.len() / 2 {
            assert!(
                Hierarchy::open(&p)
                    .and_then(|h| h.field("Density", &Limits::default()))
                    .is_err(),
                "cut at {cut}"
            );
        }
    }
    std::fs::write(dir.path().join("amr2_0000.cpu0000"), &full).unwrap();
    // A grid outside the domain.
    let hier = std::fs::read_to_string(src.join("amr2_0000.hierarchy")).unwrap();
    std::fs::write(
        dir.path().join("amr2_0000.hierarchy"),
        hier.replace("GridLeftEdge      = 0.25 ", "GridLeftEdge      = 0.625 ")
            .replace("GridRightEdge     = 0.75 ", "GridRightEdge     = 1.125 "),
    )
    .unwrap();
    let e = Hierarchy::open(&p).unwrap_err().to_string();
    assert!(e.contains("outside the domain"), "{e}");
    // A garbage hierarchy.
    std::fs::write(dir.path().join("amr2_0000.hierarchy"), "Grid = x\n").unwrap();
    assert!(Hierarchy::open(&p).is_err());
    // Not AMR at all.
    assert!(Hierarchy::open(&dir.path().join("nothing")).is_err());
    // A truncated .athdf.
    let a = std::fs::read(data("athena2.athdf")).unwrap();
    for cut in [10, 1000, a.len() / 2] {
        let q = dir.path().join("cut.athdf");
        std::fs::write(&q, &a[..cut]).unwrap();
        assert!(
            Hierarchy::open(&q)
                .and_then(|h| h.field("rho", &Limits::default()))
                .is_err()
        );
    }
}

// Distributed reading: each rank reads only the blocks its region needs.

fn info(name: &str) -> FieldInfo {
    FieldInfo {
        name: name.into(),
        unit: "code".into(),
        to_unit: 1.0,
    }
}

/// A three-level hierarchy of 70 blocks: a 16^3 root grid in 64 blocks of 4^3, four
/// level-1 and two level-2 blocks (nested), a smooth field of both signs, one NaN in a
/// covered root cell. Returns the hierarchy and every block's values.
fn many_blocks() -> (Hierarchy, Vec<Vec<f32>>) {
    let mut blocks = Vec::new();
    for z in 0..4 {
        for y in 0..4 {
            for x in 0..4 {
                blocks.push(Block {
                    level: 0,
                    lo: [4 * x, 4 * y, 4 * z],
                    dims: [4, 4, 4],
                });
            }
        }
    }
    for (level, lo, dims) in [
        (1, [4, 4, 4], [4, 4, 4]),
        (1, [8, 4, 4], [4, 4, 4]),
        (1, [24, 20, 24], [4, 4, 8]),
        (1, [20, 20, 8], [4, 4, 4]),
        (2, [10, 10, 10], [6, 6, 6]),
        (2, [48, 40, 52], [8, 8, 8]),
    ] {
        blocks.push(Block { level, lo, dims });
    }
    let h = Hierarchy::new(DVec3::ZERO, DVec3::ONE, [16, 16, 16], 2, blocks).unwrap();
    let g = |p: DVec3| (5.0 * p.x).sin() + (3.0 * p.y).cos() + p.z - 0.5;
    let mut values: Vec<Vec<f32>> = h
        .blocks
        .iter()
        .map(|b| cells(b).map(|c| g(centre(&h, b, c)) as f32).collect())
        .collect();
    // Root cell (3, 3, 3) lies under the first level-1 block: covered, never sampled.
    values[0][3 + 4 * (3 + 4 * 3)] = f32::NAN;
    (h, values)
}

/// The two halves of the unit domain along `axis`, split at `at`.
fn halves(lo: DVec3, hi: DVec3, axis: usize, at: f64) -> [Region; 2] {
    let mut a = Region::new(lo, hi);
    let mut b = a;
    a.hi[axis] = at;
    b.lo[axis] = at;
    [a, b]
}

/// Deterministic points in `r`: random ones, ones on its faces and corners, and ones within
/// one voxel of size `fine` of its faces.
fn points_in(r: &Region, fine: f64, n: usize, seed: u64) -> Vec<DVec3> {
    let mut rng = seed;
    let mut next = || {
        rng = rng.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1);
        (rng >> 11) as f64 / (1u64 << 53) as f64
    };
    let size = r.hi - r.lo;
    let mut out = Vec::new();
    for corner in 0..8 {
        out.push(DVec3::new(
            if corner & 1 == 0 { r.lo.x } else { r.hi.x },
            if corner & 2 == 0 { r.lo.y } else { r.hi.y },
            if corner & 4 == 0 { r.lo.z } else { r.hi.z },
        ));
    }
    for i in 0..n {
        let mut p = r.lo + DVec3::new(next(), next(), next()) * size;
        let axis = i % 3;
        match (i / 3) % 5 {
            0 => p[axis] = r.lo[axis],
            1 => p[axis] = r.hi[axis],
            2 => p[axis] = (r.lo[axis] + next() * fine).min(r.hi[axis]),
            3 => p[axis] = (r.hi[axis] - next() * fine).max(r.lo[axis]),
            _ => {}
        }
        assert!(r.contains(p), "{p} outside {r:?}");
        out.push(p);
    }
    out
}

fn assert_samples_identical(full: &AmrField, part: &AmrField, r: &Region, fine: f64) {
    for p in points_in(r, fine, 3000, 7) {
        assert_eq!(
            part.sample(p).to_bits(),
            full.sample(p).to_bits(),
            "{p} in {r:?}: {} vs {}",
            part.sample(p),
            full.sample(p)
        );
    }
}

/// Compares every brick (all levels) whose stored voxels lie in `r`; returns how many.
fn assert_bricks_identical(
    h: &Hierarchy,
    full: &Arc<AmrField>,
    part: &Arc<AmrField>,
    r: &Region,
) -> usize {
    let (fs, ps) = (full.source(), part.source());
    let layout = fs.layout();
    let (b, s) = (layout.brick, layout.stored_edge());
    let mut compared = 0;
    for (j, g) in fs.geometries().iter().enumerate() {
        let n = layout.bricks(g.dims);
        // The exact voxel centres, as the source computes them.
        let cell = h.cell_size(h.max_level() - j as u32);
        for idx in 0..(n[0] * n[1] * n[2]) {
            let bi = [idx % n[0], (idx / n[0]) % n[1], idx / (n[0] * n[1])];
            let inside = (0..3).all(|a| {
                let v0 = (bi[a] * b) as i64 - 1;
                let v1 = v0 + s as i64 - 1;
                let c = |v: i64| {
                    h.domain_lo[a] + (v.clamp(0, g.dims[a] as i64 - 1) as f64 + 0.5) * cell[a]
                };
                c(v0) >= r.lo[a] && c(v1) <= r.hi[a]
            });
            if !inside {
                continue;
            }
            let want = fs.read_brick(j, idx as u64).unwrap();
            let got = ps.read_brick(j, idx as u64).unwrap();
            assert!(
                want.iter()
                    .zip(&got)
                    .all(|(a, b)| a.to_bits() == b.to_bits()),
                "level {j} brick {idx} differs in {r:?}"
            );
            compared += 1;
        }
    }
    compared
}

/// The stored macrocells of the finest level bound the reconstruction at every voxel of
/// each macrocell lying in `r`.
fn assert_macrocells_bound(h: &Hierarchy, values: &[Vec<f32>], r: &Region) {
    let part = Arc::new(AmrField::new_within(h, info("g"), values.to_vec(), Some(*r)).unwrap());
    let src = part.source();
    let k = 4;
    let cells = src.stored_macrocells(0, k).unwrap().unwrap();
    let n = src.geometries()[0].dims;
    let cell = h.cell_size(h.max_level());
    let world = |v: [usize; 3]| {
        h.domain_lo + (DVec3::new(v[0] as f64, v[1] as f64, v[2] as f64) + 0.5) * cell
    };
    let mut checked = 0;
    let d = cells.dims();
    for mz in 0..d[2] {
        for my in 0..d[1] {
            for mx in 0..d[0] {
                let m = [mx, my, mz];
                let lo = m.map(|a| a * k);
                let hi = [0, 1, 2].map(|a| (m[a] * k + k).min(n[a] - 1));
                if !(r.contains(world(lo)) && r.contains(world(hi))) {
                    continue;
                }
                let (min, max) = cells.min_max(m);
                for z in lo[2]..=hi[2] {
                    for y in lo[1]..=hi[1] {
                        for x in lo[0]..=hi[0] {
                            let v = part.sample(world([x, y, z]));
                            assert!(
                                v.is_nan() || (min <= v && v <= max),
                                "{v} outside macrocell {m:?} [{min}, {max}]"
                            );
                        }
                    }
                }
                checked += 1;
            }
        }
    }
    assert!(checked > 0, "no macrocell inside {r:?}");
}

/// Synthetic hierarchy: halves along each axis read strictly fewer blocks than all, the
/// union of their needed blocks is every block, and inside each half samples and bricks are
/// bit-identical to the whole field's.
#[test]
fn regions_read_only_their_blocks_and_sample_bit_identically() {
    let (h, values) = many_blocks();
    let total = h.blocks.len();
    assert_eq!(total, 70);
    let full = Arc::new(AmrField::new(&h, info("g"), values.clone()).unwrap());
    assert_eq!(full.blocks_read(), total);
    let fine = h.cell_size(h.max_level()).x;
    let mut counts = Vec::new();
    // Splits on block faces, and within half a cell of a root, level-1 or level-2 block's
    // face (where only that block's tents reach the region); halves at the middle read
    // strictly fewer blocks than all.
    for (axis, at) in (0..3).flat_map(|a| [0.5, 0.48, 0.52, 0.61, 0.745, 0.155].map(|t| (a, t))) {
        let parts = halves(h.domain_lo, h.domain_hi, axis, at);
        let mut union = vec![false; total];
        for r in &parts {
            let part = AmrField::new_within(&h, info("g"), values.clone(), Some(*r)).unwrap();
            let needed = h.needed_blocks(Some(r));
            assert_eq!(part.blocks_read(), needed.iter().filter(|&&n| n).count());
            if (0.48..=0.52).contains(&at) {
                assert!(part.blocks_read() < total, "axis {axis}: {r:?} reads all");
            }
            for (i, u) in union.iter_mut().enumerate() {
                assert_eq!(part.is_present(i), needed[i]);
                assert_eq!(part.block_values(i).is_empty(), !needed[i]);
                *u |= part.is_present(i);
            }
            if at == 0.5 {
                counts.push(part.blocks_read());
            }
            assert_samples_identical(&full, &part, r, fine);
            assert_macrocells_bound(&h, &values, r);
        }
        assert!(
            union.iter().all(|&u| u),
            "axis {axis}: a block nobody reads"
        );
    }
    // Overlapping halves (a k-d split plus a ghost layer) hold whole finest bricks.
    let mut bricks = 0;
    for axis in 0..3 {
        let [a, _] = halves(h.domain_lo, h.domain_hi, axis, 0.55);
        let [_, b] = halves(h.domain_lo, h.domain_hi, axis, 0.45);
        for r in [a, b] {
            let part =
                Arc::new(AmrField::new_within(&h, info("g"), values.clone(), Some(r)).unwrap());
            assert!(part.blocks_read() < total);
            assert_samples_identical(&full, &part, &r, fine);
            bricks += assert_bricks_identical(&h, &full, &part, &r);
        }
    }
    assert!(bricks >= 24, "{bricks} bricks compared");
    eprintln!("synthetic halves read {counts:?} of {total} blocks; {bricks} bricks compared");
}

/// A uneven partition into 8 boxes: the combined statistics of the restricted fields are
/// the whole field's (the duplicated NaN counted more than once, never zero).
#[test]
fn combined_region_stats_equal_the_whole_fields() {
    let (h, values) = many_blocks();
    let full = AmrField::new(&h, info("g"), values.clone()).unwrap();
    let whole = full.stats();
    assert_eq!(whole.non_finite, 1);
    assert!(whole.range.is_some_and(|(a, b)| a < 0.0 && b > 0.0));
    for cut in [
        DVec3::splat(0.5),
        DVec3::new(0.3, 0.6, 0.45),
        DVec3::splat(0.9),
    ] {
        let mut acc = AmrStats::default();
        for k in 0..8 {
            let pick = |a: usize| {
                if k >> a & 1 == 0 {
                    (h.domain_lo[a], cut[a])
                } else {
                    (cut[a], h.domain_hi[a])
                }
            };
            let (x, y, z) = (pick(0), pick(1), pick(2));
            let r = Region::new(DVec3::new(x.0, y.0, z.0), DVec3::new(x.1, y.1, z.1));
            let part = AmrField::new_within(&h, info("g"), values.clone(), Some(r)).unwrap();
            acc = AmrStats::combine(acc, part.stats());
        }
        assert_eq!(acc.range, whole.range, "cut {cut}");
        assert_eq!(acc.positive_min, whole.positive_min, "cut {cut}");
        assert!(acc.non_finite >= whole.non_finite);
        assert_eq!(acc.non_finite == 0, whole.non_finite == 0);
    }
    // with_stats serves the given statistics through the brick source.
    let part = AmrField::new_within(
        &h,
        info("g"),
        values,
        Some(Region::new(DVec3::ZERO, DVec3::splat(0.2))),
    )
    .unwrap();
    assert_ne!(part.stats(), whole);
    let part = Arc::new(part.with_stats(whole));
    let src = part.source();
    assert_eq!(src.finite_range(), whole.range);
    assert_eq!(src.positive_min(), whole.positive_min);
    assert_eq!(src.non_finite(), whole.non_finite);
}

/// The Enzo and Athena++ fixtures read per region: blocks away from the region are not
/// read, and inside it samples and values are the whole field's.
#[test]
fn fixtures_read_only_the_regions_blocks() {
    // Enzo: the root grid and one level-1 grid over [0.25, 0.75]^3.
    let h = Hierarchy::open(&data("enzo2/amr2_0000")).unwrap();
    let lim = Limits::default();
    let full = Arc::new(h.field("Density", &lim).unwrap());
    let fine = h.cell_size(1).x;
    let mut seen = Vec::new();
    for axis in 0..3 {
        let parts = halves(h.domain_lo, h.domain_hi, axis, 0.05);
        let mut union = [false; 2];
        for r in &parts {
            let part = h.field_within("Density", &lim, Some(*r)).unwrap();
            for (i, u) in union.iter_mut().enumerate() {
                *u |= part.is_present(i);
                if part.is_present(i) {
                    assert_eq!(part.block_values(i), full.block_values(i));
                }
            }
            seen.push(part.blocks_read());
            assert_samples_identical(&full, &part, r, fine);
        }
        assert_eq!(union, [true; 2]);
    }
    assert_eq!(seen, [1, 2, 1, 2, 1, 2], "enzo");
    // Athena++: 7 root blocks and 8 level-1 blocks in the (-x, -y, -z) octant.
    let h = Hierarchy::open(&data("athena2.athdf")).unwrap();
    let full = Arc::new(h.field("rho", &lim).unwrap());
    let fine = h.cell_size(1).x;
    let mut seen = Vec::new();
    for axis in 0..3 {
        let mut union = [false; 15];
        for at in [-0.5, 0.5] {
            for r in &halves(h.domain_lo, h.domain_hi, axis, at) {
                let part = h.field_within("rho", &lim, Some(*r)).unwrap();
                for (i, u) in union.iter_mut().enumerate() {
                    *u |= part.is_present(i);
                    if part.is_present(i) {
                        assert_eq!(part.block_values(i), full.block_values(i));
                    }
                }
                seen.push(part.blocks_read());
                assert_samples_identical(&full, &part, r, fine);
            }
        }
        assert_eq!(union, [true; 15]);
    }
    // x < -0.5 skips the four root blocks at x > 0; x > 0.5 every level-1 block and the
    // three root blocks at x < 0.
    assert_eq!(seen[..4], [11, 15, 15, 4], "athena");
    assert_eq!(seen[4..], seen[..4].repeat(2));
    // A region outside the domain needs nothing and reads nothing.
    let far = Region::new(DVec3::splat(5.0), DVec3::splat(6.0));
    assert_eq!(
        h.field_within("rho", &lim, Some(far))
            .unwrap()
            .blocks_read(),
        0
    );
    // A malformed region is a parameter error.
    let bad = Region::new(DVec3::ONE, DVec3::ZERO);
    assert!(matches!(
        h.field_within("rho", &lim, Some(bad)),
        Err(Error::Parameter(_))
    ));
}

/// Enzo output with grid 2 in its own file: when that file is missing or truncated, a
/// region needing grid 2 fails naming it, and one that does not reads fine.
#[test]
fn a_missing_block_file_fails_only_the_regions_that_need_it() {
    let dir = tempfile::tempdir().unwrap();
    let src = data("enzo2");
    for name in ["amr2_0000", "amr2_0000.cpu0000"] {
        std::fs::copy(src.join(name), dir.path().join(name)).unwrap();
    }
    // The same packed file under a second name holds grid 2 (found by its group name).
    let hier = std::fs::read_to_string(src.join("amr2_0000.hierarchy")).unwrap();
    let at = hier.rfind("amr2_0000.cpu0000").unwrap();
    let hier = format!("{}amr2_0000.cpu0001{}", &hier[..at], &hier[at + 17..]);
    std::fs::write(dir.path().join("amr2_0000.hierarchy"), hier).unwrap();
    let second = dir.path().join("amr2_0000.cpu0001");
    let bytes = std::fs::read(src.join("amr2_0000.cpu0000")).unwrap();
    std::fs::write(&second, &bytes).unwrap();
    let p = dir.path().join("amr2_0000");
    let lim = Limits::default();
    let h = Hierarchy::open(&p).unwrap();
    let whole = h.field("Density", &lim).unwrap();
    let want = Hierarchy::open(&data("enzo2/amr2_0000"))
        .unwrap()
        .field("Density", &lim)
        .unwrap();
    for i in 0..2 {
        assert_eq!(whole.block_values(i), want.block_values(i));
    }
    let corner = Some(Region::new(DVec3::ZERO, DVec3::splat(0.05)));
    let centre = Some(Region::new(DVec3::splat(0.4), DVec3::splat(0.6)));
    // Missing.
    std::fs::remove_file(&second).unwrap();
    let ok = h.field_within("Density", &lim, corner).unwrap();
    assert_eq!(ok.blocks_read(), 1);
    assert_eq!(ok.block_values(0), want.block_values(0));
    let e = h.field_within("Density", &lim, centre).unwrap_err();
    assert!(matches!(e, Error::Io(_)), "{e:?}");
    assert!(e.to_string().contains("amr2_0000.cpu0001"), "{e}");
    // Truncated anywhere: an error naming the file, never a panic (a cut that spares grid
    // 2's bytes, which h5py wrote first, still reads them right).
    let mut failed = 0;
    for cut in (0..bytes.len()).step_by(61) {
        std::fs::write(&second, &bytes[..cut]).unwrap();
        assert_eq!(
            h.field_within("Density", &lim, corner)
                .unwrap()
                .blocks_read(),
            1
        );
        match h.field_within("Density", &lim, centre) {
            Ok(f) => assert_eq!(f.block_values(1), want.block_values(1), "cut {cut}"),
            Err(e) => {
                assert!(
                    e.to_string().contains("amr2_0000.cpu0001"),
                    "cut {cut}: {e}"
                );
                failed += 1;
            }
        }
        if cut < 1000 {
            assert!(
                h.field_within("Density", &lim, centre).is_err(),
                "cut {cut}"
            );
        }
    }
    assert!(failed >= 17, "{failed} cuts failed");
}

/// `open_field_within` calls the reduction exactly once, on success and on failure, and
/// serves what it returns.
#[test]
fn open_field_within_reduces_exactly_once() {
    use std::cell::Cell;
    let path = data("athena2.athdf");
    let lim = Limits::default();
    let cache = BrickCache::new(16 << 20);
    let region = Some(Region::new(DVec3::splat(-1.0), DVec3::splat(-0.6)));
    let local = Hierarchy::open(&path)
        .unwrap()
        .field_within("rho", &lim, region)
        .unwrap()
        .stats();
    let global = AmrStats {
        range: Some((-7.0, 9.0)),
        positive_min: Some(0.25),
        non_finite: 3,
    };
    let calls = Cell::new(0);
    let (name, f) = open_field_within(&path, None, cache.clone(), &lim, region, &|s| {
        calls.set(calls.get() + 1);
        assert_eq!(s.unwrap(), local);
        Ok(global)
    })
    .unwrap();
    assert_eq!(calls.get(), 1);
    assert_eq!(name, "rho");
    assert_eq!(f.source().finite_range(), global.range);
    assert_eq!(f.source().positive_min(), global.positive_min);
    assert_eq!(f.source().non_finite(), 3);
    // A peer failed: the reduction's error is returned.
    calls.set(0);
    let e = open_field_within(&path, None, cache.clone(), &lim, region, &|s| {
        calls.set(calls.get() + 1);
        assert!(s.is_ok());
        Err(Error::Invalid("rank 3 failed".into()))
    })
    .unwrap_err();
    assert_eq!(calls.get(), 1);
    assert!(e.to_string().contains("rank 3"), "{e}");
    // This rank fails (a missing file, an unknown field): still exactly one call, with Err.
    for (p, name) in [
        (data("nothing.athdf"), None),
        (path.clone(), Some("no-such-field")),
    ] {
        calls.set(0);
        let e = open_field_within(&p, name, cache.clone(), &lim, region, &|s| {
            calls.set(calls.get() + 1);
            s
        })
        .unwrap_err();
        assert_eq!(calls.get(), 1, "{e}");
    }
    // A reduction that returns statistics for a failed read still fails.
    let e = open_field_within(&data("nothing.athdf"), None, cache, &lim, region, &|s| {
        assert!(s.is_err());
        Ok(AmrStats::default())
    })
    .unwrap_err();
    assert!(e.to_string().contains("read failed"), "{e}");
}
