//! Publication figures of Doppler renders: true-colour panels with a scale bar and the
//! Doppler colour key, a velocity-coded (moment-1) panel with its colour bar in km/s, and the
//! picked spectra with readable ticks.

use crate::plot::PALETTE as RING;
use std::path::Path;

use anyhow::{Context, Result, anyhow};
use blueshift_doppler::{
    CubeLineWidth, CubeSpec, DopplerScene, DopplerSettings, SpectralAxis, doppler_colour_key,
    render_cube,
};
use plotters::prelude::*;

use crate::output::write_via_temp_path;
use crate::plot::{FONT, register_font};

/// Ticks at 1, 2 or 5 times a power of ten covering `[lo, hi]` with about `n` intervals, and
/// their step.
pub fn nice_ticks(lo: f64, hi: f64, n: usize) -> (Vec<f64>, f64) {
    if !(lo.is_finite() && hi.is_finite() && hi > lo) {
        return (vec![lo], 1.0);
    }
    let raw = (hi - lo) / n.max(1) as f64;
    let p = 10f64.powf(raw.log10().floor());
    let step = [1.0, 2.0, 5.0, 10.0]
        .into_iter()
        .map(|m| m * p)
        .find(|s| *s >= raw)
        .unwrap_or(10.0 * p);
    let first = (lo / step).ceil() as i64;
    let last = (hi / step).floor() as i64;
    ((first..=last).map(|k| k as f64 * step).collect(), step)
}

/// A tick label with as many decimals as the step needs (`3.5`, not `3.50e0`; `0` for
/// zero); scientific notation only for very large or small magnitudes.
pub fn tick_label(v: f64, step: f64) -> String {
    if v == 0.0 || v.abs() < step * 1e-9 {
        return "0".into();
    }
    let mag = v.abs().max(step.abs());
    if !(1e-3..1e6).contains(&mag) {
        let digits = ((mag.log10().floor() - step.log10().floor()).max(0.0)) as usize;
        return format!("{v:.digits$e}");
    }
    let decimals = (-step.log10().floor()).max(0.0) as usize;
    format!("{v:.decimals$}")
}

/// An axis label of a value at any tick step: at most 4 significant decimals, trailing zeros
/// dropped (`3.5`, `2`, `0.25`; scientific only for very large or small magnitudes).
pub fn axis_label(v: f64) -> String {
    if v == 0.0 || !v.is_finite() {
        return "0".into();
    }
    if !(1e-3..1e6).contains(&v.abs()) {
        let t = format!("{v:.3e}");
        let (m, e) = t.split_once('e').unwrap_or((&t, "0"));
        let m = if m.contains('.') {
            m.trim_end_matches('0').trim_end_matches('.')
        } else {
            m
        };
        return format!("{m}e{e}");
    }
    let t = format!("{v:.4}");
    let t = t.trim_end_matches('0').trim_end_matches('.');
    if t == "-0" { "0".into() } else { t.to_owned() }
}

/// A diverging blue-white-red map for line-of-sight velocities (ColorBrewer RdBu, reversed:
/// approaching blue, receding red), `t` in [0, 1].
pub fn diverging(t: f64) -> [u8; 3] {
    const STOPS: [[f64; 3]; 7] = [
        [33.0, 102.0, 172.0],
        [103.0, 169.0, 207.0],
        [209.0, 229.0, 240.0],
        [247.0, 247.0, 247.0],
        [253.0, 219.0, 199.0],
        [239.0, 138.0, 98.0],
        [178.0, 24.0, 43.0],
    ];
    let t = if t.is_finite() {
        t.clamp(0.0, 1.0)
    } else {
        0.5
    };
    let x = t * (STOPS.len() - 1) as f64;
    let i = (x.floor() as usize).min(STOPS.len() - 2);
    let f = x - i as f64;
    std::array::from_fn(|c| (STOPS[i][c] + f * (STOPS[i + 1][c] - STOPS[i][c])).round() as u8)
}

