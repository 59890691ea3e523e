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

/// A header card's value.
#[derive(Clone, Debug, PartialEq)]
pub enum FitsValue {
    /// `T` or `F`.
    Logical(bool),
    /// An integer.
    Integer(i64),
    /// A real number (FITS `E` or `D` exponents).
    Real(f64),
    /// A string (quotes removed, `''` unescaped, trailing spaces dropped).
    Text(String),
}

impl FitsValue {
    /// The value as a number (integers and reals).
    #[must_use]
    pub fn as_f64(&self) -> Option<f64> {
        match self {
            Self::Integer(i) => Some(*i as f64),
            Self::Real(r) => Some(*r),
            _ => None,
        }
    }
}

/// One WCS axis of a FITS header (`CTYPEi`, `CUNITi`, `CRVALi`, `CDELTi`, `CRPIXi`; the
/// standard's defaults where a card is missing: empty type and unit, value 0, step 1,
/// reference pixel 0).
#[derive(Clone, Debug, PartialEq)]
pub struct WcsAxis {
    /// `NAXISi`: samples along the axis.
    pub length: usize,
    /// `CTYPEi`.
    pub ctype: String,
    /// `CUNITi`.
    pub cunit: String,
    /// `CRVALi`: the world coordinate at the reference pixel.
    pub crval: f64,
    /// `CDELTi`: the world step per pixel.
    pub cdelt: f64,
    /// `CRPIXi`: the reference pixel (1-based, FITS).
    pub crpix: f64,
}

/// The primary header of a FITS file (what `blueshift info` prints).
#[derive(Clone, Debug, PartialEq)]
pub struct FitsHeader {
    /// `BITPIX`: 8, 16, 32, 64 (integers) or -32, -64 (IEEE floats).
    pub bitpix: i64,
    /// The axes in FITS order (axis 1 first) with their WCS.
    pub axes: Vec<WcsAxis>,
    /// `BUNIT` (empty if absent).
    pub bunit: String,
    /// Every valued card in file order (`COMMENT`, `HISTORY` and blank cards left out).
    pub cards: Vec<(String, FitsValue)>,
    /// Finite minimum and maximum of the data (floating-point `BITPIX` only; `None` for
    /// integer data or no finite value).
    pub data_range: Option<(f64, f64)>,
}

impl FitsHeader {
    /// The value of card `key`.
    #[must_use]
    pub fn get(&self, key: &str) -> Option<&FitsValue> {
        self.cards.iter().find(|(k, _)| k == key).map(|(_, v)| v)
    }
}

fn parse_value(raw: &str) -> Option<FitsValue> {
    let raw = raw.trim_start();
    if let Some(rest) = raw.strip_prefix('\'') {
        // A string: '' is a quote; it ends at a single quote.
        let mut out = String::new();
        let mut chars = rest.chars().peekable();
        loop {
            match chars.next()? {
                '\'' if chars.peek() == Some(&'\'') => {
                    chars.next();
                    out.push('\'');
                }
                '\'' => break,
                c => out.push(c),
            }
        }
        return Some(FitsValue::Text(out.trim_end().to_owned()));
    }
    let v = raw.split('/').next().unwrap_or("").trim();
    match v {
        "T" => Some(FitsValue::Logical(true)),
        "F" => Some(FitsValue::Logical(false)),
        "" => None,
        _ => v.parse::<i64>().map(FitsValue::Integer).ok().or_else(|| {
            v.replace(['D', 'd'], "E")
                .parse::<f64>()
                .ok()
                .map(FitsValue::Real)
        }),
    }
}

