//! `blueshift spectrum`: build a spectrum (black body, emission lines, Doppler shift), write
//! it as CSV and as a plot, and print its colour.

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use blueshift_spectrum::{
    Blackbody, Catalogue, DopplerModel, LineProfile, Observer, PiecewiseLinear,
    RadiometricTransform, WavelengthShift, read_line_list, srgb_encode,
};
use clap::ValueEnum;
use serde_json::json;

use crate::output::write_atomic;
use crate::plot::{Series, exact_polyline as polyline, line_plot};

/// Doppler model (flag value).
#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum DopplerArg {
    /// First order, radial: s = 1 + v/c (Doppler paper Eq. 6).
    Classical,
    /// Special relativity, radial motion: s = sqrt((1 + beta) / (1 - beta)) (Eq. 4).
    Relativistic,
}

/// Radiometric transform under a shift (flag value).
#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum RadiometricArg {
    /// Values kept, axis stretched (integral x s).
    None,
    /// I_nu / nu^3 invariant: values x s^-5 (a black body stays a black body at T / s).
    Invariant,
}

/// Line profile (flag value).
#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum ProfileArg {
    /// A box of full width --line-width (the paper's profile).
    Box,
    /// A triangle with FWHM --line-width.
    Triangle,
}

/// Observer (flag value).
#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum ObserverArg {
    /// CIE 1931 2-degree.
    #[value(name = "1931")]
    Cie1931,
    /// CIE 1964 10-degree.
    #[value(name = "1964")]
    Cie1964,
}

/// Arguments of `blueshift spectrum`.
///
/// Values are spectral radiance in W sr^-1 m^-2 nm^-1. A catalogue line of relative
/// intensity r contributes r x --line-strength W sr^-1 m^-2 (its area).
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Black-body temperature in kelvin.
    #[arg(long, value_name = "T_K", allow_negative_numbers = true)]
    blackbody: Option<f64>,
    /// Built-in line catalogues, comma separated: H (Balmer), He (He I), C (C I).
    #[arg(long, value_name = "H,He,C", value_delimiter = ',')]
    lines: Vec<String>,
    /// A user line list (CSV with header wavelength_nm,relative_intensity); repeatable.
    #[arg(long, value_name = "CSV")]
    line_list: Vec<PathBuf>,
    /// Integrated radiance of a line of relative intensity 1, W sr^-1 m^-2.
    #[arg(long, default_value_t = 1.0, value_name = "W_PER_SR_M2")]
    line_strength: f64,
    /// Line width in nm (box full width, or triangle FWHM).
    #[arg(long, default_value_t = 1.0, value_name = "NM")]
    line_width: f64,
    /// Line profile.
    #[arg(long, value_enum, default_value = "box")]
    line_profile: ProfileArg,
    /// Wavelength ratio s = lambda_obs / lambda_emit (> 1 is a red shift).
    #[arg(
        long,
        value_name = "S",
        conflicts_with = "radial_velocity",
        allow_negative_numbers = true
    )]
    shift: Option<f64>,
    /// Radial velocity in m/s (positive = receding = red shift).
    #[arg(long, value_name = "V_M_PER_S", allow_negative_numbers = true)]
    radial_velocity: Option<f64>,
    /// Doppler model for --radial-velocity.
    #[arg(long, value_enum, default_value = "classical")]
    doppler: DopplerArg,
    /// How values transform under the shift.
    #[arg(long, value_enum, default_value = "none")]
    radiometric: RadiometricArg,
    /// Observed wavelength range MIN:MAX in nm (default: the CMF range 360:830).
    #[arg(long, value_name = "MIN:MAX", default_value = "360:830")]
    range: String,
    /// Maximum relative error of the piecewise-linear black body.
    #[arg(long, default_value_t = 1e-4)]
    max_error: f64,
    /// Colour matching functions.
    #[arg(long, value_enum, default_value = "1931")]
    observer: ObserverArg,
    /// Write the spectrum as CSV (wavelength_nm,value; rows joined by straight lines, a
    /// repeated wavelength marks a jump).
    #[arg(long, value_name = "FILE")]
    csv: Option<PathBuf>,
    /// Write a PNG plot of the spectrum.
    #[arg(long, value_name = "FILE")]
    plot: Option<PathBuf>,
    /// Print the result as one JSON object.
    #[arg(long)]
    json: bool,
}

