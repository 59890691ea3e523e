//! A picture of the transfer-function editor view (HDR VolVis Fig. 6c and 7): the opacity
//! curve on a linear or logarithmic axis over the fisheye-scaled data axis, the focus
//! regions, the magnification curve, the colour bar and tick labels in data units.

use ab_glyph::{Font, FontRef, PxScale, ScaleFont, point};
use image::RgbImage;
use plotters::prelude::*;

use crate::axis::{Fisheye, ValueAxis};
use crate::tf::{DataAxis, TransferFunction};
use crate::{Error, Result};

static FONT_BYTES: &[u8] = include_bytes!("../assets/DejaVuSansMono.ttf");

fn load_font() -> Result<FontRef<'static>> {
    FontRef::try_from_slice(FONT_BYTES).map_err(|_| {
        Error::Unsupported("the bundled DejaVu Sans Mono font could not be loaded".into())
    })
}

/// A piece of text to draw once the lines are done: top-left corner, pixel size, colour.
struct Label {
    text: String,
    x: f32,
    y: f32,
    size: f32,
    color: [u8; 3],
}

/// Width in pixels of `text` at `size`.
fn text_width(font: &FontRef<'_>, size: f32, text: &str) -> f32 {
    let scaled = font.as_scaled(PxScale::from(size));
    let mut w = 0.0;
    let mut prev = None;
    for c in text.chars() {
        let id = scaled.glyph_id(c);
        if let Some(p) = prev {
            w += scaled.kern(p, id);
        }
        w += scaled.h_advance(id);
        prev = Some(id);
    }
    w
}

/// Draws text with ab_glyph, each glyph at its own origin and side bearing, blending its
/// coverage into the RGB buffer.
fn draw_label(buf: &mut [u8], w: u32, h: u32, font: &FontRef<'_>, l: &Label) {
    let scaled = font.as_scaled(PxScale::from(l.size));
    let baseline = l.y + scaled.ascent();
    let mut caret = l.x;
    let mut prev = None;
    for c in l.text.chars() {
        let id = scaled.glyph_id(c);
        if let Some(p) = prev {
            caret += scaled.kern(p, id);
        }
        prev = Some(id);
        let glyph = id.with_scale_and_position(l.size, point(caret, baseline));
        caret += scaled.h_advance(id);
        let Some(outline) = font.outline_glyph(glyph) else {
            continue;
        };
        let bounds = outline.px_bounds();
        outline.draw(|gx, gy, coverage| {
            let x = bounds.min.x as i64 + i64::from(gx);
            let y = bounds.min.y as i64 + i64::from(gy);
            if x < 0 || y < 0 || x >= i64::from(w) || y >= i64::from(h) {
                return;
            }
            let o = (y as usize * w as usize + x as usize) * 3;
            let a = coverage.clamp(0.0, 1.0);
            for k in 0..3 {
                let bg = f32::from(buf[o + k]);
                buf[o + k] = (bg + (f32::from(l.color[k]) - bg) * a).round() as u8;
            }
        });
    }
}

/// What to draw. Plain data with `Default` (1024 x 512, linear axes, magnification curve on).
#[derive(Clone, Debug, PartialEq)]
pub struct EditorView {
    /// Image width in pixels (320 to 8192).
    pub width: u32,
    /// Image height in pixels (240 to 8192).
    pub height: u32,
    /// Fisheye map of the transfer function's normalised data axis (linear = no focus).
    pub fisheye: Fisheye,
    /// Vertical axis of the opacity curve.
    pub opacity_axis: ValueAxis,
    /// Draw the magnification curve M(t) of Fig. 6b over the plot.
    pub show_magnification: bool,
}

impl Default for EditorView {
    fn default() -> Self {
        Self {
            width: 1024,
            height: 512,
            fisheye: Fisheye::linear(),
            opacity_axis: ValueAxis::Linear,
            show_magnification: true,
        }
    }
}

/// Pixel rectangles of the picture's parts (x0..x1, y0..y1, end-exclusive).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Layout {
    /// Left edge of the plot, colour bar and focus bar.
    pub x0: u32,
    /// Right edge (exclusive).
    pub x1: u32,
    /// Opacity plot rows.
    pub plot_y: (u32, u32),
    /// Focus bar rows (green over the focus regions, pale over their transitions).
    pub focus_y: (u32, u32),
    /// Colour bar rows.
    pub colorbar_y: (u32, u32),
}

