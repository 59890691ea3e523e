//! Sampling, macrocells, levels of detail and out-of-core access, checked against analytic
//! truths (linear fields, convexity of trilinear interpolation, box-filter means).

use blueshift_volume::ooc::{self, BrickLayout, BrickedFile, GridSource, RawFileSource, Sampler};
use blueshift_volume::{AnyGrid, DiskType, Geometry, Grid, Macrocells, lod};
use glam::Vec3;
use half::f16;
use proptest::prelude::*;

/// A small deterministic generator (PCG-like LCG) for sample positions.
struct Lcg(u64);
impl Lcg {
    fn next_f32(&mut self) -> f32 {
        self.0 = self
            .0
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        (self.0 >> 40) as f32 / (1u64 << 24) as f32
    }
}

fn linear(p: Vec3) -> f32 {
    0.5 + 2.0 * p.x - 1.25 * p.y + 0.75 * p.z
}

#[test]
fn trilinear_reproduces_linear_fields_in_index_and_world_space() {
    let geom = Geometry {
        dims: [9, 7, 5],
        origin: Vec3::new(-1.0, 2.0, 0.5),
        spacing: Vec3::new(0.5, 0.25, 2.0),
    };
    let g = Grid::from_fn(geom, |x, y, z| {
        linear(geom.index_to_world(Vec3::new(x as f32, y as f32, z as f32)))
    })
    .unwrap();
    let mut rng = Lcg(7);
    let (lo, hi) = geom.world_bounds();
    for _ in 0..2000 {
        let w = lo + (hi - lo) * Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32());
        let got = g.sample_trilinear(w);
        let want = linear(w);
        assert!(
            (got - want).abs() <= 1e-5 * (1.0 + want.abs()),
            "at {w}: expected {want}, got {got}, diff {}",
            (got - want).abs()
        );
        // Index space agrees with world space.
        assert_eq!(g.sample_trilinear_index(geom.world_to_index(w)), got);
    }
    // A vector field whose components are linear is reproduced too.
    let vg = Grid::from_fn(geom, |x, y, z| {
        let p = geom.index_to_world(Vec3::new(x as f32, y as f32, z as f32));
        Vec3::new(linear(p), -linear(p), p.z)
    })
    .unwrap();
    let w = Vec3::new(0.3, 2.6, 3.3);
    let v = vg.sample_trilinear(w);
    assert!(
        (v - Vec3::new(linear(w), -linear(w), w.z))
            .abs()
            .max_element()
            < 1e-5,
        "{v}"
    );
}

#[test]
fn nearest_picks_the_closest_voxel_and_clamps_outside() {
    let geom = Geometry::unit([4, 4, 4]);
    let g = Grid::from_fn(geom, |x, y, z| (x + 10 * y + 100 * z) as u16).unwrap();
    assert_eq!(g.sample_nearest_index(Vec3::new(1.4, 2.6, 0.2)), 31.0);
    assert_eq!(g.sample_nearest_index(Vec3::new(-5.0, 9.0, 3.49)), 330.0);
    // Trilinear clamps to the edge too (constant outside).
    assert_eq!(g.sample_trilinear_index(Vec3::new(10.0, 10.0, 10.0)), 333.0);
    assert_eq!(g.sample_trilinear_index(Vec3::NAN), 0.0);
}

#[test]
fn half_and_byte_grids_sample_their_exact_values() {
    let geom = Geometry::unit([2, 1, 1]);
    let h = Grid::from_vec(geom, vec![f16::from_f32(1.0), f16::from_f32(3.0)]).unwrap();
    assert_eq!(h.sample_trilinear_index(Vec3::new(0.25, 0.0, 0.0)), 1.5);
    let b = Grid::from_vec(geom, vec![0u8, 255]).unwrap();
    assert_eq!(b.sample_trilinear_index(Vec3::new(0.5, 0.0, 0.0)), 127.5);
    assert!(
        Grid::from_vec(geom, vec![0u8; 3]).is_err(),
        "length must match dims"
    );
}

fn noisy_grid(dims: [usize; 3], seed: u64) -> Grid<f32> {
    let mut rng = Lcg(seed);
    let n = dims[0] * dims[1] * dims[2];
    // Heavy-tailed values so the ranges differ a lot from cell to cell.
    let data = (0..n).map(|_| (8.0 * rng.next_f32()).exp_m1()).collect();
    Grid::from_vec(
        Geometry {
            dims,
            origin: Vec3::new(1.0, -2.0, 0.0),
            spacing: Vec3::new(0.5, 1.0, 2.0),
        },
        data,
    )
    .unwrap()
}

#[test]
fn macrocell_ranges_bound_random_trilinear_samples() {
    for (dims, k) in [
        ([17, 12, 9], 4),
        ([16, 16, 16], 4),
        ([10, 7, 5], 3),
        ([5, 5, 5], 8),
        ([9, 9, 9], 1),
    ] {
        let g = noisy_grid(dims, 3);
        let cells = Macrocells::build(&g, k).unwrap();
        assert_eq!(cells.dims(), dims.map(|d| (d - 1).div_ceil(k).max(1)));
        let mut rng = Lcg(11);
        let max_i = Vec3::new(
            dims[0] as f32 - 1.0,
            dims[1] as f32 - 1.0,
            dims[2] as f32 - 1.0,
        );
        for _ in 0..20_000 {
            let p = max_i * Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32());
            let v = g.sample_trilinear_index(p);
            let (lo, hi) = cells.min_max(cells.cell_of_index(p));
            assert!(
                v >= lo && v <= hi,
                "dims {dims:?} k {k}: sample {v} at {p} outside cell range {lo}..{hi}"
            );
        }
    }
}

