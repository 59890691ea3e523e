//! The device brick pool ([`blueshift_gpu::pool`]) against independent truths: its samples
//! against the CPU's dense trilinear sampler at random points and at every brick seam, its
//! constant bricks against a brute-force pass over the voxels, a `.bsv` level against the
//! same data in memory (the same bytes rendered), a volume larger than the pool's cap
//! rendered when its non-constant bricks fit and refused (falling back under `auto`) when
//! they do not, and `--lod auto`'s choice of the finest level that fits.
//!
//! Every test prints `SKIP: no wgpu adapter: ...` and returns when there is no adapter,
//! unless `BLUESHIFT_REQUIRE_GPU_TESTS=1`.

use blueshift_gpu::context::test_context;
use blueshift_gpu::pool::{POOL_BRICK, is_pool_full};
use blueshift_gpu::tracking::{GpuTracker, GpuTrackingSession, sample_probe};
use blueshift_gpu::{DeviceChoice, GpuContext, GpuOptions};
use blueshift_tfedit::{ColorKnot, OpacityKnot, TransferFunction};
use blueshift_tracking::{Integrator, RayMarcher, RenderSettings, Scene, render};
use blueshift_volume::ooc::{self, BrickLayout, BrickedFile, GridSource};
use blueshift_volume::{AnyGrid, BrickCache, Field, Geometry, Grid};
use glam::Vec3;

/// A context of this test's own: the pool cap is per context, and tests run in parallel.
fn own_context() -> Option<GpuContext> {
    test_context()?;
    Some(GpuContext::new(GpuOptions::default()).expect("a second context"))
}

/// Fixed-seed PCG32 for the probe points.
struct Pcg(u64);
impl Pcg {
    fn f(&mut self) -> f32 {
        let old = self.0;
        self.0 = old
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        let x = (((old >> 18) ^ old) >> 27) as u32;
        (x.rotate_right((old >> 59) as u32) >> 8) as f32 / (1u32 << 24) as f32
    }
}

fn tf() -> TransferFunction {
    TransferFunction::new(
        [0.0, 1.0],
        vec![
            ColorKnot {
                x: 0.0,
                rgb: [1.0, 0.4, 0.1],
            },
            ColorKnot {
                x: 1.0,
                rgb: [0.2, 0.6, 1.0],
            },
        ],
        vec![OpacityKnot::new(0.0, 0.0), OpacityKnot::new(1.0, 0.8)],
    )
    .unwrap()
}

/// A smooth field, non-constant everywhere.
fn smooth(dims: [usize; 3]) -> Grid<f32> {
    Grid::from_fn(Geometry::unit(dims), |x, y, z| {
        0.5 + 0.4 * (0.21 * x as f32 + 0.13 * y as f32).sin() * (0.17 * z as f32).cos()
    })
    .unwrap()
}

/// Zero except a box of varying values over voxels `lo..hi` (exclusive).
fn boxed(dims: [usize; 3], lo: [usize; 3], hi: [usize; 3]) -> Grid<f32> {
    Grid::from_fn(Geometry::unit(dims), |x, y, z| {
        let inside = (lo[0]..hi[0]).contains(&x)
            && (lo[1]..hi[1]).contains(&y)
            && (lo[2]..hi[2]).contains(&z);
        if inside {
            0.2 + 0.01 * ((x * 7 + y * 3 + z) % 50) as f32
        } else {
            0.0
        }
    })
    .unwrap()
}

/// Pool bricks of `g` that are not constant, by brute force: brick `b` holds voxels
/// `32 b ..= 32 b + 32` per axis, clamped to the grid.
fn non_constant_bricks(g: &Grid<f32>) -> usize {
    let n = g.dims();
    let nb = n.map(|d| d.div_ceil(POOL_BRICK));
    let mut count = 0;
    for bz in 0..nb[2] {
        for by in 0..nb[1] {
            for bx in 0..nb[0] {
                let b = [bx, by, bz];
                let r = |a: usize| (b[a] * POOL_BRICK)..=((b[a] + 1) * POOL_BRICK).min(n[a] - 1);
                let first = g.get(*r(0).start(), *r(1).start(), *r(2).start());
                let mut constant = true;
                for z in r(2) {
                    for y in r(1) {
                        for x in r(0) {
                            constant &= g.get(x, y, z).map(f32::to_bits) == first.map(f32::to_bits);
                        }
                    }
                }
                count += usize::from(!constant);
            }
        }
    }
    count
}

