//! Renders the built-in checkerboard seen at a few speeds and prints, for each, where the
//! scene's 90-degree circle appears (cos(theta') = beta) and the head-on Doppler factor.
//!
//! Run: `cargo run -p blueshift-relativity --example checker_ramp`

use blueshift_relativity::{Camera, Checker, Effects, Environment, Velocity, render};
use glam::DVec3;

fn main() -> Result<(), blueshift_relativity::Error> {
    let env = Environment::Checker(Checker::default());
    let cam = Camera {
        look: DVec3::NEG_Z,
        width: 160,
        height: 90,
        ..Camera::default()
    };
    for b in [0.0, 0.5, 0.9, 0.99] {
        let v = Velocity::along(DVec3::NEG_Z, b)?;
        let img = render(&env, &cam, v, Effects::ALL, None)?;
        let mean: f32 = img.pixels().map(|p| p.0[1]).sum::<f32>() / (160.0 * 90.0);
        println!(
            "beta {b:4.2}: gamma {:6.3}, scene 90 deg seen at {:5.1} deg, head-on D {:6.3}, mean G {mean:.3}",
            v.gamma(),
            b.acos().to_degrees(),
            v.doppler_factor_observer(DVec3::NEG_Z),
        );
    }
    Ok(())
}
