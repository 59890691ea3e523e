//! Out-of-core channels (`.bsv` through a bounded brick cache) against the same channels in
//! memory: the finest level renders the same bytes for every method, memory stays under the
//! cache budget, a zoomed-out view reads coarse bricks only, and a corrupt brick is an error
//! at render time.

mod common;

use blueshift_tracking::scene_file::{ChannelSpec, Preloaded, RenderSceneFile};
use blueshift_tracking::{Blend, DdaMode, Integrator, RayMarcher, RenderSettings, Scene, render};
use blueshift_volume::ooc::{self, BrickLayout, BrickedFile, GridSource};
use blueshift_volume::{AnyGrid, BrickCache, Field, Grid, synth};
use common::tf;

/// Two channels of the turbulence and three-cubes datasets at 40^3 as grids and as `.bsv`
/// files (bricks of 8, so a ray crosses many bricks), read through one cache of `budget`.
fn channels(
    dir: &std::path::Path,
    budget: usize,
) -> (Vec<AnyGrid>, Vec<Field>, std::sync::Arc<BrickCache>) {
    let a = synth::turbulence(40, 3)
        .unwrap()
        .into_channels()
        .remove(0)
        .grid;
    let b = synth::three_cubes(40)
        .unwrap()
        .into_channels()
        .remove(0)
        .grid;
    let cache = BrickCache::new(budget);
    let mut fields = Vec::new();
    for (i, g) in [&a, &b].into_iter().enumerate() {
        let AnyGrid::F32(g) = g else {
            panic!("f32 synth")
        };
        let p = dir.join(format!("c{i}.bsv"));
        ooc::convert(
            &mut GridSource(g),
            &p,
            "c",
            BrickLayout { brick: 8, apron: 1 },
            &mut |_, _| {},
        )
        .unwrap();
        let f = BrickedFile::open_with_cache(&p, cache.clone()).unwrap();
        fields.push(Field::from(f.field(0).unwrap()));
    }
    (vec![a, b], fields, cache)
}

fn scene<F: Into<Field>>(chs: Vec<F>) -> Scene {
    let t = [
        tf([1.0, 0.5, 0.2], &[(0.0, 0.0), (1.0, 1.0)]),
        tf([0.2, 0.6, 1.0], &[(0.0, 0.0), (1.0, 1.0)]),
    ];
    let triples = chs
        .into_iter()
        .zip(t)
        .enumerate()
        .map(|(i, (g, t))| (format!("c{i}"), g, t))
        .collect();
    Scene::new(triples, 30.0, 4).unwrap()
}

#[test]
fn the_finest_level_renders_the_in_core_bytes_for_every_method_within_the_budget() {
    let dir = tempfile::tempdir().unwrap();
    // 6 bricks of 10^3 f32 (24 KB): far fewer than the 2 x 125 bricks of level 0.
    let budget = 6 * 10 * 10 * 10 * 4;
    let (dense, bricked, cache) = channels(dir.path(), budget);
    let (a, b) = (scene(dense), scene(bricked));
    for (x, y) in a.channels().iter().zip(b.channels()) {
        assert_eq!(
            x.macrocells(),
            y.macrocells(),
            "stored macrocells equal built ones"
        );
    }
    let methods = [
        Integrator::Woodcock { channel: 0 },
        Integrator::Mdwt {
            dda: DdaMode::NDda,
            blend: Blend::Density,
        },
        Integrator::Mdwt {
            dda: DdaMode::OneDda,
            blend: Blend::Max,
        },
        Integrator::Mdwt {
            dda: DdaMode::Summed,
            blend: Blend::Density,
        },
        Integrator::Marcher(RayMarcher::default()),
    ];
    for m in methods {
        let mut s = RenderSettings::default_for(&a, 20, 14, false);
        s.spp = 2;
        s.seed = 7;
        let x = render(&a, &m, &s).unwrap();
        let y = render(&b, &m, &s).unwrap();
        assert_eq!(x.as_raw(), y.as_raw(), "{m:?}");
    }
    let st = cache.stats();
    assert!(st.total_reads() > 6, "the budget forced re-reads: {st:?}");
    assert!(
        st.peak_bytes <= budget,
        "peak {} over the budget {budget}",
        st.peak_bytes
    );
}

