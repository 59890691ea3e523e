//! `blueshift doppler --cube`: position-position-velocity cubes (FITS + NRRD), moment maps
//! (EXR + colour-mapped PNGs with sky axes in world units and colour bars naming quantity
//! and unit) and views along any direction.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result, anyhow, bail};
use blueshift_doppler::{
    Broadening, CubeLineWidth, CubeMeta, CubeSpec, CubeUnitsSpec, DopplerScene, DopplerSettings,
    Moments, SpectralAxis, SpectralCube, fits_bytes, los_camera, nrrd_bytes, render_cube,
};
use blueshift_spectrum::named_line;
use clap::Args as ClapArgs;
use plotters::prelude::*;

use crate::output::OutputSet;
use crate::plot::{FONT, blue_red, inferno, register_font, tick_formatter};

/// Cube, broadening and view flags of `blueshift doppler`.
#[derive(Debug, Clone, Default, ClapArgs)]
pub struct CubeArgs {
    /// Write a spectral cube (FITS) instead of an image; an NRRD copy goes next to it.
    /// Lines without --thermal / --line-sigma get a box one channel wide (--line-width is
    /// not used), whose exact channel integrals are yt's tent weights. Without absorption
    /// the cube is continuum-subtracted (line emission only, as yt's PPV cubes); with
    /// absorption it holds the light that reaches the eye, black-body continuum included, so
    /// that absorption lines show against it.
    #[arg(long)]
    pub cube: Option<PathBuf>,
    /// The cube's line: a name (H-alpha, Halpha, H-beta, HeI-5876, ...) or a rest
    /// wavelength in nm.
    #[arg(long)]
    pub line: Option<String>,
    /// Velocity channels VMIN:VMAX:N in km/s (channel edges from VMIN to VMAX).
    #[arg(long, allow_hyphen_values = true)]
    pub velocity_bins: Option<String>,
    /// Wavelength channels MIN:MAX:N in nm (instead of --velocity-bins; CTYPE3 WAVE).
    #[arg(long, allow_hyphen_values = true)]
    pub wavelength_bins: Option<String>,
    /// Velocity convention of the spectral axis: vrad (radio, FITS VRAD) or vopt (optical,
    /// FITS VOPT, yt's PPVCube axis).
    #[arg(long, default_value = "vrad")]
    pub spectral_axis: String,
    /// Thermal Doppler broadening of every line (sigma = sqrt(kT/m) from the temperature
    /// field and the species' atomic mass).
    #[arg(long)]
    pub thermal: bool,
    /// Extra Gaussian line width (1 sigma), km/s.
    #[arg(long, default_value_t = 0.0)]
    pub line_sigma: f64,
    /// Atomic mass of a species, NAME=AMU (repeatable; H, He, C have catalogue masses).
    #[arg(long)]
    pub mass: Vec<String>,
    /// Write moment maps 0, 1, 2 (EXR and PNG with colour bars) next to the cube.
    #[arg(long)]
    pub moments: bool,
    /// View along an axis: the observer sits at +x, +y or +z (yt's axis projections).
    #[arg(long)]
    pub axis: Option<String>,
    /// View along any direction X,Y,Z: the observer sits at +normal (yt's normal vector);
    /// the line-of-sight velocity is -v . normal (positive: receding).
    #[arg(long, allow_hyphen_values = true)]
    pub normal: Option<String>,
    /// Voxels are cells (Enzo, yt): rays cross the voxel centres' box grown by half a voxel.
    #[arg(long)]
    pub cell_domain: bool,
    /// FITS BUNIT of the cube (default: the scene file's `cube.bunit`, else `arbitrary`).
    #[arg(long, default_value = "")]
    pub bunit: String,
    /// Spatial unit of the cube's sky axes, UNIT:SCALE (one world unit = SCALE UNIT), e.g.
    /// cm:5.6149e23 (default: the scene file's `cube.world_unit`, else world units).
    #[arg(long)]
    pub world_unit: Option<String>,
    /// Blank (NaN in the EXR, grey in the PNG) moments 1 and 2 where moment 0 is below a
    /// threshold: `NN%` of the peak moment 0, or a moment-0 value. Moment 0 is never masked.
    #[arg(long, value_name = "NN%|VALUE")]
    pub mask: Option<String>,
}

