//! From XYZ to a display image: colour matrix and luminance scaling (paper Fig. 4, Eq. 10/11).

use blueshift_spectrum::{XYZ_TO_CIE_RGB_EQ10, mat_mul, srgb_encode, xyz_to_linear_srgb_matrix};

use super::DopplerImage;
use crate::{Error, Result};
use blueshift_camera::named_enum;

/// Which RGB primaries: `srgb` or `cie`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum ColourMatrix {
    /// Linear sRGB (D65).
    #[default]
    Srgb,
    /// The paper's CIE RGB matrix (Eq. 10).
    CieRgbEq10,
}

named_enum!(ColourMatrix, "colour matrix", [Srgb => "srgb", CieRgbEq10 => "cie"]);

/// How luminance is scaled before the matrix; spelt `pNN`, a number or `per-pixel`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Exposure {
    /// The given percentile (0-100) of the non-zero pixel luminances Y maps to Y = 1.
    Percentile(f64),
    /// XYZ multiplied by this constant (Fig. 4b: one reference for all pixels).
    Fixed(f64),
    /// Each pixel divided by its own Y (Fig. 4a: chromaticity only).
    PerPixel,
}

impl std::str::FromStr for Exposure {
    type Err = Error;
    /// `pNN` (percentile, NN in [0, 100]), a number > 0 (fixed) or `per-pixel`; surrounding
    /// white space is ignored.
    fn from_str(s: &str) -> Result<Self> {
        let e = s.trim();
        if e == "per-pixel" {
            return Ok(Exposure::PerPixel);
        }
        if let Some(p) = e.strip_prefix('p') {
            match p.parse::<f64>() {
                Ok(p) if (0.0..=100.0).contains(&p) => Ok(Exposure::Percentile(p)),
                _ => Err(Error::parameter(format!(
                    "exposure {e}: a percentile pNN needs NN in [0, 100]"
                ))),
            }
        } else {
            match e.parse::<f64>() {
                Ok(k) if k.is_finite() && k > 0.0 => Ok(Exposure::Fixed(k)),
                _ => Err(Error::parameter(format!(
                    "exposure {e}: expected a number > 0, pNN (percentile) or per-pixel"
                ))),
            }
        }
    }
}

impl std::fmt::Display for Exposure {
    /// `pNN`, the number or `per-pixel` (what [`std::str::FromStr`] reads).
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Exposure::Percentile(p) => write!(f, "p{p}"),
            Exposure::Fixed(k) => write!(f, "{k}"),
            Exposure::PerPixel => f.write_str("per-pixel"),
        }
    }
}

blueshift_camera::serde_via_str!(Exposure);

/// Display options.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DisplayOptions {
    /// Primaries.
    pub matrix: ColourMatrix,
    /// Luminance scaling.
    pub exposure: Exposure,
}

impl Default for DisplayOptions {
    fn default() -> Self {
        Self {
            matrix: ColourMatrix::Srgb,
            exposure: Exposure::Percentile(99.0),
        }
    }
}

impl DisplayOptions {
    /// The scale factor `Exposure::Percentile` or `Fixed` gives for an image (1 for
    /// `PerPixel`).
    #[must_use]
    pub fn scale_for(&self, image: &DopplerImage) -> f64 {
        match self.exposure {
            Exposure::Fixed(k) => k,
            Exposure::PerPixel => 1.0,
            Exposure::Percentile(p) => {
                let mut ys: Vec<f64> = image
                    .xyz
                    .iter()
                    .map(|x| x[1])
                    .filter(|y| y.is_finite() && *y > 0.0)
                    .collect();
                if ys.is_empty() {
                    return 1.0;
                }
                ys.sort_by(f64::total_cmp);
                let i = ((p.clamp(0.0, 100.0) / 100.0) * (ys.len() - 1) as f64).round() as usize;
                1.0 / ys[i]
            }
        }
    }

    /// Linear RGB per pixel (row-major) after the luminance scaling and the colour matrix,
    /// before any clamping or tone mapping: the input of a tone-mapping operator. Out-of-gamut
    /// negative components and non-finite values become 0; values above 1 are kept.
    #[must_use]
    pub fn to_linear_rgb(&self, image: &DopplerImage) -> Vec<[f64; 3]> {
        let k = self.scale_for(image);
        let m = match self.matrix {
            ColourMatrix::Srgb => xyz_to_linear_srgb_matrix(),
            ColourMatrix::CieRgbEq10 => XYZ_TO_CIE_RGB_EQ10,
        };
        image
            .xyz
            .iter()
            .map(|x| {
                let kk = match self.exposure {
                    Exposure::PerPixel if x[1] > 0.0 => 1.0 / x[1],
                    _ => k,
                };
                mat_mul(&m, [x[0] * kk, x[1] * kk, x[2] * kk])
                    .map(|c| if c.is_finite() { c.max(0.0) } else { 0.0 })
            })
            .collect()
    }

    /// 8-bit sRGB-encoded RGB, row-major, clamped to [0, 1] after scaling.
    #[must_use]
    pub fn to_rgb8(&self, image: &DopplerImage) -> Vec<u8> {
        let mut out = Vec::with_capacity(image.xyz.len() * 3);
        for rgb in self.to_linear_rgb(image) {
            for c in rgb {
                out.push((srgb_encode(c.min(1.0)) * 255.0).round() as u8);
            }
        }
        out
    }
}
