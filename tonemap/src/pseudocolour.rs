//! Pseudocolour of log luminance with a colour bar in data units (HDR VolVis Fig. 4a).

use ab_glyph::{Font, FontRef, PxScale, ScaleFont};
use image::{Rgb, Rgb32FImage, RgbImage};

use crate::error::{Error, Result};
use crate::plane::{Plane, positive_range};
use crate::sanitize::sanitize;

/// DejaVu Sans Mono (Bitstream Vera licence, see `assets/LICENSE-DejaVu.txt`).
const FONT: &[u8] = include_bytes!("../assets/DejaVuSansMono.ttf");

/// Colour maps for [`pseudocolour()`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub enum Palette {
    /// Blue - cyan - green - yellow - red, as in HDR VolVis Fig. 4a.
    #[default]
    Rainbow,
    /// Black to white.
    Grey,
}

impl Palette {
    /// Colour for `t` in [0, 1] (clamped), 8-bit sRGB.
    #[must_use]
    pub fn colour(self, t: f32) -> [u8; 3] {
        let t = if t.is_finite() {
            t.clamp(0.0, 1.0)
        } else {
            0.0
        };
        match self {
            Palette::Grey => {
                let v = (t * 255.0).round() as u8;
                [v, v, v]
            }
            Palette::Rainbow => {
                const KNOTS: [[f32; 3]; 5] = [
                    [0.0, 0.0, 1.0],
                    [0.0, 1.0, 1.0],
                    [0.0, 1.0, 0.0],
                    [1.0, 1.0, 0.0],
                    [1.0, 0.0, 0.0],
                ];
                let x = t * 4.0;
                let i = (x.floor() as usize).min(3);
                let f = x - i as f32;
                std::array::from_fn(|c| {
                    let v = KNOTS[i][c] * (1.0 - f) + KNOTS[i + 1][c] * f;
                    (v * 255.0).round() as u8
                })
            }
        }
    }
}

/// Settings of [`pseudocolour()`].
#[derive(Clone, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct PseudocolourParams {
    /// Colour map.
    pub palette: Palette,
    /// Luminance range mapped to the palette's ends, in image units; `None` = the image's
    /// smallest non-zero and largest luminance.
    pub range: Option<(f32, f32)>,
    /// Whether to append a colour bar with labelled decades on the right.
    pub colour_bar: bool,
    /// The quantity the bar shows, written above it (default `luminance`).
    #[cfg_attr(feature = "serde", serde(default = "default_label"))]
    pub label: String,
}

fn default_label() -> String {
    "luminance".to_owned()
}

impl Default for PseudocolourParams {
    fn default() -> Self {
        Self {
            palette: Palette::Rainbow,
            range: None,
            colour_bar: true,
            label: default_label(),
        }
    }
}

/// Colours each pixel by `log10` of its luminance between the range ends; pixels of zero
/// luminance are black. With `colour_bar`, a bar labelled in luminance units (powers of
/// ten) is drawn to the right of the image.
///
/// # Errors
/// [`Error::EmptyImage`]; [`Error::Parameter`] for a range that is not `0 < lo < hi`.
pub fn pseudocolour(img: &Rgb32FImage, params: &PseudocolourParams) -> Result<RgbImage> {
    if img.width() == 0 || img.height() == 0 {
        return Err(Error::EmptyImage);
    }
    let (clean, _) = sanitize(img);
    let lum = Plane::luminance_of(&clean);
    let (lo, hi) = match params.range {
        Some((lo, hi)) => {
            if !(lo > 0.0 && hi > lo && hi.is_finite()) {
                return Err(Error::parameter(format!(
                    "pseudocolour range must satisfy 0 < lo < hi, got ({lo}, {hi})"
                )));
            }
            (lo, hi)
        }
        None => positive_range(&lum).unwrap_or((1.0, 10.0)),
    };
    let (llo, lhi) = (lo.log10(), hi.log10().max(lo.log10() + 1e-6));
    let (w, h) = (img.width(), img.height());
    let bar_w = if params.colour_bar { 110 } else { 0 };
    let mut out = RgbImage::from_pixel(w + bar_w, h, Rgb([255, 255, 255]));
    for y in 0..h {
        for x in 0..w {
            let l = lum.data[(y * w + x) as usize];
            let c = if l > 0.0 {
                params.palette.colour((l.log10() - llo) / (lhi - llo))
            } else {
                [0, 0, 0]
            };
            out.put_pixel(x, y, Rgb(c));
        }
    }
    if params.colour_bar {
        draw_bar(&mut out, w, h, llo, lhi, params.palette, &params.label);
    }
    Ok(out)
}

