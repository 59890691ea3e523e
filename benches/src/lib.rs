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

/// One curve of [`line_plot`]: a label, points and a colour (RGB).
#[derive(Debug, Clone)]
pub struct Curve {
    /// Legend label.
    pub label: String,
    /// Points `(x, y)` in order.
    pub points: Vec<(f64, f64)>,
    /// Colour.
    pub rgb: (u8, u8, u8),
}

/// Draws curves on linear axes (x from the data, y from 0) into a PNG at `path`.
pub fn line_plot(
    path: &std::path::Path,
    title: &str,
    x_label: &str,
    y_label: &str,
    curves: &[Curve],
) -> std::result::Result<(), Box<dyn std::error::Error>> {
    use plotters::prelude::*;
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        let _ = plotters::style::register_font(
            "sans-serif",
            FontStyle::Normal,
            include_bytes!("../assets/DejaVuSansMono.ttf"),
        );
    });
    let pts = curves.iter().flat_map(|c| c.points.iter());
    let (mut x0, mut x1, mut y1) = (f64::INFINITY, f64::NEG_INFINITY, 0.0f64);
    for &(x, y) in pts {
        x0 = x0.min(x);
        x1 = x1.max(x);
        y1 = y1.max(y);
    }
    if x0.partial_cmp(&x1) != Some(std::cmp::Ordering::Less) {
        return Err("nothing to plot".into());
    }
    let root = BitMapBackend::new(path, (720, 480)).into_drawing_area();
    root.fill(&WHITE)?;
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(x0..x1, 0.0..y1 * 1.05)?;
    chart
        .configure_mesh()
        .x_desc(x_label)
        .y_desc(y_label)
        .label_style(("sans-serif", 14))
        .draw()?;
    for c in curves {
        let colour = RGBColor(c.rgb.0, c.rgb.1, c.rgb.2);
        chart
            .draw_series(LineSeries::new(
                c.points.iter().copied(),
                colour.stroke_width(2),
            ))?
            .label(c.label.clone())
            .legend(move |(x, y)| {
                PathElement::new(vec![(x, y), (x + 20, y)], colour.stroke_width(2))
            });
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .label_font(("sans-serif", 14))
        .draw()?;
    root.present()?;
    Ok(())
}
