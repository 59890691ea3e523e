//! `blueshift tf`: transfer functions (HDR VolVis section 5): draw the editor view, convert
//! ParaView presets, write lookup tables.
//!
//! Every TF argument is a file in blueshift's JSON or a ParaView preset (told apart by
//! content), or `builtin:NAME` for a built-in map (viridis, inferno, cool-warm, black-body,
//! grey) over [0, 1].

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use blueshift_tfedit::picture::{EditorView, render_editor_view};
use blueshift_tfedit::{Fisheye, FocusRegion, Lut2d, TransferFunction, ValueAxis};

use crate::output::{write_bytes_atomic, write_via_temp_path};

/// Arguments of `blueshift tf`.
#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(subcommand)]
    command: TfCommand,
}

#[derive(Debug, clap::Subcommand)]
enum TfCommand {
    /// Draw the editor view (colour bar, opacity curve, fisheye data axis) as a PNG.
    Show(ShowArgs),
    /// Convert a ParaView colour-map preset to blueshift's transfer-function JSON.
    ImportParaview(ImportArgs),
    /// Convert a transfer function to a ParaView colour-map preset.
    ExportParaview(ExportArgs),
    /// Write a lookup table as an N x 1 RGBA float EXR (or its 2D encoding).
    Lut(LutArgs),
}

#[derive(Debug, clap::Args)]
struct ShowArgs {
    /// Transfer function: blueshift JSON, ParaView preset JSON, or builtin:NAME.
    tf: String,
    /// Output PNG.
    #[arg(long)]
    out: PathBuf,
    /// Focus region CENTER:WIDTH:MAG[:TRANSITION], centre, width and transition width in
    /// data units (transition defaults to a quarter of the width); repeat for several.
    #[arg(long, value_name = "CENTER:WIDTH:MAG[:TRANSITION]")]
    focus: Vec<String>,
    /// Logarithmic opacity axis (HDR VolVis Fig. 7).
    #[arg(long)]
    log_alpha: bool,
    /// Smallest opacity shown on the logarithmic axis.
    #[arg(long, default_value_t = 1e-4)]
    alpha_floor: f64,
    /// Image width in pixels.
    #[arg(long, default_value_t = 1024)]
    width: u32,
    /// Image height in pixels.
    #[arg(long, default_value_t = 512)]
    height: u32,
}

#[derive(Debug, clap::Args)]
struct ImportArgs {
    /// ParaView preset JSON (as written by "Save preset" / "Export").
    file: PathBuf,
    /// Preset to take when the file holds several (default: the first).
    #[arg(long)]
    name: Option<String>,
    /// Output file (default: standard output).
    #[arg(long)]
    out: Option<PathBuf>,
}

#[derive(Debug, clap::Args)]
struct ExportArgs {
    /// Transfer function: blueshift JSON, ParaView preset JSON, or builtin:NAME.
    tf: String,
    /// Output file (default: standard output).
    #[arg(long)]
    out: Option<PathBuf>,
}

#[derive(Debug, clap::Args)]
struct LutArgs {
    /// Transfer function: blueshift JSON, ParaView preset JSON, or builtin:NAME.
    tf: String,
    /// Number of entries N (2 to 16,777,216); entry i is at min + i (max - min) / (N - 1).
    #[arg(long)]
    entries: usize,
    /// Output OpenEXR file.
    #[arg(long)]
    out: PathBuf,
    /// Write the 2D encoding of HDR VolVis Fig. 8 instead: m rows of n + 2 texels.
    #[arg(long)]
    encode_2d: bool,
    /// With --encode-2d: the largest texture side allowed (rows of MAX - 2 entries).
    #[arg(long, default_value_t = 4096)]
    max_texture: usize,
}

/// Runs `blueshift tf`.
pub fn run(args: Args) -> Result<()> {
    // Refuse an output that cannot be written before reading anything.
    let (out, input): (Option<&Path>, &Path) = match &args.command {
        TfCommand::Show(a) => (Some(&a.out), Path::new(&a.tf)),
        TfCommand::ImportParaview(a) => (a.out.as_deref(), &a.file),
        TfCommand::ExportParaview(a) => (a.out.as_deref(), Path::new(&a.tf)),
        TfCommand::Lut(a) => (Some(&a.out), Path::new(&a.tf)),
    };
    if let Some(out) = out {
        crate::output::check_outputs(&[out], &[input])?;
    }
    match args.command {
        TfCommand::Show(a) => show(a),
        TfCommand::ImportParaview(a) => import(a),
        TfCommand::ExportParaview(a) => export(a),
        TfCommand::Lut(a) => lut(a),
    }
}

fn load_tf(spec: &str) -> Result<TransferFunction> {
    if let Some(name) = spec.strip_prefix("builtin:") {
        return Ok(blueshift_tfedit::builtin(name)?);
    }
    Ok(blueshift_tfedit::load(spec)?)
}