#[test]
fn a_spike_on_a_cell_face_shows_up_in_both_neighbouring_cells() {
    // The +1 neighbour: a spike at voxel x = 4 is reached by interpolation in cells 0 and 1.
    let geom = Geometry::unit([9, 2, 2]);
    let g = Grid::from_fn(geom, |x, _, _| if x == 4 { 100.0 } else { 0.0 }).unwrap();
    let cells = Macrocells::build(&g, 4).unwrap();
    assert_eq!(cells.min_max([0, 0, 0]).1, 100.0);
    assert_eq!(cells.min_max([1, 0, 0]).1, 100.0);
    assert!(Macrocells::build(&g, 0).is_err());
}

#[test]
fn macrocells_are_identical_on_one_and_many_threads() {
    let g = noisy_grid([33, 30, 29], 5);
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap()
        .install(|| Macrocells::build(&g, 4).unwrap());
    let many = rayon::ThreadPoolBuilder::new()
        .num_threads(4)
        .build()
        .unwrap()
        .install(|| Macrocells::build(&g, 4).unwrap());
    assert_eq!(one, many);
}

#[test]
fn ray_intervals_are_contiguous_and_bound_the_samples_on_them() {
    let g = noisy_grid([20, 17, 13], 9);
    let geom = *g.geometry();
    let cells = Macrocells::build(&g, 4).unwrap();
    let (lo, hi) = geom.world_bounds();
    let mut rng = Lcg(21);
    let mut crossed = 0;
    for _ in 0..300 {
        let a = lo - Vec3::splat(2.0)
            + (hi - lo + Vec3::splat(4.0))
                * Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32());
        let b = lo + (hi - lo) * Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32());
        let dir = (b - a).normalize();
        let ivs: Vec<_> = cells.intervals(a, dir, 0.0..f32::INFINITY).collect();
        assert!(
            !ivs.is_empty(),
            "a ray through an interior point must cross the grid"
        );
        for w in ivs.windows(2) {
            assert_eq!(w[0].t.end, w[1].t.start, "intervals must be contiguous");
        }
        for iv in &ivs {
            crossed += 1;
            for f in [0.1f32, 0.5, 0.9] {
                let t = iv.t.start + f * (iv.t.end - iv.t.start);
                let v = g.sample_trilinear(a + t * dir);
                assert!(
                    v >= iv.value.start && v <= iv.value.end,
                    "sample {v} outside {:?} in cell {:?}",
                    iv.value,
                    iv.cell
                );
            }
        }
    }
    assert!(crossed > 1000, "only {crossed} intervals checked");
    // A ray that misses the box yields nothing.
    assert_eq!(
        cells
            .intervals(hi + Vec3::splat(5.0), Vec3::X, 0.0..100.0)
            .count(),
        0
    );
}

#[test]
fn lod_levels_are_box_means_and_halve_the_size() {
    let geom = Geometry {
        dims: [5, 4, 3],
        origin: Vec3::ZERO,
        spacing: Vec3::ONE,
    };
    let g = Grid::from_fn(geom, |x, y, z| (x * x + 3 * y + 7 * z) as f32).unwrap();
    let c = lod::downsample(&g).unwrap();
    assert_eq!(c.dims(), [3, 2, 2]);
    // Coarse voxel [1, 0, 0] is the mean of x in {2, 3}, y in {0, 1}, z in {0, 1}.
    let mut s = 0.0;
    for (x, y, z) in [
        (2, 0, 0),
        (3, 0, 0),
        (2, 1, 0),
        (3, 1, 0),
        (2, 0, 1),
        (3, 0, 1),
        (2, 1, 1),
        (3, 1, 1),
    ] {
        s += g.get(x, y, z).unwrap();
    }
    assert_eq!(c.get(1, 0, 0).unwrap(), s / 8.0);
    // The last coarse x voxel of an odd size repeats the edge voxel: mean over x = 4 only.
    assert_eq!(
        c.get(2, 0, 0).unwrap(),
        (16.0 + 16.0 + 19.0 + 19.0 + 23.0 + 23.0 + 26.0 + 26.0) / 8.0
    );
    // A linear field stays linear across levels in world space (origin shift + spacing).
    let gl = Grid::from_fn(Geometry::unit([16, 16, 16]), |x, y, z| {
        linear(Vec3::new(x as f32, y as f32, z as f32))
    })
    .unwrap();
    let cl = lod::downsample(&gl).unwrap();
    let w = Vec3::new(5.3, 7.1, 2.9);
    assert!((cl.sample_trilinear(w) - linear(w)).abs() < 1e-4);
    let p = lod::Pyramid::build(&AnyGrid::F32(gl), 4).unwrap();
    let dims: Vec<_> = p.levels().iter().map(|l| l.dims()).collect();
    assert_eq!(dims, vec![[16; 3], [8; 3], [4; 3]]);
}