impl Layout {
    /// Window position in [0, 1] of the centre of pixel column `px`.
    #[must_use]
    pub fn column_to_window(&self, px: u32) -> f64 {
        (f64::from(px) + 0.5 - f64::from(self.x0)) / f64::from(self.x1 - self.x0)
    }
    /// Pixel column containing window position `x` in [0, 1].
    #[must_use]
    pub fn window_to_column(&self, x: f64) -> u32 {
        let w = f64::from(self.x1 - self.x0);
        (f64::from(self.x0) + (x.clamp(0.0, 1.0) * w).floor()).min(f64::from(self.x1 - 1)) as u32
    }
}

impl EditorView {
    /// Where the parts go for this size.
    pub fn layout(&self) -> Result<Layout> {
        if !(320..=8192).contains(&self.width) || !(240..=8192).contains(&self.height) {
            return Err(Error::parameter(format!(
                "editor view size {} x {} must be within 320..=8192 x 240..=8192",
                self.width, self.height
            )));
        }
        let (x0, x1) = (78, self.width - 44);
        let top = 44;
        let bottom_axis = 40;
        let colorbar_h = 26;
        let focus_h = 8;
        let colorbar_y1 = self.height - bottom_axis;
        let colorbar_y0 = colorbar_y1 - colorbar_h;
        let focus_y1 = colorbar_y0 - 3;
        let focus_y0 = focus_y1 - focus_h;
        let plot_y1 = focus_y0 - 3;
        Ok(Layout {
            x0,
            x1,
            plot_y: (top, plot_y1),
            focus_y: (focus_y0, focus_y1),
            colorbar_y: (colorbar_y0, colorbar_y1),
        })
    }
}

const BG: [u8; 3] = [24, 24, 28];
const PLOT_BG: [u8; 3] = [40, 40, 46];

fn to_u8(c: f32) -> u8 {
    (c.clamp(0.0, 1.0) * 255.0).round() as u8
}

/// "Nice" tick values covering `[lo, hi]` with about `count` steps (1, 2, 5 x 10^k).
fn nice_ticks(lo: f64, hi: f64, count: usize) -> Vec<f64> {
    if hi.is_nan() || lo.is_nan() || hi <= lo || count == 0 {
        return vec![lo];
    }
    let raw = (hi - lo) / count as f64;
    let mag = 10f64.powf(raw.log10().floor());
    let step = [1.0, 2.0, 5.0, 10.0]
        .iter()
        .map(|m| m * mag)
        .find(|s| *s >= raw)
        .unwrap_or(10.0 * mag);
    // Beyond 1e6 ticks the step lost its meaning (a width at the end of f64's range).
    let (first, last) = ((lo / step).ceil(), (hi / step).floor());
    if !step.is_normal() || !(last - first).is_finite() || last - first > 1e6 {
        return vec![lo, hi];
    }
    (first as i64..=last as i64)
        .map(|k| k as f64 * step)
        .collect()
}

fn format_tick(v: f64) -> String {
    let a = v.abs();
    if v == 0.0 {
        "0".into()
    } else if !(1e-3..1e5).contains(&a) {
        let s = format!("{v:.1e}");
        s.replace(".0e", "e")
    } else {
        let s = format!("{v:.4}");
        let s = s.trim_end_matches('0').trim_end_matches('.');
        s.to_string()
    }
}

