//! The majorant never underestimates the extinction along random rays through random
//! volumes with random transfer functions, and the DDA covers the clipped ray exactly.

mod common;

use blueshift_tfedit::{ColorKnot, OpacityKnot, TransferFunction};
use blueshift_tracking::{Dda, DdaMajorantIterator, Ray, Rng, Scene};
use blueshift_volume::{AnyGrid, Geometry, Grid};
use glam::Vec3;

fn random_tf(rng: &mut Rng) -> TransferFunction {
    let n = 1 + (rng.next_u64() % 6) as usize;
    let mut xs: Vec<f64> = (0..n)
        .map(|_| f64::from(rng.uniform()) * 2.0 - 0.5)
        .collect();
    xs.sort_by(f64::total_cmp);
    let op = xs
        .iter()
        .map(|&x| {
            OpacityKnot::new(
                x,
                if rng.uniform() < 0.3 {
                    0.0
                } else {
                    rng.uniform()
                },
            )
        })
        .collect();
    TransferFunction::new(
        [-0.5, 1.5],
        vec![ColorKnot {
            x: 0.0,
            rgb: [1.0; 3],
        }],
        op,
    )
    .unwrap()
}

fn random_scene(rng: &mut Rng) -> Scene {
    let dims = [0, 1, 2].map(|_| 2 + (rng.next_u64() % 14) as usize);
    let geom = Geometry {
        dims,
        origin: Vec3::new(rng.uniform() - 0.5, rng.uniform(), -rng.uniform()),
        spacing: Vec3::new(
            0.5 + rng.uniform(),
            0.5 + rng.uniform(),
            0.5 + rng.uniform(),
        ),
    };
    let n = geom.voxel_count();
    let smooth = rng.uniform() < 0.5;
    let data: Vec<f32> = (0..n)
        .map(|i| {
            if smooth {
                (i as f32 * 0.37).sin() * 0.5 + 0.5
            } else {
                rng.uniform()
            }
        })
        .collect();
    let g = AnyGrid::F32(Grid::from_vec(geom, data).unwrap());
    let k = 1 + (rng.next_u64() % 5) as usize;
    Scene::new(
        vec![("r".into(), g, random_tf(rng))],
        0.5 + 3.0 * rng.uniform(),
        k,
    )
    .unwrap()
}

fn random_ray(rng: &mut Rng, lo: Vec3, hi: Vec3) -> Ray {
    let c = 0.5 * (lo + hi);
    let ext = hi - lo;
    let kind = rng.next_u64() % 4;
    let axis = (rng.next_u64() % 3) as usize;
    let mut dir = Vec3::new(
        rng.uniform() - 0.5,
        rng.uniform() - 0.5,
        rng.uniform() - 0.5,
    );
    if kind == 0 {
        // Along an axis, possibly on a face or a cell boundary.
        dir = Vec3::ZERO;
        dir[axis] = if rng.uniform() < 0.5 { 1.0 } else { -1.0 };
    }
    let origin = if kind == 1 {
        // Starting inside the volume.
        lo + ext * Vec3::new(rng.uniform(), rng.uniform(), rng.uniform())
    } else {
        let target = lo + ext * Vec3::new(rng.uniform(), rng.uniform(), rng.uniform());
        let mut target = target;
        if kind == 2 {
            // Grazing: the target on a face of the box.
            target[axis] = if rng.uniform() < 0.5 {
                lo[axis]
            } else {
                hi[axis]
            };
        }
        if kind == 0 {
            let mut o = target;
            o[axis] = c[axis] - dir[axis] * 3.0 * ext.max_element();
            return Ray::new(o, dir).unwrap();
        }
        target - dir.normalize_or(Vec3::X) * 2.0 * ext.length()
    };
    Ray::new(origin, dir).unwrap_or(Ray::new(origin, Vec3::X).unwrap())
}

