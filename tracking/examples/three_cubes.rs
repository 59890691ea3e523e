//! Renders the three overlapping cubes of MDWT Fig. 3 with density, max and mix blending
//! (1-DDA multi-density Woodcock tracking) and writes `three_cubes_<blend>.exr` into the
//! current folder (or the folder given as the first argument).
//!
//! `cargo run --release -p blueshift-tracking --example three_cubes -- /tmp`

use std::path::PathBuf;

use blueshift_tfedit::{ColorKnot, OpacityKnot, TransferFunction};
use blueshift_tracking::{Blend, DdaMode, Integrator, RenderSettings, Scene, render};
use blueshift_volume::synth;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let out = PathBuf::from(std::env::args().nth(1).unwrap_or_else(|| ".".into()));
    let volume = synth::three_cubes(64)?;
    // Flat primary colours, opacity proportional to the cube's density ramp.
    let tfs = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
        .into_iter()
        .map(|rgb| {
            TransferFunction::new(
                [0.0, 1.0],
                vec![ColorKnot { x: 0.0, rgb }],
                vec![OpacityKnot::new(0.0, 0.0), OpacityKnot::new(1.0, 1.0)],
            )
        })
        .collect::<Result<Vec<_>, _>>()?;
    let mut scene = Scene::from_volume(&volume, tfs, 12.0, 4)?;
    scene.background = [1.0, 1.0, 1.0];
    let mut settings = RenderSettings::default_for(&scene, 256, 256, false);
    settings.spp = 64;
    for (name, blend) in [
        ("density", Blend::Density),
        ("max", Blend::Max),
        (
            "mix",
            Blend::Mix {
                weights: Blend::equal_weights(3),
            },
        ),
    ] {
        let image = render(
            &scene,
            &Integrator::Mdwt {
                dda: DdaMode::OneDda,
                blend,
            },
            &settings,
        )?;
        let path = out.join(format!("three_cubes_{name}.exr"));
        image.save_with_format(&path, image::ImageFormat::OpenExr)?;
        println!("wrote {}", path.display());
    }
    Ok(())
}