fn parse_triple(s: &str, what: &str) -> Result<(f64, f64, usize)> {
    let p: Vec<&str> = s.split(':').collect();
    if p.len() != 3 {
        bail!("{what} '{s}': expected MIN:MAX:N");
    }
    let a: f64 = p[0]
        .trim()
        .parse()
        .map_err(|_| anyhow!("{what} '{s}': bad MIN"))?;
    let b: f64 = p[1]
        .trim()
        .parse()
        .map_err(|_| anyhow!("{what} '{s}': bad MAX"))?;
    let n: usize = p[2]
        .trim()
        .parse()
        .map_err(|_| anyhow!("{what} '{s}': bad N"))?;
    if !(a.is_finite() && b.is_finite()) || a >= b {
        bail!("{what} '{s}': the range {a}..{b} is empty (MIN must be below MAX)");
    }
    if n == 0 {
        bail!("{what} '{s}': zero channels");
    }
    Ok((a, b, n))
}

/// Applies `--cell-domain` and `--axis` / `--normal` to the settings (both view flags: an
/// error).
pub fn apply_view(args: &CubeArgs, scene: &DopplerScene, st: &mut DopplerSettings) -> Result<()> {
    st.cell_domain = args.cell_domain;
    let normal = match (&args.axis, &args.normal) {
        (Some(_), Some(_)) => bail!("give --axis or --normal, not both"),
        (Some(a), None) => match a.trim().to_ascii_lowercase().as_str() {
            "x" => glam::Vec3::X,
            "y" => glam::Vec3::Y,
            "z" => glam::Vec3::Z,
            other => bail!("unknown --axis '{other}' (x, y, z)"),
        },
        (None, Some(n)) => {
            let p: Vec<f32> = n
                .split(',')
                .map(|t| t.trim().parse::<f32>())
                .collect::<std::result::Result<_, _>>()
                .map_err(|_| anyhow!("--normal '{n}': expected X,Y,Z"))?;
            if p.len() != 3 || p.iter().any(|v| !v.is_finite()) {
                bail!("--normal '{n}': expected three finite numbers X,Y,Z");
            }
            glam::Vec3::new(p[0], p[1], p[2])
        }
        (None, None) => return Ok(()),
    };
    st.camera = los_camera(
        scene,
        normal,
        st.width as f32 / st.height.max(1) as f32,
        st.cell_domain,
    )?;
    Ok(())
}

/// The broadening from the flags.
pub fn broadening(args: &CubeArgs) -> Result<Broadening> {
    if !(args.line_sigma.is_finite() && args.line_sigma >= 0.0) {
        bail!("--line-sigma {} must be finite and >= 0", args.line_sigma);
    }
    let mut masses = Vec::new();
    for m in &args.mass {
        let (n, v) = m
            .split_once('=')
            .ok_or_else(|| anyhow!("--mass '{m}': expected NAME=AMU"))?;
        let v: f64 = v
            .trim()
            .parse()
            .map_err(|_| anyhow!("--mass '{m}': bad mass"))?;
        if !(v.is_finite() && v > 0.0) {
            bail!("--mass '{m}': the mass must be finite and > 0");
        }
        masses.push((n.trim().to_owned(), v));
    }
    Ok(Broadening {
        thermal: args.thermal,
        sigma_m_per_s: args.line_sigma * 1e3,
        masses_amu: masses,
    })
}

/// The channels from the flags.
pub fn cube_spec(args: &CubeArgs) -> Result<CubeSpec> {
    let line = args
        .line
        .as_deref()
        .ok_or_else(|| anyhow!("--cube needs --line NAME_OR_NM"))?;
    let rest_nm = match line.trim().parse::<f64>() {
        Ok(v) if v.is_finite() && v > 0.0 => v,
        Ok(v) => bail!("--line {v}: a wavelength must be finite and > 0 nm"),
        Err(_) => named_line(line)?.line.centre_nm,
    };
    match (&args.velocity_bins, &args.wavelength_bins) {
        (Some(_), Some(_)) => bail!("give --velocity-bins or --wavelength-bins, not both"),
        (Some(v), None) => {
            let (a, b, n) = parse_triple(v, "--velocity-bins")?;
            let axis: SpectralAxis = args.spectral_axis.parse()?;
            if axis == SpectralAxis::Wavelength {
                bail!("--spectral-axis wave needs --wavelength-bins");
            }
            Ok(CubeSpec {
                rest_nm,
                axis,
                min: a * 1e3,
                max: b * 1e3,
                channels: n,
                // A box one channel wide (render_cube's default): its exact channel
                // integrals are yt's tent weights 1 - |v_c - v| / dv.
                line_width: CubeLineWidth::OneChannel,
            })
        }
        (None, Some(w)) => {
            let (a, b, n) = parse_triple(w, "--wavelength-bins")?;
            Ok(CubeSpec {
                rest_nm,
                axis: SpectralAxis::Wavelength,
                min: a,
                max: b,
                channels: n,
                // A box one channel wide (render_cube's default): its exact channel
                // integrals are yt's tent weights 1 - |v_c - v| / dv.
                line_width: CubeLineWidth::OneChannel,
            })
        }
        (None, None) => bail!("--cube needs --velocity-bins VMIN:VMAX:N (km/s)"),
    }
}

