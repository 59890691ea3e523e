//! Plot helpers: the embedded font and a line plot of spectra, written as PNG.

use std::path::Path;
use std::sync::Once;

use anyhow::{Context, Result, anyhow};
use plotters::prelude::*;

/// The font family name under which the embedded DejaVu Sans is registered.
pub const FONT: &str = "sans-serif";

/// Registers the embedded font with plotters (once per process).
pub fn register_font() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        // The font is a known-good file compiled into the binary.
        let _ = plotters::style::register_font(
            FONT,
            FontStyle::Normal,
            include_bytes!("../assets/DejaVuSans.ttf"),
        );
    });
}

/// One curve of a line plot: points in order (a repeated x draws a vertical jump).
#[derive(Debug)]
pub struct Series {
    /// Legend label.
    pub label: String,
    /// The points.
    pub points: Vec<(f64, f64)>,
    /// The colour.
    pub colour: RGBColor,
}

/// Draws curves with axes, labels and a legend into a PNG at `path` (written atomically).
pub fn line_plot(
    path: &Path,
    title: &str,
    x_label: &str,
    y_label: &str,
    series: &[Series],
    size: (u32, u32),
) -> Result<()> {
    register_font();
    let (mut x0, mut x1, mut y1) = (f64::INFINITY, f64::NEG_INFINITY, 0.0f64);
    for s in series {
        for &(x, y) in &s.points {
            x0 = x0.min(x);
            x1 = x1.max(x);
            y1 = y1.max(y);
        }
    }
    if x0.partial_cmp(&x1) != Some(std::cmp::Ordering::Less) {
        return Err(anyhow!("nothing to plot"));
    }
    if y1.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
        y1 = 1.0;
    }
    let mut buf = vec![0u8; (size.0 * size.1 * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, size).into_drawing_area();
        root.fill(&WHITE).map_err(|e| anyhow!("plot: {e}"))?;
        let mut chart = ChartBuilder::on(&root)
            .caption(title, (FONT, 22))
            .margin(12)
            .x_label_area_size(45)
            .y_label_area_size(80)
            .build_cartesian_2d(x0..x1, 0.0..y1 * 1.05)
            .map_err(|e| anyhow!("plot: {e}"))?;
        chart
            .configure_mesh()
            .x_desc(x_label)
            .y_desc(y_label)
            .label_style((FONT, 14))
            .y_label_formatter(&|v| format!("{v:.3e}"))
            .draw()
            .map_err(|e| anyhow!("plot: {e}"))?;
        for s in series {
            let colour = s.colour;
            chart
                .draw_series(LineSeries::new(
                    s.points.iter().copied(),
                    colour.stroke_width(2),
                ))
                .map_err(|e| anyhow!("plot: {e}"))?
                .label(s.label.clone())
                .legend(move |(x, y)| {
                    PathElement::new([(x, y), (x + 20, y)], colour.stroke_width(2))
                });
        }
        if series.len() > 1 || !series[0].label.is_empty() {
            chart
                .configure_series_labels()
                .label_font((FONT, 14))
                .background_style(WHITE.mix(0.8))
                .border_style(BLACK)
                .draw()
                .map_err(|e| anyhow!("plot: {e}"))?;
        }
        root.present().map_err(|e| anyhow!("plot: {e}"))?;
    }
    let img =
        image::RgbImage::from_raw(size.0, size.1, buf).context("plot buffer has the wrong size")?;
    crate::output::write_via_temp_path(path, |tmp| {
        img.save_with_format(tmp, image::ImageFormat::Png)
            .with_context(|| format!("cannot write {}", path.display()))
    })
}

/// Inferno-like colour map (sRGB 8-bit) at `x` in [0, 1] (non-finite -> 0).
pub fn inferno(x: f32) -> RGBColor {
    const STOPS: [[f32; 3]; 5] = [
        [0.0, 0.0, 4.0],
        [87.0, 16.0, 110.0],
        [188.0, 55.0, 84.0],
        [249.0, 142.0, 9.0],
        [252.0, 255.0, 164.0],
    ];
    ramp(&STOPS, x)
}

/// Diverging blue-white-red colour map at `x` in [0, 1] (white at 0.5).
pub fn blue_red(x: f32) -> RGBColor {
    const STOPS: [[f32; 3]; 5] = [
        [5.0, 48.0, 97.0],
        [103.0, 169.0, 207.0],
        [247.0, 247.0, 247.0],
        [239.0, 138.0, 98.0],
        [103.0, 0.0, 31.0],
    ];
    ramp(&STOPS, x)
}

/// Linear interpolation through five evenly spaced colour stops.
fn ramp(stops: &[[f32; 3]; 5], x: f32) -> RGBColor {
    let x = if x.is_finite() {
        x.clamp(0.0, 1.0)
    } else {
        0.0
    } * 4.0;
    let i = (x.floor() as usize).min(3);
    let f = x - i as f32;
    let c = |k: usize| (stops[i][k] + f * (stops[i + 1][k] - stops[i][k])).round() as u8;
    RGBColor(c(0), c(1), c(2))
}