fn max_diff(a: &image::Rgba32FImage, b: &image::Rgba32FImage) -> f32 {
    a.as_raw()
        .iter()
        .zip(b.as_raw())
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f32::max)
}

/// The largest difference between the marcher's 1-spp image of `s` through the device
/// pool `gs` and the CPU's, at `w` x `h`; the CPU's image must not be trivial.
fn marcher_gpu_cpu_diff(
    t: &GpuTracker<'_>,
    gs: &blueshift_gpu::tracking::GpuScene<'_>,
    s: &Scene,
    w: u32,
    h: u32,
) -> f32 {
    let mut set = RenderSettings::default_for(s, w, h, false);
    set.spp = 1;
    let integ = Integrator::Marcher(RayMarcher::default());
    let gpu = t.render(gs, &integ, &set).unwrap();
    let cpu = render(s, &integ, &set).unwrap();
    assert!(
        cpu.as_raw().chunks(4).any(|p| p[3] > 0.3),
        "a trivial image"
    );
    max_diff(&cpu, &gpu)
}

fn scene_of(chs: Vec<Field>) -> Scene {
    let triples = chs
        .into_iter()
        .enumerate()
        .map(|(i, f)| (format!("c{i}"), f, tf()))
        .collect();
    Scene::new(triples, 8.0, 4).unwrap()
}

fn dense(g: &Grid<f32>) -> Field {
    Field::from(AnyGrid::F32(g.clone()))
}

/// `g` as a `.bsv` file (bricks of 16, so pool bricks span several file bricks) opened
/// through a cache of `budget` bytes.
/// Two channels on a 96 x 80 x 64 grid in `.bsv` files of several levels: a smooth field
/// (`a`) and a box (`b`).
fn two_channels(dir: &std::path::Path) -> (BrickedFile, BrickedFile) {
    let dims = [96, 80, 64];
    let (a, b) = (smooth(dims), boxed(dims, [20, 10, 5], [70, 60, 50]));
    (
        bricked(dir, "a", &a, 1 << 24),
        bricked(dir, "b", &b, 1 << 24),
    )
}

fn bricked(dir: &std::path::Path, name: &str, g: &Grid<f32>, budget: usize) -> BrickedFile {
    let p = dir.join(format!("{name}.bsv"));
    ooc::convert(
        &mut GridSource(g),
        &p,
        name,
        BrickLayout {
            brick: 16,
            apron: 1,
        },
        &mut |_, _| {},
    )
    .unwrap();
    BrickedFile::open_with_cache(&p, BrickCache::new(budget)).unwrap()
}

#[test]
fn pooled_samples_equal_the_cpu_sampler_at_random_points_and_every_seam() {
    let Some(ctx) = test_context() else { return };
    let dims = [70, 45, 33];
    let a = smooth(dims);
    let b = boxed(dims, [40, 5, 3], [52, 20, 30]);
    let s = scene_of(vec![dense(&a), dense(&b)]);
    let t = GpuTracker::new(ctx).unwrap();
    let gs = t.upload(s).unwrap();
    let st = gs.pool_stats();
    // Every brick of the smooth channel, and the box's by brute force.
    let want = non_constant_bricks(&a) + non_constant_bricks(&b);
    assert_eq!(non_constant_bricks(&a), 3 * 2 * 2);
    assert_eq!(st.resident, want, "{st}");
    assert_eq!(st.resident + st.constant, 2 * 12, "{st}");
    assert!(st.constant > 0, "the zero bricks take no slot: {st}");

    let mut pts = Vec::new();
    let mut rng = Pcg(0x5eed);
    for _ in 0..4000 {
        let p = Vec3::new(
            rng.f() * 76.0 - 3.0,
            rng.f() * 51.0 - 3.0,
            rng.f() * 39.0 - 3.0,
        );
        pts.push(p);
    }
    // Seams, brick corners and the clamped last voxels, with fractions either side.
    for &x in &[0.0, 31.0, 31.5, 31.999, 32.0, 32.25, 63.5, 64.0, 68.9, 69.0] {
        for &y in &[0.0, 31.75, 32.0, 43.5, 44.0] {
            for &z in &[0.5, 31.5, 32.0] {
                pts.push(Vec3::new(x, y, z));
            }
        }
    }
    pts.push(Vec3::new(f32::NAN, 10.0, 10.0));
    pts.push(Vec3::new(45.0, f32::NAN, f32::NAN));
    let probes: Vec<(usize, Vec3)> = pts.iter().flat_map(|&p| [(0usize, p), (1, p)]).collect();
    let got = sample_probe(&gs, &probes).unwrap();
    let mut worst = 0.0f32;
    for (&(c, p), g) in probes.iter().zip(&got) {
        let want = [&a, &b][c].sample_trilinear_index(p);
        let d = (g - want).abs();
        worst = worst.max(d);
        // f32 lerps; the device may contract them into fused multiply-adds.
        assert!(d <= 1e-6, "channel {c} at {p}: gpu {g} cpu {want}");
    }
    eprintln!("pool samples: max |gpu - cpu| = {worst:e}");
}