fn parse_range(text: &str) -> Result<(f64, f64)> {
    let (a, b) = text
        .split_once(':')
        .with_context(|| format!("--range {text:?}: expected MIN:MAX in nm"))?;
    let a: f64 = a
        .trim()
        .parse()
        .with_context(|| format!("--range {text:?}: bad minimum"))?;
    let b: f64 = b
        .trim()
        .parse()
        .with_context(|| format!("--range {text:?}: bad maximum"))?;
    if !(a.is_finite() && b.is_finite() && a > 0.0 && a < b) {
        bail!("--range {text:?}: need 0 < MIN < MAX");
    }
    Ok((a, b))
}

/// Runs `blueshift spectrum`.
pub fn run(args: Args) -> Result<()> {
    let outputs: Vec<&std::path::Path> = args
        .csv
        .iter()
        .chain(&args.plot)
        .map(PathBuf::as_path)
        .collect();
    let inputs: Vec<&std::path::Path> = args.line_list.iter().map(PathBuf::as_path).collect();
    crate::output::check_outputs(&outputs, &inputs)?;
    let (lo, hi) = parse_range(&args.range)?;
    if args.blackbody.is_none() && args.lines.is_empty() && args.line_list.is_empty() {
        bail!("nothing to build: give --blackbody T_K and/or --lines H,He,C or --line-list FILE");
    }
    let model = match args.doppler {
        DopplerArg::Classical => DopplerModel::Classical,
        DopplerArg::Relativistic => DopplerModel::Relativistic,
    };
    let shift = match (args.shift, args.radial_velocity) {
        (Some(s), _) => WavelengthShift::new(s).context("--shift")?,
        (None, Some(v)) => {
            WavelengthShift::from_radial_velocity(model, v).context("--radial-velocity")?
        }
        (None, None) => WavelengthShift::IDENTITY,
    };
    let transform = match args.radiometric {
        RadiometricArg::None => RadiometricTransform::None,
        RadiometricArg::Invariant => RadiometricTransform::Invariant,
    };
    let profile = match args.line_profile {
        ProfileArg::Box => LineProfile::Box {
            width_nm: args.line_width,
        },
        ProfileArg::Triangle => LineProfile::Triangle {
            fwhm_nm: args.line_width,
        },
    };
    let s = shift.value();

    // The rest-frame spectrum covers [lo / s, hi / s], so the observed one covers [lo, hi].
    let mut rest = PiecewiseLinear::new();
    let blackbody = match args.blackbody {
        Some(t) => {
            let bb = Blackbody::new(t).context("--blackbody")?;
            let approx = bb
                .to_piecewise(lo / s, hi / s, args.max_error)
                .map_err(|e| {
                    // Name the flag the error is about.
                    let flag = match &e {
                        blueshift_spectrum::Error::Parameter { name, .. }
                            if name.starts_with("temperature") =>
                        {
                            "--blackbody"
                        }
                        _ => "--max-error",
                    };
                    anyhow::Error::new(e).context(flag)
                })?;
            rest.add(&approx);
            Some(bb)
        }
        None => None,
    };
    let mut line_count = 0;
    for name in &args.lines {
        let cat = Catalogue::parse(name).context("--lines")?;
        for line in cat.lines() {
            line.add_to(&mut rest, profile, args.line_strength)
                .context("--line-strength/--line-width")?;
            line_count += 1;
        }
    }
    for path in &args.line_list {
        let lines = read_line_list(path)?;
        blueshift_spectrum::add_lines(&mut rest, &lines, profile, args.line_strength)
            .context("--line-strength/--line-width")?;
        line_count += lines.len();
    }
    let observed = rest.shifted(shift, transform);

    let cmf = match args.observer {
        ObserverArg::Cie1931 => Observer::Cie1931TwoDegree.cmf(),
        ObserverArg::Cie1964 => Observer::Cie1964TenDegree.cmf(),
    };
    let (cmf_lo, cmf_hi) = cmf.range_nm();
    let xyz = cmf.xyz_of_in(
        &observed,
        lo.max(cmf_lo),
        hi.min(cmf_hi).max(lo.max(cmf_lo) + 1e-9),
    )?;
    let xy = xyz.chromaticity();
    let srgb_linear = xyz.to_linear_srgb();
    let display = if xyz.y > 0.0 {
        xyz.scaled(1.0 / xyz.y).to_linear_srgb().map(srgb_encode)
    } else {
        [0.0; 3]
    };
    let integral = observed.integrate(lo, hi)?;
    // Values near f64's end (a line list of 1e308) overflow the integral and the colour:
    // refused, as a black body whose radiance overflows is, not printed as inf and NaN.
    if !(integral.is_finite() && xyz.x.is_finite() && xyz.y.is_finite() && xyz.z.is_finite()) {
        bail!(
            "the spectrum's integral ({integral:e}) or colour overflows f64: scale its \
             intensities down"
        );
    }

    if let Some(path) = &args.csv {
        let pts = polyline(&observed, lo, hi);
        write_atomic(path, |w| {
            writeln!(w, "wavelength_nm,value")?;
            for (x, y) in &pts {
                writeln!(w, "{x},{y}")?;
            }
            Ok(())
        })?;
        crate::output::wrote(path);
    }
    if let Some(path) = &args.plot {
        let mut series = Vec::new();
        if s != 1.0 {
            series.push(Series {
                label: "rest frame".into(),
                // The rest frame was built over [lo / s, hi / s] only: it ends there.
                points: polyline(&rest, lo.max(lo / s), hi.min(hi / s)),
                colour: plotters::style::RGBColor(160, 160, 160),
            });
        }
        series.push(Series {
            label: if s != 1.0 {
                format!("observed (s = {s:.6})")
            } else {
                "spectrum".into()
            },
            points: polyline(&observed, lo, hi),
            colour: plotters::style::RGBColor(20, 60, 200),
        });
        let mut title = String::new();
        if let Some(t) = args.blackbody {
            title += &format!("black body {t} K");
        }
        if line_count > 0 {
            if !title.is_empty() {
                title += " + ";
            }
            title += &format!("{line_count} lines");
        }
        line_plot(
            path,
            &title,
            "wavelength (nm)",
            "spectral radiance (W sr^-1 m^-2 nm^-1)",
            &series,
            (1000, 600),
        )?;
        crate::output::wrote(path);
    }

    let observed_t = blackbody.map(|bb| match transform {
        RadiometricTransform::Invariant => bb.shifted(shift).temperature_k(),
        RadiometricTransform::None => f64::NAN,
    });
    if args.json {
        let out = json!({
            "xyz": xyz.to_array(),
            "xy": xy,
            "srgb_linear": srgb_linear,
            "srgb_display": display,
            "observer": cmf.name(),
            "range_nm": [lo, hi],
            "integral": integral,
            "pieces": observed.piece_count(),
            "lines": line_count,
            "shift": s,
            "doppler_factor": shift.recip().value(),
            "blackbody_temperature_k": args.blackbody,
            "observed_blackbody_temperature_k": observed_t.filter(|t| t.is_finite()),
        });
        outln!("{out}");
    } else {
        outln!("pieces        {}", observed.piece_count());
        outln!("shift s       {s:.9} (D = {:.9})", shift.recip().value());
        if let Some(t) = observed_t.filter(|t| t.is_finite()) {
            outln!("observed T    {t:.3} K (black body at T / s)");
        }
        outln!("integral      {integral:.6e} W sr^-1 m^-2 over [{lo}, {hi}] nm");
        outln!(
            "XYZ           {:.6e} {:.6e} {:.6e} ({})",
            xyz.x,
            xyz.y,
            xyz.z,
            cmf.name()
        );
        match xy {
            Some([x, y]) => outln!("xy            {x:.5} {y:.5}"),
            None => outln!("xy            undefined (no light in range)"),
        }
        outln!(
            "linear sRGB   {:.6e} {:.6e} {:.6e}",
            srgb_linear[0],
            srgb_linear[1],
            srgb_linear[2]
        );
        outln!(
            "display sRGB  {:.3} {:.3} {:.3} (Y normalised to 1, clipped, encoded)",
            display[0],
            display[1],
            display[2]
        );
    }
    Ok(())
}