/// Renders the editor view of `tf`.
///
/// The horizontal axis is the transfer function's normalised data axis (linear or log in
/// the data) passed through `view.fisheye`; the opacity plotted is what
/// [`TransferFunction::eval`] returns (knot opacity times alpha_g), on `view.opacity_axis`,
/// with the area under it filled with the transfer function's colour.
pub fn render_editor_view(tf: &TransferFunction, view: &EditorView) -> Result<RgbImage> {
    let font = load_font()?;
    let mut labels: Vec<Label> = Vec::new();
    const WHITE_TEXT: [u8; 3] = [230, 230, 230];
    const YELLOW: [u8; 3] = [240, 200, 40];
    let lay = view.layout()?;
    let (w, h) = (view.width, view.height);
    let mut buf = vec![0u8; (w as usize) * (h as usize) * 3];
    let put = |buf: &mut [u8], x: u32, y: u32, c: [u8; 3]| {
        let o = (y as usize * w as usize + x as usize) * 3;
        buf[o..o + 3].copy_from_slice(&c);
    };
    for px in buf.chunks_exact_mut(3) {
        px.copy_from_slice(&BG);
    }
    let (py0, py1) = lay.plot_y;
    let plot_h = f64::from(py1 - py0);
    let y_of =
        |opacity: f64| -> f64 { f64::from(py1) - view.opacity_axis.forward(opacity) * plot_h };
    let value_of_col =
        |px: u32| tf.value_at_normalized(view.fisheye.inverse(lay.column_to_window(px)));

    // Colour bar, area under the opacity curve, focus bar: pixel by pixel.
    let mut curve = Vec::with_capacity((lay.x1 - lay.x0) as usize);
    for px in lay.x0..lay.x1 {
        let v = value_of_col(px);
        let [r, g, b, a] = tf.eval(v);
        let col = [to_u8(r), to_u8(g), to_u8(b)];
        for y in lay.colorbar_y.0..lay.colorbar_y.1 {
            put(&mut buf, px, y, col);
        }
        let top = y_of(f64::from(a));
        for y in py0..py1 {
            let c = if f64::from(y) + 0.5 >= top && a > 0.0 {
                col
            } else {
                PLOT_BG
            };
            put(&mut buf, px, y, c);
        }
        curve.push((px as i32, top.round() as i32));
        let t = view.fisheye.inverse(lay.column_to_window(px));
        let mut fc = PLOT_BG;
        for r in view.fisheye.regions() {
            let d = (t - r.center).abs();
            if d <= 0.5 * r.width {
                fc = [40, 200, 60];
            } else if d <= 0.5 * r.width + r.transition {
                fc = [110, 150, 110];
            }
        }
        for y in lay.focus_y.0..lay.focus_y.1 {
            put(&mut buf, px, y, fc);
        }
    }

    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        let draw_err = |e: DrawingAreaErrorKind<_>| {
            Error::Unsupported(format!("drawing the editor view failed: {e}"))
        };
        let white = RGBColor(230, 230, 230);
        let grid = RGBColor(75, 75, 85);

        // Horizontal grid and opacity tick labels.
        let opacity_ticks: Vec<f64> = match view.opacity_axis {
            ValueAxis::Linear => vec![0.0, 0.25, 0.5, 0.75, 1.0],
            ValueAxis::Log { floor } => {
                let k0 = floor.log10().ceil() as i32;
                (k0..=0).map(|k| 10f64.powi(k)).collect()
            }
        };
        for &o in &opacity_ticks {
            let y = y_of(o).round() as i32;
            root.draw(&PathElement::new(
                vec![(lay.x0 as i32, y), (lay.x1 as i32 - 1, y)],
                grid,
            ))
            .map_err(draw_err)?;
            let label = format_tick(o);
            let tw = text_width(&font, 12.0, &label);
            labels.push(Label {
                x: lay.x0 as f32 - 6.0 - tw,
                y: y as f32 - 7.0,
                size: 12.0,
                color: WHITE_TEXT,
                text: label,
            });
        }
        let axis_name = match view.opacity_axis {
            ValueAxis::Linear => "opacity".to_string(),
            ValueAxis::Log { .. } => "opacity (log)".to_string(),
        };
        labels.push(Label {
            text: axis_name,
            x: 4.0,
            y: 26.0,
            size: 12.0,
            color: WHITE_TEXT,
        });

        // Focus region edges.
        for r in view.fisheye.regions() {
            for (t, c) in [
                (r.center - 0.5 * r.width, RGBColor(40, 200, 60)),
                (r.center + 0.5 * r.width, RGBColor(40, 200, 60)),
            ] {
                if (0.0..=1.0).contains(&t) {
                    let x = lay.window_to_column(view.fisheye.forward(t)) as i32;
                    root.draw(&PathElement::new(
                        vec![(x, py0 as i32), (x, py1 as i32)],
                        c.stroke_width(1),
                    ))
                    .map_err(draw_err)?;
                }
            }
        }

        // Opacity curve and knots.
        root.draw(&PathElement::new(curve, white.stroke_width(2)))
            .map_err(draw_err)?;
        for k in tf.opacity_knots() {
            let x = lay.window_to_column(view.fisheye.forward(tf.normalized(k.x))) as i32;
            let y = y_of(f64::from(k.alpha) * f64::from(tf.alpha_g())).round() as i32;
            root.draw(&Circle::new((x, y), 4, white.filled()))
                .map_err(draw_err)?;
            root.draw(&Circle::new((x, y), 4, RGBColor(0, 0, 0).stroke_width(1)))
                .map_err(draw_err)?;
        }

        // Magnification curve M(t) (Fig. 6b), scaled so that max(M_c) reaches the top.
        if view.show_magnification && !view.fisheye.is_linear() {
            let mmax = view
                .fisheye
                .regions()
                .iter()
                .map(|r| r.magnification)
                .fold(1.0, f64::max);
            let pts: Vec<(i32, i32)> = (lay.x0..lay.x1)
                .map(|px| {
                    let m = view
                        .fisheye
                        .magnification(view.fisheye.inverse(lay.column_to_window(px)));
                    (
                        px as i32,
                        (f64::from(py1) - m / mmax * plot_h * 0.95).round() as i32,
                    )
                })
                .collect();
            root.draw(&PathElement::new(
                pts,
                RGBColor(240, 200, 40).stroke_width(1),
            ))
            .map_err(draw_err)?;
            let label = format!(
                "magnification: M_c {}, M_min {:.3}",
                format_tick(mmax),
                view.fisheye.m_min()
            );
            let tw = text_width(&font, 12.0, &label);
            labels.push(Label {
                x: lay.x1 as f32 - tw,
                y: py0 as f32 - 16.0,
                size: 12.0,
                color: YELLOW,
                text: label,
            });
        }

        // Data-axis ticks: context ticks over the whole domain, plus finer ticks inside
        // each focus region; labels only where they do not collide.
        let [lo, hi] = tf.domain();
        let mut ticks: Vec<(f64, bool)> = Vec::new();
        match tf.data_axis() {
            DataAxis::Linear => {
                for r in view.fisheye.regions() {
                    let a = tf.value_at_normalized(r.center - 0.5 * r.width);
                    let b = tf.value_at_normalized(r.center + 0.5 * r.width);
                    ticks.extend(nice_ticks(a, b, 4).into_iter().map(|v| (v, true)));
                }
                ticks.extend(nice_ticks(lo, hi, 8).into_iter().map(|v| (v, false)));
            }
            DataAxis::Log => {
                for r in view.fisheye.regions() {
                    let a = tf.value_at_normalized(r.center - 0.5 * r.width);
                    let b = tf.value_at_normalized(r.center + 0.5 * r.width);
                    ticks.extend(nice_ticks(a, b, 4).into_iter().map(|v| (v, true)));
                }
                let (k0, k1) = (lo.log10().ceil() as i32, hi.log10().floor() as i32);
                ticks.extend((k0..=k1).map(|k| (10f64.powi(k), false)));
            }
        }
        ticks.push((lo, false));
        ticks.push((hi, false));
        let ty = lay.colorbar_y.1 as i32;
        let mut taken: Vec<(f32, f32)> = Vec::new();
        for (v, focus) in ticks {
            if !(lo..=hi).contains(&v) {
                continue;
            }
            let x = lay.window_to_column(view.fisheye.forward(tf.normalized(v))) as i32;
            let len = if focus { 4 } else { 7 };
            root.draw(&PathElement::new(vec![(x, ty), (x, ty + len)], white))
                .map_err(draw_err)?;
            let label = format_tick(v);
            let tw = text_width(&font, 12.0, &label);
            let left = (x as f32 - tw / 2.0).clamp(0.0, (w as f32 - tw).max(0.0));
            let (a, b) = (left - 4.0, left + tw + 4.0);
            if taken.iter().any(|&(p, q)| a < q && p < b) {
                continue;
            }
            taken.push((a, b));
            labels.push(Label {
                x: left,
                y: ty as f32 + 10.0,
                size: 12.0,
                color: WHITE_TEXT,
                text: label,
            });
        }

        let title = format!(
            "{}  domain [{}, {}]  {} axis  alpha_g = {}",
            if tf.name().is_empty() {
                "transfer function"
            } else {
                tf.name()
            },
            format_tick(lo),
            format_tick(hi),
            match tf.data_axis() {
                DataAxis::Linear => "linear",
                DataAxis::Log => "log",
            },
            tf.alpha_g()
        );
        labels.push(Label {
            text: title,
            x: 4.0,
            y: 6.0,
            size: 13.0,
            color: WHITE_TEXT,
        });
        root.present().map_err(draw_err)?;
    }
    for l in &labels {
        draw_label(&mut buf, w, h, &font, l);
    }
    RgbImage::from_raw(w, h, buf)
        .ok_or_else(|| Error::Unsupported("editor view buffer has the wrong size".into()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nice_ticks_are_1_2_5_multiples_inside_the_range() {
        let t = nice_ticks(0.0, 1.0, 5);
        assert_eq!(t.len(), 6);
        for (k, v) in t.iter().enumerate() {
            assert!((v - 0.2 * k as f64).abs() < 1e-12, "{t:?}");
        }
        let t = nice_ticks(13.0, 97.0, 8);
        assert!(t.iter().all(|v| (13.0..=97.0).contains(v)), "{t:?}");
        assert_eq!(t[0], 20.0);
        // A subnormal width gives a zero step: the ends, not 2^63 ticks.
        assert_eq!(nice_ticks(0.0, 5e-324, 8), vec![0.0, 5e-324]);
        assert_eq!(nice_ticks(-1e308, 1e308, 8).len(), 2);
    }
}
