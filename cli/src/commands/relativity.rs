//! `blueshift relativity`: what a fast observer sees in an environment map (aberration,
//! Doppler colour shift, searchlight), as HDR (EXR/.hdr) and tone-mapped PNG.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use blueshift_relativity::{
    Camera, Checker, Effects, Environment, FACE_NAMES, Velocity, parse_ramp, render, to_srgb8,
};
use glam::DVec3;
use image::Rgb32FImage;

use crate::output::write_via_temp_path;

/// Built-in synthetic environments (flag value).
#[derive(Clone, Copy, Debug, clap::ValueEnum)]
pub enum Synth {
    /// A 10-degree checkerboard with orange grid lines every 30 degrees.
    Checker,
}

/// Arguments of `blueshift relativity`.
///
/// Renders the view of an observer moving with speed --beta (units of c) along --direction
/// through a pinhole camera looking along --look. ENV is an equirectangular map (.exr, .hdr,
/// .png) or a cube map (a folder with px, nx, py, ny, pz, nz files, or their common prefix).
/// Axes: +Y up; equirect centre is -Z; cube faces follow OpenGL.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Where to render: cpu (default, bit-reproducible), gpu (any wgpu adapter, lavapipe
    /// included) or auto (a hardware GPU when present, or the adapter $BLUESHIFT_GPU
    /// forces, else the CPU; an image or map over the adapter's limits renders on the CPU).
    #[arg(long, default_value = "cpu")]
    pub device: blueshift_gpu::DeviceChoice,
    /// Environment map (equirect file, cube folder or cube prefix).
    #[arg(required_unless_present = "synth")]
    pub env: Option<PathBuf>,
    /// Use a built-in environment instead of ENV.
    #[arg(long, value_enum, conflicts_with = "env")]
    pub synth: Option<Synth>,
    /// Observer speed |v| / c, in [0, 1).
    #[arg(long, default_value_t = 0.9, allow_negative_numbers = true)]
    pub beta: f64,
    /// Velocity direction x,y,z in the environment's frame (default: --look).
    #[arg(long, allow_hyphen_values = true)]
    pub direction: Option<String>,
    /// Viewing direction x,y,z.
    #[arg(long, default_value = "0,0,-1", allow_hyphen_values = true)]
    pub look: String,
    /// Camera up direction x,y,z.
    #[arg(long, default_value = "0,1,0", allow_hyphen_values = true)]
    pub up: String,
    /// Vertical field of view in degrees.
    #[arg(long, default_value_t = 90.0)]
    pub fov: f64,
    /// Image width in pixels.
    #[arg(long, default_value_t = 1280)]
    pub width: u32,
    /// Image height in pixels.
    #[arg(long, default_value_t = 720)]
    pub height: u32,
    /// Effects: comma list of aberration, doppler, searchlight (or all, none).
    #[arg(long, default_value = "aberration,doppler,searchlight")]
    pub effects: String,
    /// Output file: .exr or .hdr (linear HDR) or .png (tone-mapped). With --ramp, frame k is
    /// written as STEM_kkkk.EXT.
    #[arg(long)]
    pub out: PathBuf,
    /// Also write a tone-mapped PNG here (single frames only).
    #[arg(long)]
    pub png: Option<PathBuf>,
    /// Exposure in stops for PNG output (linear x 2^exposure, then the sRGB curve).
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    pub exposure: f64,
    /// Velocity ramp START:END:FRAMES (for example 0:0.99:60) instead of --beta.
    #[arg(long)]
    pub ramp: Option<String>,
    /// Convert the environment instead of rendering: `equirect:WxH` writes --out,
    /// `cube:SIZE` writes six faces STEMpx.EXT ... STEMnz.EXT (for example --out sky_.exr).
    #[arg(long, conflicts_with = "ramp")]
    pub convert: Option<String>,
}