#[test]
fn a_bsv_level_renders_the_bytes_of_the_same_data_in_memory() {
    let Some(ctx) = test_context() else { return };
    let dir = tempfile::tempdir().unwrap();
    let dims = [72, 40, 36];
    let a = smooth(dims);
    let b = boxed(dims, [10, 30, 2], [30, 39, 20]);
    // A cache of 4 file bricks: the pool is filled through it brick by brick.
    let budget = 4 * 18 * 18 * 18 * 4;
    let fa = bricked(dir.path(), "a", &a, budget);
    let fb = bricked(dir.path(), "b", &b, budget);
    let t = GpuTracker::new(ctx).unwrap();
    let sd = scene_of(vec![dense(&a), dense(&b)]);
    let sb = scene_of(vec![
        Field::from(fa.field(0).unwrap()),
        Field::from(fb.field(0).unwrap()),
    ]);
    let gd = t.upload(sd.clone()).unwrap();
    let gb = t.upload(sb.clone()).unwrap();
    let (pd, pb) = (gd.pool_stats(), gb.pool_stats());
    assert_eq!(
        (pd.resident, pd.constant),
        (pb.resident, pb.constant),
        "{pd} / {pb}"
    );
    assert!(
        pb.skipped_reads > 0,
        "the stored macrocells spare reading constant bricks: {pb}"
    );
    let mut set = RenderSettings::default_for(&sd, 40, 40, false);
    set.spp = 1;
    let integ = Integrator::Marcher(RayMarcher::default());
    let id = t.render(&gd, &integ, &set).unwrap();
    let ib = t.render(&gb, &integ, &set).unwrap();
    assert_eq!(id.as_raw(), ib.as_raw(), "bricked and dense pools differ");
    // And the CPU's image within the marcher's f32 tolerance, grown over about 150 steps
    // per ray (tests/tracking.rs states 2e-5 at 16^3 and 3e-4 over thousands of steps;
    // measured here 3.4e-5 on lavapipe).
    let cpu = render(&sd, &integ, &set).unwrap();
    let d = max_diff(&cpu, &ib);
    assert!(d <= 1e-4, "max |gpu - cpu| = {d}");
    assert!(
        cpu.as_raw().chunks(4).any(|p| p[3] > 0.3),
        "a trivial image"
    );
}

#[test]
fn a_volume_over_the_pool_cap_renders_when_its_bricks_fit_and_is_refused_when_not() {
    let Some(ctx) = own_context() else { return };
    // 96^3 f32 is 3.4 MiB; the cap is 1 MiB (7 slots of 33^3 f32).
    ctx.set_pool_limit(Some(1 << 20));
    assert_eq!(ctx.pool_capacity_bytes(), 1 << 20);
    let dims = [96, 96, 96];
    // One non-constant brick: the box lies inside brick (1, 1, 1) with its apron.
    let sparse = boxed(dims, [36, 40, 38], [60, 62, 58]);
    assert_eq!(non_constant_bricks(&sparse), 1);
    let s = scene_of(vec![dense(&sparse)]);
    let t = GpuTracker::new(&ctx).unwrap();
    let gs = t.upload(s.clone()).unwrap();
    let st = gs.pool_stats();
    assert_eq!(st.resident, 1, "{st}");
    assert!(st.dense_bytes > st.capacity_bytes, "{st}");
    let d = marcher_gpu_cpu_diff(&t, &gs, &s, 32, 32);
    assert!(d <= 2e-5, "max |gpu - cpu| = {d}");

    // 27 non-constant bricks do not fit 7 slots: the pool's limit, which auto falls back on.
    let full = scene_of(vec![dense(&smooth(dims))]);
    let err = t.upload(full).unwrap_err();
    assert!(is_pool_full(&err), "{err}");
    assert!(DeviceChoice::Auto.falls_back_on(&err));
    assert!(!DeviceChoice::Gpu.falls_back_on(&err));
    assert!(err.to_string().contains("--gpu-pool-mb"), "{err}");
}

