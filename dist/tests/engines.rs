//! Distributed renders against the single-process renders of the same scene, with 1 to 4
//! ranks of the in-process communicator: sample- and tile-parallel Monte Carlo bit for bit,
//! the data-parallel marcher and Doppler (without and with absorption) within stated
//! bounds, for views along each axis both ways and an oblique one; and an optically thick
//! absorber where compositing per-channel "RGB over" is visibly wrong.

use blueshift_camera::{Camera, View};
use blueshift_dist::render::{
    render_doppler_data, render_marcher_data, render_samples, render_tiles,
};
use blueshift_dist::{Decomposition, Strategy, ThreadWorld};
use blueshift_doppler::part::{optical_depth_part, render_doppler_part};
use blueshift_doppler::{DopplerScene, DopplerSettings, Species, render_doppler};
use blueshift_spectrum::EmissionLine;
use blueshift_tfedit::{ColorKnot, OpacityKnot, TransferFunction};
use blueshift_tracking::{
    Blend, DdaMode, Integrator, RayMarcher, RenderSettings, Scene, render_progressive,
};
use blueshift_volume::{AnyGrid, Geometry, Grid, synth};
use glam::Vec3;

fn tf(rgb: [f32; 3]) -> TransferFunction {
    TransferFunction::new(
        [0.0, 1.0],
        vec![ColorKnot { x: 0.0, rgb }, ColorKnot { x: 1.0, rgb }],
        vec![OpacityKnot::new(0.0, 0.0), OpacityKnot::new(1.0, 1.0)],
    )
    .unwrap()
}

fn three_cubes(res: usize, scale: f32) -> Scene {
    let vol = synth::three_cubes(res).unwrap();
    let tfs = [[1.0, 0.2, 0.0], [0.0, 1.0, 0.3], [0.2, 0.0, 1.0]]
        .map(tf)
        .to_vec();
    let mut s = Scene::from_volume(&vol, tfs, scale, 4).unwrap();
    s.background = [0.1, 0.2, 0.3];
    s
}

fn decomposition(geom: &Geometry, n: usize) -> Decomposition {
    let f = Strategy::auto(n).factors(n).unwrap();
    Decomposition::new(geom.dims, geom.origin, geom.spacing, &f).unwrap()
}

/// The views: along each axis both ways, and an oblique one.
fn views(lo: Vec3, hi: Vec3, orthographic: bool) -> Vec<Camera> {
    let mut v: Vec<Camera> = [
        View::X,
        View::NegX,
        View::Y,
        View::NegY,
        View::Z,
        View::NegZ,
    ]
    .into_iter()
    .map(|view| Camera::view_of(lo, hi, view, 1.0, orthographic))
    .collect();
    v.push(
        Camera::framing(
            lo,
            hi,
            Vec3::new(0.6, -0.5, 0.7),
            Vec3::Y,
            1.0,
            orthographic,
            35.0,
        )
        .unwrap(),
    );
    v
}

#[test]
fn sample_and_tile_parallel_tracking_is_bit_identical() {
    let scene = three_cubes(16, 6.0);
    let mut s = RenderSettings::default_for(&scene, 12, 9, false);
    s.spp = 5;
    s.seed = 1234;
    for integ in [
        Integrator::Woodcock { channel: 1 },
        Integrator::Mdwt {
            dda: DdaMode::OneDda,
            blend: Blend::Density,
        },
    ] {
        let single = render_progressive(&scene, &integ, &s, |_, _| {}).unwrap();
        for n in 1..=4 {
            for tiles in [false, true] {
                let got = ThreadWorld::run(n, |c| {
                    if tiles {
                        render_tiles(&c, &scene, &integ, &s).unwrap()
                    } else {
                        render_samples(&c, &scene, &integ, &s).unwrap()
                    }
                });
                let img = got[0].as_ref().unwrap();
                assert_eq!(
                    img.mean_image().as_raw(),
                    single.mean_image().as_raw(),
                    "n {n} tiles {tiles}"
                );
                for (x, y) in [(0, 0), (5, 4), (11, 8)] {
                    assert_eq!(img.variance(x, y), single.variance(x, y));
                }
                assert_eq!(img.noise(), single.noise());
            }
        }
        // Not vacuous: another seed changes the image.
        let mut other = s.clone();
        other.seed = 1235;
        let b = render_progressive(&scene, &integ, &other, |_, _| {}).unwrap();
        assert_ne!(b.mean_image().as_raw(), single.mean_image().as_raw());
    }
}