#[test]
fn a_zoomed_out_view_reads_coarse_bricks_only_and_converges_as_the_level_refines() {
    let dir = tempfile::tempdir().unwrap();
    let g = Grid::from_fn(blueshift_volume::Geometry::unit([64, 64, 64]), |x, y, z| {
        let d = ((x as f32 - 32.0).powi(2) + (y as f32 - 32.0).powi(2) + (z as f32 - 32.0).powi(2))
            .sqrt();
        (1.0 - d / 30.0).max(0.0)
    })
    .unwrap();
    let p = dir.path().join("ball.bsv");
    ooc::convert(
        &mut GridSource(&g),
        &p,
        "ball",
        BrickLayout { brick: 8, apron: 1 },
        &mut |_, _| {},
    )
    .unwrap();
    let file = |lod: &str, zoom: f32| RenderSceneFile {
        channels: vec![ChannelSpec {
            volume: Some(p.clone()),
            tf: "builtin:viridis".into(),
            ..ChannelSpec::default()
        }],
        method: Some("marcher".parse().unwrap()),
        width: Some(16),
        height: Some(16),
        zoom: Some(zoom),
        density_scale: Some(0.05),
        lod: Some(lod.into()),
        ..RenderSceneFile::default()
    };
    let run = |lod: &str, zoom: f32| {
        let cache = BrickCache::new(64 << 20);
        let memory = Preloaded {
            cache: Some(cache.clone()),
            ..Preloaded::default()
        };
        let (scene, m, s) = file(lod, zoom).build_with(&memory).unwrap();
        let level = scene.channels()[0].grid().as_bricked().unwrap().level();
        (render(&scene, &m, &s).unwrap(), level, cache.stats())
    };
    // 16 pixels over a view ten times wider than the ball: a pixel is ~40 voxels.
    let (_, level, st) = run("auto", 0.1);
    assert!(level >= 3, "auto picked level {level}");
    assert_eq!(
        st.reads[..level].iter().sum::<u64>(),
        0,
        "finer bricks read: {st:?}"
    );
    assert!(st.total_reads() > 0);
    // Close up, auto is exact.
    assert_eq!(
        run("auto", 8.0).1,
        0,
        "zoomed in, a pixel is under a voxel: the finest level"
    );
    // Levels 3, 2, 1, 0 of the same view get closer and closer to the exact image.
    let exact = run("exact", 1.0).0;
    let err = |l: usize| {
        let img = run(&l.to_string(), 1.0).0;
        img.as_raw()
            .iter()
            .zip(exact.as_raw())
            .map(|(a, b)| f64::from((a - b).abs()))
            .sum::<f64>()
    };
    let e: Vec<f64> = (0..4).map(err).collect();
    assert_eq!(e[0], 0.0);
    assert!(e[1] < e[2] && e[2] < e[3], "{e:?}");
}

#[test]
fn a_corrupt_brick_is_an_error_at_render_time_not_a_panic() {
    let dir = tempfile::tempdir().unwrap();
    let (_, bricked, _) = channels(dir.path(), 1 << 20);
    let sc = scene(bricked);
    // Corrupt every brick of channel 0's level 0 after the scene is built.
    let p = dir.path().join("c0.bsv");
    let mut bytes = std::fs::read(&p).unwrap();
    for b in &mut bytes[4096..4096 + 125 * 4000] {
        *b ^= 0x5a;
    }
    std::fs::write(&p, &bytes).unwrap();
    let mut s = RenderSettings::default_for(&sc, 8, 8, false);
    s.spp = 1;
    let m = Integrator::Mdwt {
        dda: DdaMode::OneDda,
        blend: Blend::Density,
    };
    let e = render(&sc, &m, &s).unwrap_err().to_string();
    assert!(e.contains("corrupt") || e.contains("brick"), "{e}");
    // A file truncated under the open scene: a read error, again no panic.
    std::fs::write(&p, &bytes[..5000]).unwrap();
    let e = render(&sc, &m, &s).unwrap_err().to_string();
    assert!(
        e.contains("truncated") && e.contains("brick") && e.contains("c0.bsv"),
        "names the file: {e}"
    );
}

