//! The tone-mapping operators and their common entry point [`Operator`].

pub mod drago;
pub mod durand;
pub mod fattal;
pub mod linear;
pub mod reinhard;

use image::Rgb32FImage;

use crate::error::{Error, Result};
use crate::inverse::GlobalCurve;
use crate::io::HdrSource;
use crate::plane::{log_average, recolour_in_gamut};
use crate::sanitize::{CleanImage, CleanStats};

pub use drago::{DragoParams, Roi};
pub use durand::DurandParams;
pub use fattal::FattalParams;
pub use linear::{ExposureSeries, LinearParams, exposure_series};
pub use reinhard::{ReinhardLocalParams, ReinhardParams};

/// A tone-mapping operator with its parameters. [`Operator::apply`] maps a linear HDR
/// image (any unit) to a display-referred linear image whose useful range is [0, 1]; the
/// display encoding (sRGB transfer, 8 or 16 bits) happens when writing
/// ([`crate::io::write_png`]).
#[derive(Clone, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub enum Operator {
    /// Linear scaling with an exposure (global).
    Linear(LinearParams),
    /// Drago et al. 2003 adaptive logarithmic mapping (global).
    Drago(DragoParams),
    /// Reinhard et al. 2002 photographic operator, global version (Eq. 4).
    Reinhard(ReinhardParams),
    /// Reinhard et al. 2002 local dodging and burning (Eq. 9).
    ReinhardLocal(ReinhardLocalParams),
    /// Durand and Dorsey 2002 bilateral base/detail decomposition (local).
    Durand(DurandParams),
    /// Fattal et al. 2002 gradient-domain compression (local).
    Fattal(FattalParams),
}

impl Default for Operator {
    fn default() -> Self {
        Operator::Drago(DragoParams::default())
    }
}

pub(crate) fn check_finite(name: &str, v: f32) -> Result<()> {
    if v.is_finite() {
        Ok(())
    } else {
        Err(Error::parameter(format!("{name} must be finite, got {v}")))
    }
}

pub(crate) fn check_saturation(s: f32) -> Result<()> {
    if s > 0.0 && s <= 4.0 {
        Ok(())
    } else {
        Err(Error::parameter(format!(
            "saturation exponent must lie in (0, 4], got {s}"
        )))
    }
}

fn check_not_empty(img: &Rgb32FImage) -> Result<()> {
    if img.width() == 0 || img.height() == 0 {
        Err(Error::EmptyImage)
    } else {
        Ok(())
    }
}