#[test]
fn lod_auto_uploads_the_finest_level_whose_bricks_fit() {
    let Some(ctx) = own_context() else { return };
    let dir = tempfile::tempdir().unwrap();
    let dims = [96, 96, 96];
    let f = bricked(dir.path(), "s", &smooth(dims), 1 << 22);
    let s = scene_of(vec![Field::from(f.field(0).unwrap())]);
    let t = GpuTracker::new(&ctx).unwrap();
    // Level 0 (96^3) has 27 pool bricks, level 1 (48^3) 8, level 2 (24^3) 1 (all
    // non-constant): with 7 slots level 2 is the finest that fits; with 8, level 1.
    for (slots, want) in [(7u64, 2usize), (8, 1), (27, 0)] {
        ctx.set_pool_limit(Some(slots * blueshift_gpu::pool::SLOT_BYTES));
        let (gs, level) = t.upload_fitting(s.clone()).unwrap();
        assert_eq!(level, Some(want), "{slots} slots");
        assert_eq!(gs.scene().geometry().dims, [96 >> want; 3]);
        assert_eq!(gs.pool_stats().resident, [27, 8, 1][want]);
    }
    // A cap below one slot: no level fits, and the error is the pool's.
    ctx.set_pool_limit(Some(1024));
    let err = t.upload_fitting(s).map(|_| ()).unwrap_err();
    assert!(is_pool_full(&err), "{err}");
}

/// A level per region in stripes: level `(rx + 2 rz) % 3` for the region whose box starts
/// at `lo` (regions of `edge` voxels of a unit-spacing grid).
fn striped(edge: f32) -> impl Fn(Vec3, Vec3) -> usize {
    move |lo, _| ((lo.x / edge) as usize + 2 * (lo.z / edge) as usize) % 3
}