/// Reads the primary header of a FITS file (and the finite range of floating-point data):
/// the cards up to `END` in 2880-byte blocks, the mandatory `SIMPLE`, `BITPIX`, `NAXIS`,
/// `NAXISn`, the WCS of every axis and `BUNIT`. Refuses what is not a FITS primary header
/// or holds less data than it announces, with [`Error::MalformedFits`].
pub fn read_fits(bytes: &[u8]) -> Result<FitsHeader> {
    let bad = |m: String| Error::MalformedFits(m);
    if bytes.len() < 2880 {
        return Err(bad(format!(
            "{} bytes: shorter than one 2880-byte header block",
            bytes.len()
        )));
    }
    if !bytes.starts_with(b"SIMPLE  = ") {
        return Err(bad("the file does not start with SIMPLE = T".into()));
    }
    let mut cards = Vec::new();
    let mut end = None;
    for (i, card) in bytes.chunks_exact(80).enumerate() {
        let text = std::str::from_utf8(card)
            .ok()
            .filter(|t| t.chars().all(|c| (' '..='~').contains(&c)))
            .ok_or_else(|| bad(format!("card {} is not printable ASCII", i + 1)))?;
        let key = text[..8].trim_end();
        if key == "END" {
            end = Some(i);
            break;
        }
        if text[8..].starts_with("= ") {
            let v = parse_value(&text[10..])
                .ok_or_else(|| bad(format!("card {key}: unreadable value")))?;
            cards.push((key.to_owned(), v));
        }
    }
    let end = end.ok_or_else(|| bad("no END card".into()))?;
    let find = |k: &str| cards.iter().find(|(c, _)| c == k).map(|(_, v)| v);
    if find("SIMPLE") != Some(&FitsValue::Logical(true)) {
        return Err(bad("SIMPLE is not T".into()));
    }
    let int = |k: &str| match find(k) {
        Some(FitsValue::Integer(i)) => Ok(*i),
        Some(_) => Err(bad(format!("{k} is not an integer"))),
        None => Err(bad(format!("{k} is missing"))),
    };
    let bitpix = int("BITPIX")?;
    if ![8, 16, 32, 64, -32, -64].contains(&bitpix) {
        return Err(bad(format!(
            "BITPIX {bitpix} is not 8, 16, 32, 64, -32 or -64"
        )));
    }
    let naxis = int("NAXIS")?;
    if !(0..=999).contains(&naxis) {
        return Err(bad(format!("NAXIS {naxis} is not in 0..=999")));
    }
    let text = |k: String| match find(&k) {
        Some(FitsValue::Text(s)) => s.clone(),
        _ => String::new(),
    };
    let num = |k: String, default: f64| find(&k).and_then(FitsValue::as_f64).unwrap_or(default);
    let mut axes = Vec::new();
    for a in 1..=naxis {
        let n = int(&format!("NAXIS{a}"))?;
        let length = usize::try_from(n).map_err(|_| bad(format!("NAXIS{a} {n} is negative")))?;
        axes.push(WcsAxis {
            length,
            ctype: text(format!("CTYPE{a}")),
            cunit: text(format!("CUNIT{a}")),
            crval: num(format!("CRVAL{a}"), 0.0),
            cdelt: num(format!("CDELT{a}"), 1.0),
            crpix: num(format!("CRPIX{a}"), 0.0),
        });
    }
    let values = if naxis == 0 {
        0
    } else {
        axes.iter()
            .try_fold(1usize, |n, a| n.checked_mul(a.length))
            .ok_or_else(|| bad("the axis lengths overflow".into()))?
    };
    let size = (bitpix.unsigned_abs() / 8) as usize;
    let data_start = ((end + 1) * 80).div_ceil(2880) * 2880;
    let data_len = values
        .checked_mul(size)
        .ok_or_else(|| bad("the data size overflows".into()))?;
    let data_end = data_start.saturating_add(data_len);
    if bytes.len() < data_end {
        return Err(bad(format!(
            "the header announces {data_len} bytes of data, the file holds {}",
            bytes.len().saturating_sub(data_start)
        )));
    }
    let data = &bytes[data_start..data_end];
    let range = |it: &mut dyn Iterator<Item = f64>| {
        it.filter(|v| v.is_finite())
            .fold(None, |r: Option<(f64, f64)>, v| {
                Some(r.map_or((v, v), |(a, b)| (a.min(v), b.max(v))))
            })
    };
    let data_range = match bitpix {
        -32 => range(
            &mut data
                .chunks_exact(4)
                .map(|c| f64::from(f32::from_be_bytes([c[0], c[1], c[2], c[3]]))),
        ),
        -64 => range(
            &mut data
                .chunks_exact(8)
                .map(|c| f64::from_be_bytes(c.try_into().expect("chunks of eight bytes"))),
        ),
        _ => None,
    };
    Ok(FitsHeader {
        bitpix,
        axes,
        bunit: text("BUNIT".into()),
        cards,
        data_range,
    })
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{CubeLineWidth, CubeSpec};

    fn cube() -> SpectralCube {
        SpectralCube {
            nx: 3,
            ny: 2,
            spec: CubeSpec {
                rest_nm: 656.28,
                axis: SpectralAxis::OpticalVelocity,
                min: -1e5,
                max: 1e5,
                channels: 4,
                line_width: CubeLineWidth::OneChannel,
            },
            data: (0..24).map(|i| i as f32 - 3.0).collect(),
            pixel_world: (0.5, 0.25),
        }
    }

    /// A header whose data size wraps past the end of memory when added to the header's
    /// is refused in one message, not sliced.
    #[test]
    fn a_data_size_at_the_end_of_memory_is_refused() {
        let card = |s: String| format!("{s:<80}");
        let mut h: String = [
            "SIMPLE  =                    T".to_string(),
            "BITPIX  =                    8".to_string(),
            "NAXIS   =                    2".to_string(),
            "NAXIS1  =                    3".to_string(),
            format!("NAXIS2  = {:>20}", (u64::MAX / 3)),
            "END".to_string(),
        ]
        .into_iter()
        .map(card)
        .collect();
        h.push_str(&" ".repeat(2880 - h.len()));
        let e = read_fits(h.as_bytes()).unwrap_err().to_string();
        assert!(e.contains("announces"), "{e}");
    }

    #[test]
    fn fits_written_is_read_back_with_its_wcs() {
        let meta = CubeMeta {
            bunit: "cm-2".into(),
            object: "it's".into(),
            world_unit: Some(("pc".into(), 4.0)),
        };
        let h = read_fits(&fits_bytes(&cube(), &meta).unwrap()).unwrap();
        assert_eq!(h.bitpix, -32);
        assert_eq!(h.bunit, "cm-2");
        assert_eq!(h.get("OBJECT"), Some(&FitsValue::Text("it's".into())));
        let lens: Vec<usize> = h.axes.iter().map(|a| a.length).collect();
        assert_eq!(lens, [3, 2, 4]);
        let (x, y, v) = (&h.axes[0], &h.axes[1], &h.axes[2]);
        assert_eq!((x.ctype.as_str(), x.cunit.as_str()), ("LINEAR", "pc"));
        assert_eq!((x.crpix, x.crval, x.cdelt), (2.0, 0.0, 2.0));
        assert_eq!((y.crpix, y.cdelt), (1.5, 1.0));
        assert_eq!((v.ctype.as_str(), v.cunit.as_str()), ("VOPT", "m/s"));
        // Channels 50 km/s wide from -100 km/s: the first centre at -75 km/s.
        assert!((v.crval + 7.5e4).abs() < 1e-6 && (v.cdelt - 5e4).abs() < 1e-6);
        assert_eq!(v.crpix, 1.0);
        assert_eq!(h.data_range, Some((-3.0, 20.0)));
    }

    #[test]
    fn fits_malformed_headers_are_refused() {
        let good = fits_bytes(&cube(), &CubeMeta::default()).unwrap();
        let no_end = String::from_utf8_lossy(&good[..2880]).replace("END     ", "XEND    ");
        let bad_bitpix = String::from_utf8_lossy(&good).replace(
            "BITPIX  =                  -32",
            "BITPIX  =                  -31",
        );
        for (bytes, why) in [
            (good[..100].to_vec(), "shorter"),
            (no_end.into_bytes(), "END"),
            (bad_bitpix.into_bytes(), "BITPIX"),
            (good[..2880 + 10].to_vec(), "data"),
            (b"P".repeat(2880), "SIMPLE"),
        ] {
            let e = read_fits(&bytes).unwrap_err();
            assert!(matches!(e, Error::MalformedFits(_)), "{e}");
            assert!(e.to_string().contains(why), "{e}");
        }
    }

    #[test]
    fn fits_units_of_a_scene_file_are_parsed_and_checked() {
        let base = std::path::Path::new(".");
        let s = crate::SceneFile::parse(
            r#"{"cube": {"bunit": "cm-2", "world_unit": "cm:3e18"}}"#,
            base,
        )
        .unwrap();
        let c = s.cube.unwrap();
        assert_eq!(c.bunit.as_deref(), Some("cm-2"));
        assert_eq!(c.world_unit.as_deref(), Some("cm:3e18"));
        assert!(crate::SceneFile::parse(r#"{"cube": {"bunits": "cm-2"}}"#, base).is_err());
    }
}
