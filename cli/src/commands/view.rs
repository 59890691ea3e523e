//! `blueshift view`: the interactive viewer. Builds the scene the way `render`, `doppler`,
//! `relativity` or `tonemap` would from the same flags, then serves it to a browser page
//! (blueshift-view) and prints one line with the URL. It opens no browser.

use std::net::IpAddr;
use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use blueshift_view::{
    Config, DopplerSource, HdrSource, RelativitySource, Server, Source, TrackingSource,
};
use clap::Parser;

/// Arguments of `blueshift view`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Render scene file (JSON, as `blueshift render SCENE.json` takes).
    pub scene: Option<PathBuf>,
    /// Volume file of a channel (repeat; pairs with --tf in order).
    #[arg(long = "volume")]
    pub volumes: Vec<PathBuf>,
    /// Transfer function per channel (repeat) or one for all: JSON file (blueshift or
    /// ParaView preset), builtin:NAME or log:NAME [default: builtin:viridis].
    #[arg(long = "tf")]
    pub tfs: Vec<String>,
    /// Synthetic dataset: rendered by tracking (three-cubes, galaxy, channels12, ...), or a
    /// Doppler scene with --doppler (galaxy, shell).
    #[arg(long)]
    pub synth: Option<String>,
    /// Resolution of --synth (voxels per edge).
    #[arg(long, default_value_t = 64)]
    pub res: usize,
    /// Stretch the transfer functions over `data` or `LO:HI` (as `render --tf-range`).
    #[arg(long, value_name = "data|LO:HI", allow_hyphen_values = true)]
    pub tf_range: Option<String>,
    /// Tracking method [default: mdwt-1dda] (woodcock, mdwt-ndda, mdwt-1dda, mdwt-summed, marcher).
    #[arg(long)]
    pub method: Option<String>,
    /// Samples per pixel the refinement stops at [default: the scene file's, else 256].
    #[arg(long)]
    pub spp: Option<u32>,
    /// Doppler scene JSON (as `blueshift doppler --scene` takes).
    #[arg(long, value_name = "FILE.json")]
    pub doppler_scene: Option<PathBuf>,
    /// Show --synth (galaxy or shell) as a Doppler scene.
    #[arg(long)]
    pub doppler: bool,
    /// Environment map (equirectangular .exr/.hdr/.pfm/.png or a cube map) for the
    /// relativistic observer; `checker` for the built-in checkerboard.
    #[arg(long, value_name = "ENVMAP")]
    pub env: Option<PathBuf>,
    /// Observer speed |v| / c of relativity mode, in [0, 1).
    #[arg(long, default_value_t = 0.5)]
    pub beta: f64,
    /// HDR image to tone-map (OpenEXR, Radiance .hdr, PFM).
    #[arg(long, value_name = "IMAGE")]
    pub hdr: Option<PathBuf>,
    /// Image width in pixels [default: 256].
    #[arg(long)]
    pub width: Option<u32>,
    /// Image height in pixels [default: 256].
    #[arg(long)]
    pub height: Option<u32>,
    /// Display operator of tracking frames (as `render --tonemap`).
    #[arg(long, default_value = "exposure")]
    pub tonemap: String,
    /// Display exposure in stops.
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    pub exposure: f32,
    /// Where tracking scenes render: cpu, gpu or auto (the page can change it).
    #[arg(long, default_value = "cpu")]
    pub device: blueshift_gpu::DeviceChoice,
    /// Port to listen on (0: any free port).
    #[arg(long, default_value_t = 8765)]
    pub port: u16,
    /// Address to bind [default: 127.0.0.1]; any other address is reachable from other
    /// machines (a warning says so), still behind the URL's token.
    #[arg(long)]
    pub bind: Option<IpAddr>,
    /// Folder the page's "save" writes into (created if missing).
    #[arg(long, default_value = ".")]
    pub save_dir: PathBuf,
    /// Worker threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
}

/// A clap error as one line (its first, without clap's `error: `).
fn flag_error(e: clap::Error) -> anyhow::Error {
    let text = e.to_string();
    let line = text.lines().next().unwrap_or("bad flags");
    anyhow::anyhow!("{}", line.trim_start_matches("error: "))
}