#[test]
fn progressive_lod_previews_coarse_levels_then_gives_the_plain_render() {
    use blueshift_tracking::{Progressive, TrackingSession};
    use std::sync::Mutex;
    let dir = tempfile::tempdir().unwrap();
    let (_, bricked, _) = channels(dir.path(), 64 << 20);
    let s = scene(bricked);
    let (level, count) = s.lod().expect("bricked alike");
    assert_eq!((level, count), (0, 4), "40^3 in bricks of 8: 40, 20, 10, 5");
    let mut st = RenderSettings::default_for(&s, 16, 12, false);
    st.spp = 3;
    #[derive(Default)]
    struct Log(Mutex<Vec<(char, u32, usize)>>);
    impl blueshift_camera::Observer<Progressive> for Log {
        fn level(&self, step: u32, level: usize) {
            self.0.lock().unwrap().push(('l', step, level));
        }
        fn pass(&self, pass: u32, _: &Progressive, _: Option<f64>) {
            self.0.lock().unwrap().push(('p', pass, 0));
        }
    }
    for from in [0, 2] {
        let s = s.at_level(from).unwrap();
        let session =
            TrackingSession::new(s.clone(), Integrator::Woodcock { channel: 0 }, st.clone())
                .unwrap();
        let log = Log::default();
        let out = session.render_lod(&log).unwrap();
        let plain = session.render(&blueshift_camera::Silent).unwrap();
        assert_eq!(
            out.image.mean_image().as_raw(),
            plain.image.mean_image().as_raw(),
            "from level {from}"
        );
        // One preview pass per coarser level, coarsest first, then the render's own passes.
        let mut want = Vec::new();
        for (i, l) in (from + 1..count).rev().enumerate() {
            want.extend([('l', i as u32 + 1, l), ('p', i as u32 + 1, 0)]);
        }
        want.push(('l', (count - from) as u32, from));
        want.extend((1..=3).map(|p| ('p', p, 0)));
        assert_eq!(log.0.into_inner().unwrap(), want, "from level {from}");
    }
    assert!(s.at_level(count).is_err());
}

/// Residency-driven levels (HDR VolVis 6.3, refining while bricks load): with nothing
/// cached every region samples the coarsest level; with the finest level's bricks of one
/// half of the volume read, exactly the regions whose centres lie in those bricks sample
/// the finest level, and their samples are the finest level's.
#[test]
fn resident_regions_follow_what_the_cache_holds() {
    let dir = tempfile::tempdir().unwrap();
    let (_, bricked, cache) = channels(dir.path(), 64 << 20);
    let b = bricked[0].as_bricked().unwrap().clone();
    let coarsest = b.levels() - 1;
    cache.clear();
    let (f, at0) = b.resident_regions().unwrap();
    assert_eq!(at0, 0);
    let map = f.level_map().unwrap();
    assert!(map.levels().iter().all(|&l| usize::from(l) == coarsest));
    // Read the finest bricks with x index below 2 (voxels 0..16 of 40), through samples.
    let n = b.brick_counts();
    assert_eq!(n, [5, 5, 5]);
    for z in 0..40 {
        for y in 0..40 {
            for x in 0..16 {
                let _ = b.sample_index(glam::Vec3::new(x as f32, y as f32, z as f32));
            }
        }
    }
    let (f, at0) = b.resident_regions().unwrap();
    assert_eq!(at0, 2 * 5 * 5, "two slabs of 5 x 5 bricks");
    let map = f.level_map().unwrap();
    for (i, &l) in map.levels().iter().enumerate() {
        let x = i % 5;
        assert_eq!(usize::from(l) == 0, x < 2, "region {i}: level {l}");
    }
    // A region at level 0 samples the finest level itself.
    let p = glam::Vec3::new(5.3, 17.6, 30.2);
    assert_eq!(f.sample_index(p).to_bits(), b.sample_index(p).to_bits());
    assert_eq!(f.coarsest_sampled_level(), coarsest);
    assert_eq!(f.resident_count(), 2 * 5 * 5);
    // From level 1 (20^3 in bricks of 8: 3^3 regions), levels are absolute: nothing of
    // level 1 is held yet, so every region reads the coarsest level.
    let b1 = b.at_level(1).unwrap();
    let (f1, at1) = b1.resident_regions().unwrap();
    assert_eq!((at1, b1.resident_count()), (0, 0));
    assert_eq!(f1.coarsest_sampled_level(), coarsest);
    assert_eq!(b1.coarsest_sampled_level(), 1);
}

/// Brick-by-brick progressive: a coarsest-level pass, quick passes over whatever has
/// loaded, then the plain render's bytes; the steps are numbered in order and every quick
/// step before the last samples a coarser level somewhere.
#[test]
fn brick_progressive_ends_on_the_plain_render() {
    let dir = tempfile::tempdir().unwrap();
    let (_, bricked, cache) = channels(dir.path(), 64 << 20);
    let s = scene(bricked);
    let (_, count) = s.lod().unwrap();
    let mut st = RenderSettings::default_for(&s, 16, 12, false);
    st.spp = 3;
    // From the scene's level 1 too: steps report absolute levels, coarser than 1.
    for from in [0, 1] {
        let s = s.at_level(from).unwrap();
        let (level, _) = s.lod().unwrap();
        assert_eq!(level, from);
        brick_steps(&s, &st, &cache, count);
    }
}