/// The line-of-sight velocity map (km/s, row 0 at the top) of the H-alpha line: moment 1 of
/// a spectral cube of the lines alone (black body off, the scene's velocity factor 1, so the
/// velocities are physical) over +-`vmax_kms`; pixels whose moment 0 is below `mask` times
/// the 99th percentile of moment 0 are `None` (their moment 1 is noise).
pub fn velocity_map(
    scene: &DopplerScene,
    settings: &DopplerSettings,
    vmax_kms: f64,
    mask: f64,
) -> Result<Option<Vec<Option<f32>>>> {
    let Some(rest) = scene
        .species()
        .iter()
        .flat_map(|s| s.emission_lines.iter())
        .map(|l| l.centre_nm)
        .filter(|c| (c - 656.28).abs() < 0.5)
        .reduce(f64::min)
    else {
        return Ok(None);
    };
    let mut sc = scene.clone();
    sc.factors.blackbody = 0.0;
    sc.factors.absorption = 0.0;
    sc.factors.velocity = 1.0;
    let spec = CubeSpec {
        rest_nm: rest,
        axis: SpectralAxis::RadioVelocity,
        min: -vmax_kms * 1e3,
        max: vmax_kms * 1e3,
        channels: 64,
        line_width: CubeLineWidth::OneChannel,
    };
    let cube = render_cube(&sc, settings, &spec, &|| {}).context("velocity panel")?;
    let m = cube.moments();
    let mut m0: Vec<f32> = m.m0.iter().copied().filter(|v| *v > 0.0).collect();
    m0.sort_by(f32::total_cmp);
    let p99 = m0
        .get((m0.len().saturating_sub(1)) * 99 / 100)
        .copied()
        .unwrap_or(0.0);
    let (w, h) = (m.nx, m.ny);
    let mut out = vec![None; w * h];
    for y in 0..h {
        for x in 0..w {
            let i = (h - 1 - y) * w + x;
            if f64::from(m.m0[i]) > mask * f64::from(p99) && m.m1[i].is_finite() {
                out[y * w + x] = Some(m.m1[i] / 1e3);
            }
        }
    }
    Ok(Some(out))
}

/// Density and velocity voxels for figure statistics: the scene's own in memory, the
/// coarsest level of detail when they are bricked.
fn figure_samples(
    scene: &DopplerScene,
    density: &blueshift_volume::Field,
    v: &blueshift_volume::VectorField,
) -> Option<(Vec<f32>, blueshift_volume::Grid<glam::Vec3>)> {
    let limits = blueshift_volume::Limits::default();
    match scene.levels() {
        Some(levels) if levels.len() > 1 => {
            let coarse = scene.at_level(levels.len() - 1).ok()?;
            let d = coarse.species().first()?.density.dense_f32().ok()?;
            Some((d, coarse.velocity()?.to_dense(&limits).ok()?))
        }
        _ => Some((density.dense_f32().ok()?, v.to_dense(&limits).ok()?)),
    }
}

/// The largest line-of-sight speed (km/s, physical) of gas whose first species' density is
/// above 1e-3 of its maximum, seen along the camera of `settings` (the velocity panel's
/// range); 100 km/s without a velocity field.
pub fn los_speed_kms(scene: &DopplerScene, settings: &DopplerSettings) -> f64 {
    let (Some(v), Some(sp)) = (scene.velocity(), scene.species().first()) else {
        return 100.0;
    };
    let dir = settings.camera.basis().0;
    // Out-of-core scenes: the coarsest level (a few bricks) stands in for the voxels.
    let Some((d, vel)) = figure_samples(scene, &sp.density, v) else {
        return 100.0;
    };
    let dmax = d.iter().copied().fold(0.0f32, f32::max);
    let mut speeds: Vec<f32> = vel
        .data()
        .iter()
        .zip(&d)
        .filter(|(_, rho)| **rho > 1e-3 * dmax)
        .map(|(vel, _)| vel.dot(dir).abs() / 1e3)
        .collect();
    if speeds.is_empty() {
        return 100.0;
    }
    speeds.sort_by(f32::total_cmp);
    let p = f64::from(speeds[(speeds.len() - 1) * 995 / 1000]);
    let (ticks, step) = nice_ticks(0.0, (1.1 * p).max(1.0), 4);
    ticks
        .last()
        .copied()
        .unwrap_or(1.0)
        .max(step)
        .max(1.1 * p)
        .ceil()
}