#[test]
fn out_of_core_sampling_equals_in_core_sampling_voxel_for_voxel() {
    let dims = [37, 21, 19];
    let g = noisy_grid(dims, 13);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("v.bsv");
    let layout = BrickLayout { brick: 8, apron: 1 };
    let mut calls = 0;
    ooc::convert(
        &mut GridSource(&g),
        &path,
        "density",
        layout,
        &mut |_, _| calls += 1,
    )
    .unwrap();
    assert!(calls >= 3, "progress reported {calls} times");
    // A cache of 4 bricks, far fewer than the 5 x 3 x 3 bricks of level 0, forces eviction.
    let f = BrickedFile::open(&path, 4).unwrap();
    assert_eq!(f.channel_name(), "density");
    let l0 = f.level(0).unwrap();
    assert_eq!(Sampler::geometry(&l0), *g.geometry());
    for z in 0..dims[2] {
        for y in 0..dims[1] {
            for x in 0..dims[0] {
                let p = Vec3::new(x as f32, y as f32, z as f32);
                assert_eq!(
                    l0.sample_index(p).unwrap(),
                    g.sample_trilinear_index(p),
                    "voxel {p}"
                );
            }
        }
    }
    let mut rng = Lcg(17);
    for _ in 0..5000 {
        let p = Vec3::new(
            rng.next_f32() * 40.0 - 1.0,
            rng.next_f32() * 23.0 - 1.0,
            rng.next_f32() * 21.0 - 1.0,
        );
        assert_eq!(
            l0.sample_index(p).unwrap(),
            g.sample_trilinear_index(p),
            "at {p}"
        );
    }
    assert!(
        f.resident_bricks() <= 4,
        "cache exceeded its bound: {}",
        f.resident_bricks()
    );
    // Every coarser level equals the in-core pyramid.
    let pyr = lod::Pyramid::build(&AnyGrid::F32(g.clone()), 8).unwrap();
    assert_eq!(f.levels(), pyr.levels().len());
    for (l, lv) in pyr.levels().iter().enumerate() {
        let AnyGrid::F32(loaded) = f.load_level(l, &Default::default()).unwrap() else {
            unreachable!()
        };
        assert_eq!(&loaded, lv, "level {l}");
    }
    // Progressive refinement: after touching only the coarsest level, that level is the
    // finest resident one.
    f.clear_cache();
    let top = f.levels() - 1;
    let w = Vec3::new(5.0, 2.0, 3.0);
    assert_eq!(f.finest_resident_level(w), None);
    f.level(top).unwrap().sample_world(w).unwrap();
    assert_eq!(f.finest_resident_level(w), Some(top));
    l0.sample_world(w).unwrap();
    assert_eq!(f.finest_resident_level(w), Some(0));
}

#[test]
fn streaming_conversion_from_a_raw_file_matches_in_core() {
    // i16 big-endian raw file, streamed slice by slice.
    let dims = [19, 11, 23];
    let geom = Geometry::unit(dims);
    let g = Grid::from_fn(geom, |x, y, z| {
        ((x * 37 + y * 11 + z * 5) % 601) as f32 - 300.0
    })
    .unwrap();
    let dir = tempfile::tempdir().unwrap();
    let raw = dir.path().join("in.raw");
    let mut bytes = vec![0u8; 7]; // a 7-byte header to skip
    for v in g.data() {
        bytes.extend_from_slice(&(*v as i16).to_be_bytes());
    }
    std::fs::write(&raw, &bytes).unwrap();
    let mut src = RawFileSource::new(
        &raw,
        7,
        DiskType::I16,
        blueshift_volume::io::Endian::Big,
        geom,
    )
    .unwrap();
    let out = dir.path().join("o.bsv");
    ooc::convert(
        &mut src,
        &out,
        "ct",
        BrickLayout { brick: 4, apron: 1 },
        &mut |_, _| {},
    )
    .unwrap();
    let f = BrickedFile::open(&out, 2).unwrap();
    let AnyGrid::F32(back) = f.load_level(0, &Default::default()).unwrap() else {
        unreachable!()
    };
    assert_eq!(back.data(), g.data());
    let l1 = f.level(1).unwrap();
    let c = lod::downsample(&g).unwrap();
    for p in [Vec3::new(1.5, 2.25, 3.0), Vec3::new(8.0, 0.0, 10.9)] {
        assert_eq!(l1.sample_index(p).unwrap(), c.sample_trilinear_index(p));
    }
    // A truncated raw file is refused before anything is written.
    std::fs::write(&raw, &bytes[..100]).unwrap();
    assert!(
        RawFileSource::new(
            &raw,
            7,
            DiskType::I16,
            blueshift_volume::io::Endian::Big,
            geom
        )
        .is_err()
    );
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]

    #[test]
    fn mutated_bricked_files_error_without_panic(pos in 0usize..80, val in any::<u8>(), cut in 0.0f64..1.0) {
        let g = noisy_grid([9, 9, 9], 1);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("v.bsv");
        ooc::convert(&mut GridSource(&g), &path, "d", BrickLayout { brick: 4, apron: 1 }, &mut |_, _| {}).unwrap();
        let mut b = std::fs::read(&path).unwrap();
        b[pos] = val;
        let n = if cut > 0.5 { b.len() } else { (b.len() as f64 * cut * 2.0) as usize };
        std::fs::write(&path, &b[..n]).unwrap();
        if let Ok(f) = BrickedFile::open(&path, 2) {
            for l in 0..f.levels() {
                let _ = f.level(l).unwrap().sample_index(Vec3::splat(3.5));
            }
        }
    }
}