#[test]
fn per_brick_levels_sample_and_render_as_the_cpu_does() {
    let Some(ctx) = test_context() else { return };
    let dir = tempfile::tempdir().unwrap();
    let (fa, fb) = two_channels(dir.path());
    assert!(fa.levels() >= 3, "a pyramid of {} levels", fa.levels());
    let region = |f: &BrickedFile| -> Field {
        f.field(0)
            .unwrap()
            .per_region(striped(16.0))
            .unwrap()
            .into()
    };
    let (ra, rb) = (region(&fa), region(&fb));
    let hist = ra.as_bricked().unwrap().level_map().unwrap().histogram();
    assert!(hist.len() == 3 && hist.iter().all(|&n| n > 0), "{hist:?}");
    let s = scene_of(vec![ra.clone(), rb.clone()]);
    assert!(
        blueshift_gpu::tracking::supports(&s, &RenderSettings::default_for(&s, 8, 8, false))
            .is_ok()
    );
    let t = GpuTracker::new(ctx).unwrap();
    let gs = t.upload(s.clone()).unwrap();
    let st = gs.pool_stats();
    assert_eq!(st.levels, 3, "{st}");

    // Random points (inside, outside, on region seams) and NaN coordinates: each sample is
    // the level its region takes, as the CPU's per-region sampler computes it.
    let mut pts = Vec::new();
    let mut rng = Pcg(0x10d);
    for _ in 0..6000 {
        pts.push(Vec3::new(
            rng.f() * 104.0 - 4.0,
            rng.f() * 88.0 - 4.0,
            rng.f() * 72.0 - 4.0,
        ));
    }
    for &x in &[0.0, 15.5, 15.999, 16.0, 16.5, 31.75, 32.0, 47.9, 48.0, 95.0] {
        for &z in &[0.25, 15.9, 16.0, 32.5, 63.0] {
            pts.push(Vec3::new(x, 40.5, z));
        }
    }
    pts.push(Vec3::new(f32::NAN, 10.0, 10.0));
    pts.push(Vec3::new(40.0, f32::NAN, 33.0));
    let probes: Vec<(usize, Vec3)> = pts.iter().flat_map(|&p| [(0usize, p), (1, p)]).collect();
    let got = sample_probe(&gs, &probes).unwrap();
    let mut worst = 0.0f32;
    let mut coarse = 0;
    for (&(c, p), g) in probes.iter().zip(&got) {
        let f = [&ra, &rb][c];
        let want = f.sample_scalar_index(p);
        // The level's own sample, from the level loaded whole (independent of the
        // per-region sampler): the region's level at the point's clamped voxel.
        let q = p.clamp(Vec3::ZERO, Vec3::new(95.0, 79.0, 63.0));
        let q = if p.is_nan() {
            Vec3::new(
                if p.x.is_nan() { 0.0 } else { q.x },
                if p.y.is_nan() { 0.0 } else { q.y },
                if p.z.is_nan() { 0.0 } else { q.z },
            )
        } else {
            q
        };
        let level = striped(16.0)(
            Vec3::new(
                (q.x as usize / 16 * 16) as f32,
                0.0,
                (q.z as usize / 16 * 16) as f32,
            ),
            Vec3::ZERO,
        );
        coarse += usize::from(level > 0);
        let d = (g - want).abs();
        worst = worst.max(d);
        // The device may contract the world transform and the lerps into fused
        // multiply-adds.
        assert!(
            d <= 1e-5,
            "channel {c} at {p} (level {level}): gpu {g} cpu {want}"
        );
    }
    assert!(coarse > 1000, "coarse regions sampled: {coarse}");
    eprintln!("per-brick pool samples: max |gpu - cpu| = {worst:e}");

    // The levels themselves, loaded whole, at a few points of coarse regions: the CPU's
    // per-region samples are those levels' trilinear samples.
    let lv: Vec<Grid<f32>> = (0..3)
        .map(|l| match fa.load_level(l, &Default::default()).unwrap() {
            AnyGrid::F32(g) => g,
            _ => panic!("f32"),
        })
        .collect();
    for p in [
        Vec3::new(20.0, 30.0, 3.0),
        Vec3::new(40.3, 12.7, 20.1),
        Vec3::new(70.0, 70.0, 40.0),
    ] {
        let l = striped(16.0)(
            Vec3::new(
                (p.x as usize / 16 * 16) as f32,
                0.0,
                (p.z as usize / 16 * 16) as f32,
            ),
            Vec3::ZERO,
        );
        let g = lv[l].geometry();
        let want = lv[l].sample_trilinear_index(g.world_to_index(p));
        let cpu = ra.sample_scalar_index(p);
        assert!(
            (want - cpu).abs() <= 1e-6,
            "level {l} at {p}: {want} vs {cpu}"
        );
    }

    // The marcher's image through the per-brick pool against the CPU's.
    let d = marcher_gpu_cpu_diff(&t, &gs, &s, 48, 40);
    assert!(d <= 1e-4, "max |gpu - cpu| = {d}");
}

/// A smooth 128^3 `.bsv` (bricks of 16) and a scene of it with one region (file brick
/// (0, 0, 0), voxels 0..16) at the finest level and every other at level 2 (32^3: one pool
/// brick); level 1 is sampled nowhere.
fn one_fine_region(dir: &std::path::Path) -> (BrickedFile, Scene) {
    let f = bricked(dir, "s", &smooth([128; 3]), 1 << 26);
    let field: Field = f
        .field(0)
        .unwrap()
        .per_region(|lo, _| if lo.max_element() < 16.0 { 0 } else { 2 })
        .unwrap()
        .into();
    (f, scene_of(vec![field]))
}

