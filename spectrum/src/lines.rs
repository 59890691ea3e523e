//! Emission lines: built-in catalogues, user line lists and line profiles.

use crate::error::{Error, Result, non_negative, positive};
use crate::piecewise::PiecewiseLinear;

/// An emission line: a centre wavelength (air, nm) and a strength, the line's integrated
/// radiance (spectral radiance unit x nm; for catalogue lines, the relative intensity).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct EmissionLine {
    /// Centre wavelength, nm.
    pub centre_nm: f64,
    /// Integrated strength (area under the profile), value unit x nm.
    pub strength: f64,
}

/// The shape a line is given (a delta peak cannot be represented; nature broadens lines).
/// Every profile keeps the line's strength as its area.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub enum LineProfile {
    /// A box of full width `width_nm` (the paper's `delta lambda`, Fig. 9b).
    Box {
        /// Full width, nm.
        width_nm: f64,
    },
    /// A symmetric triangle with full width at half maximum `fwhm_nm` (base 2 x FWHM).
    Triangle {
        /// Full width at half maximum, nm.
        fwhm_nm: f64,
    },
    /// A Gaussian of standard deviation `sigma_nm` (for a velocity dispersion `sigma_v`,
    /// `sigma_nm = centre * sigma_v / c`; thermal: `sigma_v = sqrt(k T / m)`), as the
    /// 32-piece [`crate::PwlGaussian`] (area exact, sup error < 0.9 % of the peak).
    Gaussian {
        /// Standard deviation, nm.
        sigma_nm: f64,
    },
}

impl Default for LineProfile {
    fn default() -> Self {
        Self::Box { width_nm: 1.0 }
    }
}

impl EmissionLine {
    /// A line; refuses a non-positive centre or a negative strength.
    pub fn new(centre_nm: f64, strength: f64) -> Result<Self> {
        positive("line centre (nm)", centre_nm)?;
        non_negative("line strength", strength)?;
        Ok(Self {
            centre_nm,
            strength,
        })
    }

    /// Adds the line, with `profile`, scaled by `weight` (>= 0), to a spectrum.
    pub fn add_to(
        &self,
        spectrum: &mut PiecewiseLinear,
        profile: LineProfile,
        weight: f64,
    ) -> Result<()> {
        non_negative("line weight", weight)?;
        let area = self.strength * weight;
        let c = self.centre_nm;
        match profile {
            LineProfile::Box { width_nm } => {
                let (a, b) = line_edges(c, width_nm / 2.0, "line width (nm)", width_nm)?;
                spectrum.add_box(a, b, area / (b - a))
            }
            LineProfile::Triangle { fwhm_nm } => {
                let (a, b) = line_edges(c, fwhm_nm, "line FWHM (nm)", fwhm_nm)?;
                let peak = 2.0 * area / (b - a);
                spectrum.add_trapezoid(a, c, 0.0, peak)?;
                spectrum.add_trapezoid(c, b, peak, 0.0)
            }
            LineProfile::Gaussian { sigma_nm } => {
                crate::profiles::PwlGaussian::default().add_to(spectrum, c, sigma_nm, area)
            }
        }
    }

    /// The line alone as a piecewise-linear spectrum.
    pub fn to_piecewise(&self, profile: LineProfile) -> Result<PiecewiseLinear> {
        let mut s = PiecewiseLinear::new();
        self.add_to(&mut s, profile, 1.0)?;
        Ok(s)
    }
}

/// The built-in line catalogues (visible lines, air wavelengths, relative intensities with
/// the strongest line = 1). Sources, all compiled from or matched to the NIST Atomic Spectra
/// Database, are named in `data/lines_*.csv` and `data/make_line_catalogues.py`:
/// - H I Balmer n = 3..12: Storey & Hummer 1995 Case B (T = 1e4 K, n_e = 100 cm^-3) via
///   PyNeb 1.1.32, wavelengths from NIST ASD level energies;
/// - He I: Porter et al. 2012/2013 recombination lines via PyNeb 1.1.32, NIST ASD wavelengths;
/// - C I: the 12 strongest lines in 380-780 nm of an LTE gas at 1e4 K from NIST-compiled
///   A-values (van Hoof's Atomic Line List v3.00b4 via PyEMILI 1.2.0).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub enum Catalogue {
    /// Neutral hydrogen, Balmer series.
    HydrogenBalmer,
    /// Neutral helium.
    HeliumI,
    /// Neutral carbon.
    CarbonI,
}