#[test]
fn majorant_never_underestimates_and_segments_tile_the_ray() {
    let mut rng = Rng::new(2024, 0, 0);
    let mut checked = 0u64;
    for _ in 0..300 {
        let scene = random_scene(&mut rng);
        let (lo, hi) = scene.bounds();
        let grid = scene.channels()[0].majorant();
        for _ in 0..20 {
            let ray = random_ray(&mut rng, lo, hi);
            let segs: Vec<_> = DdaMajorantIterator::new(grid, &ray, f32::INFINITY).collect();
            if let Some((t0, t1)) = ray.clip_box(lo, hi)
                && t1 - t0 > 1e-3 * (hi - lo).length()
            {
                {
                    assert!(
                        !segs.is_empty(),
                        "ray {ray:?} crosses the box but got no cells"
                    );
                    let first = segs.first().unwrap();
                    let last = segs.last().unwrap();
                    let tol = 1e-4 * (1.0 + t1.abs());
                    assert!(
                        (first.t_min - t0).abs() <= tol,
                        "entry {} vs {t0}",
                        first.t_min
                    );
                    assert!(
                        (last.t_max - t1).abs() <= tol,
                        "exit {} vs {t1}",
                        last.t_max
                    );
                }
            }
            for w in segs.windows(2) {
                assert_eq!(w[0].t_max, w[1].t_min, "segments must be contiguous");
            }
            for s in &segs {
                assert!(s.t_max >= s.t_min);
                for j in 0..5 {
                    let t = s.t_min + (s.t_max - s.t_min) * (j as f32 + 0.5) / 5.0;
                    let (sigma, _) = scene.sample(0, ray.at(t));
                    assert!(
                        sigma <= s.sigma_maj,
                        "sigma {sigma} above majorant {} at t {t} of {ray:?}",
                        s.sigma_maj
                    );
                    checked += 1;
                }
            }
        }
    }
    assert!(checked > 10_000, "too few points checked: {checked}");
}

#[test]
fn dda_visits_every_cell_once_along_an_axis() {
    // 17 voxels, k = 4: 4 cells per axis; a ray along x through the middle visits 4 cells.
    let g = common::grid([17, 17, 17], |_, _, _| 0.0);
    let scene = Scene::new(
        vec![("z".into(), g, common::tf([1.0; 3], &[(0.0, 1.0)]))],
        1.0,
        4,
    )
    .unwrap();
    for (o, d) in [
        (Vec3::new(-1.0, 8.0, 8.0), Vec3::X),
        (Vec3::new(20.0, 8.0, 8.0), -Vec3::X),
        // On a cell boundary plane (y = 8 = 2 k) and on the box face z = 0.
        (Vec3::new(-1.0, 8.0, 0.0), Vec3::X),
        (Vec3::new(-1.0, 16.0, 16.0), Vec3::X),
    ] {
        let cells: Vec<_> =
            Dda::new(scene.layout(), &Ray::new(o, d).unwrap(), f32::INFINITY).collect();
        assert_eq!(cells.len(), 4, "{o} {d}: {cells:?}");
        let total: f32 = cells.iter().map(|c| c.t_max - c.t_min).sum();
        assert!((total - 16.0).abs() < 1e-4);
        let mut ids: Vec<_> = cells.iter().map(|c| c.cell).collect();
        ids.dedup();
        assert_eq!(ids.len(), 4);
    }
    // Starting inside at x = 9.5 going +x: cells 2 and 3, length 6.5.
    let cells: Vec<_> = Dda::new(
        scene.layout(),
        &Ray::new(Vec3::new(9.5, 3.0, 3.0), Vec3::X).unwrap(),
        f32::INFINITY,
    )
    .collect();
    assert_eq!(cells.len(), 2);
    assert!((cells[0].t_min).abs() < 1e-6 && (cells[1].t_max - 6.5).abs() < 1e-5);
    // Missing the box, and pointing away from it.
    assert_eq!(
        Dda::new(
            scene.layout(),
            &Ray::new(Vec3::new(-1.0, 20.0, 8.0), Vec3::X).unwrap(),
            f32::INFINITY
        )
        .count(),
        0
    );
    assert_eq!(
        Dda::new(
            scene.layout(),
            &Ray::new(Vec3::new(-1.0, 8.0, 8.0), -Vec3::X).unwrap(),
            f32::INFINITY
        )
        .count(),
        0
    );
}

#[test]
fn majorant_grid_follows_a_transfer_function_change() {
    let g = common::grid([9, 9, 9], |x, _, _| x as f32 / 8.0);
    let mut scene = Scene::new(
        vec![(
            "x".into(),
            g,
            common::tf([1.0; 3], &[(0.0, 0.0), (1.0, 1.0)]),
        )],
        2.0,
        4,
    )
    .unwrap();
    // Cells along x cover [0, 0.5] and [0.5, 1]: majorants 1.0 and 2.0 (opacity x scale 2).
    let v = scene.channels()[0].majorant().values().to_vec();
    assert!(
        (v[0] - 1.0).abs() < 1e-4 && (v[1] - 2.0).abs() < 1e-4,
        "{v:?}"
    );
    scene
        .set_transfer_function(0, common::tf([1.0; 3], &[(0.0, 0.5), (0.5, 0.0)]))
        .unwrap();
    let v = scene.channels()[0].majorant().values().to_vec();
    assert!((v[0] - 1.0).abs() < 1e-4 && v[1] < 1e-4, "{v:?}");
    scene.set_density_scale(4.0).unwrap();
    assert!((scene.channels()[0].majorant().values()[0] - 2.0).abs() < 1e-4);
}
