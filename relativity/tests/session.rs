//! The relativity session: the same frames as `render`, edits equal fresh renders.

use blueshift_camera::{Observer, Session, Silent};
use blueshift_relativity::{
    Camera, Checker, Effects, Environment, Error, RelativitySession, Velocity, render,
};
use glam::DVec3;
use image::Rgb32FImage;

fn cam() -> Camera {
    Camera {
        width: 24,
        height: 16,
        ..Camera::default()
    }
}

#[test]
fn session_frames_equal_render_and_edits_equal_fresh_frames() {
    let env = Environment::Checker(Checker::default());
    let v = Velocity::along(DVec3::NEG_Z, 0.6).unwrap();
    let mut s = RelativitySession::new(env.clone(), cam(), v, Effects::ALL).unwrap();
    let expected = render(&env, &cam(), v, Effects::ALL, None).unwrap();
    assert_eq!(s.run(&Silent).unwrap(), expected);
    // A speed ramp is a velocity edit per frame.
    for beta in [0.0, 0.3, 0.9] {
        let v = Velocity::along(DVec3::X, beta).unwrap();
        s.set_velocity(v);
        s.set_effects(Effects::ABERRATION);
        assert_eq!(
            s.render(&Silent).unwrap(),
            render(&env, &cam(), v, Effects::ABERRATION, None).unwrap()
        );
    }
    let mut wide = cam();
    wide.fov_y_deg = 120.0;
    s.set_camera(wide.clone()).unwrap();
    assert_eq!(
        s.render(&Silent).unwrap(),
        render(&env, &wide, s.velocity(), Effects::ABERRATION, None).unwrap()
    );
    // A bad camera is refused and the old one stays.
    let mut bad = wide.clone();
    bad.fov_y_deg = 180.0;
    assert!(s.set_camera(bad).is_err());
    assert_eq!(s.camera(), &wide);

    struct Stop;
    impl Observer<Rgb32FImage> for Stop {
        fn cancelled(&self) -> bool {
            true
        }
    }
    assert!(matches!(s.render(&Stop), Err(Error::Cancelled)));
}