#[test]
fn a_diagonal_ray_through_cell_corners_visits_each_diagonal_cell_once() {
    // 17^3 voxels, k = 4: 4 cells per axis; the main diagonal passes exactly through corners.
    let g = Grid::from_fn(Geometry::unit([17, 17, 17]), |x, y, z| (x + y + z) as f32).unwrap();
    let cells = Macrocells::build(&g, 4).unwrap();
    let ivs: Vec<_> = cells
        .intervals(Vec3::splat(-2.0), Vec3::ONE, 0.0..100.0)
        .collect();
    let visited: Vec<_> = ivs.iter().map(|iv| iv.cell).collect();
    assert_eq!(visited, vec![[0, 0, 0], [1, 1, 1], [2, 2, 2], [3, 3, 3]]);
    assert!(ivs.iter().all(|iv| iv.t.end > iv.t.start), "{ivs:?}");
    assert_eq!(
        (ivs[0].t.start, ivs[3].t.end),
        (2.0, 18.0),
        "clipped to the voxel-centre box 0..=16"
    );
}

#[test]
fn byte_volumes_stay_one_byte_per_voxel_in_the_bricked_file() {
    let geom = Geometry::unit([20, 20, 20]);
    let g8 = Grid::from_fn(geom, |x, y, z| ((x * 7 + y * 13 + z * 29) % 256) as u8).unwrap();
    let g32 = Grid::from_fn(geom, |x, y, z| g8.get(x, y, z).unwrap() as f32).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let (p8, p32) = (dir.path().join("a.bsv"), dir.path().join("b.bsv"));
    let layout = BrickLayout { brick: 8, apron: 1 };
    ooc::convert(&mut GridSource(&g8), &p8, "u8", layout, &mut |_, _| {}).unwrap();
    ooc::convert(&mut GridSource(&g32), &p32, "f32", layout, &mut |_, _| {}).unwrap();
    let (f8, f32_) = (
        BrickedFile::open(&p8, 4).unwrap(),
        BrickedFile::open(&p32, 4).unwrap(),
    );
    assert_eq!(f8.level0_type(), blueshift_volume::ScalarType::U8);
    // Level 0 shrinks four-fold: 27 bricks of 10^3 voxels, 1 byte instead of 4.
    let (s8, s32) = (
        std::fs::metadata(&p8).unwrap().len(),
        std::fs::metadata(&p32).unwrap().len(),
    );
    assert_eq!(s32 - s8, 27 * 1000 * 3, "sizes {s8} and {s32}");
    let mut rng = Lcg(5);
    for _ in 0..2000 {
        let p = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 19.0;
        let want = g8.sample_trilinear_index(p);
        assert_eq!(f8.level(0).unwrap().sample_index(p).unwrap(), want);
        assert_eq!(f32_.level(0).unwrap().sample_index(p).unwrap(), want);
        assert_eq!(
            f8.level(1).unwrap().sample_index(p / 2.0).unwrap(),
            f32_.level(1).unwrap().sample_index(p / 2.0).unwrap()
        );
    }
    assert_eq!(
        f8.load_level(0, &Default::default()).unwrap(),
        AnyGrid::U8(g8)
    );
}

#[test]
fn uncompressed_nrrd_and_metaimage_stream_without_loading() {
    let data = |n: &str| {
        std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("tests/data/valid")
            .join(n)
    };
    let reference = blueshift_volume::read(data("headsq_crop_16x16x8_int16.raw")).unwrap();
    let AnyGrid::F32(want) = &reference.channels()[0].grid else {
        unreachable!()
    };
    for (file, streams) in [
        ("headsq_crop.mhd", true),
        ("headsq_crop.nhdr", true),
        ("headsq_crop_be.nrrd", true),
        ("headsq_crop_16x16x8_int16.raw", true),
        ("headsq_crop.mha", false), // zlib
        ("headsq_crop_gzip.nrrd", false),
    ] {
        let src = RawFileSource::probe(&data(file)).unwrap();
        assert_eq!(src.is_some(), streams, "{file}");
        if let Some(mut src) = src {
            let g = ooc::SlabSource::geometry(&src);
            assert_eq!(g.dims, [16, 16, 8]);
            let mut slice = vec![0f32; 256];
            for z in 0..8 {
                ooc::SlabSource::read_slice(&mut src, z, &mut slice).unwrap();
                assert_eq!(
                    &slice[..],
                    &want.data()[z * 256..(z + 1) * 256],
                    "{file} slice {z}"
                );
            }
        }
    }
}