#[test]
fn data_parallel_marcher_equals_the_single_process_image() {
    let mut scene = three_cubes(20, 4.0);
    let geom = *scene.geometry();
    let (lo, hi) = scene.bounds();
    let integ = Integrator::Marcher(RayMarcher {
        early_termination: 1.0,
        ..RayMarcher::default()
    });
    for orthographic in [true, false] {
        for camera in views(lo, hi, orthographic) {
            let mut s = RenderSettings::default_for(&scene, 14, 14, orthographic);
            s.camera = camera;
            s.spp = 2;
            s.seed = 5;
            let single = render_progressive(&scene, &integ, &s, |_, _| {}).unwrap();
            let want = single.mean_image();
            let peak = want.as_raw().iter().fold(0.0f32, |a, &b| a.max(b));
            assert!(peak > 0.3, "the view shows something");
            for n in 1..=4 {
                let d = decomposition(&geom, n);
                let got = ThreadWorld::run(n, |c| {
                    let mut sc = scene.clone();
                    render_marcher_data(&c, &mut sc, &integ, &s, &d).unwrap()
                });
                let img = got[0].as_ref().unwrap().mean_image();
                // The single process composites step by step in f32; the pieces in f64:
                // a few f32 ulps per step of the colour's size (40 steps here at most).
                let worst = img
                    .as_raw()
                    .iter()
                    .zip(want.as_raw())
                    .map(|(a, b)| (a - b).abs())
                    .fold(0.0f32, f32::max);
                assert!(
                    worst <= 2e-5,
                    "n {n} ortho {orthographic} {camera:?}: {worst}"
                );
            }
        }
    }
    // The clip box is honoured: the pieces' images differ from the whole (not vacuous).
    let s = RenderSettings::default_for(&scene, 14, 14, true);
    let whole = render_progressive(&scene, &integ, &s, |_, _| {})
        .unwrap()
        .mean_image();
    scene.clip = Some(decomposition(&geom, 2).pieces()[0].clip);
    let part = render_progressive(&scene, &integ, &s, |_, _| {})
        .unwrap()
        .mean_image();
    assert_ne!(whole.as_raw(), part.as_raw());
}

#[test]
fn clip_box_is_refused_by_the_trackers() {
    let mut scene = three_cubes(8, 4.0);
    scene.clip = Some(blueshift_camera::ClipBox::ALL);
    let e = Integrator::Woodcock { channel: 0 }
        .prepared(&scene)
        .unwrap_err();
    assert!(e.to_string().contains("ray marcher only"), "{e}");
}

fn galaxy(absorption: f64) -> DopplerScene {
    let v = synth::galaxy(20, 3).unwrap();
    let mut scene = DopplerScene::from_volume(&v, &["bb", "H", "C"]).unwrap();
    scene.factors.velocity = 30.0;
    scene.factors.absorption = absorption;
    scene.factors.blackbody = 0.1;
    scene
}

fn compare_xyz(got: &[[f64; 3]], want: &[[f64; 3]], bound: &[[f64; 3]], what: &str) -> f64 {
    let mut worst = 0.0f64;
    for ((a, b), e) in got.iter().zip(want).zip(bound) {
        for c in 0..3 {
            let err = (a[c] - b[c]).abs();
            assert!(
                err <= e[c] + 1e-12 * b[c].abs() + 1e-300,
                "{what}: {a:?} vs {b:?} (bound {e:?})"
            );
            worst = worst.max(err / b[c].abs().max(1e-300));
        }
    }
    worst
}