/// Every file `--cube OUT` writes: the FITS, the NRRD and (with `--moments`) the moment
/// maps' EXRs and PNGs.
pub fn cube_outputs(args: &CubeArgs, out: &Path) -> Vec<PathBuf> {
    let mut v = vec![out.to_path_buf(), out.with_extension("nrrd")];
    if args.moments {
        for m in ["mom0", "mom1", "mom2"] {
            v.push(sibling(out, &format!("_{m}.exr")));
            v.push(sibling(out, &format!("_{m}.png")));
        }
    }
    v
}

fn sibling(out: &Path, suffix: &str) -> PathBuf {
    let stem = out.file_stem().and_then(|s| s.to_str()).unwrap_or("cube");
    out.with_file_name(format!("{stem}{suffix}"))
}

/// The moment-0 threshold of `--mask`: `NN%` of `peak`, or a value.
fn mask_threshold(text: &str, peak: f32) -> Result<f32> {
    let t = text.trim();
    let (num, percent) = match t.strip_suffix('%') {
        Some(n) => (n.trim(), true),
        None => (t, false),
    };
    let v: f32 = num
        .parse()
        .map_err(|_| anyhow!("--mask '{text}': expected NN% of the peak or a moment-0 value"))?;
    if !(v.is_finite() && v >= 0.0) {
        bail!("--mask '{text}': the threshold must be finite and >= 0");
    }
    if percent && v > 100.0 {
        bail!("--mask '{text}': a percentage of the peak must be at most 100%");
    }
    Ok(if percent { v / 100.0 * peak } else { v })
}

/// Renders and writes the cube (and moments): called by `blueshift doppler --cube`.
/// `units` are the scene file's cube units (the flags override them).
pub fn run_cube(
    args: &CubeArgs,
    scene: &DopplerScene,
    st: &DopplerSettings,
    units: Option<&CubeUnitsSpec>,
    distributed: Option<(blueshift_dist::Mode, &str)>,
) -> Result<()> {
    let out = args.cube.as_ref().ok_or_else(|| anyhow!("no --cube"))?;
    let spec = cube_spec(args)?;
    spec.validate(st.range_nm)?;
    if let Some(m) = &args.mask {
        mask_threshold(m, 1.0)?;
    }
    let world_unit_text = args
        .world_unit
        .clone()
        .or_else(|| units.and_then(|u| u.world_unit.clone()));
    let bunit = if args.bunit.is_empty() {
        units.and_then(|u| u.bunit.clone()).unwrap_or_default()
    } else {
        args.bunit.clone()
    };
    let world_unit = match &world_unit_text {
        None => None,
        Some(w) => {
            let (u, k) = w
                .split_once(':')
                .ok_or_else(|| anyhow!("--world-unit '{w}': expected UNIT:SCALE"))?;
            let k: f64 = k
                .trim()
                .parse()
                .map_err(|_| anyhow!("--world-unit '{w}': bad SCALE"))?;
            if !(k.is_finite() && k > 0.0) {
                bail!("--world-unit '{w}': SCALE must be finite and > 0");
            }
            Some((u.trim().to_owned(), k))
        }
    };
    let meta = CubeMeta {
        bunit: bunit.clone(),
        object: String::new(),
        world_unit,
    };
    let bar = crate::progress::Progress::new(
        u64::from(st.height),
        "{bar:30} {pos}/{len} rows [{elapsed}]",
        "cube",
        "rows",
    );
    let start = Instant::now();
    let cube = match distributed {
        None => render_cube(scene, st, &spec, &|| bar.inc(1))?,
        // Rank 0 gets the cube and writes it; the other ranks are done.
        Some((mode, compositing)) => {
            match crate::dist::cube(mode, scene, st, &spec, compositing)? {
                Some(c) => c,
                None => return Ok(()),
            }
        }
    };
    bar.finish();
    let secs = start.elapsed().as_secs_f64();
    let fits = fits_bytes(&cube, &meta)?;
    let nrrd = nrrd_bytes(&cube)?;
    // One set: the moment maps, the NRRD, then the FITS, renamed only once all are staged.
    let mut set = OutputSet::new();
    let moment_files = if args.moments {
        write_moments(&mut set, out, &cube, args.mask.as_deref(), &meta)?
    } else {
        Vec::new()
    };
    let nrrd_path = out.with_extension("nrrd");
    set.put(&nrrd_path, &nrrd)?;
    set.put(out, &fits)?;
    set.commit()?;
    crate::output::wrote_with(
        out,
        &format!(
            "{}x{}x{} channels {} {:.4}..{:.4} nm, {:.2} s",
            cube.nx,
            cube.ny,
            spec.channels,
            spec.axis.ctype(),
            spec.edge_nm(0),
            spec.edge_nm(spec.channels),
            secs
        ),
    );
    crate::output::wrote(&nrrd_path);
    for p in moment_files {
        crate::output::wrote(&p);
    }
    Ok(())
}

