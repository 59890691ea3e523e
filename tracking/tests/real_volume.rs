//! A real CT crop (16 x 16 x 8 voxels of VTK's headsq, anisotropic 3.2 x 3.2 x 1.5 mm spacing,
//! from the volume crate's test data): Woodcock / MDWT images agree per pixel with the
//! converged ray marcher under a perspective camera.

use blueshift_tracking::{
    Blend, DdaMode, Integrator, RayMarcher, RenderSettings, Scene, render, render_progressive,
};

#[test]
fn headsq_crop_tracking_matches_the_marcher() {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../volume/tests/data/valid/headsq_crop.nhdr"
    );
    let vol = blueshift_volume::read(path).unwrap();
    let grid = &vol.channels()[0].grid;
    let (lo, hi) = grid.finite_range().unwrap();
    let tf = blueshift_tfedit::builtin_over("inferno", [f64::from(lo), f64::from(hi)]).unwrap();
    // The crop is about 48 x 48 x 10.5 mm: a density scale of 0.1 per mm gives optical
    // depths of order one through it.
    let scene = Scene::from_volume(&vol, vec![tf], 0.1, 4).unwrap();
    let mut s = RenderSettings::default_for(&scene, 10, 10, false);
    s.jitter_pixels = false;
    s.spp = 2;
    let m = RayMarcher {
        step: Some(0.02),
        ..RayMarcher::default()
    };
    let reference = render(&scene, &Integrator::Marcher(m), &s).unwrap();
    let centre = reference.get_pixel(5, 5).0;
    assert!(centre[3] > 0.2, "the crop should absorb: {centre:?}");
    s.spp = 600;
    for integ in [
        Integrator::Woodcock { channel: 0 },
        Integrator::Mdwt {
            dda: DdaMode::NDda,
            blend: Blend::Density,
        },
    ] {
        let p = render_progressive(&scene, &integ, &s, |_, _| {}).unwrap();
        for y in 0..10 {
            for x in 0..10 {
                let m = p.mean(x, y);
                let v = p.variance(x, y);
                let r = reference.get_pixel(x, y).0;
                for c in 0..4 {
                    let se = (v[c] / 600.0).sqrt();
                    let d = (m[c] - f64::from(r[c])).abs();
                    assert!(
                        d <= 5.0 * se + 0.01,
                        "{integ:?} pixel ({x}, {y}) component {c}: {} vs marcher {} (se {se:.4})",
                        m[c],
                        r[c]
                    );
                }
            }
        }
    }
}