#[test]
fn data_parallel_doppler_emission_adds_exactly() {
    let scene = galaxy(0.0);
    assert!(!scene.absorbs());
    let geom = *scene.geometry();
    let (lo, hi) = geom.world_bounds();
    for orthographic in [true, false] {
        for camera in views(lo, hi, orthographic) {
            let mut st = DopplerSettings::default_for(&scene, 10, 10);
            st.camera = camera;
            let single = render_doppler(&scene, &st, &|| {}).unwrap();
            let bound: Vec<[f64; 3]> = single.xyz.iter().map(|x| x.map(|v| 1e-12 * v)).collect();
            for n in 1..=4 {
                let d = decomposition(&geom, n);
                let got =
                    ThreadWorld::run(n, |c| render_doppler_data(&c, &scene, &st, &d).unwrap());
                let img = got[0].as_ref().unwrap();
                compare_xyz(&img.xyz, &single.xyz, &bound, &format!("n {n} {camera:?}"));
            }
        }
    }
}

#[test]
fn data_parallel_doppler_absorption_is_exact_within_the_merge_bound() {
    let scene = galaxy(5.0);
    let clear = galaxy(0.0);
    assert!(scene.absorbs());
    let geom = *scene.geometry();
    let (lo, hi) = geom.world_bounds();
    for tol in [0.0, 1e-3, 2e-2] {
        for orthographic in [true, false] {
            for camera in views(lo, hi, orthographic) {
                let mut st = DopplerSettings::default_for(&scene, 8, 8);
                st.camera = camera;
                st.merge_tolerance = tol;
                st.piece_budget = 1 << 20;
                let single = render_doppler(&scene, &st, &|| {}).unwrap();
                let emitted = render_doppler(&clear, &st, &|| {}).unwrap();
                // Both renders are within tol x the unattenuated emission of the exact image,
                // per channel: they differ by at most twice that (plus rounding).
                let bound: Vec<[f64; 3]> = emitted
                    .xyz
                    .iter()
                    .map(|x| x.map(|v| (2.0 * tol + 1e-9) * v))
                    .collect();
                for n in 1..=4 {
                    let d = decomposition(&geom, n);
                    let got =
                        ThreadWorld::run(n, |c| render_doppler_data(&c, &scene, &st, &d).unwrap());
                    let img = got[0].as_ref().unwrap();
                    compare_xyz(&img.xyz, &single.xyz, &bound, &format!("tol {tol} n {n}"));
                }
            }
        }
    }
}

/// An emitter at the back (low z) seen through a thick absorber at the front (high z) in
/// the same line, from the default view (+z): the absorber hides the line.
fn thick_absorber() -> DopplerScene {
    let geom = Geometry::unit([4, 4, 16]);
    let mut s = DopplerScene::new(geom).unwrap();
    let back = Grid::from_fn(geom, |_, _, z| if z < 8 { 1.0f32 } else { 0.0 }).unwrap();
    let front = Grid::from_fn(geom, |_, _, z| if z >= 8 { 1.0f32 } else { 0.0 }).unwrap();
    s.add_species(Species {
        name: "emitter".into(),
        density: AnyGrid::F32(back).into(),
        emission_lines: vec![EmissionLine::new(656.3, 1.0).unwrap()],
        absorption_lines: vec![],
    })
    .unwrap();
    s.add_species(Species {
        name: "absorber".into(),
        density: AnyGrid::F32(front).into(),
        emission_lines: vec![],
        absorption_lines: vec![EmissionLine::new(656.3, 4.0).unwrap()],
    })
    .unwrap();
    s.factors.absorption = 1.0;
    s
}