/// One image panel of a figure (RGB8, row 0 at the top).
pub struct Panel {
    /// Title above the panel.
    pub title: String,
    /// Pixels.
    pub rgb: Vec<u8>,
}

/// A strip under a panel: a colour key or a colour bar with its range and label.
pub struct Strip {
    /// Colours from left (`lo`) to right (`hi`).
    pub colours: Vec<[u8; 3]>,
    /// Range of the axis.
    pub range: (f64, f64),
    /// Axis label.
    pub label: String,
}

/// A picked pixel and its spectra (Doppler on; optionally off), wavelength nm -> value.
pub struct Pick {
    /// Pixel.
    pub xy: (u32, u32),
    /// Spectrum with Doppler on.
    pub on: Vec<(f64, f64)>,
    /// Spectrum with Doppler off (thin), if any.
    pub off: Vec<(f64, f64)>,
}

/// What a figure shows.
pub struct Figure {
    /// Image size of every panel.
    pub size: (u32, u32),
    /// Panels left to right.
    pub panels: Vec<Panel>,
    /// A strip under each panel (or none).
    pub strips: Vec<Option<Strip>>,
    /// Panels that get the pick rings.
    pub ringed: usize,
    /// World length per pixel and the unit label with its scale (value = world x scale).
    pub scale: Option<(f64, String, f64)>,
    /// The picks.
    pub picks: Vec<Pick>,
    /// Title of the spectra plot.
    pub spectra_title: String,
}

fn err(e: impl std::fmt::Display) -> anyhow::Error {
    anyhow!("figure: {e}")
}

/// The Doppler colour key over `[-vmax, vmax]` km/s: the display colour (the image's own
/// hue-preserving mapping, each colour at one luminance) of the scene's mean gas at each velocity.
pub fn colour_key(
    scene: &DopplerScene,
    settings: &DopplerSettings,
    vmax_kms: f64,
) -> Result<Strip> {
    let n = 48;
    let v: Vec<f64> = (0..n)
        .map(|i| (-vmax_kms + 2.0 * vmax_kms * (i as f64 + 0.5) / n as f64) * 1e3)
        .collect();
    let xyz = doppler_colour_key(scene, settings, &v)?;
    // The image's own mapping (hue-preserving gamut mapping), every colour at Y = 0.35.
    let g = blueshift_doppler::GamutMapper::new(blueshift_spectrum::xyz_to_linear_srgb_matrix());
    let rgb: Vec<u8> = xyz
        .iter()
        .flat_map(|x| {
            let y = x[1];
            let c = if y > 0.0 {
                g.map(x.map(|c| c * 0.35 / y))
            } else {
                [0.0; 3]
            };
            c.map(|c| (blueshift_spectrum::srgb_encode(c) * 255.0).round() as u8)
        })
        .collect();
    Ok(Strip {
        colours: rgb.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect(),
        range: (-vmax_kms, vmax_kms),
        label: format!(
            "Doppler colour key: line-of-sight velocity (km/s{})",
            if (scene.factors.velocity - 1.0).abs() > 1e-12 {
                format!(", rendered x{}", scene.factors.velocity)
            } else {
                String::new()
            }
        ),
    })
}

