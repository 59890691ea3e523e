//! Synthetic datasets checked against their definitions' analytic properties.

use blueshift_volume::synth::{self, CUBES, SHELL_RADIUS, SHELL_SPEED_M_PER_S};
use blueshift_volume::{AnyGrid, Volume};
use glam::Vec3;

fn f32_grid<'a>(v: &'a Volume, name: &str) -> &'a blueshift_volume::Grid<f32> {
    match v.grid(name).unwrap() {
        AnyGrid::F32(g) => g,
        other => panic!("{name}: {:?}", other.scalar_type()),
    }
}
fn vec_grid<'a>(v: &'a Volume, name: &str) -> &'a blueshift_volume::Grid<Vec3> {
    match v.grid(name).unwrap() {
        AnyGrid::Vec3(g) => g,
        other => panic!("{name}: {:?}", other.scalar_type()),
    }
}

#[test]
fn marschner_lobb_takes_its_analytic_values() {
    // ρ(0,0,0) = (1 - 0 + 0.25 (1 + cos 12π)) / 2.5 = 0.6; ρ(0,0,1) = (1 - 1 + 0.5) / 2.5 = 0.2.
    assert!((synth::marschner_lobb_at(Vec3::ZERO) - 0.6).abs() < 1e-6);
    assert!((synth::marschner_lobb_at(Vec3::Z) - 0.2).abs() < 1e-6);
    let v = synth::marschner_lobb(41).unwrap();
    let g = f32_grid(&v, "density");
    // Voxel 20 is the centre of [-1, 1] with 41 voxels.
    assert!((g.get(20, 20, 20).unwrap() - 0.6).abs() < 1e-5);
    assert!((g.get(20, 20, 40).unwrap() - 0.2).abs() < 1e-5);
    let (lo, hi) = v.channels()[0].grid.finite_range().unwrap();
    assert!(lo >= 0.0 && hi <= 1.0, "{lo}..{hi}");
}

#[test]
fn three_cubes_ramp_down_along_x_minus_x_and_minus_y() {
    let v = synth::three_cubes(51).unwrap();
    let geom = *v.geometry();
    let at = |name: &str, p: Vec3| f32_grid(&v, name).sample_trilinear(p);
    for (i, name) in ["red", "green", "blue"].into_iter().enumerate() {
        let (lo, hi) = CUBES[i];
        let c = (lo + hi) / 2.0;
        assert!(
            (at(name, c) - 0.5).abs() < 0.02,
            "{name} centre {}",
            at(name, c)
        );
        let step = [Vec3::X, Vec3::X, Vec3::Y][i] * 0.1;
        let sign = [-1.0, 1.0, 1.0][i];
        // Slope 1 / side (0.5) along the ramp axis.
        let d = at(name, c + step) - at(name, c);
        assert!((d - sign * 0.2).abs() < 0.01, "{name}: change {d} over 0.1");
        assert_eq!(
            at(name, Vec3::splat(0.02)),
            0.0,
            "{name} is zero outside its box"
        );
    }
    assert_eq!(geom.dims, [51; 3]);
}

#[test]
fn turbulence_spans_at_least_six_decades_with_a_heavy_tail() {
    let v = synth::turbulence(32, 7).unwrap();
    let (lo, hi) = v.channels()[0].grid.finite_range().unwrap();
    assert!(
        lo > 0.0 && hi / lo >= 1e6,
        "range {lo}..{hi}: {} decades",
        (hi / lo).log10()
    );
    let data = f32_grid(&v, "density").data();
    let mean = data.iter().map(|&x| f64::from(x)).sum::<f64>() / data.len() as f64;
    let mut sorted = data.to_vec();
    sorted.sort_by(f32::total_cmp);
    let median = f64::from(sorted[sorted.len() / 2]);
    assert!(
        mean > 3.0 * median,
        "heavy tail: mean {mean} should far exceed median {median}"
    );
}