impl Operator {
    /// The operator's name as the CLI spells it.
    #[must_use]
    pub fn name(&self) -> &'static str {
        match self {
            Operator::Linear(_) => "linear",
            Operator::Drago(_) => "drago",
            Operator::Reinhard(_) => "reinhard",
            Operator::ReinhardLocal(_) => "reinhard-local",
            Operator::Durand(_) => "durand",
            Operator::Fattal(_) => "fattal",
        }
    }

    /// Whether the operator applies one curve to every pixel (and so has an inverse).
    #[must_use]
    pub fn is_global(&self) -> bool {
        matches!(
            self,
            Operator::Linear(_) | Operator::Drago(_) | Operator::Reinhard(_)
        )
    }

    /// Checks the parameters.
    ///
    /// # Errors
    /// [`Error::Parameter`] naming the parameter that is out of range.
    pub fn validate(&self) -> Result<()> {
        match self {
            Operator::Linear(p) => p.validate(),
            Operator::Drago(p) => p.validate(),
            Operator::Reinhard(p) => p.validate(),
            Operator::ReinhardLocal(p) => p.validate(),
            Operator::Durand(p) => p.validate(),
            Operator::Fattal(p) => p.validate(),
        }
    }

    /// Tone-maps `img` (linear RGB, any positive unit) to a display-linear image.
    ///
    /// The dirty-input rule of [`crate::sanitize()`] is applied first; the output never
    /// contains NaN, and pixels of zero luminance stay black.
    ///
    /// The local operators (Reinhard local, Durand, Fattal) return every channel in
    /// [0, 1]: after the colour-ratio step `C_out = (C/L)^s L_out` a colour outside the
    /// display cube is brought in by constant-luminance desaturation towards the grey of
    /// the same luminance ([`crate::plane::fit_to_display`]), which keeps its hue, instead
    /// of a per-channel clip at display time, which turns it. The global operators keep
    /// the plain ratio step (their curve and recolouring are inverted exactly by
    /// [`GlobalCurve::invert`]); their channels above 1 clip when written.
    ///
    /// # Errors
    /// [`Error::Parameter`] for invalid parameters (or a region of interest with no lit
    /// pixel), [`Error::EmptyImage`] for a 0-pixel image.
    pub fn apply(&self, img: &Rgb32FImage) -> Result<Rgb32FImage> {
        self.validate()?;
        check_not_empty(img)?;
        self.apply_clean(&CleanImage::new(img))
    }

    /// [`Operator::apply`] on an image already cleaned by [`CleanImage`] (whose luminance
    /// and statistics are reused, so a caller that also reports the dynamic range cleans
    /// the image once).
    ///
    /// # Errors
    /// As [`Operator::apply`].
    pub fn apply_clean(&self, clean: &CleanImage) -> Result<Rgb32FImage> {
        self.validate()?;
        check_not_empty(&clean.image)?;
        let p = clean;
        let Some((floor, _)) = p.positive_range else {
            // All black: every operator maps black to black.
            return Ok(Rgb32FImage::new(p.image.width(), p.image.height()));
        };
        if self.is_global() {
            let curve = self.curve_of(p)?;
            return Ok(curve.apply_clean(&p.image, &p.luminance));
        }
        let (w, h) = (p.luminance.width, p.luminance.height);
        let (lum_out, saturation) = match self {
            Operator::ReinhardLocal(params) => {
                let lavg = log_average(&p.luminance, None).expect("has positive pixels");
                let scale = (f64::from(params.key) / lavg) as f32;
                let scaled = p.luminance.map(|v| v * scale);
                (reinhard::dodge_and_burn(&scaled, params), params.saturation)
            }
            Operator::Durand(params) => {
                let log_l = p.luminance.map(|v| v.max(floor).log10());
                let out = durand::durand_log_lit(&log_l, Some(&p.luminance), params);
                (out.map(|v| 10f32.powf(v)), params.saturation)
            }
            Operator::Fattal(params) => {
                let h_log = p.luminance.map(|v| v.max(floor).ln());
                let i = fattal::compressed_log_luminance(&h_log, params)?;
                let l_out = i.map(f32::exp);
                // Scale to the display, clipping the given percentages (lit pixels only).
                (
                    fattal::display_stretch(&l_out, &p.luminance, params),
                    params.saturation,
                )
            }
            _ => unreachable!("global operators handled above"),
        };
        debug_assert_eq!((lum_out.width, lum_out.height), (w, h));
        Ok(recolour_in_gamut(
            &p.image,
            &p.luminance,
            &lum_out,
            saturation,
        ))
    }

    /// [`Operator::apply_clean`] followed by [`crate::io::display_to_srgb8`], the same
    /// bytes: 8-bit sRGB codes, row-major RGB. The global operators (linear, Drago,
    /// Reinhard) go straight to the codes in one pass, without the floating-point display
    /// image (the CLI's 8-bit PNG output).
    ///
    /// # Errors
    /// As [`Operator::apply_clean`].
    pub fn apply_clean_srgb8(&self, clean: &CleanImage) -> Result<Vec<u8>> {
        self.validate()?;
        check_not_empty(&clean.image)?;
        if self.is_global() && clean.positive_range.is_some() {
            let curve = self.curve_of(clean)?;
            return Ok(curve.apply_clean_srgb8(&clean.image, &clean.luminance));
        }
        Ok(crate::io::display_to_srgb8(&self.apply_clean(clean)?))
    }

    /// A global operator (linear, Drago, Reinhard) over the rows of `src`, without its
    /// floating-point image or luminance plane: this first pass over the rows finds the
    /// cleaning's statistics ([`CleanImage::stats`]) and the curve; the second, by
    /// [`RowsToneMap::srgb8`] or [`RowsToneMap::write_png`], makes the display codes of
    /// [`Operator::apply_clean_srgb8`] (the same bytes). For a compact source (a run-length
    /// encoded Radiance file, OpenEXR blocks) the memory is about the file's samples.
    ///
    /// `Ok(None)`, having read the rows once, for the local operators, for an image with
    /// infinite values (replacing them needs the whole image's finite maximum first) and
    /// for one without a lit pixel: decode the image ([`HdrSource::into_image`]) and use
    /// [`Operator::apply_clean_srgb8`].
    ///
    /// # Errors
    /// As [`Operator::apply_clean`].
    pub fn apply_rows<'a>(&self, src: &'a HdrSource) -> Result<Option<RowsToneMap<'a>>> {
        self.validate()?;
        let (w, h) = src.dimensions();
        if w == 0 || h == 0 {
            return Err(Error::EmptyImage);
        }
        if !self.is_global() {
            return Ok(None);
        }
        let needs_log = !matches!(self, Operator::Linear(_));
        let Some((stats, lavg)) =
            crate::rows::clean_stats(src, self.log_average_circle(), needs_log)
        else {
            return Ok(None);
        };
        if stats.positive_range.is_none() {
            return Ok(None);
        }
        let curve = self.curve_from(stats.positive_range, || lavg)?;
        Ok(Some(RowsToneMap {
            src,
            codes: curve.row_codes(),
            stats,
        }))
    }

    /// [`Operator::apply_rows`] then [`RowsToneMap::srgb8`], with the statistics.
    ///
    /// # Errors
    /// As [`Operator::apply_rows`].
    pub fn apply_rows_srgb8(&self, src: &HdrSource) -> Result<Option<(Vec<u8>, CleanStats)>> {
        Ok(self.apply_rows(src)?.map(|t| (t.srgb8(), t.stats)))
    }

    /// The resolved global curve of this operator for `img`: the operator's parameters plus
    /// the image statistics it depends on (adaptation and maximum luminance). It maps and
    /// inverts display values (HDR VolVis Sec. 4, last paragraph).
    ///
    /// # Errors
    /// [`Error::NotInvertible`] for local operators (Reinhard local, Durand, Fattal), whose
    /// inverse is not defined; [`Error::Parameter`] / [`Error::EmptyImage`] as in
    /// [`Operator::apply`].
    pub fn global_curve(&self, img: &Rgb32FImage) -> Result<GlobalCurve> {
        self.validate()?;
        check_not_empty(img)?;
        self.curve_of(&CleanImage::new(img))
    }

    fn curve_of(&self, p: &CleanImage) -> Result<GlobalCurve> {
        self.curve_from(p.positive_range, || {
            log_average(&p.luminance, self.log_average_circle())
        })
    }

    /// The circle (centre and radius in pixels) over which the operator's log-average
    /// luminance is taken (`None`: the whole image).
    fn log_average_circle(&self) -> Option<(f32, f32, f32)> {
        match self {
            Operator::Drago(params) => params.roi.map(|r| (r.x_px, r.y_px, r.radius_px)),
            _ => None,
        }
    }

    /// The global curve from the image's positive luminance range and its log-average
    /// luminance over [`Operator::log_average_circle`] (computed only for the operators
    /// that use it; `None` where no pixel there is lit).
    fn curve_from(
        &self,
        positive_range: Option<(f32, f32)>,
        log_average: impl FnOnce() -> Option<f64>,
    ) -> Result<GlobalCurve> {
        let max = positive_range.map_or(1.0, |(_, hi)| hi);
        match self {
            Operator::Linear(params) => Ok(GlobalCurve::Linear {
                scale: f64::from(params.scale(positive_range)),
            }),
            Operator::Drago(params) => {
                let lwa = match params.roi {
                    Some(roi) => log_average().ok_or_else(|| {
                        Error::parameter(format!(
                            "the region of interest (x {}, y {}, radius {} px) contains no lit pixel",
                            roi.x_px, roi.y_px, roi.radius_px
                        ))
                    })?,
                    None => log_average().unwrap_or(1.0),
                };
                let adaptation = lwa / f64::from(params.exposure_stops).exp2();
                Ok(GlobalCurve::Drago {
                    adaptation,
                    scaled_max: f64::from(max) / adaptation,
                    bias: f64::from(params.bias),
                    max_display_luminance: f64::from(params.max_display_luminance),
                    saturation: params.saturation,
                })
            }
            Operator::Reinhard(params) => {
                let scale = f64::from(params.key) / log_average().unwrap_or(1.0);
                let white = params.white.map_or(f64::from(max) * scale, f64::from);
                Ok(GlobalCurve::Reinhard {
                    scale,
                    white,
                    saturation: params.saturation,
                })
            }
            _ => Err(Error::NotInvertible(format!(
                "the {} operator is local: the same HDR value maps to different display \
                 values, so it has no inverse (HDR VolVis Sec. 4)",
                self.name()
            ))),
        }
    }
}