#[test]
fn a_per_brick_pool_reads_only_the_bricks_its_regions_sample() {
    let Some(ctx) = test_context() else { return };
    let dir = tempfile::tempdir().unwrap();
    let (f, s) = one_fine_region(dir.path());
    f.cache().reset_stats();
    let t = GpuTracker::new(ctx).unwrap();
    let gs = t.upload(s).unwrap();
    let st = gs.pool_stats();
    // Level 0 needs the pool brick holding voxels 0..=32 (the region, its trilinear
    // neighbours and the margin): file bricks 0..=2 per axis, 27 of 512. Level 2: its
    // 2^3 file bricks. Level 1: none.
    let reads = f.cache().stats().reads;
    assert_eq!(reads.first().copied().unwrap_or(0), 27, "{reads:?}");
    assert_eq!(reads.get(1).copied().unwrap_or(0), 0, "{reads:?}");
    assert_eq!(reads.get(2).copied().unwrap_or(0), 8, "{reads:?}");
    // Pool bricks: level 0 4^3, level 1 2^3, level 2 1; two held, the rest never read.
    assert_eq!((st.levels, st.bricks_per_channel), (3, 64 + 8 + 1), "{st}");
    assert_eq!((st.resident, st.unsampled), (2, 63 + 8), "{st}");
}

#[test]
fn a_pool_keeps_its_bricks_across_views_and_evicts_the_least_recently_used() {
    let Some(ctx) = own_context() else { return };
    let dir = tempfile::tempdir().unwrap();
    let f = bricked(dir.path(), "s", &smooth([96; 3]), 1 << 24);
    let s = scene_of(vec![Field::from(f.field(0).unwrap())]);
    let at = |l: usize| s.at_level(l).unwrap();
    let t = GpuTracker::new(&ctx).unwrap();
    let integ = Integrator::Marcher(RayMarcher::default());
    let mut set = RenderSettings::default_for(&s, 24, 24, false);
    set.spp = 1;
    // Each view renders the image of a pool uploaded for it alone.
    let fresh = |view: Scene| {
        let g = t.upload(view).unwrap();
        t.render(&g, &integ, &set).unwrap()
    };
    // Level 0 has 27 pool bricks, level 1 8, level 2 1. Room for 28: level 0; level 1
    // (one free slot after growing to the cap, then the 7 least recently used level-0
    // bricks evicted); level 2 (one more level-0 brick evicted, the oldest); level 0 again
    // (19 kept, 8 uploaded into level 1's slots, older than level 2's); level 0 once more
    // (all kept).
    ctx.set_pool_limit(Some(28 * blueshift_gpu::pool::SLOT_BYTES));
    let mut gs = t.upload(at(0)).unwrap();
    let st = gs.pool_stats();
    assert_eq!((st.resident, st.kept, st.evicted), (27, 0, 0), "{st}");
    for (level, want) in [
        (1, (8, 0, 7)),
        (2, (1, 0, 1)),
        (0, (27, 19, 8)),
        (0, (27, 27, 0)),
    ] {
        gs.set_view(at(level)).unwrap();
        let st = gs.pool_stats();
        assert_eq!(
            (st.resident, st.kept, st.evicted),
            want,
            "level {level}: {st}"
        );
        assert!(
            st.pool_bytes <= 28 * blueshift_gpu::pool::SLOT_BYTES,
            "{st}"
        );
        let got = t.render(&gs, &integ, &set).unwrap();
        assert_eq!(got.as_raw(), fresh(at(level)).as_raw(), "level {level}");
    }
    // A view larger than the pool is the pool's error, and the scene renders nothing until
    // a view fits again.
    ctx.set_pool_limit(Some(20 * blueshift_gpu::pool::SLOT_BYTES));
    let mut gs = t.upload(at(1)).unwrap();
    let err = gs.set_view(at(0)).unwrap_err();
    assert!(is_pool_full(&err), "{err}");
    assert!(t.render(&gs, &integ, &set).is_err());
    gs.set_view(at(2)).unwrap();
    assert_eq!(
        t.render(&gs, &integ, &set).unwrap().as_raw(),
        fresh(at(2)).as_raw()
    );
    // Another scene's channels are not a view.
    let other = scene_of(vec![dense(&smooth([96; 3]))]);
    assert!(gs.set_view(other).is_err());
}

/// The levels an observer hears, in order.
#[derive(Default)]
struct Levels(std::sync::Mutex<Vec<usize>>);

