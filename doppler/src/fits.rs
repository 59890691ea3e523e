//! FITS and NRRD output of spectral cubes.
//!
//! FITS (Pence et al. 2010, FITS standard 4.0; WCS: Greisen & Calabretta 2002, Greisen et
//! al. 2006): one primary HDU, `BITPIX = -32` (IEEE f32, big-endian), `NAXIS = 3`
//! (`NAXIS1` horizontal, `NAXIS2` vertical with row 1 at the bottom, `NAXIS3` channels),
//! 80-character ASCII cards in 2880-byte blocks padded with spaces, the data padded with
//! zeros to a multiple of 2880 bytes. WCS: axes 1 and 2 are `LINEAR` offsets from the view
//! centre (world units, or `CUNIT` and scale from [`CubeMeta::world_unit`]); axis 3 is
//! `VRAD`/`VOPT` in m/s (with `RESTWAV` in m) or `WAVE` in m, reference pixel 1 at the
//! first channel's centre.

use super::cube::{SpectralAxis, SpectralCube};
use crate::{Error, Result};

/// Labels of a written cube.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct CubeMeta {
    /// `BUNIT` (empty: `arbitrary`).
    pub bunit: String,
    /// `OBJECT` (optional).
    pub object: String,
    /// The spatial unit and how many of it one world unit is (for example `("cm",
    /// 5.6149e23)`); `None` writes offsets in world units without `CUNIT1/2`.
    pub world_unit: Option<(String, f64)>,
}

fn card(key: &str, value: &str, comment: &str) -> String {
    let mut c = format!("{key:<8}= {value:>20}");
    if !comment.is_empty() {
        c.push_str(" / ");
        c.push_str(comment);
    }
    c.truncate(80);
    format!("{c:<80}")
}

fn fits_str(s: &str) -> Result<String> {
    if !s.chars().all(|c| (' '..='~').contains(&c)) || s.len() > 68 {
        return Err(Error::parameter(format!(
            "FITS string '{s}' must be printable ASCII of at most 68 characters"
        )));
    }
    let q = s.replace('\'', "''");
    Ok(format!("'{q:<8}'"))
}

fn fits_str_card(key: &str, s: &str, comment: &str) -> Result<String> {
    // Strings start in column 11, left-justified.
    let mut c = format!("{key:<8}= {}", fits_str(s)?);
    if !comment.is_empty() {
        c.push_str(" / ");
        c.push_str(comment);
    }
    c.truncate(80);
    Ok(format!("{c:<80}"))
}

fn real(v: f64) -> Result<String> {
    if !v.is_finite() {
        return Err(Error::parameter(format!("FITS value {v} is not finite")));
    }
    Ok(format!("{v:.12E}"))
}