fn convert(env: &Environment, spec: &str, out: &Path, exposure: f64) -> Result<()> {
    let (kind, size) = spec
        .split_once(':')
        .with_context(|| format!("--convert {spec:?}: expected equirect:WxH or cube:SIZE"))?;
    match kind {
        "equirect" => {
            let (w, h) = size
                .split_once('x')
                .with_context(|| format!("--convert {spec:?}: expected equirect:WxH"))?;
            let w: u32 = w
                .trim()
                .parse()
                .context("--convert: width is not a whole number")?;
            let h: u32 = h
                .trim()
                .parse()
                .context("--convert: height is not a whole number")?;
            let map = env.to_equirect(w, h)?;
            write_image(out, map.image(), exposure)
        }
        "cube" => {
            let n: u32 = size
                .trim()
                .parse()
                .context("--convert: size is not a whole number")?;
            let cube = env.to_cube(n)?;
            let ext = out
                .extension()
                .map(|e| e.to_string_lossy().into_owned())
                .unwrap_or_default();
            let stem = out.with_extension("").to_string_lossy().into_owned();
            for (face, name) in cube.faces().iter().zip(FACE_NAMES) {
                write_image(
                    &PathBuf::from(format!("{stem}{name}.{ext}")),
                    face,
                    exposure,
                )?;
            }
            Ok(())
        }
        _ => bail!("--convert {spec:?}: the layout must be equirect or cube"),
    }
}

fn parse_vec(name: &str, s: &str) -> Result<DVec3> {
    let parts: Vec<&str> = s.split(',').collect();
    if parts.len() != 3 {
        bail!("--{name} wants three comma-separated numbers x,y,z, got {s:?}");
    }
    let mut v = [0.0_f64; 3];
    for (o, p) in v.iter_mut().zip(parts) {
        *o = p
            .trim()
            .parse()
            .with_context(|| format!("--{name}: {p:?} is not a number"))?;
        if !o.is_finite() {
            bail!("--{name}: components must be finite");
        }
    }
    let v = DVec3::from_array(v);
    if v.length() == 0.0 {
        bail!("--{name} must not be the zero vector");
    }
    Ok(v)
}

/// Writes the image and says so (`wrote PATH`).
fn write_image(path: &Path, img: &Rgb32FImage, exposure: f64) -> Result<()> {
    encode_image(path, img, exposure)?;
    crate::output::wrote(path);
    Ok(())
}

fn encode_image(path: &Path, img: &Rgb32FImage, exposure: f64) -> Result<()> {
    let ext = path
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    if ext == "exr" {
        return crate::output::write_exr_f32(path, img.width(), img.height(), 3, img.as_raw());
    }
    write_via_temp_path(path, |tmp| {
        match ext.as_str() {
            "hdr" => image::DynamicImage::ImageRgb32F(img.clone())
                .save(tmp)
                .with_context(|| format!("cannot encode {}", path.display()))?,
            "png" => blueshift_tonemap::io::save_rgb8_png(tmp, &to_srgb8(img, exposure))
                .with_context(|| format!("cannot encode {}", path.display()))?,
            _ => bail!("unsupported output extension {ext:?} (use .exr, .hdr or .png)"),
        }
        Ok(())
    })
}

fn check_ext(path: &Path) -> Result<()> {
    let ext = path
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    if !["exr", "hdr", "png"].contains(&ext.as_str()) {
        bail!(
            "--out {}: unsupported extension (use .exr, .hdr or .png)",
            path.display()
        );
    }
    Ok(())
}

/// Bytes per pixel of a relativity render: the RGB f32 image, a copy while it is encoded
/// and an sRGB8 preview.
const RELATIVITY_BYTES_PER_PIXEL: u64 = 12 + 12 + 3;