const H1: &str = include_str!("../data/lines_h1_balmer.csv");
const HE1: &str = include_str!("../data/lines_he1.csv");
const C1: &str = include_str!("../data/lines_c1.csv");

impl Catalogue {
    /// All built-in catalogues.
    pub const ALL: [Catalogue; 3] = [Self::HydrogenBalmer, Self::HeliumI, Self::CarbonI];

    /// Parses a name: `H`, `HI`, `H I`, `hydrogen`; `He`, `HeI`, `helium`; `C`, `CI`, `carbon`
    /// (case-insensitive).
    pub fn parse(name: &str) -> Result<Self> {
        let n: String = name
            .chars()
            .filter(|c| !c.is_whitespace())
            .collect::<String>()
            .to_ascii_lowercase();
        match n.as_str() {
            "h" | "hi" | "h1" | "hydrogen" | "balmer" => Ok(Self::HydrogenBalmer),
            "he" | "hei" | "he1" | "helium" => Ok(Self::HeliumI),
            "c" | "ci" | "c1" | "carbon" => Ok(Self::CarbonI),
            _ => Err(Error::UnknownName {
                what: "line catalogue",
                name: name.to_owned(),
                known: "H, He, C",
            }),
        }
    }

    /// Short name (`H`, `He`, `C`).
    #[must_use]
    pub fn short_name(self) -> &'static str {
        match self {
            Self::HydrogenBalmer => "H",
            Self::HeliumI => "He",
            Self::CarbonI => "C",
        }
    }

    /// The catalogue's lines (strength = relative intensity).
    #[must_use]
    pub fn lines(self) -> Vec<EmissionLine> {
        let (text, name) = match self {
            Self::HydrogenBalmer => (H1, "lines_h1_balmer.csv"),
            Self::HeliumI => (HE1, "lines_he1.csv"),
            Self::CarbonI => (C1, "lines_c1.csv"),
        };
        parse_line_list(text, name).expect("built-in line catalogue is well formed")
    }
}

/// The header names a line list must have (in any order; further columns are ignored).
pub const LINE_LIST_COLUMNS: [&str; 2] = ["wavelength_nm", "relative_intensity"];

/// Parses a user line list: CSV whose first row (after `#` comments and blank lines) is a
/// header naming the columns [`LINE_LIST_COLUMNS`] `wavelength_nm` and `relative_intensity`
/// (in any order; further columns are ignored). A missing header, or one without both
/// names, is refused (a table of other columns would otherwise be read as garbage), as is a
/// malformed row, naming `source_name` and the line number.
pub fn parse_line_list(text: &str, source_name: &str) -> Result<Vec<EmissionLine>> {
    let parse_err = |line: usize, message: String| Error::Parse {
        source_name: source_name.to_owned(),
        line,
        message,
    };
    let mut rows = text
        .lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.trim()))
        .filter(|(_, l)| !l.is_empty() && !l.starts_with('#'));
    let Some((header_no, header)) = rows.next() else {
        return Err(parse_err(0, "no lines".to_owned()));
    };
    let names: Vec<&str> = header.split(',').map(str::trim).collect();
    let column = |want: &str| names.iter().position(|n| n.eq_ignore_ascii_case(want));
    let (Some(wl), Some(st)) = (column(LINE_LIST_COLUMNS[0]), column(LINE_LIST_COLUMNS[1])) else {
        return Err(parse_err(
            header_no,
            format!(
                "the header must name the columns {} and {} (found {header:?})",
                LINE_LIST_COLUMNS[0], LINE_LIST_COLUMNS[1]
            ),
        ));
    };
    let mut lines = Vec::new();
    for (line_no, row) in rows {
        let mut fields: Vec<&str> = row.split(',').map(str::trim).collect();
        // Empty fields at the end (`656.28,1.0,` as spreadsheets write) are no columns; a
        // row of more fields than the header names has shifted or unnamed columns.
        while fields.len() > names.len() && fields.last().is_some_and(|f| f.is_empty()) {
            fields.pop();
        }
        if fields.len() > names.len() {
            return Err(parse_err(
                line_no,
                format!("expected {} columns, found {}", names.len(), fields.len()),
            ));
        }
        let value = |i: usize| -> Result<f64> {
            let f = fields.get(i).ok_or_else(|| {
                parse_err(
                    line_no,
                    format!("expected {} columns, found {}", names.len(), fields.len()),
                )
            })?;
            let v: f64 = f
                .parse()
                .map_err(|_| parse_err(line_no, format!("{f:?} is not a number")))?;
            if v.is_finite() {
                Ok(v)
            } else {
                Err(parse_err(line_no, format!("{f:?} is not finite")))
            }
        };
        let line = EmissionLine::new(value(wl)?, value(st)?)
            .map_err(|e| parse_err(line_no, e.to_string()))?;
        lines.push(line);
    }
    if lines.is_empty() {
        return Err(parse_err(0, "no lines".to_owned()));
    }
    Ok(lines)
}

