//! AMR hierarchies read natively: the h5py-written Enzo and Athena++ files of
//! `tests/data/amr/make.py` read back cell by cell against the formula that made them, the
//! real Enzo snapshot's covering grid against yt's, the reconstruction's continuity across
//! levels, and the brick source every renderer samples.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use blueshift_volume::amr::{AmrField, Block, Hierarchy, is_amr};
use blueshift_volume::{BrickCache, BrickedField, Field, Geometry, Grid, Limits};
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