/// Runs `blueshift relativity`.
pub fn run(args: Args) -> Result<()> {
    check_ext(&args.out)?;
    if let Some(p) = &args.png {
        check_ext(p)?;
    }
    let mut outputs = vec![args.out.as_path()];
    outputs.extend(args.png.as_deref());
    crate::output::check_outputs(
        &outputs,
        &args.env.iter().map(PathBuf::as_path).collect::<Vec<_>>(),
    )?;
    if !args.exposure.is_finite() {
        bail!("--exposure must be finite");
    }
    let effects = Effects::parse(&args.effects)?;
    let look = parse_vec("look", &args.look)?;
    let up = parse_vec("up", &args.up)?;
    let direction = match &args.direction {
        Some(s) => parse_vec("direction", s)?,
        None => look,
    };
    let cam = Camera {
        look,
        up,
        fov_y_deg: args.fov,
        width: args.width,
        height: args.height,
    };
    blueshift_relativity::CameraFrame::new(&cam)?;
    // The image (RGB f32), its copy while encoding and an 8-bit preview.
    crate::limits::check(
        format_args!(
            "this image ({}x{}, {RELATIVITY_BYTES_PER_PIXEL} bytes per pixel)",
            args.width, args.height
        ),
        blueshift_volume::budget::image_bytes(
            args.width.into(),
            args.height.into(),
            RELATIVITY_BYTES_PER_PIXEL,
        ),
    )?;
    let speeds = match &args.ramp {
        Some(spec) => Some(parse_ramp(spec)?),
        None => {
            Velocity::along(direction, args.beta)?;
            None
        }
    };
    if let Some(speeds) = &speeds {
        // Every frame's file, checked before the first is written (one may be the map).
        let frames: Vec<PathBuf> = (0..speeds.len())
            .map(|k| super::observer_args::frame_path(&args.out, k))
            .collect();
        let refs: Vec<&Path> = frames.iter().map(PathBuf::as_path).collect();
        crate::output::check_outputs(
            &refs,
            &args.env.iter().map(PathBuf::as_path).collect::<Vec<_>>(),
        )?;
    }
    let env = match (&args.synth, &args.env) {
        (Some(Synth::Checker), _) => Environment::Checker(Checker::default()),
        (None, Some(p)) => Environment::load(p)?,
        (None, None) => bail!("give an environment map ENV or --synth checker"),
    };
    if let Some(spec) = &args.convert {
        return convert(&env, spec, &args.out, args.exposure);
    }
    // The GPU pipeline is built on first use and kept for every frame of a ramp.
    let gpu = std::cell::OnceCell::new();
    let device = args.device;
    let render = |env: &Environment, cam: &Camera, v: Velocity, fx: Effects| -> Result<_> {
        let ran = blueshift_gpu::run_with_fallback(
            device,
            || blueshift_gpu::relativity::supports(fx),
            |ctx| {
                let g = match gpu.get() {
                    Some(g) => g,
                    None => {
                        let g = blueshift_gpu::relativity::GpuRelativity::new(ctx, None)?;
                        gpu.get_or_init(|| g)
                    }
                };
                g.render(env, cam, v, fx)
            },
            || -> Result<_> { Ok(render(env, cam, v, fx, None)?) },
        )
        .map_err(crate::commands::doppler::device_error)?;
        if let Some(why) = &ran.fallback {
            errln!("--device auto: {why}; rendering on the CPU");
        }
        Ok(ran.value)
    };
    // Pixels the Doppler colour shift sends outside what an RGB map holds: said once.
    let out_of_map =
        |v: Velocity| blueshift_relativity::out_of_map_fraction(&cam, v, effects, None);
    let warn = |fraction: f64, which: &str| {
        errln!(
            "note: {:.1}% of the pixels{which} are black: their Doppler factor shifts the \
             visible window outside the 380-780 nm an RGB map's spectrum holds",
            100.0 * fraction
        );
    };
    match speeds {
        None => {
            let v = Velocity::along(direction, args.beta)?;
            let f = out_of_map(v)?;
            if f > 0.0 {
                warn(f, "");
            }
            let img = render(&env, &cam, v, effects)?;
            write_image(&args.out, &img, args.exposure)?;
            if let Some(p) = &args.png {
                write_image(p, &img, args.exposure)?;
            }
        }
        Some(speeds) => {
            let mut worst: Option<(usize, f64)> = None;
            for (k, &b) in speeds.iter().enumerate() {
                let v = Velocity::along(direction, b)?;
                let f = out_of_map(v)?;
                if f > worst.map_or(0.0, |w| w.1) {
                    worst = Some((k, f));
                }
                let img = render(&env, &cam, v, effects)?;
                let path = super::observer_args::frame_path(&args.out, k);
                errln!("frame {k}: beta {b:.4}");
                write_image(&path, &img, args.exposure)?;
            }
            if let Some((k, f)) = worst {
                warn(f, &format!(" of frame {k} (the most of any frame)"));
            }
        }
    }
    Ok(())
}
