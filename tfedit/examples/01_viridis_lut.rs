//! Builds a 16-bit (65,536-entry) lookup table from the built-in viridis map with a low
//! global opacity, encodes it into a 4,096-wide texture (HDR VolVis Fig. 8) and queries a
//! macrocell majorant.
//!
//! Run with `cargo run -p blueshift-tfedit --example 01_viridis_lut`.

use blueshift_tfedit::{Lut2d, Result, builtin_over};

fn main() -> Result<()> {
    // Viridis stretched over a 16-bit data range, with alpha_g = 0.005 (HDR VolVis Fig. 3c).
    let tf = builtin_over("viridis", [0.0, 65_535.0])?.with_alpha_g(0.005)?;
    let lut = tf.lut(65_536)?;
    let tex = Lut2d::encode_for_max_texture(&lut, 4096)?;
    println!(
        "{} entries -> {} x {} texture (n = {} entries per row)",
        lut.len(),
        tex.rows(),
        tex.width(),
        tex.row_len()
    );
    // A macrocell whose voxels span [1,000, 20,000] never exceeds this opacity.
    let majorant = tf.max_opacity(1_000.0..=20_000.0);
    println!("max opacity over [1000, 20000] = {majorant:e}");
    println!("rgba at 30,000 = {:?}", tf.eval(30_000.0));
    Ok(())
}
