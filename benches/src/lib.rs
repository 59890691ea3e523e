//! # blueshift-benches: paper reproductions on the CPU
//!
//! Criterion benchmarks that repeat the MDWT paper's evaluation (Fig. 8: render time
//! against macrocell size; Fig. 9: render time against channel count for N-DDA, 1-DDA and
//! the ray marcher; Table 1: memory of macrocell and majorant grids against the data),
//! writing their tables as CSV under `target/blueshift-benches/`.
//!
//! ## Where do I start?
//! `cargo bench -p blueshift-benches -- --warm-up-time 1 --measurement-time 3`, then read
//! the CSV files. This library holds the shared scene builders ([`channel_scene`]).
//!
//! ## Glossary (paper term → item)
//! | Paper | Here |
//! |---|---|
//! | Fig. 8 (macrocell size) | bench `mdwt`, group `fig8_macrocell` |
//! | Fig. 9 (channel count) | bench `mdwt`, group `fig9_channels` |
//! | Table 1 (memory) | [`memory_table`] |

use std::path::PathBuf;

use blueshift_tfedit::{ColorKnot, OpacityKnot, TransferFunction};
use blueshift_tracking::{Result, Scene};
use blueshift_volume::synth;

/// A flat transfer function over `[0, 1]`: colour `rgb`, opacity rising linearly from 0 at
/// 0.05 to 1 at 1 (so empty space has zero majorant).
pub fn ramp_tf(rgb: [f32; 3]) -> Result<TransferFunction> {
    Ok(TransferFunction::new(
        [0.0, 1.0],
        vec![ColorKnot { x: 0.0, rgb }, ColorKnot { x: 1.0, rgb }],
        vec![
            OpacityKnot::new(0.0, 0.0),
            OpacityKnot::new(0.05, 0.0),
            OpacityKnot::new(1.0, 1.0),
        ],
    )?)
}

/// The first `n` channels (1..=12) of `synth::channels12(res, 7)` with ramp transfer
/// functions of distinct hues, macrocells of `k` voxels, density scale `density_scale`.
pub fn channel_scene(n: usize, res: usize, k: usize, density_scale: f32) -> Result<Scene> {
    let vol = synth::channels12(res, 7)?;
    let mut triples = Vec::new();
    for (i, ch) in vol.channels().iter().take(n.clamp(1, 12)).enumerate() {
        let h = i as f32 / 12.0;
        let rgb = [
            0.5 + 0.5 * (std::f32::consts::TAU * h).cos(),
            0.5 + 0.5 * (std::f32::consts::TAU * (h + 0.33)).cos(),
            0.5 + 0.5 * (std::f32::consts::TAU * (h + 0.67)).cos(),
        ];
        triples.push((ch.name.clone(), ch.grid.clone(), ramp_tf(rgb)?));
    }
    Scene::new(triples, density_scale, k)
}

/// Table 1: `(channels, data bytes, macrocell bytes, majorant bytes)` for a scene.
#[must_use]
pub fn memory_table(scene: &Scene) -> (usize, usize, usize, usize) {
    let n = scene.channel_count();
    let voxels = scene.geometry().voxel_count();
    let data: usize = scene
        .channels()
        .iter()
        .map(|c| voxels * c.grid().scalar_type().size_bytes())
        .sum();
    let cells = scene.layout().len();
    let macro_bytes = n * cells * 2 * std::mem::size_of::<f32>();
    let maj: usize = scene
        .channels()
        .iter()
        .map(|c| c.majorant().memory_bytes())
        .sum();
    (n, data, macro_bytes, maj)
}

/// Where the benches write their CSV files: `$CARGO_TARGET_DIR` or `target/`, then
/// `blueshift-benches/`.
#[must_use]
pub fn out_dir() -> PathBuf {
    let base = std::env::var_os("CARGO_TARGET_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../target")));
    let dir = base.join("blueshift-benches");
    let _ = std::fs::create_dir_all(&dir);
    dir
}
