//! `blueshift tonemap`: tone-map an HDR image, write an exposure series or a pseudocolour
//! picture, and print the image's dynamic range.

use std::path::{Path, PathBuf};
use std::time::Instant;

use std::fmt::Write as _;

use anyhow::{Context, Result, bail};
use blueshift_tonemap::io::{self, PngDepth};
use blueshift_tonemap::{
    DragoParams, DurandParams, ExposureSeries, FattalParams, LinearParams, Operator,
    PseudocolourParams, ReinhardLocalParams, ReinhardParams, Roi,
};
use image::Rgb32FImage;

/// The operators of `--op`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Op {
    /// Drago et al. 2003 adaptive logarithmic mapping (global).
    Drago,
    /// Reinhard et al. 2002 photographic, global.
    Reinhard,
    /// Reinhard et al. 2002 photographic, local dodging and burning.
    ReinhardLocal,
    /// Durand and Dorsey 2002 fast bilateral filtering.
    Durand,
    /// Fattal et al. 2002 gradient domain compression.
    Fattal,
    /// Linear with exposure: by default the 99th percentile of the lit pixels' luminance
    /// maps to display 1 (--white sets that luminance; --exposure adds stops).
    Linear,
}

/// Arguments of `blueshift tonemap`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Where the operator runs: cpu (default, bit-reproducible), gpu (any wgpu adapter,
    /// lavapipe included) or auto (a hardware GPU when present, or the adapter
    /// $BLUESHIFT_GPU forces, else the CPU; an image over the adapter's limits, e.g. Fattal's
    /// DCT matrices, is tone-mapped on the CPU).
    #[arg(long, default_value = "cpu")]
    pub device: blueshift_gpu::DeviceChoice,
    /// Input HDR image: OpenEXR, Radiance .hdr or PFM (detected from the content).
    pub input: PathBuf,
    /// Output file: .png (display, sRGB), .exr, .hdr or .pfm (display-linear floats).
    #[arg(long)]
    pub out: PathBuf,
    /// Tone-mapping operator.
    #[arg(long, value_enum, default_value = "drago")]
    pub op: Op,
    /// PNG bits per channel (8 or 16).
    #[arg(long, default_value_t = 8, value_parser = parse_depth)]
    pub depth: u8,
    /// Exposure in stops: each stop doubles the display values (linear and drago before
    /// their curve; the other operators on their display output, gamut-mapped).
    #[arg(long, allow_negative_numbers = true)]
    pub exposure: Option<f32>,
    /// Drago bias b (0.85).
    #[arg(long)]
    pub bias: Option<f32>,
    /// Drago maximum display luminance Ld_max in cd/m^2 (100).
    #[arg(long)]
    pub ld_max: Option<f32>,
    /// Drago region of interest X,Y,R in pixels: adaptation from this circle.
    #[arg(long, value_parser = parse_roi)]
    pub roi: Option<Roi>,
    /// Reinhard key a (0.18).
    #[arg(long)]
    pub key: Option<f32>,
    /// Reinhard global L_white in scaled units (default: the largest scaled luminance);
    /// linear: the luminance that maps to 1 (default: the 99th percentile of the lit
    /// pixels, so a few hot pixels do not turn the rest black).
    #[arg(long)]
    pub white: Option<f32>,
    /// Reinhard local sharpening phi (8).
    #[arg(long)]
    pub phi: Option<f32>,
    /// Reinhard local threshold epsilon (0.05).
    #[arg(long)]
    pub epsilon: Option<f32>,
    /// Reinhard local number of scales (8).
    #[arg(long)]
    pub scales: Option<usize>,
    /// Durand spatial sigma in pixels (default 2 % of the image size).
    #[arg(long)]
    pub sigma_s: Option<f32>,
    /// Durand range sigma in log10 units (0.4).
    #[arg(long)]
    pub sigma_r: Option<f32>,
    /// Durand target base contrast (5).
    #[arg(long)]
    pub contrast: Option<f32>,
    /// Fattal alpha as a fraction of the mean gradient (0.1).
    #[arg(long)]
    pub alpha: Option<f32>,
    /// Fattal beta (0.85).
    #[arg(long)]
    pub beta: Option<f32>,
    /// Colour saturation exponent s (1 for all but Fattal, 0.5 there).
    #[arg(long)]
    pub saturation: Option<f32>,
    /// Write N linearly mapped images at increasing exposure (OUT-00.png, ...) instead.
    #[arg(long)]
    pub exposure_series: Option<usize>,
    /// Exposure step between series images in stops (default: span the dynamic range).
    #[arg(long, allow_negative_numbers = true)]
    pub stops_step: Option<f32>,
    /// Write a pseudocolour picture of log luminance with a colour bar instead.
    #[arg(long, alias = "pseudocolour")]
    pub pseudocolor: bool,
    /// Print a JSON summary on stdout instead of text (on stderr when the image goes to
    /// standard output).
    #[arg(long)]
    pub json: bool,
    /// Output format, for an --out whose name does not tell (`-` for standard output, a
    /// device or FIFO: PNG unless given) or to override its extension.
    #[arg(long, value_parser = ["png", "exr", "hdr", "pfm"])]
    pub format: Option<String>,
}

