//! The Doppler engine API: a session equals the one-call functions, a factor edit equals a
//! fresh session with those factors (for every integrator, with and without absorption),
//! picks and traces reuse the tables, and a run can be cancelled.

use std::sync::atomic::{AtomicU64, Ordering};

use blueshift_camera::{Observer, OnProgress, Progress, Session, Silent};
use blueshift_doppler::{
    DopplerImage, DopplerScene, DopplerSession, DopplerSettings, Error, LineKind, Prepared,
    SpectralIntegrator, pixel_spectrum, render_doppler, trace_ray,
};
use blueshift_volume::synth;

fn galaxy(absorption: f64, velocity: f64) -> DopplerScene {
    let vol = synth::galaxy(16, 1).unwrap();
    let mut s = DopplerScene::from_volume(&vol, &["bb", "H", "He"]).unwrap();
    s.factors.absorption = absorption;
    s.factors.velocity = velocity;
    s
}

fn settings(s: &DopplerScene, integrator: &str) -> DopplerSettings {
    let mut st = DopplerSettings::default_for(s, 12, 10);
    st.integrator = integrator.parse().unwrap();
    st
}

#[test]
fn a_session_equals_the_one_call_functions() {
    for integ in ["pwl", "banded:40", "banded-ec:40"] {
        let sc = galaxy(0.5, 3.0);
        let st = settings(&sc, integ);
        let img = render_doppler(&sc, &st, &|| {}).unwrap();
        let pick = pixel_spectrum(&sc, &st, 6, 5).unwrap();
        let trace = trace_ray(&sc, &st, 6, 5).unwrap();
        let mut session = DopplerSession::new(sc, st).unwrap();
        assert_eq!(session.run(&Silent).unwrap().xyz, img.xyz, "{integ}");
        assert_eq!(session.pixel_spectrum(6, 5).unwrap(), pick, "{integ}");
        let t = session.trace(6, 5).unwrap();
        assert_eq!(t.len(), trace.len());
        assert_eq!(
            t.last().map(|s| &s.spectrum),
            trace.last().map(|s| &s.spectrum)
        );
        assert!(session.pixel_spectrum(12, 0).is_err());
    }
}

#[test]
fn a_factor_edit_equals_a_fresh_session_with_those_factors() {
    for integ in ["pwl", "banded:40", "banded-ec:40"] {
        for (abs0, abs1) in [(0.0, 0.0), (0.0, 1.0), (1.0, 0.3)] {
            let sc = galaxy(abs0, 2.0);
            let st = settings(&sc, integ);
            let mut session = DopplerSession::new(sc, st.clone()).unwrap();
            // The first render keeps the samples; the edited render reuses them.
            session.render(&Silent).unwrap();
            let mut f = session.scene().factors;
            f.velocity = 0.5;
            f.absorption = abs1;
            f.emission = 2.0;
            session.set_factors(f).unwrap();
            let mut fresh_scene = galaxy(abs0, 2.0);
            fresh_scene.factors = f;
            let fresh = DopplerSession::new(fresh_scene, st).unwrap();
            assert_eq!(
                session.render(&Silent).unwrap().xyz,
                fresh.render(&Silent).unwrap().xyz,
                "{integ}, absorption {abs0} -> {abs1}"
            );
            assert_eq!(session.prepared().absorbing(), abs1 > 0.0);
        }
    }
    // A bad factor is refused and the old factors stay.
    let mut s = DopplerSession::new(galaxy(0.0, 1.0), settings(&galaxy(0.0, 1.0), "pwl")).unwrap();
    let mut f = s.scene().factors;
    f.velocity = f64::NAN;
    assert!(matches!(s.set_factors(f), Err(Error::Parameter(_))));
    assert_eq!(s.scene().factors.velocity, 1.0);
}

#[test]
fn camera_and_settings_edits_equal_fresh_renders() {
    let sc = galaxy(0.0, 2.0);
    let st = settings(&sc, "pwl");
    let mut inclined = st.clone();
    inclined.incline(&sc, 40.0).unwrap();
    let expected = render_doppler(&sc, &inclined, &|| {}).unwrap();
    let mut session = DopplerSession::new(sc, st.clone()).unwrap();
    // Kept samples belong to the old view: a camera edit must not reuse them.
    session.render(&Silent).unwrap();
    session.set_camera(inclined.camera).unwrap();
    assert_eq!(session.render(&Silent).unwrap().xyz, expected.xyz);
    let mut banded = st;
    banded.integrator = SpectralIntegrator::Banded {
        bands: 30,
        shift: blueshift_doppler::BandShift::Nearest,
    };
    let expected = render_doppler(session.scene(), &banded, &|| {}).unwrap();
    session.render(&Silent).unwrap();
    session.set_settings(banded).unwrap();
    assert_eq!(session.render(&Silent).unwrap().xyz, expected.xyz);
}

#[test]
fn line_entries_are_the_lines_or_the_rest_frame_bands() {
    let sc = galaxy(0.5, 1.0);
    let pwl = Prepared::new(&sc, &settings(&sc, "pwl")).unwrap();
    let lines: usize = sc.species().iter().map(|s| s.emission_lines.len()).sum();
    let e = pwl.line_entries(&sc, LineKind::Emission);
    assert_eq!(e.len(), lines);
    // Strengths carry the factors.
    let a = pwl.line_entries(&sc, LineKind::Absorption);
    let sp = &sc.species()[a[0].species];
    assert_eq!(a[0].strength, sp.absorption_lines[0].strength * 0.5);
    // Nearest-band entries: the bands' rest-frame area equals the lines' area inside the
    // range (each line's box deposited as band means).
    let st = settings(&sc, "banded:40");
    let b = Prepared::new(&sc, &st).unwrap();
    let entries = b.line_entries(&sc, LineKind::Emission);
    let (lo, hi) = st.range_nm;
    let bw = (hi - lo) / 40.0;
    for m in 0..sc.species().len() {
        let area_bands: f64 = entries
            .iter()
            .filter(|x| x.species == m)
            .map(|x| x.strength * bw)
            .sum();
        // Each line's box counts with the part of it inside the range.
        let w = st.line_width_nm;
        let area_lines: f64 = sc.species()[m]
            .emission_lines
            .iter()
            .map(|l| {
                let inside = (l.centre_nm + 0.5 * w).min(hi) - (l.centre_nm - 0.5 * w).max(lo);
                l.strength * inside.clamp(0.0, w) / w
            })
            .sum();
        assert!(
            (area_bands - area_lines).abs() <= 1e-12 * area_lines.max(1.0),
            "species {m}: {area_bands} vs {area_lines}"
        );
    }
}

#[test]
fn rows_report_progress_and_a_cancel_stops_the_render() {
    let sc = galaxy(0.0, 1.0);
    let st = settings(&sc, "pwl");
    let session = DopplerSession::new(sc, st).unwrap();
    let rows = AtomicU64::new(0);
    let img = session
        .render(&OnProgress::new(|p: Progress| {
            assert_eq!(p.total, 10);
            rows.fetch_add(1, Ordering::Relaxed);
        }))
        .unwrap();
    assert_eq!(rows.load(Ordering::Relaxed), 10);
    assert_eq!(img.xyz.len(), 120);

    struct Stop;
    impl Observer<DopplerImage> for Stop {
        fn cancelled(&self) -> bool {
            true
        }
    }
    assert!(matches!(session.render(&Stop), Err(Error::Cancelled)));
}
