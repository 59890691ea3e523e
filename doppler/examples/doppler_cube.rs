//! A position-position-velocity cube of the rotating hydrogen shell: H-alpha in 32 radio-
//! velocity channels, thermal broadening at 10^4 K, seen from +z; writes `shell_cube.fits`
//! and `shell_cube.nrrd` into the system's temporary folder and prints moment 1 along the
//! middle row (it follows the shell's rotation, omega x).
//!
//! Run: `cargo run --release -p blueshift-doppler --example doppler_cube`

use blueshift_doppler::{
    CubeLineWidth, CubeMeta, CubeSpec, DopplerScene, DopplerSettings, SpectralAxis, fits_bytes,
    los_camera, nrrd_bytes, render_cube,
};
use blueshift_volume::{AnyGrid, Grid, synth};
use glam::Vec3;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let vol = synth::hydrogen_shell(48, 1)?;
    let mut scene = DopplerScene::from_volume(&vol, &["H"])?;
    // A temperature field for thermal broadening, carried by a dark black body.
    let g = *scene.geometry();
    let density = vol
        .channel("hi_density")
        .ok_or("no hi_density")?
        .grid
        .clone();
    scene.set_blackbody(density, AnyGrid::F32(Grid::from_fn(g, |_, _, _| 1e4f32)?))?;
    scene.factors.blackbody = 0.0;
    let mut st = DopplerSettings::default_for(&scene, 48, 48);
    st.camera = los_camera(&scene, Vec3::Z, 1.0, false)?;
    st.broadening.thermal = true;
    let spec = CubeSpec {
        rest_nm: blueshift_spectrum::named_line("H-alpha")?.line.centre_nm,
        axis: SpectralAxis::RadioVelocity,
        min: -400e3,
        max: 400e3,
        channels: 32,
        // The settings' line width (1 nm) under the thermal profile; the default,
        // `CubeLineWidth::OneChannel`, is a box one channel wide.
        line_width: CubeLineWidth::Settings,
    };
    let cube = render_cube(&scene, &st, &spec, &|| {})?;
    let dir = std::env::temp_dir();
    std::fs::write(
        dir.join("shell_cube.fits"),
        fits_bytes(&cube, &CubeMeta::default())?,
    )?;
    std::fs::write(dir.join("shell_cube.nrrd"), nrrd_bytes(&cube)?)?;
    let m = cube.moments();
    let row: Vec<String> = (0..cube.nx)
        .step_by(4)
        .map(|x| format!("{:.0}", m.m1[(cube.ny / 2) * cube.nx + x] / 1e3))
        .collect();
    println!("moment 1 along the middle row (km/s): {}", row.join(" "));
    println!("wrote {}", dir.join("shell_cube.fits").display());
    Ok(())
}
