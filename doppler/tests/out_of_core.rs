//! A Doppler scene whose fields are `.bsv` files read through a small brick cache renders
//! the same XYZ bytes as the scene in memory (piecewise-linear, banded, with absorption,
//! the black body's derived emission bricks and a velocity given as three components), and
//! its spectral cube is the same too, and so is the image with the mean velocity
//! subtracted.

use blueshift_doppler::{
    CubeSpec, DopplerImage, DopplerScene, DopplerSettings, Species, SpectralAxis,
    SpectralIntegrator, render_cube, render_doppler, render_doppler_lod,
};
use blueshift_spectrum::Catalogue;
use blueshift_volume::ooc::{self, BrickLayout, BrickedFile, GridSource};
use blueshift_volume::{AnyGrid, BrickCache, Field, Grid, VectorField, synth};

fn scalar(v: &blueshift_volume::Volume, name: &str) -> Grid<f32> {
    match &v.channel(name).unwrap().grid {
        AnyGrid::F32(g) => g.clone(),
        _ => panic!("f32"),
    }
}

#[test]
fn bricked_fields_render_the_in_core_bytes() {
    let vol = synth::galaxy(32, 2).unwrap();
    let (hi, temp) = (scalar(&vol, "hi_density"), scalar(&vol, "temperature_k"));
    let AnyGrid::Vec3(vel) = &vol.channel("velocity_m_per_s").unwrap().grid else {
        panic!("vector")
    };
    let g = *hi.geometry();
    let comp = |a: usize| Grid::from_vec(g, vel.data().iter().map(|v| v[a]).collect()).unwrap();
    let dir = tempfile::tempdir().unwrap();
    // Room for 8 of the 32 bricks per field: evictions all along.
    let cache = BrickCache::new(8 * 10 * 10 * 10 * 4);
    let brick = |name: &str, grid: &Grid<f32>| -> Field {
        let p = dir.path().join(format!("{name}.bsv"));
        ooc::convert(
            &mut GridSource(grid),
            &p,
            name,
            BrickLayout { brick: 8, apron: 1 },
            &mut |_, _| {},
        )
        .unwrap();
        BrickedFile::open_with_cache(&p, cache.clone())
            .unwrap()
            .field(0)
            .unwrap()
            .into()
    };
    let lines = Catalogue::HydrogenBalmer.lines();
    let build = |density: Field, t: Field, v: VectorField| {
        let mut s = DopplerScene::new(g).unwrap();
        s.add_species(Species {
            name: "H".into(),
            density: density.clone(),
            emission_lines: lines.clone(),
            absorption_lines: lines.clone(),
        })
        .unwrap();
        s.set_blackbody(density, t).unwrap();
        s.set_velocity(v).unwrap();
        s.factors.blackbody = 1e-3;
        s.factors.velocity = 20.0;
        s
    };
    let dense = build(hi.clone().into(), temp.clone().into(), vel.clone().into());
    let bricked = build(
        brick("hi", &hi),
        brick("t", &temp),
        VectorField::Components(Box::new([
            brick("vx", &comp(0)),
            brick("vy", &comp(1)),
            brick("vz", &comp(2)),
        ])),
    );
    for (integrator, absorption) in [
        (SpectralIntegrator::PiecewiseLinear, 0.0),
        (SpectralIntegrator::PiecewiseLinear, 0.5),
        ("banded:16".parse().unwrap(), 0.0),
    ] {
        let (mut a, mut b) = (dense.clone(), bricked.clone());
        a.factors.absorption = absorption;
        b.factors.absorption = absorption;
        let mut st = DopplerSettings::default_for(&a, 12, 10);
        st.integrator = integrator;
        let x = render_doppler(&a, &st, &|| {}).unwrap();
        let y = render_doppler(&b, &st, &|| {}).unwrap();
        assert_eq!(x.xyz, y.xyz, "{integrator:?} absorption {absorption}");
    }
    // The bulk motion subtracted: component files are averaged streaming and shifted
    // brick by brick, the same bytes as in memory.
    let (mut a, mut b) = (dense.clone(), bricked.clone());
    a.subtract_mean_velocity().unwrap();
    b.subtract_mean_velocity().unwrap();
    let st = DopplerSettings::default_for(&a, 12, 10);
    let (x, y) = (
        render_doppler(&a, &st, &|| {}).unwrap(),
        render_doppler(&b, &st, &|| {}).unwrap(),
    );
    assert_eq!(x.xyz, y.xyz, "subtract_mean_velocity");
    let plain = render_doppler(&dense, &st, &|| {}).unwrap();
    assert_ne!(
        plain.xyz, x.xyz,
        "the mean velocity is not zero: the image changes"
    );
    let mut st = DopplerSettings::default_for(&dense, 8, 8);
    st.camera =
        blueshift_camera::Camera::default_view(g.world_bounds().0, g.world_bounds().1, 1.0, true);
    let spec = CubeSpec {
        rest_nm: 656.28,
        axis: SpectralAxis::OpticalVelocity,
        min: -3e5,
        max: 3e5,
        channels: 12,
        line_width: Default::default(),
    };
    let (x, y) = (
        render_cube(&dense, &st, &spec, &|| {}).unwrap(),
        render_cube(&bricked, &st, &spec, &|| {}).unwrap(),
    );
    assert_eq!(x.data, y.data);
    assert!(cache.stats().peak_bytes <= cache.budget());
}

