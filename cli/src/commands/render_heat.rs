//! Heat maps of `blueshift render --heatmap`: the per-pixel work counters of the tracking
//! (DDA cells, tentative collisions, null-collision rejections, time) as named channels of
//! one OpenEXR file `OUT.heat.exr`, and each as a colour-mapped PNG `OUT.heat-NAME.png`
//! with a colour bar labelled in data units.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, anyhow};
use blueshift_tracking::{HeatMap, Progressive};
use plotters::prelude::*;

use crate::output::OutputSet;
use crate::plot::{FONT, inferno, register_font};

/// `OUT` with its extension replaced by `suffix` (`img.exr` -> `img.heat.exr`).
fn beside(out: &Path, suffix: &str) -> PathBuf {
    let stem = out
        .file_stem()
        .map_or_else(|| "render".into(), |s| s.to_string_lossy().into_owned());
    out.with_file_name(format!("{stem}.{suffix}"))
}

/// Every file `--heatmap NAME...` writes beside `out` (unknown names are left to the
/// parser's error).
pub fn heat_outputs(out: &Path, names: &[String]) -> Vec<PathBuf> {
    if names.is_empty() {
        return Vec::new();
    }
    let mut v = vec![beside(out, "heat.exr")];
    for n in names {
        if let Ok(m) = n.parse::<HeatMap>() {
            v.push(beside(out, &format!("heat-{}.png", m.name())));
        }
    }
    v
}

/// Stages the requested heat maps (none: nothing) in `set` and returns a JSON summary of
/// the files, means and maxima, and the files in the order to report them.
pub fn write_heatmaps(
    set: &mut OutputSet,
    out: &Path,
    acc: &Progressive,
    maps: &[HeatMap],
) -> Result<(serde_json::Value, Vec<PathBuf>)> {
    if maps.is_empty() {
        return Ok((serde_json::Value::Null, Vec::new()));
    }
    let mut maps: Vec<HeatMap> = maps.to_vec();
    maps.dedup();
    let (w, h) = {
        let img = acc.mean_image();
        (img.width() as usize, img.height() as usize)
    };
    let mut layers = Vec::new();
    for &m in &maps {
        let v = acc
            .heatmap(m)
            .ok_or_else(|| anyhow!("heat maps were not recorded"))?;
        layers.push((m, v));
    }
    let exr_path = beside(out, "heat.exr");
    set.via_path(&exr_path, |p| {
        use exr::prelude::*;
        let channels: SmallVec<[AnyChannel<FlatSamples>; 4]> = layers
            .iter()
            .map(|(m, v)| AnyChannel::new(m.name(), FlatSamples::F32(v.clone())))
            .collect();
        let layer = Layer::new(
            (w, h),
            LayerAttributes::named("heat"),
            Encoding::FAST_LOSSLESS,
            AnyChannels::sort(channels),
        );
        // One block after the other: the same bytes on every run.
        Image::from_layer(layer)
            .write()
            .non_parallel()
            .to_file(p)
            .with_context(|| format!("cannot write {}", exr_path.display()))
    })?;
    let mut files = vec![exr_path.clone()];
    let mut summary = serde_json::Map::new();
    summary.insert("exr".into(), serde_json::json!(exr_path));
    for (m, v) in &layers {
        let png = beside(out, &format!("heat-{}.png", m.name()));
        let max = v.iter().copied().fold(0.0f32, f32::max);
        let mean = v.iter().map(|&x| f64::from(x)).sum::<f64>() / v.len().max(1) as f64;
        colour_mapped_png(set, &png, v, w, h, max, *m)?;
        files.push(png.clone());
        summary.insert(
            m.name().into(),
            serde_json::json!({ "png": png, "mean": mean, "max": max }),
        );
    }
    Ok((serde_json::Value::Object(summary), files))
}

/// The heat map scaled 0..`max`, with a colour bar on the right labelled in data units.
fn colour_mapped_png(
    set: &mut OutputSet,
    path: &Path,
    v: &[f32],
    w: usize,
    h: usize,
    max: f32,
    m: HeatMap,
) -> Result<()> {
    register_font();
    let bar_w = 150usize;
    let height = h.max(160);
    let (iw, ih) = ((w + bar_w) as u32, height as u32);
    let mut buf = vec![0u8; iw as usize * ih as usize * 3];
    let scale = if max > 0.0 { 1.0 / max } else { 0.0 };
    {
        let root = BitMapBackend::with_buffer(&mut buf, (iw, ih)).into_drawing_area();
        let err = |e| anyhow!("heat map plot: {e:?}");
        root.fill(&WHITE).map_err(err)?;
        for y in 0..h {
            for x in 0..w {
                root.draw_pixel((x as i32, y as i32), &inferno(v[y * w + x] * scale))
                    .map_err(err)?;
            }
        }
        let (x0, y0, y1) = (w as i32 + 12, 20i32, height as i32 - 20);
        for y in y0..=y1 {
            let t = (y1 - y) as f32 / (y1 - y0).max(1) as f32;
            root.draw(&Rectangle::new(
                [(x0, y), (x0 + 16, y + 1)],
                inferno(t).filled(),
            ))
            .map_err(err)?;
        }
        let style = (FONT, 12).into_font().color(&BLACK);
        for (t, y) in [(1.0f32, y0), (0.5, (y0 + y1) / 2), (0.0, y1)] {
            root.draw(&Text::new(
                format!("{:.3}", max * t),
                (x0 + 20, y - 6),
                style.clone(),
            ))
            .map_err(err)?;
        }
        root.draw(&Text::new(m.name().to_string(), (x0, 4), style.clone()))
            .map_err(err)?;
        let unit = m.unit();
        root.draw(&Text::new(
            unit.to_string(),
            (x0 - 4, y1 + 4),
            (FONT, 9).into_font().color(&BLACK),
        ))
        .map_err(err)?;
        root.present().map_err(err)?;
    }
    let img = image::RgbImage::from_raw(iw, ih, buf).ok_or_else(|| anyhow!("heat map buffer"))?;
    set.via_path(path, |p| {
        blueshift_tonemap::io::save_rgb8_png(p, &img)
            .with_context(|| format!("cannot write {}", path.display()))
    })
}