#[test]
fn optically_thick_absorber_exact_where_rgb_over_is_wrong() {
    let scene = thick_absorber();
    let geom = *scene.geometry();
    let mut st = DopplerSettings::default_for(&scene, 4, 4);
    st.merge_tolerance = 0.0;
    let single = render_doppler(&scene, &st, &|| {}).unwrap();
    let mut unabsorbed = scene.clone();
    unabsorbed.factors.absorption = 0.0;
    let emitted = render_doppler(&unabsorbed, &st, &|| {}).unwrap();
    // Centre pixels: the line's light is almost all absorbed (depth ~ 4 per voxel over 8
    // voxels), so the exact image is dark.
    let c = 5;
    assert!(
        single.xyz[c][1] < 1e-6 * emitted.xyz[c][1],
        "{:?} {:?}",
        single.xyz[c],
        emitted.xyz[c]
    );
    for n in 2..=4 {
        let d = decomposition(&geom, n);
        let got = ThreadWorld::run(n, |c| render_doppler_data(&c, &scene, &st, &d).unwrap());
        let img = got[0].as_ref().unwrap();
        let bound: Vec<[f64; 3]> = emitted.xyz.iter().map(|x| x.map(|v| 1e-9 * v)).collect();
        compare_xyz(&img.xyz, &single.xyz, &bound, &format!("n {n}"));
    }
    // "RGB over" with two pieces: the back piece's XYZ through the front piece's
    // per-channel transmittance (its depth's transmittance averaged with each CMF as the
    // weight: what an RGBA compositor keeps of a piece). The absorber takes a 1 nm line out
    // of a CMF ~100 nm wide, so nearly all the light comes through: visibly wrong.
    let d = decomposition(&geom, 2);
    let order = d.visibility_order(blueshift_dist::Viewpoint::of(&st.camera));
    let (front, back) = (&d.pieces()[order[0]], &d.pieces()[order[1]]);
    let back_img = render_doppler_part(&scene, &st, &back.clip, None).unwrap();
    let front_img = render_doppler_part(&scene, &st, &front.clip, None).unwrap();
    let depth = optical_depth_part(&scene, &st, &front.clip).unwrap();
    let cmf = blueshift_spectrum::Cmf::cie1931_2deg();
    let rgb_over: Vec<[f64; 3]> = (0..16)
        .map(|i| {
            let tau = |l: f64| {
                depth[i]
                    .iter()
                    .find(|p| p.start_nm <= l && l < p.end_nm)
                    .map_or(0.0, |p| p.at(l))
            };
            let (mut num, mut den) = ([0.0f64; 3], [0.0f64; 3]);
            let mut l = 360.0;
            while l < 830.0 {
                let w = cmf.eval(l);
                for c in 0..3 {
                    num[c] += w[c] * (-tau(l)).exp();
                    den[c] += w[c];
                }
                l += 0.01;
            }
            [0, 1, 2].map(|c| front_img.xyz[i][c] + num[c] / den[c] * back_img.xyz[i][c])
        })
        .collect();
    // The back piece alone is bright (a good part of the unabsorbed light: the absorber
    // reaches into it only through the interpolation across the face) ...
    assert!(back_img.xyz[c][1] > 0.1 * emitted.xyz[c][1]);
    // ... and "RGB over" lets nearly all of it through, where the exact image is dark.
    assert!(
        rgb_over[c][1] > 0.95 * back_img.xyz[c][1] && rgb_over[c][1] > 1e6 * single.xyz[c][1],
        "RGB over {:?}, back piece {:?}, exact {:?}",
        rgb_over[c],
        back_img.xyz[c],
        single.xyz[c]
    );
}

/// Tile-parallel Doppler images are the single-process image bit for bit (pixels and piece
/// statistics), for the piecewise-linear and banded integrators, with and without
/// absorption (each pixel's arithmetic does not depend on which rank runs it).
#[test]
fn tile_parallel_doppler_is_bit_identical() {
    use blueshift_dist::render::render_doppler_tiles;
    use blueshift_doppler::{BandShift, SpectralIntegrator};
    for absorption in [0.0, 5.0] {
        let scene = galaxy(absorption);
        for integrator in [
            SpectralIntegrator::PiecewiseLinear,
            SpectralIntegrator::Banded {
                bands: 200,
                shift: BandShift::EnergyConserving,
            },
        ] {
            let mut st = DopplerSettings::default_for(&scene, 9, 7);
            st.integrator = integrator;
            let single = render_doppler(&scene, &st, &|| {}).unwrap();
            for n in 1..=4 {
                let got = ThreadWorld::run(n, |c| render_doppler_tiles(&c, &scene, &st).unwrap());
                let img = got[0].as_ref().unwrap();
                assert!(got[1..].iter().all(Option::is_none));
                assert_eq!(
                    img.xyz, single.xyz,
                    "{integrator:?} absorption {absorption} n {n}"
                );
                assert_eq!(img.pieces, single.pieces);
            }
        }
    }
}

fn cube_spec() -> blueshift_doppler::CubeSpec {
    blueshift_doppler::CubeSpec {
        rest_nm: 656.28,
        axis: blueshift_doppler::SpectralAxis::OpticalVelocity,
        min: -600e3,
        max: 600e3,
        channels: 24,
        line_width: blueshift_doppler::CubeLineWidth::OneChannel,
    }
}