impl blueshift_camera::Observer<blueshift_tracking::Progressive> for Levels {
    fn level(&self, _step: u32, level: usize) {
        self.0.lock().unwrap().push(level);
    }
}

#[test]
fn progressive_levels_and_bricks_on_the_gpu_end_with_the_full_render() {
    let Some(ctx) = test_context() else { return };
    let dir = tempfile::tempdir().unwrap();
    let f = bricked(dir.path(), "s", &smooth([96; 3]), 1 << 24);
    let s = scene_of(vec![Field::from(f.field(0).unwrap())]);
    let (first, count) = s.lod().unwrap();
    assert!(first == 0 && count >= 3, "{count} levels");
    let integ = Integrator::Marcher(RayMarcher::default());
    let mut set = RenderSettings::default_for(&s, 24, 24, false);
    set.spp = 2;
    let t = GpuTracker::new(ctx).unwrap();
    let plain = t
        .render(&t.upload(s.clone()).unwrap(), &integ, &set)
        .unwrap();
    let mut sess = GpuTrackingSession::new(ctx, s.clone(), integ.clone(), set.clone()).unwrap();
    // Levels: one quick pass per coarser level, coarsest first, then the scene's.
    let heard = Levels::default();
    let out = sess.render_lod(&heard).unwrap();
    assert_eq!(out.image.mean_image().as_raw(), plain.as_raw());
    let want: Vec<usize> = (0..count).rev().collect();
    assert_eq!(*heard.0.lock().unwrap(), want);
    // Bricks: the coarsest level first, the scene's level last, in the same pool.
    f.clear_cache();
    let heard = Levels::default();
    let out = sess.render_bricks(&heard, &mut |_, _, _| {}).unwrap();
    assert_eq!(out.image.mean_image().as_raw(), plain.as_raw());
    let got = heard.0.lock().unwrap().clone();
    assert_eq!(got.first(), Some(&(count - 1)), "{got:?}");
    assert_eq!(got.last(), Some(&0), "{got:?}");
    assert_eq!(sess.scene().scene().geometry().dims, [96; 3]);
}

#[test]
fn a_per_brick_view_too_large_for_the_pool_moves_every_region_coarser_until_it_fits() {
    let Some(ctx) = own_context() else { return };
    let dir = tempfile::tempdir().unwrap();
    // Two non-constant pool bricks.
    let (_f, s) = one_fine_region(dir.path());
    let t = GpuTracker::new(&ctx).unwrap();
    let slot = blueshift_gpu::pool::SLOT_BYTES;
    ctx.set_pool_limit(Some(2 * slot));
    let (gs, k) = t.upload_fitting_regions(s.clone()).unwrap();
    assert_eq!((k, gs.pool_stats().resident), (0, 2));
    // One slot: the regions move coarser together until the view holds one brick.
    ctx.set_pool_limit(Some(slot));
    let (gs, k) = t.upload_fitting_regions(s.clone()).unwrap();
    assert!(
        k >= 1 && gs.pool_stats().resident == 1,
        "k {k}: {}",
        gs.pool_stats()
    );
    let (view, moved) = s.coarser_regions(k).unwrap();
    assert!(moved);
    // The view uploaded is the coarser one: the device samples it as the CPU does.
    let pts: Vec<(usize, Vec3)> = [[3.0, 4.0, 5.0], [70.5, 20.25, 100.0], [127.0, 0.0, 64.0]]
        .iter()
        .map(|&p| (0, Vec3::from(p)))
        .collect();
    let got = sample_probe(&gs, &pts).unwrap();
    for ((_, p), g) in pts.iter().zip(got) {
        let want = view.channels()[0].grid().sample_scalar_index(*p);
        assert!((g - want).abs() <= 1e-5, "{p}: {g} vs {want}");
    }
    // Below one slot nothing fits: the pool's error.
    ctx.set_pool_limit(Some(1024));
    let err = t.upload_fitting_regions(s).map(|_| ()).unwrap_err();
    assert!(is_pool_full(&err), "{err}");
}