/// `render` flags, parsed by clap exactly as `blueshift render` parses them.
#[derive(Debug, Parser)]
#[command(no_binary_name = true)]
struct RenderFlags {
    #[command(flatten)]
    args: super::render::Args,
}

fn tracking(args: &Args) -> Result<Source> {
    let mut flags: Vec<String> = Vec::new();
    if let Some(s) = &args.scene {
        flags.push(s.display().to_string());
    }
    for v in &args.volumes {
        flags.extend(["--volume".into(), v.display().to_string()]);
    }
    if let Some(s) = &args.synth {
        flags.extend([
            "--synth".into(),
            s.clone(),
            "--res".into(),
            args.res.to_string(),
        ]);
    }
    let inline = !args.volumes.is_empty() || args.synth.is_some();
    if args.tfs.is_empty() && inline {
        flags.extend(["--tf".into(), "builtin:viridis".into()]);
    }
    for t in &args.tfs {
        flags.extend(["--tf".into(), t.clone()]);
    }
    if let Some(r) = &args.tf_range {
        flags.extend(["--tf-range".into(), r.clone()]);
    }
    if let Some(m) = &args.method {
        flags.extend(["--method".into(), m.clone()]);
    }
    flags.extend(["--out".into(), "unused.exr".into()]);
    let parsed = RenderFlags::try_parse_from(&flags).map_err(flag_error)?;
    let mut file = super::render::merge(&parsed.args)?;
    let size = |v: Option<u32>, file_v: Option<u32>| v.or(file_v).or(Some(256));
    file.width = size(args.width, file.width);
    file.height = size(args.height, file.height);
    file.spp = args.spp.or(file.spp).or(Some(256));
    let (scene, _, _) = file.build()?;
    let mut inputs: Vec<PathBuf> = args.volumes.clone();
    inputs.extend(args.scene.clone());
    inputs.extend(
        args.tfs
            .iter()
            .filter(|t| !t.contains(':'))
            .map(PathBuf::from),
    );
    Ok(Source::Tracking(Box::new(TrackingSource {
        file,
        scene,
        inputs,
        tonemap: args.tonemap.clone(),
        exposure: args.exposure,
        device: args.device,
    })))
}

/// `doppler` flags, parsed as `blueshift doppler` parses them.
#[derive(Debug, Parser)]
#[command(no_binary_name = true)]
struct DopplerFlags {
    #[command(flatten)]
    args: super::doppler::Args,
}

fn doppler(args: &Args) -> Result<Source> {
    let mut base: Vec<String> = Vec::new();
    match (&args.doppler_scene, &args.synth) {
        (Some(p), _) => {
            // An absolute path, so the printed command works from any folder.
            let p = std::fs::canonicalize(p)
                .with_context(|| format!("--doppler-scene {}", p.display()))?;
            base.extend(["--scene".into(), p.display().to_string()]);
        }
        (None, Some(s)) => {
            base.extend([
                "--synth".into(),
                s.clone(),
                "--res".into(),
                args.res.to_string(),
            ]);
        }
        (None, None) => base.extend(["--synth".into(), "galaxy".into()]),
    }
    let (w, h) = (args.width.unwrap_or(256), args.height.unwrap_or(256));
    let mut flags = base.clone();
    flags.extend([
        "--width".into(),
        w.to_string(),
        "--height".into(),
        h.to_string(),
    ]);
    let parsed = DopplerFlags::try_parse_from(&flags).map_err(flag_error)?;
    let d = &parsed.args;
    let (scene, mut st) = super::doppler::build(d)?;
    super::doppler_cube::apply_view(&d.cube, &scene, &mut st)?;
    super::doppler::apply_camera(d, &scene, &mut st)?;
    st.broadening = super::doppler_cube::broadening(&d.cube)?;
    let display = super::doppler::display(d)?;
    let panel: blueshift_view::PanelFn = Box::new(|scene, st| {
        let mut phys = scene.clone();
        phys.factors.velocity = 1.0;
        let vmax = crate::figure::los_speed_kms(&phys, st);
        let map = crate::figure::velocity_map(&phys, st, vmax, 0.01)
            .map_err(|e| format!("{e:#}"))?
            .ok_or("panels: the scene has no H-alpha line for the velocity panel")?;
        let (rgb, _) = crate::figure::velocity_panel(&map, vmax);
        let img =
            image::RgbImage::from_raw(st.width, st.height, rgb).ok_or("panels: image size")?;
        Ok((
            img,
            serde_json::json!({
                "vmin": -vmax, "vmax": vmax, "unit": "km/s",
                "label": "H-alpha moment 1: line-of-sight velocity (km/s, + receding)",
            }),
        ))
    });
    Ok(Source::Doppler(Box::new(DopplerSource {
        scene,
        settings: st,
        base_args: base,
        inputs: args.doppler_scene.iter().cloned().collect(),
        display,
        exposure: f64::from(args.exposure),
        panel: Some(panel),
    })))
}