/// A big-endian Open SciVis file (`..._int16be.raw`) streams with its bytes swapped, as the
/// in-core reader reads it; a file longer than its name says is refused by both readers.
#[test]
fn scivis_raw_streams_in_the_byte_order_its_name_gives_and_at_its_size_only() {
    let valid = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/valid");
    let little = std::fs::read(valid.join("headsq_crop_16x16x8_int16.raw")).unwrap();
    let reference = blueshift_volume::read(valid.join("headsq_crop_16x16x8_int16.raw")).unwrap();
    let AnyGrid::F32(want) = &reference.channels()[0].grid else {
        unreachable!()
    };
    let dir = tempfile::tempdir().unwrap();
    let big = dir.path().join("headsq_16x16x8_int16be.raw");
    let swapped: Vec<u8> = little.chunks_exact(2).flat_map(|b| [b[1], b[0]]).collect();
    std::fs::write(&big, &swapped).unwrap();
    let in_core = blueshift_volume::read(&big).unwrap();
    assert_eq!(in_core.channels()[0].grid, AnyGrid::F32(want.clone()));
    let mut src = RawFileSource::probe(&big).unwrap().unwrap();
    let mut slice = vec![0f32; 256];
    for z in 0..8 {
        ooc::SlabSource::read_slice(&mut src, z, &mut slice).unwrap();
        assert_eq!(
            &slice[..],
            &want.data()[z * 256..(z + 1) * 256],
            "slice {z}"
        );
    }
    // One byte more than 16 x 16 x 8 int16 values: misnamed, for both readers.
    let long = dir.path().join("headsq_16x16x8_int16.raw");
    let mut bytes = little.clone();
    bytes.push(0);
    std::fs::write(&long, &bytes).unwrap();
    let said = |e: blueshift_volume::Error| {
        let m = e.to_string();
        assert!(m.contains("4096 bytes") && m.contains("4097"), "{m}");
    };
    said(blueshift_volume::read(&long).unwrap_err());
    said(RawFileSource::probe(&long).unwrap_err());
}

#[test]
fn a_bricked_header_cut_inside_the_channel_name_is_refused() {
    let g = noisy_grid([4, 4, 4], 2);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("v.bsv");
    ooc::convert(
        &mut GridSource(&g),
        &path,
        "a-long-channel-name",
        BrickLayout { brick: 4, apron: 1 },
        &mut |_, _| {},
    )
    .unwrap();
    let b = std::fs::read(&path).unwrap();
    for cut in [0, 7, 79, 80, 85, 98, 4096, b.len() - 1] {
        std::fs::write(&path, &b[..cut]).unwrap();
        assert!(BrickedFile::open(&path, 1).is_err(), "cut at {cut}");
    }
    // Bytes after the end the header records: another file's data, refused the same way.
    std::fs::write(&path, &b).unwrap();
    assert!(BrickedFile::open(&path, 1).is_ok());
    let mut longer = b.clone();
    longer.extend_from_slice(&[0; 3]);
    std::fs::write(&path, &longer).unwrap();
    let e = BrickedFile::open(&path, 1).unwrap_err().to_string();
    assert!(e.contains("3 bytes after its end"), "{e}");
}

#[test]
fn stored_macrocells_and_value_statistics_match_a_direct_pass() {
    // Odd dims (no level is a whole number of bricks or macrocells), negative values and a
    // scatter of NaN and infinities, which the statistics count and the ranges skip.
    let dims = [45, 23, 31];
    let mut g = noisy_grid(dims, 29);
    let mut rng = Lcg(5);
    for v in g.data_mut().iter_mut() {
        *v -= 0.4;
        let r = rng.next_f32();
        if r < 0.01 {
            *v = f32::NAN;
        } else if r < 0.015 {
            *v = f32::INFINITY;
        } else if r < 0.02 {
            *v = f32::NEG_INFINITY;
        }
    }
    let finite: Vec<f32> = g.data().iter().copied().filter(|v| v.is_finite()).collect();
    let lo = finite.iter().copied().fold(f32::INFINITY, f32::min);
    let hi = finite.iter().copied().fold(f32::NEG_INFINITY, f32::max);
    let pos = finite
        .iter()
        .copied()
        .filter(|&v| v > 0.0)
        .fold(f32::INFINITY, f32::min);
    let bad = g.data().len() - finite.len();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("v.bsv");
    let layout = BrickLayout { brick: 8, apron: 1 };
    ooc::convert(&mut GridSource(&g), &path, "d", layout, &mut |_, _| {}).unwrap();
    let f = BrickedFile::open(&path, 4).unwrap();
    let src = f.source();
    assert_eq!(src.finite_range(), Some((lo, hi)));
    assert_eq!(src.positive_min(), Some(pos));
    assert_eq!(src.non_finite(), bad as u64);
    let pyr = lod::Pyramid::build(&AnyGrid::F32(g.clone()), 8).unwrap();
    for (l, lv) in pyr.levels().iter().enumerate() {
        let stored = src
            .stored_macrocells(l, 4)
            .unwrap()
            .expect("k = 4 is stored");
        // The direct pass: min and max over each cell's k + 1 voxels per axis, NaN skipped.
        let n = lv.dims();
        let c = stored.dims();
        for cz in 0..c[2] {
            for cy in 0..c[1] {
                for cx in 0..c[0] {
                    let (mut a, mut b) = (f32::INFINITY, f32::NEG_INFINITY);
                    for z in 4 * cz..=(4 * cz + 4).min(n[2] - 1) {
                        for y in 4 * cy..=(4 * cy + 4).min(n[1] - 1) {
                            for x in 4 * cx..=(4 * cx + 4).min(n[0] - 1) {
                                let v = lv.data()[x + n[0] * (y + n[1] * z)];
                                if !v.is_nan() {
                                    a = a.min(v);
                                    b = b.max(v);
                                }
                            }
                        }
                    }
                    let r = stored.range([cx, cy, cz]);
                    assert_eq!((r.start, r.end), (a, b), "level {l} cell {cx},{cy},{cz}");
                }
            }
        }
        assert_eq!(stored, Macrocells::build(lv, 4).unwrap(), "level {l}");
    }
}