fn brick_steps(s: &Scene, st: &RenderSettings, cache: &std::sync::Arc<BrickCache>, count: usize) {
    use blueshift_tracking::{Progressive, TrackingSession};
    use std::sync::Mutex;
    let (level, _) = s.lod().unwrap();
    #[derive(Default)]
    struct Log(Mutex<Vec<(char, u32, usize)>>);
    impl blueshift_camera::Observer<Progressive> for Log {
        fn level(&self, step: u32, level: usize) {
            self.0.lock().unwrap().push(('l', step, level));
        }
        fn pass(&self, pass: u32, _: &Progressive, _: Option<f64>) {
            self.0.lock().unwrap().push(('p', pass, 0));
        }
    }
    let session =
        TrackingSession::new(s.clone(), Integrator::Woodcock { channel: 0 }, st.clone()).unwrap();
    let plain = session.render(&blueshift_camera::Silent).unwrap();
    cache.clear();
    let log = Log::default();
    let mut steps = Vec::new();
    let out = session
        .render_bricks(&log, &mut |step, at, regions| {
            steps.push((step, at, regions))
        })
        .unwrap();
    assert_eq!(
        out.image.mean_image().as_raw(),
        plain.image.mean_image().as_raw()
    );
    let log = log.0.into_inner().unwrap();
    assert_eq!(log[0], ('l', 1, count - 1), "{log:?}");
    assert_eq!(log[1], ('p', 1, 0));
    let last_step = log.iter().filter(|e| e.0 == 'l').count() as u32;
    assert_eq!(log[log.len() - 4], ('l', last_step, level), "{log:?}");
    for (i, e) in log[2..log.len() - 4].chunks(2).enumerate() {
        let step = i as u32 + 2;
        assert_eq!(e[1], ('p', step, 0), "{log:?}");
        assert_eq!(e[0].1, step);
        assert!(
            e[0].2 > level,
            "a quick step samples coarser bricks somewhere"
        );
    }
    // The regions at the finest level never decrease while bricks load.
    for w in steps.windows(2) {
        assert!(w[1].1 > w[0].1, "{steps:?}");
    }
    let all: usize = s
        .channels()
        .iter()
        .map(|c| {
            c.grid()
                .as_bricked()
                .unwrap()
                .brick_counts()
                .iter()
                .product::<usize>()
        })
        .sum();
    assert_eq!(all, if level == 0 { 250 } else { 54 });
    assert!(
        steps
            .iter()
            .all(|&(_, at, regions)| at < regions && regions == all)
    );
}

/// The same volume in bricks of 8 (levels 64^3 .. 8^3, four) and of 16 (64^3 .. 16^3, three):
/// a level of detail is one both files have, whichever channel comes first, and
/// progressive refinement runs over the three levels they share.
#[test]
fn channels_in_different_brick_edges_share_their_common_levels() {
    let dir = tempfile::tempdir().unwrap();
    let g = Grid::from_fn(blueshift_volume::Geometry::unit([64, 64, 64]), |x, y, z| {
        ((x * 7 + y * 3 + z) % 17) as f32 / 17.0
    })
    .unwrap();
    let mut paths = Vec::new();
    for brick in [8, 16] {
        let p = dir.path().join(format!("b{brick}.bsv"));
        ooc::convert(
            &mut GridSource(&g),
            &p,
            "v",
            BrickLayout { brick, apron: 1 },
            &mut |_, _| {},
        )
        .unwrap();
        assert_eq!(
            BrickedFile::open(&p, 4).unwrap().levels(),
            if brick == 8 { 4 } else { 3 }
        );
        paths.push(p);
    }
    let file = |order: [usize; 2], lod: &str| RenderSceneFile {
        channels: order
            .iter()
            .map(|&i| ChannelSpec {
                volume: Some(paths[i].clone()),
                tf: "builtin:viridis".into(),
                ..ChannelSpec::default()
            })
            .collect(),
        method: Some("marcher".parse().unwrap()),
        width: Some(12),
        height: Some(12),
        density_scale: Some(0.05),
        lod: Some(lod.into()),
        ..RenderSceneFile::default()
    };
    for lod in ["3", "2", "auto"] {
        let mut images = Vec::new();
        for order in [[0, 1], [1, 0]] {
            let (scene, m, s) = file(order, lod).build().unwrap();
            let levels: Vec<usize> = scene
                .channels()
                .iter()
                .map(|c| c.grid().as_bricked().unwrap().level())
                .collect();
            assert_eq!(levels[0], levels[1], "--lod {lod}, order {order:?}");
            assert!(levels[0] <= 2, "a level both files have: {levels:?}");
            if lod != "auto" {
                assert_eq!(
                    levels[0], 2,
                    "--lod {lod}: level 2, the coarsest both files have"
                );
            }
            assert_eq!(scene.lod(), Some((levels[0], 3)));
            images.push(render(&scene, &m, &s).unwrap());
        }
        assert_eq!(images[0].as_raw(), images[1].as_raw(), "--lod {lod}");
    }
}