fn relativity(args: &Args, env: &std::path::Path) -> Result<Source> {
    let (environment, base, inputs) = if env.as_os_str() == "checker" {
        (
            blueshift_relativity::Environment::Checker(blueshift_relativity::Checker::default()),
            vec!["--synth".to_string(), "checker".into()],
            Vec::new(),
        )
    } else {
        let abs = std::fs::canonicalize(env).with_context(|| format!("--env {}", env.display()))?;
        (
            blueshift_relativity::Environment::load(&abs)?,
            vec![abs.display().to_string()],
            vec![abs],
        )
    };
    blueshift_relativity::Velocity::along(glam::DVec3::NEG_Z, args.beta)?;
    Ok(Source::Relativity(Box::new(RelativitySource {
        env: environment,
        base_args: base,
        inputs,
        size: (args.width.unwrap_or(512), args.height.unwrap_or(256)),
        beta: args.beta,
        fov: 90.0,
    })))
}

fn hdr(path: &std::path::Path) -> Result<Source> {
    let image = blueshift_tonemap::io::read_hdr_image(path)?;
    Ok(Source::Hdr(Box::new(HdrSource {
        image,
        path: std::fs::canonicalize(path).unwrap_or_else(|_| path.to_path_buf()),
    })))
}

/// Runs `blueshift view`.
pub fn run(args: Args) -> Result<()> {
    let modes = [
        args.hdr.is_some(),
        args.env.is_some(),
        args.doppler_scene.is_some() || args.doppler,
        args.scene.is_some() || !args.volumes.is_empty() || (args.synth.is_some() && !args.doppler),
    ];
    if modes.iter().filter(|m| **m).count() > 1 {
        bail!(
            "give one of SCENE.json / --volume / --synth (tracking), --doppler-scene or --synth NAME --doppler, --env, --hdr"
        );
    }
    if let Some(t) = args.threads {
        crate::limits::check_threads(t)?;
        rayon::ThreadPoolBuilder::new()
            .num_threads(t)
            .build_global()
            .context("cannot start worker threads")?;
    }
    let source = if let Some(p) = &args.hdr {
        hdr(p)?
    } else if let Some(e) = &args.env {
        relativity(&args, e)?
    } else if modes[2] {
        doppler(&args)?
    } else if modes[3] {
        tracking(&args)?
    } else {
        bail!(
            "nothing to show: give SCENE.json, --volume FILE [--tf TF], --synth NAME, --doppler-scene FILE.json, --synth galaxy --doppler, --env ENVMAP|checker or --hdr IMAGE"
        );
    };
    let address = args
        .bind
        .unwrap_or(IpAddr::V4(std::net::Ipv4Addr::LOCALHOST));
    if !address.is_loopback() {
        errln!(
            "warning: --bind {address}: the viewer is reachable from other machines (anyone with the URL's token can use it)"
        );
    }
    let server = Server::bind(
        source,
        Config {
            address,
            port: args.port,
            save_dir: args.save_dir.clone(),
            token: None,
        },
    )?;
    outln!("blueshift view: {}", server.url());
    use std::io::Write as _;
    let _ = std::io::stdout().flush();
    server.run()?;
    Ok(())
}