/// Stages the moment maps (EXR and PNG each) in `set`; returns their paths.
fn write_moments(
    set: &mut OutputSet,
    out: &Path,
    cube: &SpectralCube,
    mask: Option<&str>,
    meta: &CubeMeta,
) -> Result<Vec<PathBuf>> {
    let mut files = Vec::new();
    let mut m: Moments = cube.moments();
    if let Some(text) = mask {
        let peak =
            m.m0.iter()
                .copied()
                .filter(|v| v.is_finite())
                .fold(0.0, f32::max);
        m = m.masked(mask_threshold(text, peak)?);
    }
    let velocity = cube.spec.axis != SpectralAxis::Wavelength;
    let (k, unit) = if velocity {
        (1e-3, "km/s")
    } else {
        (1.0, "nm")
    };
    let bunit = if meta.bunit.is_empty() {
        "arbitrary units"
    } else {
        meta.bunit.as_str()
    };
    let maps: [(&str, Vec<f32>, String, String); 3] = [
        (
            "mom0",
            m.m0.clone(),
            "moment 0: integrated line emission".to_owned(),
            bunit.to_owned(),
        ),
        (
            "mom1",
            m.m1.iter().map(|v| (f64::from(*v) * k) as f32).collect(),
            format!(
                "moment 1: mean {}",
                if velocity { "velocity" } else { "wavelength" }
            ),
            unit.to_owned(),
        ),
        (
            "mom2",
            m.m2.iter().map(|v| (f64::from(*v) * k) as f32).collect(),
            format!("moment 2: dispersion ({unit})"),
            unit.to_owned(),
        ),
    ];
    // Sky axes: offsets from the view centre in world units, or in the --world-unit.
    let (scale, sky_unit) = match &meta.world_unit {
        Some((u, s)) => (*s, u.clone()),
        None => (1.0, "world units".to_owned()),
    };
    let sky = Sky {
        half_x: 0.5 * cube.pixel_world.0 * cube.nx as f64 * scale,
        half_y: 0.5 * cube.pixel_world.1 * cube.ny as f64 * scale,
        unit: sky_unit,
    };
    for (name, v, title, bar_unit) in maps {
        // Flip to image order (row 0 at the top).
        let (w, h) = (m.nx, m.ny);
        let mut img = Vec::with_capacity(v.len());
        for y in (0..h).rev() {
            img.extend_from_slice(&v[y * w..(y + 1) * w]);
        }
        let rgba: Vec<f32> = img.iter().flat_map(|&p| [p, p, p, 1.0]).collect();
        let path = sibling(out, &format!("_{name}.exr"));
        // Block after block (the same bytes every run), via a temporary file.
        crate::output::stage_exr_f32(set, &path, (w as u32, h as u32), 4, &rgba)?;
        files.push(path);
        let diverging = name == "mom1" && velocity;
        let png = sibling(out, &format!("_{name}.png"));
        colour_png(set, &png, &img, (w, h), &title, &bar_unit, &sky, diverging)?;
        files.push(png);
    }
    Ok(files)
}

/// The sky extent of a moment map: half widths from the view centre, in `unit`.
struct Sky {
    half_x: f64,
    half_y: f64,
    unit: String,
}