/// Writes the figure as a PNG.
pub fn write_figure(path: &Path, fig: &Figure) -> Result<()> {
    register_font();
    let (w, h) = fig.size;
    let np = fig.panels.len().max(1) as u32;
    let scale = ((420.0 / f64::from(w.max(h).max(1))).round() as u32).clamp(1, 6);
    let (sw, sh) = (w * scale, h * scale);
    let gap = 24;
    let left = 20;
    let width = (left * 2 + np * sw + (np - 1) * gap).max(900);
    let top = 34;
    let strip_h = if fig.strips.iter().any(Option::is_some) {
        66
    } else {
        0
    };
    let plot_y = top + sh + strip_h + 14;
    let plot_h = if fig.picks.is_empty() { 0 } else { 400 };
    let dims = (width, plot_y + plot_h);
    let mut buf = vec![255u8; (dims.0 * dims.1 * 3) as usize];
    let x0s: Vec<u32> = (0..np).map(|i| left + i * (sw + gap)).collect();
    for (p, &x0) in fig.panels.iter().zip(&x0s) {
        for y in 0..sh {
            for x in 0..sw {
                let s = (((y / scale) * w + x / scale) * 3) as usize;
                let d = (((top + y) * dims.0 + x0 + x) * 3) as usize;
                if s + 3 <= p.rgb.len() {
                    buf[d..d + 3].copy_from_slice(&p.rgb[s..s + 3]);
                }
            }
        }
    }
    {
        let root = BitMapBackend::with_buffer(&mut buf, dims).into_drawing_area();
        let text = |s: &str, x: i32, y: i32, size: u32, c: &RGBColor| {
            root.draw(&Text::new(
                s.to_owned(),
                (x, y),
                (FONT, size).into_font().color(c),
            ))
            .map_err(err)
        };
        for (p, &x0) in fig.panels.iter().zip(&x0s) {
            text(&p.title, x0 as i32, 8, 17, &BLACK)?;
        }
        // Scale bar (bottom-left of every panel) in world units.
        if let Some((per_px, unit, k)) = &fig.scale {
            let span = per_px * f64::from(w) * k;
            let (ticks, step) = nice_ticks(0.0, span / 4.0, 1);
            let len = ticks.last().copied().filter(|l| *l > 0.0).unwrap_or(step);
            let px = (len / (per_px * k) * f64::from(scale)).round() as i32;
            for &x0 in &x0s {
                let (bx, by) = (x0 as i32 + 12, (top + sh) as i32 - 16);
                root.draw(&Rectangle::new(
                    [(bx - 1, by - 1), (bx + px + 1, by + 5)],
                    BLACK.filled(),
                ))
                .map_err(err)?;
                root.draw(&Rectangle::new(
                    [(bx, by), (bx + px, by + 4)],
                    WHITE.filled(),
                ))
                .map_err(err)?;
                let label = format!("{} {unit}", tick_label(len, step));
                // A black outline around white text: readable on any panel.
                for (dx, dy) in [(-1, 0), (1, 0), (0, -1), (0, 1), (1, 1), (-1, -1)] {
                    text(&label, bx + dx, by - 18 + dy, 14, &BLACK)?;
                }
                text(&label, bx, by - 18, 14, &WHITE)?;
            }
        }
        for (k, p) in fig.picks.iter().enumerate() {
            let c = RING[k % RING.len()];
            for &x0 in x0s.iter().take(fig.ringed) {
                let cx = (x0 + p.xy.0 * scale + scale / 2) as i32;
                let cy = (top + p.xy.1 * scale + scale / 2) as i32;
                root.draw(&Circle::new((cx, cy), 7, c.stroke_width(2)))
                    .map_err(err)?;
            }
        }
        for (s, &x0) in fig.strips.iter().zip(&x0s) {
            let Some(s) = s else { continue };
            let y0 = (top + sh + 6) as i32;
            let n = s.colours.len().max(1) as u32;
            for x in 0..sw {
                let c = s.colours[((x * n) / sw).min(n - 1) as usize];
                root.draw(&Rectangle::new(
                    [
                        (x0 as i32 + x as i32, y0),
                        (x0 as i32 + x as i32 + 1, y0 + 14),
                    ],
                    RGBColor(c[0], c[1], c[2]).filled(),
                ))
                .map_err(err)?;
            }
            let (ticks, step) = nice_ticks(s.range.0, s.range.1, 4);
            for t in ticks {
                let fx = (t - s.range.0) / (s.range.1 - s.range.0);
                let x = x0 as i32 + (fx * f64::from(sw)).round() as i32;
                root.draw(&PathElement::new([(x, y0 + 14), (x, y0 + 19)], BLACK))
                    .map_err(err)?;
                let l = tick_label(t, step);
                text(&l, x - 4 * l.len() as i32, y0 + 21, 13, &BLACK)?;
            }
            // One line when it fits the panel (about 7 pixels a character), else two.
            let fits = s.label.len() * 7 <= sw as usize;
            match s.label.split_once(": ").filter(|_| !fits) {
                Some((a, b)) => {
                    text(a, x0 as i32, y0 + 34, 13, &BLACK)?;
                    text(b, x0 as i32, y0 + 48, 13, &BLACK)?;
                }
                None => text(&s.label, x0 as i32, y0 + 38, 13, &BLACK)?,
            }
        }
        if !fig.picks.is_empty() {
            let (_, plot) = root.split_vertically(plot_y);
            let (mut xa, mut xb, mut y1) = (f64::INFINITY, f64::NEG_INFINITY, 0.0f64);
            for p in &fig.picks {
                for &(x, y) in p.on.iter().chain(&p.off) {
                    xa = xa.min(x);
                    xb = xb.max(x);
                    y1 = y1.max(y);
                }
            }
            if xa.partial_cmp(&xb) != Some(std::cmp::Ordering::Less) {
                return Err(anyhow!("figure: no spectrum to plot"));
            }
            if y1.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
                y1 = 1.0;
            }
            let mut chart = ChartBuilder::on(&plot)
                .caption(&fig.spectra_title, (FONT, 16))
                .margin(12)
                .x_label_area_size(40)
                .y_label_area_size(70)
                .build_cartesian_2d(xa..xb, 0.0..y1 * 1.05)
                .map_err(err)?;
            chart
                .configure_mesh()
                .x_desc("wavelength (nm)")
                .y_desc("spectral radiance (model units / nm)")
                .label_style((FONT, 13))
                .x_label_formatter(&|v| axis_label(*v))
                .y_label_formatter(&|v| axis_label(*v))
                .draw()
                .map_err(err)?;
            for (k, p) in fig.picks.iter().enumerate() {
                let c = RING[k % RING.len()];
                if !p.off.is_empty() {
                    chart
                        .draw_series(LineSeries::new(
                            p.off.iter().copied(),
                            c.mix(0.6).stroke_width(1),
                        ))
                        .map_err(err)?;
                }
                chart
                    .draw_series(LineSeries::new(p.on.iter().copied(), c.stroke_width(2)))
                    .map_err(err)?
                    .label(format!("pixel {},{}", p.xy.0, p.xy.1))
                    .legend(move |(x, y)| {
                        PathElement::new([(x, y), (x + 20, y)], c.stroke_width(2))
                    });
            }
            chart
                .configure_series_labels()
                .label_font((FONT, 13))
                .background_style(WHITE.mix(0.8))
                .border_style(BLACK)
                .draw()
                .map_err(err)?;
        }
        root.present().map_err(err)?;
    }
    let img = image::RgbImage::from_raw(dims.0, dims.1, buf).context("figure buffer size")?;
    write_via_temp_path(path, |p| {
        blueshift_tonemap::io::save_rgb8_png(p, &img)
            .with_context(|| format!("cannot write {}", path.display()))
    })
}

