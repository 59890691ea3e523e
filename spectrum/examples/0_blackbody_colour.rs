//! The colour of black bodies from 1,000 K to 40,000 K, and the piece count of their
//! piecewise-linear approximation at 0.1 % error.
//!
//!     cargo run -p blueshift-spectrum --example 0_blackbody_colour

use blueshift_spectrum::*;

fn main() -> Result<()> {
    println!("T_K,x,y,r,g,b,pieces_at_1e-3");
    for t in [
        1000.0, 1500.0, 2000.0, 3000.0, 4000.0, 5800.0, 6500.0, 10_000.0, 20_000.0, 40_000.0,
    ] {
        let bb = Blackbody::new(t)?;
        let xyz = bb.to_xyz();
        let [x, y] = xyz.chromaticity().expect("non-zero");
        // Display colour: luminance normalised to 1, then sRGB-encoded.
        let rgb = xyz.scaled(1.0 / xyz.y).to_linear_srgb().map(srgb_encode);
        let pieces = bb.to_piecewise(360.0, 830.0, 1e-3)?.piece_count();
        println!(
            "{t},{x:.5},{y:.5},{:.3},{:.3},{:.3},{pieces}",
            rgb[0], rgb[1], rgb[2]
        );
    }
    Ok(())
}