fn parse_depth(s: &str) -> std::result::Result<u8, String> {
    match s {
        "8" => Ok(8),
        "16" => Ok(16),
        _ => Err(format!("--depth must be 8 or 16, got {s:?}")),
    }
}

fn parse_roi(s: &str) -> std::result::Result<Roi, String> {
    let v: Vec<f32> = s
        .split(',')
        .map(|t| t.trim().parse::<f32>())
        .collect::<std::result::Result<_, _>>()
        .map_err(|e| format!("--roi expects X,Y,R numbers: {e}"))?;
    match v[..] {
        [x, y, r] if x.is_finite() && y.is_finite() && r > 0.0 => Ok(Roi {
            x_px: x,
            y_px: y,
            radius_px: r,
        }),
        _ => Err(format!("--roi expects X,Y,R with R > 0, got {s:?}")),
    }
}

/// Builds the operator from the flags.
pub fn operator(args: &Args) -> Operator {
    match args.op {
        Op::Linear => Operator::Linear(LinearParams {
            exposure_stops: args.exposure.unwrap_or(0.0),
            white: args.white,
        }),
        Op::Drago => {
            let d = DragoParams::default();
            Operator::Drago(DragoParams {
                bias: args.bias.unwrap_or(d.bias),
                max_display_luminance: args.ld_max.unwrap_or(d.max_display_luminance),
                exposure_stops: args.exposure.unwrap_or(0.0),
                roi: args.roi,
                saturation: args.saturation.unwrap_or(d.saturation),
            })
        }
        Op::Reinhard => {
            let d = ReinhardParams::default();
            Operator::Reinhard(ReinhardParams {
                key: args.key.unwrap_or(d.key),
                white: args.white,
                saturation: args.saturation.unwrap_or(d.saturation),
            })
        }
        Op::ReinhardLocal => {
            let d = ReinhardLocalParams::default();
            Operator::ReinhardLocal(ReinhardLocalParams {
                key: args.key.unwrap_or(d.key),
                phi: args.phi.unwrap_or(d.phi),
                epsilon: args.epsilon.unwrap_or(d.epsilon),
                scales: args.scales.unwrap_or(d.scales),
                saturation: args.saturation.unwrap_or(d.saturation),
                ..d
            })
        }
        Op::Durand => {
            let d = DurandParams::default();
            Operator::Durand(DurandParams {
                sigma_spatial_px: args.sigma_s,
                sigma_range: args.sigma_r.unwrap_or(d.sigma_range),
                base_contrast: args.contrast.unwrap_or(d.base_contrast),
                saturation: args.saturation.unwrap_or(d.saturation),
            })
        }
        Op::Fattal => {
            let d = FattalParams::default();
            Operator::Fattal(FattalParams {
                alpha_ratio: args.alpha.unwrap_or(d.alpha_ratio),
                beta: args.beta.unwrap_or(d.beta),
                saturation: args.saturation.unwrap_or(d.saturation),
                ..d
            })
        }
    }
}

fn extension(path: &Path) -> String {
    path.extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default()
}

/// Image `i` of an exposure series written for `--out out`: `OUT-0i.EXT`.
fn series_path(out: &Path, i: usize, ext: &str) -> PathBuf {
    PathBuf::from(format!("{}-{i:02}.{ext}", out.with_extension("").display()))
}

/// The output's format: `--format`, else --out's extension, else PNG for an output that is
/// not a file name (`-`, `/dev/stdout`, a FIFO).
fn output_format(args: &Args) -> Result<String> {
    if let Some(f) = &args.format {
        return Ok(f.clone());
    }
    let ext = extension(&args.out);
    if ["png", "exr", "hdr", "pfm"].contains(&ext.as_str()) {
        return Ok(ext);
    }
    if crate::output::direct_target(&args.out).is_some() {
        return Ok("png".into());
    }
    bail!(
        "unknown output extension {ext:?} (use .png, .exr, .hdr or .pfm, or --format): {}",
        args.out.display()
    )
}