/// Adds `lines`, each with `profile` and scaled by `weight`, to `spectrum` in one sweep:
/// O(n log n) in the number of lines however much they overlap (adding them one by one with
/// [`EmissionLine::add_to`] costs the number of pieces each one overlaps). Gaussian profiles
/// are added one by one.
///
/// # Errors
/// As [`EmissionLine::add_to`]; a result of more than [`crate::MAX_PIECES`] pieces.
pub fn add_lines(
    spectrum: &mut PiecewiseLinear,
    lines: &[EmissionLine],
    profile: LineProfile,
    weight: f64,
) -> Result<()> {
    non_negative("line weight", weight)?;
    let mut traps = Vec::with_capacity(lines.len() * 2);
    for l in lines {
        let area = l.strength * weight;
        let c = l.centre_nm;
        match profile {
            LineProfile::Box { width_nm } => {
                let (a, b) = line_edges(c, width_nm / 2.0, "line width (nm)", width_nm)?;
                let v = area / (b - a);
                non_negative("trapezoid start value", v)?;
                crate::error::range("trapezoid", a, b)?;
                traps.push((a, b, v, v));
            }
            LineProfile::Triangle { fwhm_nm } => {
                let (a, b) = line_edges(c, fwhm_nm, "line FWHM (nm)", fwhm_nm)?;
                let peak = 2.0 * area / (b - a);
                non_negative("trapezoid end value", peak)?;
                crate::error::range("trapezoid", a, c)?;
                crate::error::range("trapezoid", c, b)?;
                traps.push((a, c, 0.0, peak));
                traps.push((c, b, peak, 0.0));
            }
            LineProfile::Gaussian { .. } => l.add_to(spectrum, profile, weight)?,
        }
    }
    spectrum.add_trapezoids(&traps)
}

/// The ends `c - half` and `c + half` of a line's profile as f64 rounds them, after `width`
/// (named `what`) is checked positive: the profile's height is taken from these ends, so its
/// area is the line's strength however few ulps wide it is. A width that rounds to nothing
/// at `c` (or to a one-sided profile) is refused.
fn line_edges(c: f64, half: f64, what: &'static str, width: f64) -> Result<(f64, f64)> {
    positive(what, width)?;
    let (a, b) = (c - half, c + half);
    if !(a < c && c < b) {
        return Err(crate::Error::Parameter {
            name: what,
            value: width,
            reason: "narrower than f64 resolves at the line's centre",
        });
    }
    Ok((a, b))
}

/// Reads a user line list from a file (see [`parse_line_list`]).
/// Refuses a path that is not a regular file (a FIFO would block the read forever).
pub fn read_line_list(path: &std::path::Path) -> Result<Vec<EmissionLine>> {
    let meta = std::fs::metadata(path).map_err(|source| Error::Io {
        path: path.display().to_string(),
        source,
    })?;
    if !meta.is_file() {
        return Err(Error::Io {
            path: path.display().to_string(),
            source: std::io::Error::new(
                std::io::ErrorKind::InvalidInput,
                "not a regular file (a FIFO, device, socket or folder)",
            ),
        });
    }
    let text = std::fs::read_to_string(path).map_err(|source| Error::Io {
        path: path.display().to_string(),
        source,
    })?;
    parse_line_list(&text, &path.display().to_string())
}