fn cube_settings(scene: &DopplerScene, view: Vec3) -> DopplerSettings {
    let mut st = DopplerSettings::default_for(scene, 10, 8);
    st.camera = blueshift_doppler::los_camera(scene, view, 1.0, true).unwrap();
    st
}

/// Tile-parallel spectral cubes are the single-process cube bit for bit, emission-only and
/// absorbing (the absorbing cube marches each pixel's ray over the channels' window).
#[test]
fn tile_parallel_cubes_are_bit_identical() {
    use blueshift_dist::render::render_cube_tiles;
    for absorption in [0.0, 5.0] {
        let scene = galaxy(absorption);
        let st = cube_settings(&scene, Vec3::new(0.3, -0.4, 1.0));
        let spec = cube_spec();
        let single = blueshift_doppler::render_cube(&scene, &st, &spec, &|| {}).unwrap();
        assert!(single.data.iter().any(|&v| v > 0.0));
        for n in 1..=4 {
            let got = ThreadWorld::run(n, |c| render_cube_tiles(&c, &scene, &st, &spec).unwrap());
            let cube = got[0].as_ref().unwrap();
            assert_eq!(
                cube.data.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                single.data.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                "absorption {absorption} n {n}"
            );
            assert_eq!(
                (cube.nx, cube.ny, cube.pixel_world),
                (single.nx, single.ny, single.pixel_world)
            );
        }
    }
}

/// Data-parallel spectral cubes of an emission-only scene: the channel values of the pieces
/// add to the single-process cube (each value within 1e-6 of it relative to the cube's
/// peak: f64 sums grouped differently, then rounded to f32), along each axis both ways and
/// an oblique view; and the channel total, the projected line emission, is conserved.
#[test]
fn data_parallel_emission_cube_adds_up() {
    use blueshift_dist::render::render_cube_data;
    let scene = galaxy(0.0);
    let geom = *scene.geometry();
    let spec = cube_spec();
    for view in [
        Vec3::X,
        -Vec3::X,
        Vec3::Y,
        -Vec3::Y,
        Vec3::Z,
        -Vec3::Z,
        Vec3::new(0.6, -0.5, 0.7),
    ] {
        let st = cube_settings(&scene, view);
        let single = blueshift_doppler::render_cube(&scene, &st, &spec, &|| {}).unwrap();
        let peak = single.data.iter().fold(0.0f32, |a, &b| a.max(b.abs()));
        assert!(peak > 0.0);
        let total: f64 = single.data.iter().map(|&v| f64::from(v)).sum();
        for n in 2..=4 {
            let d = decomposition(&geom, n);
            let got =
                ThreadWorld::run(n, |c| render_cube_data(&c, &scene, &st, &spec, &d).unwrap());
            let cube = got[0].as_ref().unwrap();
            let worst = cube
                .data
                .iter()
                .zip(&single.data)
                .map(|(a, b)| (a - b).abs() / peak)
                .fold(0.0f32, f32::max);
            assert!(worst <= 1e-6, "view {view} n {n}: {worst}");
            let t: f64 = cube.data.iter().map(|&v| f64::from(v)).sum();
            assert!(
                (t - total).abs() <= 1e-6 * total.abs(),
                "view {view} n {n}: {t} vs {total}"
            );
        }
    }
}