fn write_display(path: &Path, format: &str, img: &Rgb32FImage, depth: u8) -> Result<()> {
    // The library writers go through the CLI's temporary naming and non-regular handling.
    let via = |write: &dyn Fn(&Path) -> blueshift_tonemap::Result<()>| {
        crate::output::write_via_temp_path(path, |p| Ok(write(p)?))
    };
    match format {
        "png" => via(&|p| {
            io::write_png(
                p,
                img,
                if depth == 16 {
                    PngDepth::Sixteen
                } else {
                    PngDepth::Eight
                },
            )
        }),
        // Not io::write_exr: its blocks are written in the order threads finish them.
        "exr" => crate::output::write_exr_f32(path, img.width(), img.height(), 3, img.as_raw()),
        "hdr" => via(&|p| io::write_radiance_hdr(p, img)),
        "pfm" => via(&|p| io::write_pfm(p, img)),
        other => bail!(
            "unknown output extension {other:?} (use .png, .exr, .hdr or .pfm): {}",
            path.display()
        ),
    }
}

/// Runs `blueshift tonemap`.
pub fn run(args: Args) -> Result<()> {
    let ext = output_format(&args)?;
    // Every file the run writes is checked against the input (an exposure series' names
    // too: `in-01.exr` may be the input).
    if let Some(n) = args.exposure_series
        && !(1..=blueshift_tonemap::MAX_EXPOSURE_SERIES).contains(&n)
    {
        bail!(
            "--exposure-series {n}: 1 to {} images",
            blueshift_tonemap::MAX_EXPOSURE_SERIES
        );
    }
    let outs = match args.exposure_series {
        Some(n) => (0..n).map(|i| series_path(&args.out, i, &ext)).collect(),
        None => vec![args.out.clone()],
    };
    let out_refs: Vec<&Path> = outs.iter().map(PathBuf::as_path).collect();
    crate::output::check_outputs(&out_refs, &[args.input.as_path()])?;
    if args.stops_step.is_some() && args.exposure_series.is_none() {
        bail!("--stops-step applies to --exposure-series only");
    }
    if args.stops_step == Some(0.0) && args.exposure_series.is_some_and(|n| n > 1) {
        bail!(
            "--stops-step 0 makes every image of the exposure series the same: give a non-zero step"
        );
    }
    if args.exposure_series.is_some() && crate::output::direct_target(&args.out).is_some() {
        bail!(
            "--exposure-series writes one file per image (OUT-00.png, ...): give --out a file \
             name, not {}",
            args.out.display()
        );
    }
    let t0 = Instant::now();
    let limits = io::Limits {
        max_bytes: crate::limits::budget().bytes(),
        ..io::Limits::default()
    };
    let source = io::read_hdr_source_with(&args.input, &limits)
        .map_err(|e| match e {
            blueshift_tonemap::Error::Memory {
                width,
                height,
                needed,
                ..
            } => crate::limits::check(format_args!("decoding this {width}x{height} image"), needed)
                .err()
                .unwrap_or_else(|| anyhow::anyhow!("{e}")),
            e => anyhow::Error::new(e),
        })
        .with_context(|| "cannot read the input image".to_string())?;
    let read_ms = t0.elapsed().as_secs_f64() * 1e3;
    let mut op = operator(&args);
    let t1 = Instant::now();
    // A global operator to an 8-bit PNG on the CPU: two passes over the rows, from the
    // file's own encoding where it is compact, straight to the sRGB codes (the same bytes as
    // the path below, without the floating-point image and its luminance plane).
    let streamed = if straight_to_codes(&args, &ext)
        && !matches!(&op, Operator::Linear(p) if p.white.is_none())
    {
        op.apply_rows(&source)?
    } else {
        None
    };
    let (w, h) = source.dimensions();
    let (kind, outputs, stats) = match streamed {
        Some(rows) => {
            crate::output::write_via_temp_path(&args.out, |p| Ok(rows.write_png(p)?))?;
            (op.name(), vec![args.out.clone()], rows.stats)
        }
        None => {
            // One cleaning pass (dirty-input rule + luminance + range) shared by the
            // dynamic-range report and the operator.
            let clean = blueshift_tonemap::CleanImage::from_image(source.into_image());
            let (kind, outputs) = tonemap_clean(&args, &ext, &mut op, &clean)?;
            (kind, outputs, clean.stats())
        }
    };
    let op_ms = t1.elapsed().as_secs_f64() * 1e3;
    let report = stats.report;
    let dr = stats.dynamic_range();
    // The summary goes to stderr when the image itself goes to standard output.
    let mut text = String::new();
    if args.json {
        let summary = serde_json::json!({
            "input": args.input,
            "width": w,
            "height": h,
            "operator": kind,
            "parameters": op,
            "dynamic_range": dr,
            "sanitized": report,
            "outputs": outputs,
            "read_ms": read_ms,
            "tonemap_and_write_ms": op_ms,
        });
        let _ = writeln!(text, "{}", serde_json::to_string_pretty(&summary)?);
    } else {
        let _ = match dr {
            Some(d) => writeln!(
                text,
                "dynamic range: {:.3e}:1 ({:.2} orders of magnitude; luminance {:.3e} .. {:.3e}, {} black pixels)",
                d.ratio, d.orders_of_magnitude, d.min_positive, d.max, d.zero_pixels
            ),
            None => writeln!(
                text,
                "dynamic range: undefined (no pixel has positive luminance)"
            ),
        };
        if report.total() > 0 {
            let _ = writeln!(
                text,
                "dirty input: {} NaN, {} negative, {} +Inf channel values replaced",
                report.nan, report.negative, report.positive_infinite
            );
        }
    }
    if crate::output::direct_target(&args.out).is_some() {
        errout!("{text}");
    } else {
        out!("{text}");
    }
    for o in &outputs {
        crate::output::wrote(o);
    }
    Ok(())
}