fn parse_focus(tf: &TransferFunction, spec: &str) -> Result<FocusRegion> {
    let parts: Vec<&str> = spec.split(':').collect();
    if !(3..=4).contains(&parts.len()) {
        bail!("--focus {spec:?}: expected CENTER:WIDTH:MAG or CENTER:WIDTH:MAG:TRANSITION");
    }
    let num = |i: usize, what: &str| -> Result<f64> {
        let v: f64 = parts[i]
            .trim()
            .parse()
            .with_context(|| format!("--focus {spec:?}: {what} {:?} is not a number", parts[i]))?;
        if !v.is_finite() {
            bail!("--focus {spec:?}: {what} must be finite");
        }
        Ok(v)
    };
    let (c, w, m) = (
        num(0, "centre")?,
        num(1, "width")?,
        num(2, "magnification")?,
    );
    if w <= 0.0 {
        bail!("--focus {spec:?}: width must be > 0");
    }
    let [lo, hi] = tf.domain();
    if !(lo..=hi).contains(&c) {
        bail!("--focus {spec:?}: centre {c} is outside the domain [{lo}, {hi}]");
    }
    // Data units to the normalised (linear or log) axis.
    let (a, b) = (tf.normalized(c - 0.5 * w), tf.normalized(c + 0.5 * w));
    let (ta, tb) = if tf.data_axis() == blueshift_tfedit::DataAxis::Log && c - 0.5 * w <= 0.0 {
        // The left edge is not on a log axis: keep the region symmetric around the centre.
        let tc = tf.normalized(c);
        (2.0 * tc - b, b)
    } else {
        (a, b)
    };
    let width = tb - ta;
    if width <= 0.0 {
        bail!("--focus {spec:?}: the region has no width inside the domain");
    }
    let transition = if parts.len() == 4 {
        let t = num(3, "transition")?;
        if t < 0.0 {
            bail!("--focus {spec:?}: transition must be >= 0");
        }
        t / w * width
    } else {
        0.25 * width
    };
    Ok(FocusRegion {
        center: 0.5 * (ta + tb),
        width,
        magnification: m,
        transition,
    })
}

fn show(a: ShowArgs) -> Result<()> {
    let tf = load_tf(&a.tf).with_context(|| format!("cannot load {}", a.tf))?;
    let regions = a
        .focus
        .iter()
        .map(|s| parse_focus(&tf, s))
        .collect::<Result<Vec<_>>>()?;
    let view = EditorView {
        width: a.width,
        height: a.height,
        fisheye: Fisheye::new(regions)?,
        opacity_axis: if a.log_alpha {
            ValueAxis::log(a.alpha_floor)?
        } else {
            ValueAxis::Linear
        },
        show_magnification: true,
    };
    let img = render_editor_view(&tf, &view)?;
    write_via_temp_path(&a.out, |p| {
        blueshift_tonemap::io::save_rgb8_png(p, &img)
            .with_context(|| format!("cannot write {}", a.out.display()))
    })?;
    crate::output::wrote_with(
        &a.out,
        &format!(
            "{} x {}, M_min = {:.4}",
            a.width,
            a.height,
            view.fisheye.m_min()
        ),
    );
    Ok(())
}

fn emit(out: Option<&Path>, text: &str) -> Result<()> {
    match out {
        Some(p) => {
            write_bytes_atomic(p, text.as_bytes())?;
            crate::output::wrote(p);
            Ok(())
        }
        None => {
            out!("{text}");
            Ok(())
        }
    }
}

fn import(a: ImportArgs) -> Result<()> {
    let meta =
        std::fs::metadata(&a.file).with_context(|| format!("cannot read {}", a.file.display()))?;
    if meta.len() > blueshift_tfedit::MAX_FILE_BYTES {
        bail!("{} is too large for a colour-map preset", a.file.display());
    }
    let text = std::fs::read_to_string(&a.file)
        .with_context(|| format!("cannot read {}", a.file.display()))?;
    let tf = blueshift_tfedit::paraview::from_paraview_str(&text, a.name.as_deref())
        .with_context(|| format!("cannot import {}", a.file.display()))?;
    emit(a.out.as_deref(), &tf.to_json_string())
}

fn export(a: ExportArgs) -> Result<()> {
    let tf = load_tf(&a.tf).with_context(|| format!("cannot load {}", a.tf))?;
    emit(
        a.out.as_deref(),
        &blueshift_tfedit::paraview::to_paraview_string(&tf),
    )
}

fn lut(a: LutArgs) -> Result<()> {
    let ext = a
        .out
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase());
    if ext.as_deref() != Some("exr") {
        bail!(
            "--out {}: lookup tables are written as OpenEXR, use a .exr file name",
            a.out.display()
        );
    }
    let tf = load_tf(&a.tf).with_context(|| format!("cannot load {}", a.tf))?;
    let lut = tf.lut(a.entries)?;
    let (w, h, data) = if a.encode_2d {
        let tex = Lut2d::encode_for_max_texture(&lut, a.max_texture)?;
        (tex.width(), tex.rows(), tex.as_rgba().to_vec())
    } else {
        (lut.len(), 1, lut.into_rgba())
    };
    let (w32, h32) = (u32::try_from(w)?, u32::try_from(h)?);
    let img = image::Rgba32FImage::from_raw(w32, h32, data)
        .context("lookup table buffer has the wrong size")?;
    // Block after block, so the same table always gives the same bytes.
    crate::output::write_exr_f32(&a.out, w32, h32, 4, img.as_raw())?;
    crate::output::wrote_with(&a.out, &format!("{w} x {h} RGBA f32"));
    Ok(())
}