/// The cube as a FITS file (bytes); see the module docs for the layout.
pub fn fits_bytes(cube: &SpectralCube, meta: &CubeMeta) -> Result<Vec<u8>> {
    let n = cube.nx * cube.ny * cube.spec.channels;
    if n != cube.data.len() || n == 0 {
        return Err(Error::parameter("cube data does not match its dimensions"));
    }
    let (unit, scale) = match &meta.world_unit {
        Some((u, k)) if k.is_finite() && *k > 0.0 => (Some(u.as_str()), *k),
        Some((u, k)) => {
            return Err(Error::parameter(format!(
                "world unit scale {k} {u} must be finite and > 0"
            )));
        }
        None => (None, 1.0),
    };
    let sp = &cube.spec;
    let (ctype3, cunit3, crval3, cdelt3) = match sp.axis {
        SpectralAxis::Wavelength => ("WAVE", "m", sp.centre(0) * 1e-9, sp.width() * 1e-9),
        a => (a.ctype(), "m/s", sp.centre(0), sp.width()),
    };
    let mut cards = vec![
        card("SIMPLE", "T", "conforms to FITS standard 4.0"),
        card("BITPIX", "-32", "IEEE single precision"),
        card("NAXIS", "3", ""),
        card("NAXIS1", &cube.nx.to_string(), "horizontal"),
        card("NAXIS2", &cube.ny.to_string(), "vertical"),
        card("NAXIS3", &sp.channels.to_string(), "spectral channels"),
        fits_str_card(
            "BUNIT",
            if meta.bunit.is_empty() {
                "arbitrary"
            } else {
                &meta.bunit
            },
            "line emission integrated over each channel",
        )?,
        card("WCSAXES", "3", ""),
    ];
    for (i, (d, np)) in [(cube.pixel_world.0, cube.nx), (cube.pixel_world.1, cube.ny)]
        .into_iter()
        .enumerate()
    {
        let ax = i + 1;
        cards.push(fits_str_card(
            &format!("CTYPE{ax}"),
            "LINEAR",
            "offset from the view centre",
        )?);
        if let Some(u) = unit {
            cards.push(fits_str_card(&format!("CUNIT{ax}"), u, "")?);
        }
        cards.push(card(
            &format!("CRPIX{ax}"),
            &real(0.5 * (np as f64 + 1.0))?,
            "",
        ));
        cards.push(card(&format!("CRVAL{ax}"), &real(0.0)?, ""));
        cards.push(card(&format!("CDELT{ax}"), &real(d * scale)?, ""));
    }
    cards.push(fits_str_card("CTYPE3", ctype3, "")?);
    cards.push(fits_str_card("CUNIT3", cunit3, "")?);
    cards.push(card("CRPIX3", &real(1.0)?, "first channel"));
    cards.push(card(
        "CRVAL3",
        &real(crval3)?,
        "centre of the first channel",
    ));
    cards.push(card("CDELT3", &real(cdelt3)?, "channel width"));
    if sp.axis != SpectralAxis::Wavelength {
        cards.push(card(
            "RESTWAV",
            &real(sp.rest_nm * 1e-9)?,
            "rest wavelength, m",
        ));
    }
    if !meta.object.is_empty() {
        cards.push(fits_str_card("OBJECT", &meta.object, "")?);
    }
    cards.push(fits_str_card("ORIGIN", "blueshift", "")?);
    cards.push(format!("{:<80}", "END"));
    let mut out: Vec<u8> = cards.concat().into_bytes();
    out.resize(out.len().div_ceil(2880) * 2880, b' ');
    out.reserve(n * 4 + 2880);
    for v in &cube.data {
        out.extend_from_slice(&v.to_be_bytes());
    }
    out.resize(out.len().div_ceil(2880) * 2880, 0);
    Ok(out)
}

/// The cube as an NRRD file with an attached header (f32 little-endian raw, axes x, y,
/// channel; `spacings` in world units and the axis unit, `axis mins` at the first sample).
pub fn nrrd_bytes(cube: &SpectralCube) -> Result<Vec<u8>> {
    let n = cube.nx * cube.ny * cube.spec.channels;
    if n != cube.data.len() || n == 0 {
        return Err(Error::parameter("cube data does not match its dimensions"));
    }
    let sp = &cube.spec;
    let (label, unit) = match sp.axis {
        SpectralAxis::Wavelength => ("wavelength", "nm"),
        SpectralAxis::RadioVelocity => ("radio velocity", "m/s"),
        SpectralAxis::OpticalVelocity => ("optical velocity", "m/s"),
    };
    let mut h = String::from("NRRD0004\n# blueshift spectral cube (row 0 at the bottom)\n");
    h.push_str("type: float\ndimension: 3\n");
    h.push_str(&format!("sizes: {} {} {}\n", cube.nx, cube.ny, sp.channels));
    h.push_str(&format!(
        "spacings: {} {} {}\n",
        cube.pixel_world.0,
        cube.pixel_world.1,
        sp.width()
    ));
    h.push_str(&format!(
        "axis mins: {} {} {}\n",
        -0.5 * cube.pixel_world.0 * (cube.nx as f64 - 1.0),
        -0.5 * cube.pixel_world.1 * (cube.ny as f64 - 1.0),
        sp.centre(0)
    ));
    h.push_str(&format!("labels: \"x\" \"y\" \"{label}\"\n"));
    h.push_str(&format!("units: \"world\" \"world\" \"{unit}\"\n"));
    h.push_str("endian: little\nencoding: raw\n\n");
    let mut out = h.into_bytes();
    out.reserve(n * 4);
    for v in &cube.data {
        out.extend_from_slice(&v.to_le_bytes());
    }
    Ok(out)
}