/// The velocity panel as RGB8 (masked pixels dark grey) and its colour bar.
pub fn velocity_panel(map: &[Option<f32>], vmax_kms: f64) -> (Vec<u8>, Strip) {
    let rgb = map
        .iter()
        .flat_map(|v| match v {
            Some(v) => diverging(0.5 + f64::from(*v) / (2.0 * vmax_kms)),
            None => [40, 40, 40],
        })
        .collect();
    let colours = (0..64)
        .map(|i| diverging((f64::from(i) + 0.5) / 64.0))
        .collect();
    (
        rgb,
        Strip {
            colours,
            range: (-vmax_kms, vmax_kms),
            label: "H-alpha moment 1: line-of-sight velocity (km/s, + receding)".into(),
        },
    )
}

/// An orientation triad for an image of a camera: world x (red), y (green) and z (blue)
/// drawn from a corner as the camera projects them (`right`, `up` of its basis), labelled;
/// an axis along the view shows as a short stub. Returns an RGB8 overlay, black where
/// nothing is drawn.
pub fn triad_overlay(w: u32, h: u32, camera: &blueshift_camera::Camera) -> Result<Vec<u8>> {
    register_font();
    let (_, right, up) = camera.basis();
    let len = (f64::from(w.min(h)) / 8.0).clamp(10.0, 60.0);
    let (ox, oy) = (f64::from(w) - len - 14.0, f64::from(h) - len - 14.0);
    let mut buf = vec![0u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        for (axis, name, colour) in [
            (glam::Vec3::X, "x", RGBColor(255, 64, 64)),
            (glam::Vec3::Y, "y", RGBColor(64, 230, 64)),
            (glam::Vec3::Z, "z", RGBColor(90, 140, 255)),
        ] {
            let (dx, dy) = (f64::from(axis.dot(right)), -f64::from(axis.dot(up)));
            let tip = (
                (ox + dx * len).round() as i32,
                (oy + dy * len).round() as i32,
            );
            root.draw(&PathElement::new(
                [(ox as i32, oy as i32), tip],
                colour.stroke_width(2),
            ))
            .map_err(err)?;
            if dx.hypot(dy) > 0.2 {
                let lx = tip.0 + (dx * 8.0).round() as i32 - 3;
                let ly = tip.1 + (dy * 8.0).round() as i32 - 6;
                root.draw(&Text::new(
                    name,
                    (lx, ly),
                    (FONT, 12).into_font().color(&colour),
                ))
                .map_err(err)?;
            }
        }
        root.present().map_err(err)?;
    }
    Ok(buf)
}