/// Version 4 checksums the header and each level's macrocells: a changed value range (which
/// transfer functions map over) is refused at open, changed macrocells (majorants) when
/// that level's are read; the other levels still read. Version 3 files (no such checksums)
/// still open and sample.
#[test]
fn corrupt_headers_and_macrocells_are_refused_and_version_3_still_reads() {
    let g = noisy_grid([21, 18, 19], 3);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("v.bsv");
    let layout = BrickLayout { brick: 8, apron: 1 };
    ooc::convert(&mut GridSource(&g), &path, "d", layout, &mut |_, _| {}).unwrap();
    let good = std::fs::read(&path).unwrap();
    let u64_at = |o: usize| u64::from_le_bytes(good[o..o + 8].try_into().unwrap()) as usize;
    let write = |b: &[u8]| {
        let p = dir.path().join("bad.bsv");
        std::fs::write(&p, b).unwrap();
        p
    };
    // The header's finite range, set to [-1, 1].
    let mut b = good.clone();
    b[364..372].copy_from_slice(&[0, 0, 0x80, 0xbf, 0, 0, 0x80, 0x3f]);
    let err = BrickedFile::open(&write(&b), 2).unwrap_err().to_string();
    assert!(err.contains("header is corrupt"), "{err}");
    // The last level's macrocells end where the checksum table starts.
    let f = BrickedFile::open(&path, 2).unwrap();
    let last = f.levels() - 1;
    let mut b = good.clone();
    let at = u64_at(348) - 4;
    b[at..at + 4].copy_from_slice(&0.0f32.to_le_bytes());
    let bad = BrickedFile::open(&write(&b), 2).unwrap();
    let err = bad
        .source()
        .stored_macrocells(last, 4)
        .unwrap_err()
        .to_string();
    assert!(
        err.contains(&format!("macrocells of level {last} are corrupt")),
        "{err}"
    );
    assert!(bad.source().stored_macrocells(0, 4).unwrap().is_some());
    // Version 3 (as written before: no checksums, zeros from byte 384) reads without the
    // checks, the range included.
    let mut b = good.clone();
    b[8..12].copy_from_slice(&3u32.to_le_bytes());
    b[384..4096].fill(0);
    b[364..372].copy_from_slice(&[0, 0, 0x80, 0xbf, 0, 0, 0x80, 0x3f]);
    let old = write(&b);
    let f = BrickedFile::open(&old, 2).unwrap();
    assert_eq!(f.source().finite_range(), Some((-1.0, 1.0)));
    for l in 0..f.levels() {
        f.level(l).unwrap().sample_index(Vec3::splat(0.5)).unwrap();
    }
}

/// Slices copied out of a grid one at a time: the converter's path for sources that do not
/// hold the volume in memory.
struct Copied<'a>(GridSource<'a, f32>);

impl ooc::SlabSource for Copied<'_> {
    fn geometry(&self) -> Geometry {
        self.0.geometry()
    }
    fn read_slice(&mut self, z: usize, out: &mut [f32]) -> blueshift_volume::Result<()> {
        self.0.read_slice(z, out)
    }
}