#[test]
fn channels_with_different_regions_share_the_coarsest_level_per_region() {
    let Some(ctx) = test_context() else { return };
    let dir = tempfile::tempdir().unwrap();
    let (fa, fb) = two_channels(dir.path());
    // Two channels whose regions take different levels (as two files' resident views do
    // while their bricks load): one lookup cannot serve both, so the GPU refuses them.
    let ra: Field = fa
        .field(0)
        .unwrap()
        .per_region(striped(16.0))
        .unwrap()
        .into();
    let rb: Field = fb
        .field(0)
        .unwrap()
        .per_region(|lo, _| usize::from(lo.y >= 48.0))
        .unwrap()
        .into();
    let s = scene_of(vec![ra.clone(), rb.clone()]);
    let set = RenderSettings::default_for(&s, 8, 8, false);
    assert!(blueshift_gpu::tracking::supports(&s, &set).is_err());
    // Shared: each region at the coarser of the two levels, in both channels.
    let shared = s.shared_regions().unwrap();
    assert!(blueshift_gpu::tracking::supports(&shared, &set).is_ok());
    let la = ra.as_bricked().unwrap().region_levels();
    let lb = rb.as_bricked().unwrap().region_levels();
    for c in shared.channels() {
        let got = c.grid().as_bricked().unwrap().region_levels();
        let want: Vec<u8> = la.iter().zip(&lb).map(|(x, y)| *x.max(y)).collect();
        assert_eq!(got, want);
    }
    let t = GpuTracker::new(ctx).unwrap();
    let gs = t.upload(shared.clone()).unwrap();
    let mut rng = Pcg(0x5a7e);
    let probes: Vec<(usize, Vec3)> = (0..2000)
        .map(|i| {
            let p = Vec3::new(rng.f() * 96.0, rng.f() * 80.0, rng.f() * 64.0);
            (i % 2, p)
        })
        .collect();
    let got = sample_probe(&gs, &probes).unwrap();
    for ((c, p), g) in probes.iter().zip(got) {
        let want = shared.channels()[*c].grid().sample_scalar_index(*p);
        assert!(
            (g - want).abs() <= 1e-5,
            "channel {c} at {p}: {g} vs {want}"
        );
    }
}

/// Every level of detail covers the finest level's box on the device too: Woodcock and N-DDA
/// through the pool at coarser levels of a constant medium give the level-0 CPU marcher's
/// alpha (Beer-Lambert along each ray) within the Monte Carlo error. Rays clipped to a
/// coarse level's own voxel box, or walks that stop at its faces, lose a rim of
/// (2^L - 1) / 2 fine voxels.
#[test]
fn every_level_of_a_constant_medium_covers_the_finest_box_on_the_device() {
    let Some(ctx) = own_context() else { return };
    let dir = tempfile::tempdir().unwrap();
    let g = Grid::from_fn(Geometry::unit([64, 45, 40]), |_, _, _| 0.5).unwrap();
    let f = bricked(dir.path(), "c", &g, 1 << 24);
    let s = scene_of(vec![Field::from(f.field(0).unwrap())]);
    let mut set = RenderSettings::default_for(&s, 24, 20, true);
    set.jitter_pixels = false;
    let alpha = |img: &image::Rgba32FImage| -> Vec<f64> {
        img.pixels().map(|p| f64::from(p.0[3])).collect()
    };
    let a0 = alpha(&render(&s, &Integrator::Marcher(RayMarcher::default()), &set).unwrap());
    let want: f64 = a0.iter().sum();
    assert!(want > 50.0, "a trivial image: {want}");
    let t = GpuTracker::new(&ctx).unwrap();
    for level in 1..f.levels().min(3) {
        let view = s.at_level(level).unwrap();
        assert_eq!(view.bounds(), s.bounds());
        let gs = t.upload(view).unwrap();
        for m in [
            Integrator::Woodcock { channel: 0 },
            Integrator::Mdwt {
                dda: blueshift_tracking::DdaMode::NDda,
                blend: blueshift_tracking::Blend::Density,
            },
        ] {
            let mut st = set.clone();
            st.spp = 64;
            st.seed = 5;
            let got: f64 = alpha(&t.render(&gs, &m, &st).unwrap()).iter().sum();
            let se = a0.iter().map(|v| v * (1.0 - v) / 64.0).sum::<f64>().sqrt();
            assert!(
                (got - want).abs() < 5.0 * se,
                "{m:?} level {level}: {got} vs {want} (se {se})"
            );
        }
    }
}