#[test]
fn hydrogen_shell_rotates_about_y_at_300_km_per_s() {
    let v = synth::hydrogen_shell(48, 1).unwrap();
    let dens = f32_grid(&v, "hi_density");
    let vel = vec_grid(&v, "velocity_m_per_s");
    // Density sits in the shell.
    assert!(dens.sample_trilinear(Vec3::new(SHELL_RADIUS, 0.0, 0.0)) > 0.8);
    assert_eq!(dens.sample_trilinear(Vec3::ZERO), 0.0);
    assert_eq!(dens.sample_trilinear(Vec3::new(0.95, 0.0, 0.0)), 0.0);
    // Rigid rotation: v_z = -ω x, so the x > 0 side moves to -z (away from a viewer at +z).
    let right = vel.sample_trilinear(Vec3::new(SHELL_RADIUS, 0.0, 0.0));
    let left = vel.sample_trilinear(Vec3::new(-SHELL_RADIUS, 0.0, 0.0));
    assert!((right.z + SHELL_SPEED_M_PER_S).abs() < 1e3, "{right}");
    assert!((left.z - SHELL_SPEED_M_PER_S).abs() < 1e3, "{left}");
    assert!(
        vel.data().iter().all(|v| v.y == 0.0),
        "no motion along the rotation axis"
    );
}

#[test]
fn galaxy_has_its_species_and_a_flat_rotation_curve() {
    let v = synth::galaxy(48, 3).unwrap();
    let names: Vec<_> = v.channels().iter().map(|c| c.name.as_str()).collect();
    assert_eq!(
        names,
        [
            "hi_density",
            "he_density",
            "c_density",
            "dust_density",
            "temperature_k",
            "velocity_m_per_s"
        ]
    );
    let vel = vec_grid(&v, "velocity_m_per_s");
    for r in [5.0f32, 8.0, 11.0] {
        for phi in [0.3f32, 2.0, 4.0] {
            let p = Vec3::new(r * phi.cos(), r * phi.sin(), 0.0);
            let tangential = Vec3::new(-phi.sin(), phi.cos(), 0.0);
            let vt = vel.sample_trilinear(p).dot(tangential);
            assert!(
                (vt - 220e3).abs() < 30e3,
                "tangential speed {vt} m/s at r = {r} kpc"
            );
        }
    }
    let speed_max = vel.data().iter().map(|v| v.length()).fold(0.0, f32::max);
    assert!(
        speed_max > 150e3 && speed_max < 500e3,
        "speeds of a few hundred km/s, got {speed_max}"
    );
    let t = v.grid("temperature_k").unwrap().finite_range().unwrap();
    assert!(t.0 >= 100.0 && t.1 > 5e5, "temperature {t:?}");
    let hi = f32_grid(&v, "hi_density");
    // Exponential disk: density falls with radius and height.
    assert!(
        hi.sample_trilinear(Vec3::new(2.0, 0.0, 0.0))
            > hi.sample_trilinear(Vec3::new(12.0, 0.0, 0.0))
    );
    assert!(
        hi.sample_trilinear(Vec3::new(3.0, 1.0, 0.0))
            > 10.0 * hi.sample_trilinear(Vec3::new(3.0, 1.0, 3.0))
    );
}

#[test]
fn datasets_are_deterministic_by_seed_and_thread_count() {
    for name in synth::NAMES {
        let a = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap()
            .install(|| synth::by_name(name, 12, 5).unwrap());
        let b = rayon::ThreadPoolBuilder::new()
            .num_threads(3)
            .build()
            .unwrap()
            .install(|| synth::by_name(name, 12, 5).unwrap());
        assert_eq!(a, b, "{name}");
    }
    assert_ne!(
        synth::turbulence(12, 1).unwrap(),
        synth::turbulence(12, 2).unwrap()
    );
    assert_eq!(synth::channels12(8, 1).unwrap().channels().len(), 12);
    assert!(synth::by_name("nope", 8, 1).is_err());
    assert!(synth::by_name("galaxy", 1, 1).is_err());
}

/// No gas on the box's faces: a render of the galaxy shows its disk fading out, not a slab
/// cut off by the box (which the old galaxy drew as a glowing rectangle).
#[test]
fn galaxy_gas_fades_to_zero_at_the_box_faces() {
    let v = synth::galaxy(32, 1).unwrap();
    let [nx, ny, nz] = v.geometry().dims;
    for name in ["hi_density", "he_density"] {
        let g = v.channel(name).unwrap().grid.to_f32_vec();
        let (mut face_max, mut inner_max) = (0.0f32, 0.0f32);
        for z in 0..nz {
            for y in 0..ny {
                for x in 0..nx {
                    let d = g[(z * ny + y) * nx + x];
                    if x == 0 || y == 0 || z == 0 || x == nx - 1 || y == ny - 1 || z == nz - 1 {
                        face_max = face_max.max(d);
                    } else {
                        inner_max = inner_max.max(d);
                    }
                }
            }
        }
        assert!(inner_max > 0.0);
        assert!(
            face_max <= 1e-6 * inner_max,
            "{name}: {face_max} on a face vs {inner_max}"
        );
    }
}