#[test]
fn progressive_levels_run_coarse_to_fine_and_end_on_the_exact_image() {
    use std::sync::Mutex;
    let vol = synth::galaxy(48, 3).unwrap();
    let hi = scalar(&vol, "hi_density");
    let g = *hi.geometry();
    let dir = tempfile::tempdir().unwrap();
    let cache = BrickCache::new(64 << 20);
    let p = dir.path().join("hi.bsv");
    ooc::convert(
        &mut GridSource(&hi),
        &p,
        "hi",
        BrickLayout { brick: 8, apron: 1 },
        &mut |_, _| {},
    )
    .unwrap();
    let f = BrickedFile::open_with_cache(&p, cache.clone()).unwrap();
    let levels = f.levels();
    assert!(levels >= 3, "{levels} levels");
    let density: Field = f.field(0).unwrap().into();
    let mut scene = DopplerScene::new(g).unwrap();
    scene
        .add_species(Species {
            name: "H".into(),
            density,
            emission_lines: Catalogue::HydrogenBalmer.lines(),
            absorption_lines: Catalogue::HydrogenBalmer.lines(),
        })
        .unwrap();
    let st = DopplerSettings::default_for(&scene, 16, 12);
    #[derive(Default)]
    struct Log {
        events: Mutex<Vec<(char, u32, usize)>>,
        images: Mutex<Vec<Vec<[f64; 3]>>>,
    }
    impl blueshift_camera::Observer<DopplerImage> for Log {
        fn level(&self, pass: u32, level: usize) {
            self.events.lock().unwrap().push(('l', pass, level));
        }
        fn pass(&self, pass: u32, image: &DopplerImage, _: Option<f64>) {
            self.events.lock().unwrap().push(('p', pass, 0));
            self.images.lock().unwrap().push(image.xyz.clone());
        }
    }
    for target in [0, 1] {
        let log = Log::default();
        let img = render_doppler_lod(&scene, &st, target, &log).unwrap();
        // Every level from the coarsest down to the target, each announced then delivered.
        let ev = log.events.into_inner().unwrap();
        let want: Vec<(char, u32, usize)> = (target..levels)
            .rev()
            .enumerate()
            .flat_map(|(i, l)| [('l', i as u32 + 1, l), ('p', i as u32 + 1, 0)])
            .collect();
        assert_eq!(ev, want, "target {target}");
        // Each pass is the plain render of its level, the last one the target's.
        let images = log.images.into_inner().unwrap();
        for (i, l) in (target..levels).rev().enumerate() {
            let plain = render_doppler(&scene.at_level(l).unwrap(), &st, &|| {}).unwrap();
            assert_eq!(images[i], plain.xyz, "pass {} level {l}", i + 1);
        }
        let exact = render_doppler(&scene.at_level(target).unwrap(), &st, &|| {}).unwrap();
        assert_eq!(img.xyz, exact.xyz);
    }
    assert!(render_doppler_lod(&scene, &st, levels, &blueshift_camera::Silent).is_err());
}

/// Every level of detail covers the finest level's box: the emission of a constant medium
/// (no absorption, no motion) is its path length through the box, the same at every level,
/// and the line-of-sight camera of a cube (its WCS) is the same. Clipped to a coarse
/// level's own voxel box, paths were (2^L - 1) / 2 fine voxels shorter at each face.
#[test]
fn every_level_of_a_constant_medium_covers_the_finest_box() {
    let g = blueshift_volume::Geometry::unit([32, 29, 24]);
    let grid = Grid::from_fn(g, |_, _, _| 1.0).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("n.bsv");
    ooc::convert(
        &mut GridSource(&grid),
        &p,
        "n",
        BrickLayout { brick: 8, apron: 1 },
        &mut |_, _| {},
    )
    .unwrap();
    let f = BrickedFile::open(&p, 256).unwrap();
    let mut scene = DopplerScene::new(g).unwrap();
    scene
        .add_species(Species {
            name: "H".into(),
            density: f.field(0).unwrap().into(),
            emission_lines: Catalogue::HydrogenBalmer.lines(),
            absorption_lines: Vec::new(),
        })
        .unwrap();
    let st = DopplerSettings::default_for(&scene, 20, 16);
    let y = |s: &DopplerScene| -> Vec<f64> {
        render_doppler(s, &st, &|| {})
            .unwrap()
            .xyz
            .iter()
            .map(|p| p[1])
            .collect()
    };
    let y0 = y(&scene);
    let lit = y0.iter().filter(|v| **v > 0.0).count();
    assert!(
        lit > 50 && lit < y0.len(),
        "the box fills part of the view: {lit}"
    );
    let peak = y0.iter().copied().fold(0.0, f64::max);
    let normal = glam::Vec3::new(0.3, -0.5, 1.0);
    for level in 1..f.levels().min(4) {
        let coarse = scene.at_level(level).unwrap();
        assert_eq!(
            coarse.frame_bounds(false),
            scene.frame_bounds(false),
            "level {level}"
        );
        assert_eq!(
            DopplerSettings::default_for(&coarse, 20, 16).camera,
            st.camera
        );
        for cells in [false, true] {
            assert_eq!(
                blueshift_doppler::los_camera(&coarse, normal, 1.25, cells).unwrap(),
                blueshift_doppler::los_camera(&scene, normal, 1.25, cells).unwrap(),
                "level {level} cell domain {cells}"
            );
        }
        let worst = y0
            .iter()
            .zip(y(&coarse))
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        assert!(worst < 1e-4 * peak, "level {level}: {worst} of {peak}");
    }
}