/// A volume read in place (an in-core f32 grid) and slices copied one by one (a source
/// without `in_place`, raw files and NRRDs with headers of every alignment, read with
/// positioned reads) give the same bytes, NaNs, infinities and signed zeros included.
#[test]
fn in_place_and_copied_sources_give_the_same_bricked_file() {
    use ooc::SlabSource;
    let dims = [37, 29, 23];
    let mut g = noisy_grid(dims, 21);
    let special = [
        f32::NAN,
        -f32::NAN,
        f32::INFINITY,
        f32::NEG_INFINITY,
        -0.0,
        0.0,
    ];
    for (i, v) in g.data_mut().iter_mut().enumerate() {
        if i % 37 == 5 {
            *v = special[(i / 37) % special.len()];
        }
    }
    let dir = tempfile::tempdir().unwrap();
    let raw = dir.path().join("v_37x29x23_float32.raw");
    let bytes: Vec<u8> = g.data().iter().flat_map(|v| v.to_le_bytes()).collect();
    std::fs::write(&raw, &bytes).unwrap();
    // Header lengths 4-byte aligned and not.
    let nrrd = |pad: usize| {
        let p = dir.path().join(format!("v{pad}.nrrd"));
        let mut f = format!(
            "NRRD0004\ntype: float\ndimension: 3\nsizes: 37 29 23\nspacings: 0.5 1 2\n\
             encoding: raw\nendian: little\n# {}\n\n",
            "x".repeat(pad)
        )
        .into_bytes();
        f.extend(&bytes);
        std::fs::write(&p, f).unwrap();
        p
    };
    let nrrds = [nrrd(0), nrrd(1), nrrd(2), nrrd(3)];
    // gzip NRRDs, attached and detached (the latter in two gzip members), decompressed as
    // the converter reads them.
    let gz = |data: &[u8]| {
        use std::io::Write;
        let mut e = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
        e.write_all(data).unwrap();
        e.finish().unwrap()
    };
    let head = "NRRD0004\ntype: float\ndimension: 3\nsizes: 37 29 23\nencoding: gzip\n\
                endian: little\n";
    let attached = dir.path().join("a.nrrd");
    let mut f = format!("{head}\n").into_bytes();
    f.extend(gz(&bytes));
    std::fs::write(&attached, f).unwrap();
    let detached = dir.path().join("d.nhdr");
    std::fs::write(&detached, format!("{head}data file: d.raw.gz\n\n")).unwrap();
    let half = bytes.len() / 3;
    let mut two = gz(&bytes[..half]);
    two.extend(gz(&bytes[half..]));
    std::fs::write(dir.path().join("d.raw.gz"), &two).unwrap();
    for layout in [
        BrickLayout { brick: 8, apron: 1 },
        BrickLayout {
            brick: 16,
            apron: 3,
        },
    ] {
        let convert = |src: &mut (dyn SlabSource + Send), name: &str| {
            let out = dir.path().join(format!("{name}.bsv"));
            ooc::convert(src, &out, "d", layout, &mut |_, _| {}).unwrap();
            std::fs::read(out).unwrap()
        };
        let want = convert(&mut Copied(GridSource(&g)), "copied");
        assert!(GridSource(&g).in_place().is_some());
        // The first differing byte, if any.
        let first_difference = |got: Vec<u8>| {
            (got.len() != want.len())
                .then_some(got.len().min(want.len()))
                .or_else(|| want.iter().zip(&got).position(|(a, b)| a != b))
        };
        let grid = convert(&mut GridSource(&g), "grid");
        assert_eq!(first_difference(grid), None, "{layout:?}");
        let mut file = RawFileSource::probe(&raw).unwrap().unwrap();
        file.set_geometry(*g.geometry()).unwrap();
        // Files are never mapped (a truncated input must be an error, not SIGBUS).
        assert!(file.in_place().is_none());
        let file = convert(&mut file, "raw");
        assert_eq!(first_difference(file), None, "{layout:?}");
        for p in &nrrds {
            let mut src = RawFileSource::probe(p).unwrap().unwrap();
            src.set_geometry(*g.geometry()).unwrap();
            let nrrd = convert(&mut src, "nrrd");
            assert_eq!(first_difference(nrrd), None, "{layout:?} {}", p.display());
        }
        for p in [&attached, &detached] {
            assert!(RawFileSource::probe(p).unwrap().is_none());
            let mut src = ooc::GzipFileSource::probe(p).unwrap().unwrap();
            src.set_geometry(*g.geometry()).unwrap();
            let nrrd = convert(&mut src, "gzip");
            assert_eq!(first_difference(nrrd), None, "{layout:?} {}", p.display());
        }
    }
}

/// A source that fails part way: the conversion is an error and leaves no file behind.
#[test]
fn a_failed_conversion_leaves_no_file() {
    struct Failing(Geometry);
    impl ooc::SlabSource for Failing {
        fn geometry(&self) -> Geometry {
            self.0
        }
        fn read_slice(&mut self, z: usize, out: &mut [f32]) -> blueshift_volume::Result<()> {
            if z == 20 {
                return Err(blueshift_volume::Error::Invalid("disk on fire".into()));
            }
            out.fill(z as f32);
            Ok(())
        }
    }
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("v.bsv");
    let layout = BrickLayout { brick: 8, apron: 1 };
    let r = ooc::convert(
        &mut Failing(Geometry::unit([9, 10, 40])),
        &out,
        "d",
        layout,
        &mut |_, _| {},
    );
    assert!(r.is_err());
    let left: Vec<_> = std::fs::read_dir(dir.path()).unwrap().collect();
    assert!(left.is_empty(), "{left:?}");
}

/// A gzip NRRD streamed into a `.bsv`: a stream that ends early is a clean error naming the
/// slice and leaves no file; slices are refused out of order; other encodings and skips are
/// not taken (they are read in core).
#[test]
fn a_gzip_stream_that_ends_early_is_an_error_and_leaves_no_file() {
    use ooc::SlabSource;
    use std::io::Write;
    let dir = tempfile::tempdir().unwrap();
    let dims = [16usize, 12, 10];
    let bytes: Vec<u8> = (0..dims.iter().product::<usize>())
        .flat_map(|i| (i as u16).to_be_bytes())
        .collect();
    let mut e = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
    e.write_all(&bytes[..bytes.len() * 7 / 10]).unwrap();
    let cut = e.finish().unwrap();
    let head = "NRRD0004\ntype: uint16\ndimension: 3\nsizes: 16 12 10\nencoding: gzip\n\
                endian: big\n";
    let p = dir.path().join("cut.nrrd");
    let mut f = format!("{head}\n").into_bytes();
    f.extend(&cut);
    std::fs::write(&p, f).unwrap();
    let mut src = ooc::GzipFileSource::probe(&p).unwrap().unwrap();
    assert_eq!(src.scalar_type(), blueshift_volume::ScalarType::U16);
    let mut slice = vec![0.0f32; 16 * 12];
    // Big-endian uint16 values as written.
    src.read_slice(0, &mut slice).unwrap();
    assert_eq!(slice[..3], [0.0, 1.0, 2.0]);
    assert!(src.read_slice(5, &mut slice).is_err(), "out of order");
    let out = dir.path().join("cut.bsv");
    let mut src = ooc::GzipFileSource::probe(&p).unwrap().unwrap();
    let err = ooc::convert(
        &mut src,
        &out,
        "d",
        BrickLayout { brick: 8, apron: 1 },
        &mut |_, _| {},
    )
    .unwrap_err()
    .to_string();
    assert!(err.contains("ends in slice 7 of 10"), "{err}");
    assert!(!out.exists());
    // A byte skip is counted before decompression: not streamed.
    let skip = dir.path().join("skip.nrrd");
    let mut f = format!("{head}byte skip: 4\n\n").into_bytes();
    f.extend(&cut);
    std::fs::write(&skip, f).unwrap();
    assert!(ooc::GzipFileSource::probe(&skip).unwrap().is_none());
}

