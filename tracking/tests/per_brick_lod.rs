//! Levels of detail per brick (`--lod brick`, `BrickedField::per_region`, HDR VolVis 6.3):
//! the rule gives nearer bricks finer levels (never coarser than a farther brick's), an
//! orthographic view gives every brick the per-view level, a perspective view from a
//! corner reads level-0 bricks only where the map says level 0, every sample of the mapped
//! field lies inside its widened macrocell (what majorants rely on), Woodcock tracking of
//! the mapped field agrees with the marcher's image of it, and a map of level 0 everywhere
//! renders the base level's bytes.

mod common;

use blueshift_camera::{Camera, Projection};
use blueshift_tracking::{Integrator, RayMarcher, RenderSettings, Scene, render};
use blueshift_volume::ooc::{self, BrickLayout, BrickedFile, GridSource};
use blueshift_volume::{AnyGrid, BrickCache, BrickedField, Field, Grid, lod_level, synth};
use common::tf;
use glam::Vec3;

/// The 96^3 turbulence as a `.bsv` of 16^3 bricks (6^3 regions; levels 96, 48, 24, 12),
/// through a cache of `budget` bytes, with the dense grid.
fn volume(dir: &std::path::Path, budget: usize) -> (Grid<f32>, BrickedField) {
    let AnyGrid::F32(g) = synth::turbulence(96, 5)
        .unwrap()
        .into_channels()
        .remove(0)
        .grid
    else {
        panic!("f32")
    };
    let p = dir.join("t.bsv");
    ooc::convert(
        &mut GridSource(&g),
        &p,
        "t",
        BrickLayout {
            brick: 16,
            apron: 1,
        },
        &mut |_, _| {},
    )
    .unwrap();
    let f = BrickedFile::open_with_cache(&p, BrickCache::new(budget)).unwrap();
    (g, f.field(0).unwrap())
}

/// A perspective camera near the (0, 0, 0) corner looking across the volume.
fn corner_camera(b: &BrickedField) -> Camera {
    let (lo, hi) = b.geometry().world_bounds();
    let d = hi - lo;
    Camera {
        eye: lo - 0.08 * d,
        target: lo + 0.6 * d,
        up: Vec3::Y,
        projection: Projection::Perspective { fov_y_deg: 50.0 },
    }
}

fn mapped(b: &BrickedField, cam: &Camera, height: u32) -> BrickedField {
    let g = b.source().geometries().to_vec();
    b.per_region(|lo, hi| lod_level(&g, cam.pixel_footprint(lo, hi, height)))
        .unwrap()
}

fn scene(f: BrickedField) -> Scene {
    Scene::new(
        vec![(
            "t".to_owned(),
            Field::from(f),
            tf([1.0, 0.6, 0.3], &[(0.0, 0.0), (1.0, 1.0)]),
        )],
        20.0,
        4,
    )
    .unwrap()
}

#[test]
fn nearer_bricks_are_finer_and_far_ones_are_read_coarse() {
    let dir = tempfile::tempdir().unwrap();
    let (_, b) = volume(dir.path(), 1 << 26);
    let cam = corner_camera(&b);
    // 24 pixels high: a pixel spans a level-0 voxel about half a box from the eye.
    let height = 24;
    let m = mapped(&b, &cam, height);
    let map = m.level_map().unwrap();
    let hist = map.histogram();
    assert!(hist.len() >= 3 && hist[0] > 0, "levels per brick {hist:?}");
    // The rule is monotone in the distance from the eye to each brick.
    let geo = *b.geometry();
    let dist: Vec<f32> = (0..216)
        .map(|i| {
            let r = [i % 6, (i / 6) % 6, i / 36];
            let lo = geo.index_to_world(Vec3::from(r.map(|c| (c * 16) as f32)));
            let hi = geo.index_to_world(Vec3::from(r.map(|c| (c * 16 + 15) as f32)));
            (cam.eye.clamp(lo, hi) - cam.eye).length()
        })
        .collect();
    let lv = map.levels();
    for i in 0..216 {
        for j in 0..216 {
            if dist[i] < dist[j] {
                assert!(lv[i] <= lv[j], "brick {i} nearer than {j} but coarser");
            }
        }
    }
    // Rendering reads level-0 bricks only for regions of level 0 (a brick's apron holds
    // the neighbours a sample needs), and far regions at coarser levels.
    let s = scene(m.clone());
    let mut st = RenderSettings::default_for(&s, 24, 24, false);
    st.camera = cam;
    st.spp = 1;
    // On one thread, so each read is of a distinct brick: two threads that miss the same
    // brick at once both read it (the cache reads outside its lock), counting it twice.
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    m.cache().reset_stats();
    one.install(|| render(&s, &Integrator::Marcher(RayMarcher::default()), &st))
        .unwrap();
    let reads = m.cache().stats().reads;
    assert!(
        reads[0] > 0 && reads[0] as usize <= hist[0],
        "{reads:?} {hist:?}"
    );
    assert!(reads.iter().skip(1).any(|&r| r > 0), "{reads:?}");
    // Exact reads every level-0 brick a ray meets: more than the map's.
    b.cache().clear();
    b.cache().reset_stats();
    one.install(|| {
        render(
            &scene(b.clone()),
            &Integrator::Marcher(RayMarcher::default()),
            &st,
        )
    })
    .unwrap();
    let exact = b.cache().stats().reads[0];
    eprintln!("per brick: regions per level {hist:?}, reads per level {reads:?}; exact: {exact}");
    assert!(exact > reads[0], "exact {exact} vs per-brick {}", reads[0]);
}