/// A global operator resolved for the rows of an [`HdrSource`] ([`Operator::apply_rows`]).
pub struct RowsToneMap<'a> {
    src: &'a HdrSource,
    codes: crate::rows::RowCodes,
    /// The cleaning's statistics (those of [`CleanImage::stats`]).
    pub stats: CleanStats,
}

impl std::fmt::Debug for RowsToneMap<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RowsToneMap")
            .field("src", &self.src.dimensions())
            .field("stats", &self.stats)
            .finish_non_exhaustive()
    }
}

impl RowsToneMap<'_> {
    /// The 8-bit sRGB codes (row-major RGB), rows in parallel.
    #[must_use]
    pub fn srgb8(&self) -> Vec<u8> {
        crate::rows::codes(self.src, &self.codes, self.stats.report.total() > 0)
    }

    /// Writes the codes as an 8-bit PNG (the bytes of [`crate::io::write_rgb8_png`] of
    /// [`RowsToneMap::srgb8`]), each part of the file's stream compressed by the thread that
    /// made its rows, without the whole image of codes.
    ///
    /// # Errors
    /// As [`crate::io::write_rgb8_png`].
    pub fn write_png(&self, path: &std::path::Path) -> Result<()> {
        crate::rows::write_png(self.src, &self.codes, self.stats.report.total() > 0, path)
    }
}