/// A colour-mapped picture (NaN grey) at least 256 pixels across, with sky axes (offsets
/// from the view centre) and a colour bar labelled with `bar_unit`: inferno from the
/// minimum to the maximum, or blue-white-red symmetric about 0.
#[allow(clippy::too_many_arguments)]
fn colour_png(
    set: &mut OutputSet,
    path: &Path,
    v: &[f32],
    (w, h): (usize, usize),
    title: &str,
    bar_unit: &str,
    sky: &Sky,
    diverging: bool,
) -> Result<()> {
    register_font();
    let finite = v.iter().copied().filter(|x| x.is_finite());
    let (mut lo, mut hi) = finite.fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), x| {
        (a.min(x), b.max(x))
    });
    if !lo.is_finite() {
        (lo, hi) = (0.0, 1.0);
    }
    if diverging {
        let m = lo.abs().max(hi.abs()).max(1e-6);
        (lo, hi) = (-m, m);
    }
    if hi <= lo {
        hi = lo + 1.0;
    }
    let zoom = (256 / w.max(h).max(1)).max(1);
    let (pw, ph) = (w * zoom, h * zoom);
    let (left, bottom, top, bar_w) = (70usize, 45usize, 30usize, 150usize);
    let (iw, ih) = (
        (left + pw + 10 + bar_w) as u32,
        (top + ph.max(200) + bottom) as u32,
    );
    let mut buf = vec![0u8; iw as usize * ih as usize * 3];
    let map = |x: f32| {
        if !x.is_finite() {
            RGBColor(128, 128, 128)
        } else if diverging {
            blue_red((x - lo) / (hi - lo))
        } else {
            inferno((x - lo) / (hi - lo))
        }
    };
    {
        let root = BitMapBackend::with_buffer(&mut buf, (iw, ih)).into_drawing_area();
        let err = |e| anyhow!("moment map plot: {e:?}");
        root.fill(&WHITE).map_err(err)?;
        let style = (FONT, 13).into_font().color(&BLACK);
        root.draw(&Text::new(title.to_owned(), (4, 6), style.clone()))
            .map_err(err)?;
        let (image_area, bar_area) = root.split_horizontally((left + pw + 10) as u32);
        let image_area = image_area.margin(top as u32, (ih as usize - top - ph) as u32 - 45, 0, 10);
        let (sx, sy) = (sky.half_x, sky.half_y);
        let mut chart = ChartBuilder::on(&image_area)
            .x_label_area_size(40)
            .y_label_area_size(left as u32 - 10)
            .build_cartesian_2d(-sx..sx, -sy..sy)
            .map_err(err)?;
        chart
            .configure_mesh()
            .disable_mesh()
            .x_desc(format!("x ({})", sky.unit))
            .y_desc(format!("y ({})", sky.unit))
            .label_style((FONT, 12))
            .x_labels(5)
            .y_labels(5)
            .x_label_formatter(&tick_formatter(-sx, sx))
            .y_label_formatter(&tick_formatter(-sy, sy))
            .draw()
            .map_err(err)?;
        let (dx, dy) = (2.0 * sx / w as f64, 2.0 * sy / h as f64);
        chart
            .draw_series((0..h).flat_map(|y| {
                (0..w).map(move |x| {
                    let x0 = -sx + x as f64 * dx;
                    let y0 = sy - y as f64 * dy;
                    Rectangle::new([(x0, y0), (x0 + dx, y0 - dy)], map(v[y * w + x]).filled())
                })
            }))
            .map_err(err)?;
        let (x0, y0, y1) = (14i32, (top + 10) as i32, (top + ph.max(200)) as i32 - 10);
        bar_area
            .draw(&Text::new(
                bar_unit.to_owned(),
                (x0, top as i32 - 8),
                style.clone(),
            ))
            .map_err(err)?;
        for y in y0..=y1 {
            let t = (y1 - y) as f32 / (y1 - y0).max(1) as f32;
            bar_area
                .draw(&Rectangle::new(
                    [(x0, y), (x0 + 16, y + 1)],
                    map(lo + t * (hi - lo)).filled(),
                ))
                .map_err(err)?;
        }
        let fmt = tick_formatter(f64::from(lo), f64::from(hi));
        for t in [1.0f32, 0.75, 0.5, 0.25, 0.0] {
            let y = y1 - (t * (y1 - y0) as f32).round() as i32;
            let val = f64::from(lo + t * (hi - lo));
            bar_area
                .draw(&Text::new(fmt(&val), (x0 + 22, y - 6), style.clone()))
                .map_err(err)?;
        }
        root.present().map_err(err)?;
    }
    let img = image::RgbImage::from_raw(iw, ih, buf).ok_or_else(|| anyhow!("plot buffer"))?;
    set.via_path(path, |p| {
        blueshift_tonemap::io::save_rgb8_png(p, &img)
            .with_context(|| format!("cannot write {}", path.display()))
    })
}