fn draw_bar(
    out: &mut RgbImage,
    x0: u32,
    h: u32,
    llo: f32,
    lhi: f32,
    palette: Palette,
    label: &str,
) {
    let px = (h as f32 / 20.0).clamp(8.0, 14.0);
    let margin = 8u32.min(h / 4);
    // Room for the quantity's name above the bar.
    let title_h = (px * 1.4).ceil() as u32 + 2;
    let top = (margin + title_h).min(h / 3);
    let bottom = h.saturating_sub(margin).max(top + 1);
    let (bx0, bx1) = (x0 + 8, x0 + 28);
    let span = (bottom - top).max(1) as f32;
    for y in top..bottom {
        let t = 1.0 - (y - top) as f32 / span;
        let c = palette.colour(t);
        for x in bx0..bx1 {
            out.put_pixel(x, y, Rgb(c));
        }
    }
    let font = FontRef::try_from_slice(FONT).expect("bundled font parses");
    draw_text(out, &font, label, (x0 + 6) as f32, top as f32 - 4.0, px);
    // Ticks at integer decades; if the range spans less than one decade, at its ends.
    let mut ticks: Vec<f32> = (llo.ceil() as i32..=lhi.floor() as i32)
        .map(|e| e as f32)
        .collect();
    let max_ticks = ((bottom - top) as f32 / (px * 1.5)).max(2.0) as usize;
    if ticks.len() > max_ticks {
        let stride = ticks.len().div_ceil(max_ticks);
        ticks = ticks.into_iter().step_by(stride).collect();
    }
    if ticks.is_empty() {
        ticks = vec![llo, lhi];
    }
    for e in ticks {
        let t = (e - llo) / (lhi - llo).max(1e-6);
        let y = bottom as f32 - t * span;
        let yi = (y.round() as u32).clamp(top, bottom - 1);
        for x in bx1..bx1 + 5 {
            out.put_pixel(x, yi, Rgb([0, 0, 0]));
        }
        let label = if (e - e.round()).abs() < 1e-4 {
            format!("1e{}", e.round() as i32)
        } else {
            format!("{:.2e}", 10f32.powf(e))
        };
        draw_text(out, &font, &label, (bx1 + 8) as f32, y + px * 0.35, px);
    }
}

/// Draws `text` in black from `(x, baseline)` at `px` pixels (darkening only).
fn draw_text(out: &mut RgbImage, font: &FontRef<'_>, text: &str, x: f32, baseline: f32, px: f32) {
    let scaled = font.as_scaled(PxScale::from(px));
    let mut caret = x;
    for ch in text.chars() {
        let gid = font.glyph_id(ch);
        let glyph =
            gid.with_scale_and_position(PxScale::from(px), ab_glyph::point(caret, baseline));
        caret += scaled.h_advance(gid);
        if let Some(outline) = font.outline_glyph(glyph) {
            let b = outline.px_bounds();
            outline.draw(|gx, gy, cov| {
                let xx = b.min.x as i64 + i64::from(gx);
                let yy = b.min.y as i64 + i64::from(gy);
                if xx >= 0 && yy >= 0 && (xx as u32) < out.width() && (yy as u32) < out.height() {
                    let p = out.get_pixel_mut(xx as u32, yy as u32);
                    let v = (255.0 * (1.0 - cov.clamp(0.0, 1.0))) as u8;
                    let v = v.min(p[0]);
                    *p = Rgb([v, v, v]);
                }
            });
        }
    }
}