/// Lays an RGB8 overlay (black = transparent) over an RGB8 image.
pub fn apply_overlay(rgb: &mut [u8], overlay: &[u8]) {
    for (p, o) in rgb.chunks_exact_mut(3).zip(overlay.chunks_exact(3)) {
        if o.iter().any(|&c| c > 0) {
            p.copy_from_slice(o);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ticks_are_round_and_labels_readable() {
        let (t, s) = nice_ticks(0.0, 3.7, 6);
        assert_eq!(s, 1.0);
        assert_eq!(t, vec![0.0, 1.0, 2.0, 3.0]);
        let (_, s) = nice_ticks(0.0, 3.7, 8);
        assert_eq!(s, 0.5);
        assert_eq!(tick_label(3.5, s), "3.5");
        assert_eq!(tick_label(0.0, s), "0");
        assert_eq!(tick_label(450.0, 50.0), "450");
        assert_eq!(tick_label(0.004, 0.002), "0.004");
        let (t, s) = nice_ticks(-300.0, 300.0, 4);
        assert_eq!(s, 200.0);
        assert_eq!(t, vec![-200.0, 0.0, 200.0]);
        assert!(tick_label(2.5e-7, 1e-7).contains('e'));
        assert_eq!(axis_label(3.5), "3.5");
        assert_eq!(axis_label(2.0), "2");
        assert_eq!(axis_label(0.25), "0.25");
        assert_eq!(axis_label(656.3), "656.3");
        assert_eq!(axis_label(2.5e-4), "2.5e-4");
        assert_eq!(axis_label(1e-5), "1e-5");
    }

    #[test]
    fn the_velocity_map_is_blue_white_red() {
        let [r0, _, b0] = diverging(0.0);
        let [r1, _, b1] = diverging(1.0);
        assert!(b0 > r0 && r1 > b1);
        assert_eq!(diverging(0.5), [247, 247, 247]);
    }
}
