//! The black body between voxels: its emission is the interpolation of the voxels'
//! emission (exactly at the reconstruction's 700 nm), not `B` of the interpolated
//! temperature, whose steepness turned thin hot shells of the Enzo snapshot into a lattice
//! of dots. Truth: Planck's law at 700 nm.

use blueshift_doppler::{
    BB_REF_NM, DopplerScene, DopplerSettings, brightness_temperature, pixel_spectrum, planck_factor,
};
use blueshift_spectrum::planck;
use blueshift_volume::{AnyGrid, Geometry, Grid};
use glam::Vec3;

#[test]
fn emission_between_a_hot_and_a_cold_voxel_is_their_interpolation() {
    let geom = Geometry {
        dims: [2, 2, 2],
        origin: Vec3::ZERO,
        spacing: Vec3::ONE,
    };
    let (hot, cold) = (8000.0f32, 10.0f32);
    let grid =
        |f: fn(usize) -> f32| AnyGrid::F32(Grid::from_fn(geom, move |x, _, _| f(x)).unwrap());
    let mut scene = DopplerScene::new(geom).unwrap();
    scene
        .set_blackbody(grid(|_| 1.0), grid(|x| if x == 0 { 8000.0 } else { 10.0 }))
        .unwrap();
    // 3 x 3 pixels over the unit box: pixel centres at x = 1/6, 1/2, 5/6.
    let st = DopplerSettings::default_for(&scene, 3, 3);
    let at = |px: u32| pixel_spectrum(&scene, &st, px, 1).unwrap().eval(BB_REF_NM);
    let b = |t: f32| planck(BB_REF_NM, f64::from(t)).unwrap();
    for (px, w_hot) in [(0u32, 5.0 / 6.0), (1, 0.5)] {
        let want = w_hot * b(hot) + (1.0 - w_hot) * b(cold);
        let got = at(px) / at(2);
        let want_ratio = want / ((1.0 / 6.0) * b(hot) + (5.0 / 6.0) * b(cold));
        assert!(
            (got / want_ratio - 1.0).abs() < 0.03,
            "pixel {px}: ratio {got} vs the interpolated emission's {want_ratio}"
        );
    }
    // B of the interpolated temperature would give far less at the midpoint.
    let naive = b(0.5 * (hot + cold)) / b(hot / 6.0 + 5.0 * cold / 6.0);
    assert!((at(1) / at(2) - naive).abs() > 0.5 * naive.max(1.0));
}

#[test]
fn the_brightness_temperature_inverts_the_planck_factor() {
    for t in [350.0, 1000.0, 5800.0, 1e5, 1e7] {
        let back = brightness_temperature(planck_factor(t));
        assert!((back / t - 1.0).abs() < 1e-9, "{t}: {back}");
    }
    assert_eq!(brightness_temperature(0.0), 0.0);
    assert_eq!(planck_factor(-1.0), 0.0);
}
