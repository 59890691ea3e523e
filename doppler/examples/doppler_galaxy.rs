//! Renders the synthetic galaxy seen at 60 degrees with Doppler shifts (velocity x30) and line
//! absorption, and prints the time, the optical-depth pieces per ray and a few pixels' XYZ.
//!
//! `cargo run --release -p blueshift-doppler --example doppler_galaxy [RES] [SIZE] [ABSORPTION]`

use std::time::Instant;

use blueshift_doppler::Projection;
use blueshift_doppler::{DopplerScene, DopplerSettings, render_doppler};
use glam::Vec3;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let arg = |i: usize, d: f64| -> f64 {
        std::env::args()
            .nth(i)
            .and_then(|a| a.parse().ok())
            .unwrap_or(d)
    };
    let (res, size, absorption) = (arg(1, 64.0) as usize, arg(2, 32.0) as u32, arg(3, 5.0));
    let vol = blueshift_volume::synth::galaxy(res, 1)?;
    let mut scene = DopplerScene::from_volume(&vol, &["bb", "H", "C"])?;
    scene.factors.velocity = 30.0;
    scene.factors.absorption = absorption;
    scene.factors.blackbody = 0.1;
    let mut st = DopplerSettings::default_for(&scene, size, size);
    let (lo, hi) = scene.geometry().world_bounds();
    let (c, r) = (0.5 * (lo + hi), 0.5 * (hi - lo).length());
    let (si, ci) = 60f32.to_radians().sin_cos();
    st.camera.target = c;
    st.camera.eye = c - Vec3::new(0.0, si, ci) * (r + 1.0);
    st.camera.up = Vec3::new(0.0, ci, -si);
    st.camera.projection = Projection::Orthographic { height: 30.0 };
    let t = Instant::now();
    let img = render_doppler(&scene, &st, &|| {})?;
    println!(
        "{size}x{size} from a {res}^3 galaxy, absorption x{absorption}: {:.3} s, pieces per ray mean {:.1} max {}",
        t.elapsed().as_secs_f64(),
        img.pieces.mean,
        img.pieces.max
    );
    let mid = (size / 2 * size + size / 2) as usize;
    println!("centre pixel XYZ {:?}", img.xyz[mid]);
    Ok(())
}