/// Every level of detail covers the finest level's box: a coarse level's voxel centres lie
/// up to half a coarse voxel inside it, and rays still cross the whole box (samples there
/// clamp to the edge voxels). A constant medium is the same at every level, so every
/// method's image of it must be the same at levels 1-3 as at level 0 (Beer-Lambert along
/// each ray: exact for the marcher, within the Monte Carlo error for the trackers). Clipped
/// to a coarse level's own voxel box, rays were (2^L - 1) / 2 fine voxels shorter at each
/// face and the box's rim went transparent.
#[test]
fn every_level_of_a_constant_medium_covers_the_finest_box() {
    let dir = tempfile::tempdir().unwrap();
    // Odd and even dims: a level's top face lies inside or outside the finest box.
    let g = Grid::from_fn(blueshift_volume::Geometry::unit([32, 29, 24]), |_, _, _| {
        1.0
    })
    .unwrap();
    let p = dir.path().join("c.bsv");
    ooc::convert(
        &mut GridSource(&g),
        &p,
        "c",
        BrickLayout { brick: 8, apron: 1 },
        &mut |_, _| {},
    )
    .unwrap();
    let f = BrickedFile::open(&p, 64).unwrap();
    let t = tf([1.0, 0.8, 0.6], &[(0.0, 0.5), (1.0, 0.5)]);
    let fine = Scene::new(
        vec![("c".to_string(), Field::from(f.field(0).unwrap()), t)],
        0.08,
        4,
    )
    .unwrap();
    // One view for every level: the finest scene's, seen from a corner so rays leave
    // through low and high faces alike.
    for ortho in [true, false] {
        let mut st = RenderSettings::default_for(&fine, 24, 20, ortho);
        st.jitter_pixels = false;
        let marcher = Integrator::Marcher(RayMarcher::default());
        let exact = render(&fine, &marcher, &st).unwrap();
        let alpha =
            |img: &image::Rgba32FImage| -> Vec<f32> { img.pixels().map(|p| p.0[3]).collect() };
        let a0 = alpha(&exact);
        let lit = a0.iter().filter(|a| **a > 0.01).count();
        assert!(
            lit > 100 && lit < a0.len(),
            "the box fills part of the view: {lit}"
        );
        for level in 1..f.levels().min(4) {
            let coarse = fine.at_level(level).unwrap();
            assert_eq!(coarse.bounds(), fine.bounds(), "level {level}");
            let al = alpha(&render(&coarse, &marcher, &st).unwrap());
            let worst = a0
                .iter()
                .zip(&al)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0f32, f32::max);
            assert!(worst < 2e-3, "marcher level {level} ortho {ortho}: {worst}");
            // Woodcock and N-DDA: the image's total alpha within 5 standard errors.
            for m in [
                Integrator::Woodcock { channel: 0 },
                Integrator::Mdwt {
                    dda: DdaMode::NDda,
                    blend: Blend::Density,
                },
            ] {
                let mut s = st.clone();
                s.spp = 64;
                s.seed = 11;
                let got: f64 = alpha(&render(&coarse, &m, &s).unwrap())
                    .iter()
                    .map(|&v| f64::from(v))
                    .sum();
                let want: f64 = a0.iter().map(|&v| f64::from(v)).sum();
                // Each pixel's alpha is a mean of 64 Bernoulli draws.
                let se: f64 = a0
                    .iter()
                    .map(|&v| f64::from(v) * (1.0 - f64::from(v)) / 64.0)
                    .sum::<f64>()
                    .sqrt();
                assert!(
                    (got - want).abs() < 5.0 * se,
                    "{m:?} level {level} ortho {ortho}: {got} vs {want} (se {se})"
                );
            }
        }
    }
}
