//! Plot helpers: the embedded font, a line plot of spectra written as PNG, the exact
//! polyline of a piecewise-linear spectrum and readable tick labels.

use std::path::Path;
use std::sync::Once;

use anyhow::{Context, Result, anyhow};
use blueshift_spectrum::PiecewiseLinear;
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

/// The curve and pick-ring colours of every plot and figure, in order.
pub const PALETTE: [RGBColor; 6] = [
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
    RGBColor(148, 103, 189),
    RGBColor(255, 127, 14),
    RGBColor(23, 190, 207),
];

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
            .x_label_formatter(&tick_formatter(x0, x1))
            .y_label_formatter(&tick_formatter(0.0, y1 * 1.05))
            .draw()
            .map_err(|e| anyhow!("plot: {e}"))?;
        for s in series {
            let colour = s.colour;
            // One element per segment: plotters fills a wide polyline as ONE polygon, in
            // which a narrow box (up, across a pixel, down) has no area and vanished.
            chart
                .draw_series(
                    s.points
                        .windows(2)
                        .map(|w| PathElement::new([w[0], w[1]], colour.stroke_width(2))),
                )
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
        blueshift_tonemap::io::save_rgb8_png(tmp, &img)
            .with_context(|| format!("cannot write {}", path.display()))
    })
}

/// The points of a spectrum for plots and CSV, exactly: both ends of every piece clipped to
/// `[lo, hi]`, with zeros in the gaps and vertical jumps (a repeated wavelength) at the
/// piece edges, so no piece is lost however narrow it is (no sampling on a grid).
pub fn exact_polyline(s: &PiecewiseLinear, lo: f64, hi: f64) -> Vec<(f64, f64)> {
    let mut pts: Vec<(f64, f64)> = vec![(lo, s.eval(lo))];
    for p in s.pieces() {
        if p.end_nm <= lo || p.start_nm >= hi {
            continue;
        }
        let a = p.start_nm.max(lo);
        let b = p.end_nm.min(hi);
        let last = *pts.last().expect("non-empty");
        if last.0 < a && last.1 != 0.0 {
            pts.push((last.0, 0.0));
        }
        if last.0 < a {
            pts.push((a, 0.0));
        }
        pts.push((a, p.at(a)));
        pts.push((b, p.at(b)));
    }
    let last = *pts.last().expect("non-empty");
    if last.0 < hi {
        if last.1 != 0.0 {
            pts.push((last.0, 0.0));
        }
        pts.push((hi, 0.0));
    }
    pts.dedup();
    pts
}

/// Tick labels for an axis spanning `lo..hi` (about ten ticks): fixed notation with as many
/// decimals as the tick step needs (`3.5`, `400`, `0.025`), scientific with a short mantissa
/// (`3.5e4`, `2e-6`) for very large or very small values. For plotters'
/// `x_label_formatter` / `y_label_formatter` and colour bars.
pub fn tick_formatter(lo: f64, hi: f64) -> impl Fn(&f64) -> String {
    let span = (hi - lo).abs();
    let step = if span > 0.0 && span.is_finite() {
        span / 10.0
    } else {
        1.0
    };
    // Digits that resolve a tenth of a step (ticks at 2.5 x 10^k need one more than the
    // step's decade); trailing zeros are trimmed.
    let step_exp = step.log10().floor() - 1.0;
    let mag = lo.abs().max(hi.abs());
    let mag_exp = if mag > 0.0 { mag.log10().floor() } else { 0.0 };
    let scientific = mag_exp >= 4.0 || mag_exp <= -4.0;
    move |v: &f64| {
        let v = *v;
        if v == 0.0 {
            return "0".to_owned();
        }
        if scientific {
            let digits = (mag_exp - step_exp).clamp(0.0, 6.0) as usize;
            let s = format!("{v:.digits$e}");
            // 3.50e4 -> 3.5e4, 2.0e-6 -> 2e-6.
            match s.split_once('e') {
                Some((m, e)) if m.contains('.') => {
                    format!("{}e{e}", m.trim_end_matches('0').trim_end_matches('.'))
                }
                _ => s,
            }
        } else {
            let decimals = (-step_exp).clamp(0.0, 9.0) as usize;
            let s = format!("{v:.decimals$}");
            if s.contains('.') {
                s.trim_end_matches('0').trim_end_matches('.').to_owned()
            } else {
                s
            }
        }
    }
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tick_labels_are_short_and_resolve_the_step() {
        let f = tick_formatter(0.0, 5.0);
        assert_eq!(f(&3.5), "3.5");
        assert_eq!(f(&1.0), "1");
        let f = tick_formatter(360.0, 830.0);
        assert_eq!(f(&400.0), "400");
        let f = tick_formatter(0.0, 0.25);
        assert_eq!(f(&0.025), "0.025");
        let f = tick_formatter(0.0, 3.5e4);
        assert_eq!(f(&3.5e4), "3.5e4");
        assert_eq!(f(&0.0), "0");
        let f = tick_formatter(0.0, 2e-5);
        assert_eq!(f(&2e-6), "2e-6");
    }

    #[test]
    fn exact_polyline_keeps_every_edge_of_a_narrow_box() {
        let s = PiecewiseLinear::boxed(500.0, 500.001, 7.0).unwrap();
        let pts = exact_polyline(&s, 360.0, 830.0);
        assert_eq!(
            pts,
            vec![
                (360.0, 0.0),
                (500.0, 0.0),
                (500.0, 7.0),
                (500.001, 7.0),
                (500.001, 0.0),
                (830.0, 0.0)
            ]
        );
    }
}
