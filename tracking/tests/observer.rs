//! A moving observer in the RGB volume renders (issue 27): at rest nothing changes; flying
//! head-on through an orthographic view (every ray's direction unchanged by aberration,
//! every pixel the same Doppler factor `sqrt((1 + b) / (1 - b))`) each pixel is the exact
//! colour matrix `K(D)` of the relativity crate applied to the pixel at rest, times `D^4`
//! with the searchlight; an oblique motion moves the picture (aberration).

mod common;

use blueshift_relativity::{DopplerColourTable, MovingObserver, SpectralPrimaries, Velocity};
use blueshift_tracking::{Blend, DdaMode, Integrator, RenderSettings, Scene, render};
use blueshift_volume::synth;
use common::tf;
use glam::DVec3;

fn scene() -> Scene {
    let tfs = [[1.0, 0.3, 0.1], [0.2, 1.0, 0.3], [0.1, 0.4, 1.0]]
        .iter()
        .map(|&c| tf(c, &[(0.0, 0.0), (1.0, 1.0)]))
        .collect();
    let mut s = Scene::from_volume(&synth::three_cubes(16).unwrap(), tfs, 6.0, 4).unwrap();
    s.background = [0.2, 0.25, 0.3];
    s
}

fn integrators() -> [Integrator; 2] {
    [
        Integrator::Mdwt {
            dda: DdaMode::OneDda,
            blend: Blend::Density,
        },
        Integrator::Woodcock { channel: 0 },
    ]
}

fn settings(s: &Scene) -> RenderSettings {
    let mut st = RenderSettings::default_for(s, 16, 12, true);
    st.spp = 2;
    st.seed = 3;
    st
}

#[test]
fn at_rest_renders_are_unchanged_bit_for_bit() {
    let sc = scene();
    for integrator in integrators() {
        let mut st = settings(&sc);
        let a = render(&sc, &integrator, &st).unwrap();
        st.observer = Some(MovingObserver::new(Velocity::ZERO));
        let b = render(&sc, &integrator, &st).unwrap();
        assert_eq!(a.as_raw(), b.as_raw());
    }
}

#[test]
fn head_on_each_pixel_is_the_colour_matrix_of_the_doppler_factor() {
    let sc = scene();
    let b: f64 = 0.2;
    let d = ((1.0 + b) / (1.0 - b)).sqrt();
    // The exact K(D), computed from the spectral primaries (not the renderer's table).
    let k = SpectralPrimaries::mallett_yuksel_2019()
        .unwrap()
        .doppler_matrix(d)
        .unwrap();
    for integrator in integrators() {
        for searchlight in [false, true] {
            let mut st = settings(&sc);
            let rest = render(&sc, &integrator, &st).unwrap();
            let f = st.camera.target - st.camera.eye;
            let v = Velocity::along(f.as_dvec3(), b).unwrap();
            st.observer = Some(MovingObserver {
                velocity: v,
                searchlight,
            });
            let moving = render(&sc, &integrator, &st).unwrap();
            let scale = if searchlight { d.powi(4) } else { 1.0 };
            let mut max_rel = 0.0f64;
            for (p, q) in rest.pixels().zip(moving.pixels()) {
                for i in 0..3 {
                    let want = scale * (0..3).map(|j| k[i][j] * f64::from(p.0[j])).sum::<f64>();
                    let err = (f64::from(q.0[i]) - want).abs() / want.abs().max(1e-3);
                    max_rel = max_rel.max(err);
                }
                assert_eq!(p.0[3], q.0[3], "alpha is coverage, not colour");
            }
            // The renderer interpolates K(D) in a table of 2048 entries over ln D.
            assert!(
                max_rel < 1e-3,
                "{integrator:?} searchlight {searchlight}: {max_rel}"
            );
            // ... and the shift is not the identity.
            let ident = DopplerColourTable::global().apply(1.0, [1.0, 1.0, 1.0]);
            assert!(ident.iter().all(|c| (c - 1.0).abs() < 1e-2));
            assert!(k[0][0] < 0.9 || k[2][2] > 1.1 || k[1][1] < 0.9, "{k:?}");
        }
    }
}

#[test]
fn an_oblique_motion_moves_the_picture() {
    let sc = scene();
    let integrator = &integrators()[0];
    let mut st = RenderSettings::default_for(&sc, 24, 24, false);
    st.jitter_pixels = false;
    let rest = render(&sc, integrator, &st).unwrap();
    st.observer = Some(MovingObserver::new(
        Velocity::new(DVec3::new(0.5, 0.0, 0.0)).unwrap(),
    ));
    let moving = render(&sc, integrator, &st).unwrap();
    // Alpha (coverage) does not depend on colour: where it differs, the rays went elsewhere.
    let moved = rest
        .pixels()
        .zip(moving.pixels())
        .filter(|(p, q)| (p.0[3] - q.0[3]).abs() > 0.05)
        .count();
    assert!(moved > 20, "{moved} pixels changed coverage");
}