/// Data-parallel spectral cubes of absorbing scenes compose exactly: each piece's light is
/// marched behind the summed optical depth in front of it, in closed form (no chords), so
/// with the merges off (merge tolerance 0, an unbounded piece budget) the composite is the
/// single-process cube up to the f64 sums' order: every value within 1e-6 of the peak
/// (measured: bit for bit in f32), along each axis both ways and an oblique view, for 2 to
/// 4 ranks, in a moderately and an optically thick case, at any `max_depth_step` (cubes do
/// not use it). Adding the pieces' cubes without the depth in front is off by 38 % of the
/// peak, which shows the depth in front matters.
#[test]
fn data_parallel_absorbing_cube_composes_exactly() {
    use blueshift_dist::render::render_cube_data;
    let spec = cube_spec();
    let data_cube = |scene: &DopplerScene, st: &DopplerSettings, n: usize| {
        let d = decomposition(scene.geometry(), n);
        let got = ThreadWorld::run(n, |c| render_cube_data(&c, scene, st, &spec, &d).unwrap());
        got[0].clone().unwrap()
    };
    let settings = |scene: &DopplerScene, view: Vec3, step: f64| {
        let mut st = cube_settings(scene, view);
        st.merge_tolerance = 0.0;
        st.piece_budget = usize::MAX;
        st.max_depth_step = step;
        st
    };
    for absorption in [5.0, 200.0] {
        let scene = galaxy(absorption);
        for view in [
            Vec3::X,
            -Vec3::X,
            Vec3::Y,
            -Vec3::Y,
            Vec3::Z,
            -Vec3::Z,
            Vec3::new(0.6, -0.5, 0.7),
        ] {
            let st = settings(&scene, view, 0.005);
            let single = blueshift_doppler::render_cube(&scene, &st, &spec, &|| {}).unwrap();
            let peak = single.data.iter().fold(0.0f32, |a, &b| a.max(b.abs()));
            assert!(peak > 0.0);
            for n in 2..=4 {
                let worst = max_rel(&data_cube(&scene, &st, n).data, &single.data, peak);
                assert!(
                    worst <= 1e-6,
                    "absorption {absorption} view {view} n {n}: {worst}"
                );
            }
        }
    }
    // Thick, 3 ranks cut across the view, a coarse depth step: still exact.
    let scene = galaxy(200.0);
    let st = settings(&scene, Vec3::X, 0.05);
    let single = blueshift_doppler::render_cube(&scene, &st, &spec, &|| {}).unwrap();
    let peak = single.data.iter().fold(0.0f32, |a, &b| a.max(b.abs()));
    let worst = max_rel(&data_cube(&scene, &st, 3).data, &single.data, peak);
    assert!(worst <= 1e-6, "{worst}");
    // The pieces' cubes without the depth in front, added.
    let d = decomposition(scene.geometry(), 3);
    let mut naive = vec![0.0f64; single.data.len()];
    for p in d.pieces() {
        let part = blueshift_doppler::part::render_cube_part(
            &scene,
            &st,
            &spec,
            Some(&p.clip),
            None,
            0..st.height as usize,
        )
        .unwrap();
        for (a, b) in naive.iter_mut().zip(part) {
            *a += b;
        }
    }
    let naive = blueshift_doppler::part::cube_from_rows(&st, &spec, &naive).unwrap();
    let off = max_rel(&naive.data, &single.data, peak);
    assert!(off > 0.2, "{off}");
}

/// Data-parallel absorbing cubes with thermal broadening: a box's own segments merge a
/// line's Gaussians along a ray only within the box, so the composite differs from the
/// single process within that merge's bound (0.25 % of a merged Gaussian's peak); the depth
/// in front is the boxes' depth as their rays march it (depth Gaussians on the cube's
/// lattice; it once was the spectrum path's 32-piece Gaussians: 4.2e-3 off). Within 1e-3 of
/// the peak (measured 2.9e-4) for 2 to 4 ranks, along an axis and an oblique view, in a
/// moderately and an optically thick case.
#[test]
fn data_parallel_absorbing_thermal_cube_stays_within_the_merge_bound() {
    use blueshift_dist::render::render_cube_data;
    let spec = cube_spec();
    for absorption in [5.0, 200.0] {
        let mut scene = galaxy(absorption);
        // Sweeps of a few sigma: the lines stay Gaussians.
        scene.factors.velocity = 1.0;
        for view in [Vec3::X, Vec3::new(0.6, -0.5, 0.7)] {
            let mut st = cube_settings(&scene, view);
            st.broadening.thermal = true;
            let single = blueshift_doppler::render_cube(&scene, &st, &spec, &|| {}).unwrap();
            let peak = single.data.iter().fold(0.0f32, |a, &b| a.max(b.abs()));
            assert!(peak > 0.0);
            for n in 2..=4 {
                let d = decomposition(scene.geometry(), n);
                let got =
                    ThreadWorld::run(n, |c| render_cube_data(&c, &scene, &st, &spec, &d).unwrap());
                let worst = max_rel(&got[0].as_ref().unwrap().data, &single.data, peak);
                assert!(
                    worst <= 1e-3,
                    "absorption {absorption} view {view} n {n}: {worst}"
                );
            }
        }
    }
}