#[test]
fn an_orthographic_view_gives_every_brick_the_per_view_level() {
    let dir = tempfile::tempdir().unwrap();
    let (_, b) = volume(dir.path(), 1 << 26);
    let (lo, hi) = b.geometry().world_bounds();
    let g = b.source().geometries().to_vec();
    for height in [24, 48, 96, 400] {
        let cam = Camera::default_view(lo, hi, 1.0, true);
        let want = lod_level(&g, cam.pixel_footprint(lo, hi, height));
        let m = mapped(&b, &cam, height);
        let map = m.level_map().unwrap();
        assert!(
            map.levels().iter().all(|&l| usize::from(l) == want),
            "height {height}: {:?} vs {want}",
            map.histogram()
        );
    }
}

#[test]
fn every_sample_lies_in_its_widened_macrocell_and_woodcock_agrees_with_the_marcher() {
    let dir = tempfile::tempdir().unwrap();
    let (_, b) = volume(dir.path(), 1 << 26);
    let m = mapped(&b, &corner_camera(&b), 24);
    assert!(m.level_map().unwrap().histogram().len() >= 3);
    let cells = m.macrocells(4).unwrap();
    let n = b.geometry().dims;
    // Fixed-seed points over the whole volume.
    let mut x = 0x9e37_79b9_7f4a_7c15u64;
    let mut next = || {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        (x >> 40) as f32 / (1u64 << 24) as f32
    };
    for _ in 0..20_000 {
        let p = Vec3::new(next(), next(), next()) * Vec3::from(n.map(|d| (d - 1) as f32));
        let v = m.sample_index(p);
        let c = [p.x, p.y, p.z].map(|c| ((c / 4.0) as usize).min(23));
        let (lo, hi) = cells.min_max(c);
        assert!(lo <= v && v <= hi, "{v} outside [{lo}, {hi}] at {p}");
    }
    // Woodcock tracking (unbiased when the majorants bound) against the marcher at a fine
    // step: image means within 2 % (independent estimates of the same integral).
    let s = scene(m);
    let mut st = RenderSettings::default_for(&s, 24, 24, false);
    st.camera = corner_camera(&b);
    st.spp = 256;
    st.seed = 3;
    let wood = render(&s, &Integrator::Woodcock { channel: 0 }, &st).unwrap();
    st.spp = 1;
    let march = render(
        &s,
        &Integrator::Marcher(RayMarcher {
            step: Some(0.002),
            ..RayMarcher::default()
        }),
        &st,
    )
    .unwrap();
    let mean = |img: &image::Rgba32FImage| {
        img.pixels().map(|p| f64::from(p.0[0])).sum::<f64>() / f64::from(24 * 24)
    };
    let (a, c) = (mean(&wood), mean(&march));
    assert!(c > 0.05, "a trivial image: {c}");
    assert!((a - c).abs() <= 0.02 * c, "woodcock {a} marcher {c}");
}

#[test]
fn a_map_of_level_zero_renders_the_base_bytes() {
    let dir = tempfile::tempdir().unwrap();
    let (_, b) = volume(dir.path(), 1 << 26);
    let m = b.per_region(|_, _| 0).unwrap();
    assert_eq!(m.level_map().unwrap().histogram(), vec![216]);
    let (s0, s1) = (scene(b), scene(m));
    let mut st = RenderSettings::default_for(&s0, 32, 32, false);
    st.spp = 1;
    let integ = Integrator::Marcher(RayMarcher::default());
    let a = render(&s0, &integ, &st).unwrap();
    let c = render(&s1, &integ, &st).unwrap();
    assert_eq!(a.as_raw(), c.as_raw());
}
