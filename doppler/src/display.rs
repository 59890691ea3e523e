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
    /// These options with an exposure of `stops` folded in: the scale the luminance
    /// scaling gives for `image`, times 2^stops (`PerPixel` and 0 stops are unchanged).
    #[must_use]
    pub fn with_stops(&self, stops: f64, image: &DopplerImage) -> DisplayOptions {
        if stops == 0.0 || self.exposure == Exposure::PerPixel {
            return *self;
        }
        DisplayOptions {
            exposure: Exposure::Fixed(self.scale_for(image) * stops.exp2()),
            ..*self
        }
    }

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

    /// The XYZ-to-RGB matrix of the primaries.
    fn matrix(&self) -> [[f64; 3]; 3] {
        match self.matrix {
            ColourMatrix::Srgb => xyz_to_linear_srgb_matrix(),
            ColourMatrix::CieRgbEq10 => XYZ_TO_CIE_RGB_EQ10,
        }
    }

    /// Scaled XYZ per pixel (the exposure applied), non-finite values as 0.
    fn scaled(&self, image: &DopplerImage) -> Vec<[f64; 3]> {
        let k = self.scale_for(image);
        image
            .xyz
            .iter()
            .map(|x| {
                let kk = match self.exposure {
                    Exposure::PerPixel if x[1] > 0.0 => 1.0 / x[1],
                    _ => k,
                };
                x.map(|c| if c.is_finite() { c * kk } else { 0.0 })
            })
            .collect()
    }

    /// Linear RGB per pixel (row-major) after the luminance scaling and the colour matrix,
    /// before any tone mapping: the input of a tone-mapping operator. Colours outside the
    /// primaries (negative components: line emission is spectral) are desaturated towards
    /// the white of the same luminance until they fit ([`GamutMapper`]); values above 1 are
    /// kept; non-finite values become 0.
    #[must_use]
    pub fn to_linear_rgb(&self, image: &DopplerImage) -> Vec<[f64; 3]> {
        let g = GamutMapper::new(self.matrix());
        self.scaled(image)
            .into_iter()
            .map(|x| g.into_positive(mat_mul(&g.m, x), x[1]))
            .collect()
    }

    /// 8-bit sRGB-encoded RGB, row-major: the scaled luminance through the highlight
    /// shoulder ([`shoulder`]: identity up to 0.8, then a smooth approach to 1, so nothing
    /// clips), then the colour brought into the display gamut at that luminance keeping its
    /// hue ([`GamutMapper::map`]), then sRGB encoding.
    #[must_use]
    pub fn to_rgb8(&self, image: &DopplerImage) -> Vec<u8> {
        let g = GamutMapper::new(self.matrix());
        let mut out = Vec::with_capacity(image.xyz.len() * 3);
        for x in self.scaled(image) {
            for c in g.map(x) {
                out.push((srgb_encode(c.clamp(0.0, 1.0)) * 255.0).round() as u8);
            }
        }
        out
    }
}

/// Where the display shoulder starts: luminances up to this are shown as they are.
pub const SHOULDER_KNEE: f64 = 0.8;

/// The highlight shoulder of the display luminance: `y` up to [`SHOULDER_KNEE`], then
/// `k + (1 - k) (1 - exp(-(y - k) / (1 - k)))`, which is continuous with a continuous slope
/// at the knee and approaches 1 without reaching it, so no luminance clips.
#[must_use]
pub fn shoulder(y: f64) -> f64 {
    let k = SHOULDER_KNEE;
    if y <= k {
        y
    } else {
        k + (1.0 - k) * (1.0 - (-(y - k) / (1.0 - k)).exp())
    }
}

/// Hue-preserving gamut mapping of XYZ into the unit RGB cube of a set of primaries:
/// desaturation towards the white of the same luminance (constant-luminance clipping
/// towards the achromatic axis, as in Morovič, *Color Gamut Mapping*, 2008, ch. 10). A
/// colour `c` with luminance `Y` becomes `w + t (c - w)` with `w` the white of luminance `Y`
/// and the largest `t` in [0, 1] that puts every channel in [0, 1]. Mixing with white moves
/// along the straight line through the white point in the chromaticity diagram, so the
/// dominant wavelength (hue) is kept, and the luminance is kept exactly; only the purity
/// drops, and only as much as the display needs. Per-channel clipping instead changes hue
/// and luminance and turns smooth spectral colours into flat saturated patches.
#[derive(Clone, Copy, Debug)]
pub struct GamutMapper {
    /// XYZ to RGB.
    m: [[f64; 3]; 3],
    /// The RGB of the white with luminance 1 (the grey axis: `Y * white`).
    white: [f64; 3],
}

impl GamutMapper {
    /// The mapper for an XYZ-to-RGB matrix (its white: RGB (1, 1, 1), scaled to luminance 1).
    #[must_use]
    pub fn new(m: [[f64; 3]; 3]) -> Self {
        let inv = glam::DMat3::from_cols_array_2d(&m).transpose().inverse();
        // Row 1 of RGB -> XYZ gives the luminance of an RGB colour.
        let y_white = inv.row(1).dot(glam::DVec3::ONE).max(f64::MIN_POSITIVE);
        let g = 1.0 / y_white;
        Self {
            m,
            white: [g, g, g],
        }
    }

    /// `rgb` (luminance `y`) with negative channels removed by desaturation towards the
    /// white of luminance `y`; values above 1 are kept (tone-mapping input).
    #[must_use]
    pub fn into_positive(&self, rgb: [f64; 3], y: f64) -> [f64; 3] {
        if !(y > 0.0 && rgb.iter().all(|c| c.is_finite())) {
            return [0.0; 3];
        }
        let w = self.white.map(|c| c * y);
        let mut t = 1.0f64;
        for i in 0..3 {
            if rgb[i] < 0.0 {
                t = t.min(w[i] / (w[i] - rgb[i]));
            }
        }
        std::array::from_fn(|i| (w[i] + t * (rgb[i] - w[i])).max(0.0))
    }

    /// Scaled XYZ to display RGB in [0, 1]: the luminance through [`shoulder`], then
    /// desaturation towards the white of that luminance until every channel is in [0, 1].
    #[must_use]
    pub fn map(&self, xyz: [f64; 3]) -> [f64; 3] {
        let y = xyz[1];
        if !(y > 0.0 && xyz.iter().all(|c| c.is_finite())) {
            return [0.0; 3];
        }
        let yd = shoulder(y);
        let rgb = mat_mul(&self.m, xyz.map(|c| c * yd / y));
        let w = self.white.map(|c| c * yd);
        let mut t = 1.0f64;
        for i in 0..3 {
            if rgb[i] < 0.0 {
                t = t.min(w[i] / (w[i] - rgb[i]));
            } else if rgb[i] > 1.0 && w[i] < 1.0 {
                t = t.min((1.0 - w[i]) / (rgb[i] - w[i]));
            }
        }
        std::array::from_fn(|i| (w[i] + t.max(0.0) * (rgb[i] - w[i])).clamp(0.0, 1.0))
    }
}