/// Whether the output is an 8-bit PNG made on the CPU whose exposure the operator applies
/// itself: the display codes can be made without the floating-point display image.
fn straight_to_codes(args: &Args, ext: &str) -> bool {
    !args.pseudocolor
        && args.exposure_series.is_none()
        && ext == "png"
        && args.depth != 16
        && args.device == blueshift_gpu::DeviceChoice::Cpu
        && (args.exposure.is_none_or(|s| s == 0.0) || matches!(args.op, Op::Linear | Op::Drago))
}

/// Writes 8-bit sRGB codes (row-major RGB) as a PNG.
fn write_codes_png(path: &Path, w: u32, h: u32, codes: Vec<u8>) -> Result<()> {
    let pic = image::RgbImage::from_raw(w, h, codes)
        .ok_or_else(|| anyhow::anyhow!("the display image does not match its size"))?;
    crate::output::write_via_temp_path(path, |p| Ok(io::write_rgb8_png(p, &pic)?))
}

/// Tone-maps a cleaned image into the outputs `args` names: the kind of output and the
/// files written.
fn tonemap_clean(
    args: &Args,
    ext: &str,
    op: &mut Operator,
    clean: &blueshift_tonemap::CleanImage,
) -> Result<(&'static str, Vec<PathBuf>)> {
    let hdr = &clean.image;
    if let Operator::Linear(p) = op
        && p.white.is_none()
    {
        p.white = blueshift_tonemap::default_linear_white(hdr);
    }
    let mut outputs = Vec::new();
    let kind;
    if args.pseudocolor {
        kind = "pseudocolor";
        if ext != "png" {
            bail!("--pseudocolor writes a PNG: {}", args.out.display());
        }
        let pic = blueshift_tonemap::pseudocolour(hdr, &PseudocolourParams::default())?;
        crate::output::write_via_temp_path(&args.out, |p| Ok(io::write_rgb8_png(p, &pic)?))?;
        outputs.push(args.out.clone());
    } else if let Some(n) = args.exposure_series {
        kind = "exposure-series";
        let mut series = ExposureSeries::spanning(hdr, n);
        if let Some(step) = args.stops_step {
            series.step_stops = step;
        }
        let images = blueshift_tonemap::exposure_series(hdr, &series)?;
        for (i, img) in images.iter().enumerate() {
            let path = series_path(&args.out, i, ext);
            write_display(&path, ext, img, args.depth)?;
            outputs.push(path);
        }
    } else if straight_to_codes(args, ext) {
        // An 8-bit PNG on the CPU: straight to the sRGB codes (the same bytes as the float
        // display image and `write_display`; global operators skip that image).
        kind = op.name();
        let codes = op.apply_clean_srgb8(clean)?;
        let (w, h) = hdr.dimensions();
        write_codes_png(&args.out, w, h, codes)?;
        outputs.push(args.out.clone());
    } else {
        kind = op.name();
        let ran = blueshift_gpu::run_with_fallback(
            args.device,
            || blueshift_gpu::tonemap::supports(op),
            |ctx| blueshift_gpu::tonemap::tonemap(ctx, op, hdr),
            || -> Result<_> { Ok(op.apply_clean(clean)?) },
        )
        .map_err(crate::commands::doppler::device_error)?;
        if let Some(why) = &ran.fallback {
            errln!("--device auto: {why}; tone-mapping on the CPU");
        }
        let mut display = ran.value;
        // Operators without an exposure of their own (Reinhard, Reinhard local, Durand,
        // Fattal normalise their input's scale away): the stops scale the display, brought
        // back into the display gamut keeping hue and luminance.
        if let Some(stops) = args.exposure.filter(|s| *s != 0.0)
            && !matches!(args.op, Op::Linear | Op::Drago)
        {
            let gain = 2f32.powf(stops);
            for p in display.pixels_mut() {
                p.0 = blueshift_tonemap::plane::fit_to_display(p.0.map(|c| c * gain));
            }
        }
        write_display(&args.out, ext, &display, args.depth)?;
        outputs.push(args.out.clone());
    }
    Ok((kind, outputs))
}