/// Threads that miss on the same brick at once read it once: the others wait for that read
/// (each brick of a view was read 1-1.1 times by a multi-threaded render).
#[test]
fn concurrent_misses_on_one_brick_read_it_once() {
    let g = noisy_grid([32, 32, 16], 4);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("v.bsv");
    ooc::convert(
        &mut GridSource(&g),
        &path,
        "v",
        BrickLayout { brick: 8, apron: 1 },
        &mut |_, _| {},
    )
    .unwrap();
    let cache = blueshift_volume::BrickCache::new(64 << 20);
    let file = BrickedFile::open_with_cache(&path, cache.clone()).unwrap();
    let source = file.source();
    let bricks = 4 * 4 * 2;
    let threads = 8;
    let barrier = std::sync::Barrier::new(threads);
    let firsts: Vec<Vec<f32>> = std::thread::scope(|s| {
        let handles: Vec<_> = (0..threads)
            .map(|_| {
                s.spawn(|| {
                    let mut first = Vec::new();
                    for idx in 0..bricks {
                        barrier.wait();
                        first.push(cache.get(source.as_ref(), 0, idx).unwrap()[0]);
                    }
                    first
                })
            })
            .collect();
        handles.into_iter().map(|h| h.join().unwrap()).collect()
    });
    assert!(
        firsts.windows(2).all(|w| w[0] == w[1]),
        "every thread saw the same bricks"
    );
    let st = cache.stats();
    assert_eq!(st.reads, vec![bricks], "{st:?}");
    assert_eq!(st.hits, (threads as u64 - 1) * bricks, "{st:?}");
}

/// NaN voxels (no data) are left out of a coarse voxel's mean: it is the mean of the fine
/// voxels that are numbers (computed here in f64), NaN only where all eight are NaN. The
/// in-core pyramid and the `.bsv` file's level 1 hold the same bits. Before, one NaN made
/// its whole coarse voxel NaN, and the region rendered transparent at coarse levels.
#[test]
fn coarse_levels_average_the_voxels_that_are_numbers() {
    let dims = [9, 8, 7];
    let mut g = noisy_grid(dims, 12);
    let mut rng = Lcg(3);
    for v in g.data_mut().iter_mut() {
        if rng.next_f32() < 0.15 {
            *v = f32::NAN;
        }
    }
    // One coarse voxel with no number at all.
    for (x, y, z) in (0..8).map(|i| (2 + (i & 1), 4 + ((i >> 1) & 1), 2 + (i >> 2))) {
        let at = g.geometry().index(x, y, z);
        g.data_mut()[at] = f32::NAN;
    }
    let coarse = lod::downsample(&g).unwrap();
    let [cx, cy, cz] = coarse.dims();
    let mut checked = 0;
    for z in 0..cz {
        for y in 0..cy {
            for x in 0..cx {
                let (mut sum, mut n) = (0.0f64, 0u32);
                for i in 0..8 {
                    let f = |c: usize, b: usize, d: usize| (2 * c + b).min(d - 1);
                    let v = g
                        .get(
                            f(x, i & 1, dims[0]),
                            f(y, (i >> 1) & 1, dims[1]),
                            f(z, i >> 2, dims[2]),
                        )
                        .unwrap();
                    if !v.is_nan() {
                        sum += f64::from(v);
                        n += 1;
                    }
                }
                let got = coarse.get(x, y, z).unwrap();
                if n == 0 {
                    assert!(got.is_nan(), "[{x}, {y}, {z}]");
                } else {
                    let want = sum / f64::from(n);
                    assert!(
                        (f64::from(got) - want).abs() <= 1e-5 * want.abs().max(1.0),
                        "[{x}, {y}, {z}]: {got} vs {want}"
                    );
                    checked += usize::from(n < 8);
                }
            }
        }
    }
    assert!(checked > 20, "coarse voxels with some NaN: {checked}");
    assert!(coarse.get(1, 2, 1).unwrap().is_nan());
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("nan.bsv");
    ooc::convert(
        &mut GridSource(&g),
        &path,
        "nan",
        BrickLayout { brick: 4, apron: 1 },
        &mut |_, _| {},
    )
    .unwrap();
    let f = BrickedFile::open(&path, 64).unwrap();
    let AnyGrid::F32(level1) = f.load_level(1, &Default::default()).unwrap() else {
        panic!("f32 level")
    };
    let bits = |g: &Grid<f32>| g.data().iter().map(|v| v.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(&level1), bits(&coarse));
}