/// The largest difference between two cubes' values relative to `peak`.
fn max_rel(a: &[f32], b: &[f32], peak: f32) -> f32 {
    assert_eq!(a.len(), b.len());
    assert!(
        a.iter().chain(b).all(|v| v.is_finite()),
        "non-finite values"
    );
    a.iter()
        .zip(b)
        .map(|(a, b)| (a - b).abs() / peak)
        .fold(0.0f32, f32::max)
}

/// The banded integrators with absorption, data-parallel: each piece's bands are attenuated
/// by the per-band depth in front of it (summed by the scan). They differ from the single
/// process only by the face samples' own emission, whose half-depth attenuation splits
/// differently between the two pieces that share them (see `blueshift_doppler::part`): a
/// second-order term in the step. Checked: within 3e-5 of the peak Y at step 0.5 (measured
/// 1.0e-5), along each axis both ways and an oblique view, orthographic and perspective, 2
/// to 4 ranks, nearest-band and energy-conserving; halving the step shrinks the worst
/// difference at least 3x (measured 7-8x); and in the optically thick case the composite
/// stays dark where the single process is.
#[test]
fn data_parallel_banded_absorption_converges_to_the_single_process() {
    use blueshift_doppler::SpectralIntegrator;
    let scene = galaxy(5.0);
    let geom = *scene.geometry();
    let (lo, hi) = geom.world_bounds();
    let worst = |scene: &DopplerScene, st: &DopplerSettings| {
        let single = render_doppler(scene, st, &|| {}).unwrap();
        let peak = single.xyz.iter().map(|p| p[1]).fold(0.0, f64::max);
        assert!(peak > 0.0);
        let mut worst = 0.0f64;
        for n in 2..=4 {
            let d = decomposition(scene.geometry(), n);
            let got = ThreadWorld::run(n, |c| render_doppler_data(&c, scene, st, &d).unwrap());
            for (a, b) in got[0].as_ref().unwrap().xyz.iter().zip(&single.xyz) {
                for c in 0..3 {
                    worst = worst.max((a[c] - b[c]).abs() / peak);
                }
            }
        }
        worst
    };
    for integrator in ["banded:400", "banded-ec:400"] {
        let integrator = integrator.parse::<SpectralIntegrator>().unwrap();
        for orthographic in [true, false] {
            for camera in views(lo, hi, orthographic) {
                let mut st = DopplerSettings::default_for(&scene, 8, 8);
                st.camera = camera;
                st.integrator = integrator;
                st.step = Some(0.5);
                let coarse = worst(&scene, &st);
                assert!(coarse <= 3e-5, "{integrator} {camera:?}: {coarse}");
                if orthographic && coarse > 1e-7 {
                    st.step = Some(0.25);
                    let fine = worst(&scene, &st);
                    assert!(fine * 3.0 <= coarse, "{integrator}: {fine} vs {coarse}");
                }
            }
        }
        let thick = thick_absorber();
        let mut st = DopplerSettings::default_for(&thick, 4, 4);
        st.integrator = integrator;
        let single = render_doppler(&thick, &st, &|| {}).unwrap();
        let d = decomposition(thick.geometry(), 2);
        let got = ThreadWorld::run(2, |c| render_doppler_data(&c, &thick, &st, &d).unwrap());
        let img = got[0].as_ref().unwrap();
        let mut clear = thick.clone();
        clear.factors.absorption = 0.0;
        let emitted = render_doppler(&clear, &st, &|| {}).unwrap();
        let c = 5;
        assert!(single.xyz[c][1] < 1e-3 * emitted.xyz[c][1]);
        assert!(
            (img.xyz[c][1] - single.xyz[c][1]).abs() <= 1e-3 * emitted.xyz[c][1],
            "{integrator}: {:?} vs {:?}",
            img.xyz[c],
            single.xyz[c]
        );
    }
}

