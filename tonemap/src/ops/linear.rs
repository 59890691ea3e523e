//! Linear mapping with an exposure, and the exposure series of HDR VolVis Fig. 4b.

use image::Rgb32FImage;

use crate::error::{Error, Result};
use crate::ops::check_finite;

/// Linear mapping: `display = hdr * 2^exposure_stops / white`, per colour channel.
///
/// With the defaults the brightest pixel maps to display value 1 ("linearly mapped to 8
/// bits", HDR VolVis Fig. 3). Display values above 1 are clipped only when encoded.
#[derive(Clone, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct LinearParams {
    /// Exposure in stops (powers of two); positive brightens.
    pub exposure_stops: f32,
    /// The luminance that maps to display 1 at 0 stops, in image units; `None` = the image's
    /// largest luminance.
    pub white: Option<f32>,
}

impl Default for LinearParams {
    fn default() -> Self {
        Self {
            exposure_stops: 0.0,
            white: None,
        }
    }
}

impl LinearParams {
    pub(crate) fn validate(&self) -> Result<()> {
        check_finite("exposure_stops", self.exposure_stops)?;
        if let Some(w) = self.white
            && !(w.is_finite() && w > 0.0)
        {
            return Err(Error::parameter(format!(
                "linear white must be positive and finite, got {w}"
            )));
        }
        Ok(())
    }

    /// The resolved scale factor `2^stops / white` for a prepared image.
    pub(crate) fn scale(&self, positive_range: Option<(f32, f32)>) -> f32 {
        let white = self
            .white
            .or_else(|| positive_range.map(|(_, hi)| hi))
            .unwrap_or(1.0);
        self.exposure_stops.exp2() / white
    }
}

/// A series of linearly mapped images at increasing exposure (HDR VolVis Fig. 4b).
#[derive(Clone, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct ExposureSeries {
    /// Number of images (at least 1).
    pub count: usize,
    /// Exposure of the first image in stops (0 maps the brightest pixel to display 1).
    pub first_stops: f32,
    /// Exposure increase between consecutive images, in stops.
    pub step_stops: f32,
}

impl ExposureSeries {
    /// `count` exposures that span the image's dynamic range: the first maps the brightest
    /// pixel to 1, the last maps the dimmest non-zero pixel to 1.
    #[must_use]
    pub fn spanning(img: &Rgb32FImage, count: usize) -> Self {
        let stops = crate::dynamic_range(img).map_or(0.0, |d| d.ratio.log2() as f32);
        let step = if count > 1 {
            stops / (count - 1) as f32
        } else {
            0.0
        };
        Self {
            count,
            first_stops: 0.0,
            step_stops: step,
        }
    }

    /// The exposure of image `i` in stops.
    #[must_use]
    pub fn stops(&self, i: usize) -> f32 {
        self.first_stops + self.step_stops * i as f32
    }
}

/// Renders the exposure series: image `i` is [`LinearParams`] with
/// `exposure_stops = first_stops + i * step_stops` and the image's own white.
///
/// # Errors
/// [`Error::Parameter`] when `count` is 0 or above 64, or a stop value is not finite;
/// [`Error::EmptyImage`] for an empty image.
pub fn exposure_series(img: &Rgb32FImage, series: &ExposureSeries) -> Result<Vec<Rgb32FImage>> {
    if series.count == 0 || series.count > MAX_EXPOSURE_SERIES {
        return Err(Error::parameter(format!(
            "exposure series needs 1 to {MAX_EXPOSURE_SERIES} images, got {}",
            series.count
        )));
    }
    check_finite("first_stops", series.first_stops)?;
    check_finite("step_stops", series.step_stops)?;
    (0..series.count)
        .map(|i| {
            crate::Operator::Linear(LinearParams {
                exposure_stops: series.stops(i),
                white: None,
            })
            .apply(img)
        })
        .collect()
}

/// The percentile of the lit pixels' luminance that the linear operator maps to display 1
/// by default (`blueshift tonemap --op linear`, `render --tonemap linear`, the viewer).
pub const LINEAR_WHITE_PERCENTILE: f64 = 99.0;

/// The most images an exposure series may have.
pub const MAX_EXPOSURE_SERIES: usize = 64;

/// The default white of the linear operator: the [`LINEAR_WHITE_PERCENTILE`]-th percentile
/// of the luminance of the lit (positive, finite) pixels, so the brightest 1 % clip and a
/// hot pixel or a small bright source no longer maps everything else to black, as the
/// maximum did. `None` when no pixel is lit.
#[must_use]
pub fn default_linear_white(img: &image::Rgb32FImage) -> Option<f32> {
    let mut lum: Vec<f32> = img
        .pixels()
        .map(|p| crate::luminance(p.0))
        .filter(|y| y.is_finite() && *y > 0.0)
        .collect();
    if lum.is_empty() {
        return None;
    }
    let last = lum.len() - 1;
    let k = ((LINEAR_WHITE_PERCENTILE / 100.0) * last as f64).round() as usize;
    let (_, v, _) = lum.select_nth_unstable_by(k.min(last), f32::total_cmp);
    Some(*v)
}