/// Data-parallel Woodcock with rays forwarded between ranks: the image (mean and variance)
/// is the single-process render's bit for bit at the same seed, for 1 to 4 ranks, views
/// along each axis both ways and an oblique one, orthographic and perspective, with
/// emission-absorption and with gradient shading (no shadows); rays do cross pieces (the
/// forwarded count is positive with 2 or more ranks). Shadows and other trackers are
/// refused with one message.
#[test]
fn forwarded_woodcock_is_bit_identical() {
    use blueshift_dist::forward::{render_woodcock_forwarded, render_woodcock_forwarded_in_passes};
    let mut scene = three_cubes(16, 6.0);
    let geom = *scene.geometry();
    let (lo, hi) = scene.bounds();
    for shading in [false, true] {
        scene.shading = shading.then(|| blueshift_tracking::Shading {
            materials: Vec::new(),
            shadows: false,
        });
        // Rays crossing between pieces, per rank count, over all views: a view along
        // the split axis forwards every ray; one across it may forward none.
        let mut crossed = [0u64; 5];
        for orthographic in [true, false] {
            for camera in views(lo, hi, orthographic) {
                let mut s = RenderSettings::default_for(&scene, 10, 8, false);
                s.camera = camera;
                s.spp = 3;
                s.seed = 77;
                let integ = Integrator::Woodcock { channel: 1 };
                let single = render_progressive(&scene, &integ, &s, |_, _| {}).unwrap();
                for n in 1..=4 {
                    let d = decomposition(&geom, n);
                    let got = ThreadWorld::run(n, |c| {
                        render_woodcock_forwarded(&c, &scene, &integ, &s, &d).unwrap()
                    });
                    let img = got[0].0.as_ref().unwrap();
                    assert_eq!(
                        img.mean_image().as_raw(),
                        single.mean_image().as_raw(),
                        "n {n} {camera:?} shading {shading}"
                    );
                    assert_eq!(img.noise(), single.noise());
                    let forwarded: u64 = got.iter().map(|g| g.1.forwarded).sum();
                    let finished: u64 = got.iter().map(|g| g.1.finished).sum();
                    // Every sample finishes once, on one rank.
                    assert_eq!(finished, 10 * 8 * 3);
                    crossed[n] += forwarded;
                    // Passes of 2 samples per pixel (2 and 1): the same bits.
                    let pass = 10 * 8 * 2 * 24;
                    let got = ThreadWorld::run(n, |c| {
                        render_woodcock_forwarded_in_passes(&c, &scene, &integ, &s, &d, pass)
                            .unwrap()
                    });
                    let img = got[0].0.as_ref().unwrap();
                    assert_eq!(
                        img.mean_image().as_raw(),
                        single.mean_image().as_raw(),
                        "passes: n {n} {camera:?} shading {shading}"
                    );
                    assert_eq!(img.noise(), single.noise());
                }
            }
        }
        assert_eq!(crossed[1], 0);
        for (n, c) in crossed.iter().enumerate().skip(2) {
            assert!(
                *c > 0,
                "{n} ranks, shading {shading}: no ray crossed a piece"
            );
        }
    }
    // Refusals, from rank 0 only.
    let d = decomposition(&geom, 2);
    let s = RenderSettings::default_for(&scene, 4, 4, false);
    let mdwt = Integrator::Mdwt {
        dda: DdaMode::OneDda,
        blend: Blend::Density,
    };
    let got = ThreadWorld::run(2, |c| {
        render_woodcock_forwarded(&c, &scene, &mdwt, &s, &d).map(|_| ())
    });
    assert!(matches!(&got[0], Err(e) if e.to_string().contains("woodcock")));
    assert!(matches!(&got[1], Err(blueshift_dist::Error::PeerFailed(_))));
    scene.shading = Some(blueshift_tracking::Shading::default());
    scene.light = Some(blueshift_tracking::DirectionalLight {
        direction: Vec3::Y,
        radiance: [1.0; 3],
        ambient: 0.1,
    });
    let integ = Integrator::Woodcock { channel: 0 };
    let got = ThreadWorld::run(2, |c| {
        render_woodcock_forwarded(&c, &scene, &integ, &s, &d).map(|_| ())
    });
    assert!(matches!(&got[0], Err(e) if e.to_string().contains("shadow")));
}
