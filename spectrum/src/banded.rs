//! Banded spectra: N uniform bands, the paper's baseline (Doppler paper section 4.1,
//! Algorithm 1).

use crate::cie::{Cmf, Xyz};
use crate::doppler::{RadiometricTransform, WavelengthShift};
use crate::error::{Error, Result, non_negative, range};
use crate::piecewise::{Piece, PiecewiseLinear};

/// The layout of a banded spectrum: `bands` uniform bands over `[min_nm, max_nm)`.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct BandLayout {
    min_nm: f64,
    max_nm: f64,
    bands: usize,
}

impl BandLayout {
    /// `bands` bands over `[min_nm, max_nm)`. Refuses zero bands and an empty range.
    pub fn new(min_nm: f64, max_nm: f64, bands: usize) -> Result<Self> {
        let (min_nm, max_nm) = range("band range", min_nm, max_nm)?;
        if bands == 0 {
            return Err(Error::param("band count", 0.0, "must be >= 1"));
        }
        if bands > 1 << 26 {
            return Err(Error::param("band count", bands as f64, "must be <= 2^26"));
        }
        Ok(Self {
            min_nm,
            max_nm,
            bands,
        })
    }

    /// Number of bands N.
    #[must_use]
    pub fn bands(&self) -> usize {
        self.bands
    }

    /// The range `(min_nm, max_nm)`.
    #[must_use]
    pub fn range_nm(&self) -> (f64, f64) {
        (self.min_nm, self.max_nm)
    }

    /// Band width in nm.
    #[must_use]
    pub fn width_nm(&self) -> f64 {
        (self.max_nm - self.min_nm) / self.bands as f64
    }

    /// Start of band `i`, nm.
    #[must_use]
    pub fn band_start_nm(&self, i: usize) -> f64 {
        self.min_nm + i as f64 * self.width_nm()
    }

    /// Centre of band `i`, nm.
    #[must_use]
    pub fn band_centre_nm(&self, i: usize) -> f64 {
        self.min_nm + (i as f64 + 0.5) * self.width_nm()
    }

    /// The band containing `wavelength_nm`, if any.
    #[must_use]
    pub fn band_of(&self, wavelength_nm: f64) -> Option<usize> {
        if !(wavelength_nm >= self.min_nm && wavelength_nm < self.max_nm) {
            return None;
        }
        let i = ((wavelength_nm - self.min_nm) / self.width_nm()).floor() as usize;
        Some(i.min(self.bands - 1))
    }
}

impl std::fmt::Display for BandLayout {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} bands over [{}, {}) nm",
            self.bands, self.min_nm, self.max_nm
        )
    }
}

/// A spectrum of N uniform bands (N chosen at run time): each band holds the mean spectral
/// radiance over the band, so the spectrum reads as a step function.
#[derive(Clone, Debug, PartialEq)]
pub struct Banded {
    layout: BandLayout,
    values: Box<[f64]>,
}

impl Banded {
    /// The zero spectrum of a layout.
    #[must_use]
    pub fn zero(layout: BandLayout) -> Self {
        Self {
            layout,
            values: vec![0.0; layout.bands].into_boxed_slice(),
        }
    }

    /// From band values (non-negative, finite; length = band count).
    pub fn from_values(layout: BandLayout, values: Vec<f64>) -> Result<Self> {
        if values.len() != layout.bands {
            return Err(Error::param(
                "band value count",
                values.len() as f64,
                "must equal the band count",
            ));
        }
        for &v in &values {
            non_negative("band value", v)?;
        }
        Ok(Self {
            layout,
            values: values.into_boxed_slice(),
        })
    }

    /// The paper's point sampling: each band takes `f` at its centre.
    pub fn sampled(layout: BandLayout, f: impl Fn(f64) -> f64) -> Result<Self> {
        let values = (0..layout.bands)
            .map(|i| f(layout.band_centre_nm(i)))
            .collect();
        Self::from_values(layout, values)
    }

    /// The exact projection of a piecewise-linear spectrum: each band takes its mean value.
    #[must_use]
    pub fn projected(layout: BandLayout, spectrum: &PiecewiseLinear) -> Self {
        let mut out = Self::zero(layout);
        out.add_piecewise(spectrum, 1.0);
        out
    }

    /// Adds `weight` times the band means of a piecewise-linear spectrum (exact).
    pub fn add_piecewise(&mut self, spectrum: &PiecewiseLinear, weight: f64) {
        for p in spectrum.pieces() {
            self.add_piece_mean(&p, weight);
        }
    }

    fn add_piece_mean(&mut self, p: &Piece, weight: f64) {
        let l = self.layout;
        let (lo, hi) = l.range_nm();
        let a = p.start_nm.max(lo);
        let b = p.end_nm.min(hi);
        if b.partial_cmp(&a) != Some(std::cmp::Ordering::Greater) {
            return;
        }
        let w = l.width_nm();
        let first = l.band_of(a).unwrap_or(0);
        let mut i = first;
        while i < l.bands {
            let u = l.band_start_nm(i).max(a);
            let v = (l.band_start_nm(i) + w).min(b);
            if v > u {
                self.values[i] += weight * 0.5 * (v - u) * (p.at(u) + p.at(v)) / w;
            }
            if l.band_start_nm(i) + w >= b {
                break;
            }
            i += 1;
        }
    }

    /// The layout.
    #[must_use]
    pub fn layout(&self) -> BandLayout {
        self.layout
    }

    /// Band values (mean spectral radiance per band).
    #[must_use]
    pub fn values(&self) -> &[f64] {
        &self.values
    }

    /// Value at `wavelength_nm`: the value of its band, 0 outside the range.
    #[must_use]
    pub fn eval(&self, wavelength_nm: f64) -> f64 {
        self.layout
            .band_of(wavelength_nm)
            .map_or(0.0, |i| self.values[i])
    }

    /// Largest band value.
    #[must_use]
    pub fn max_value(&self) -> f64 {
        self.values.iter().copied().fold(0.0, f64::max)
    }

    /// Integral over wavelength (value x nm).
    #[must_use]
    pub fn total(&self) -> f64 {
        self.values.iter().sum::<f64>() * self.layout.width_nm()
    }

    fn check_layout(&self, other: &Banded) -> Result<()> {
        if self.layout == other.layout {
            Ok(())
        } else {
            Err(Error::LayoutMismatch {
                a: self.layout.to_string(),
                b: other.layout.to_string(),
            })
        }
    }

    /// Adds another banded spectrum of the same layout.
    pub fn add(&mut self, other: &Banded) -> Result<()> {
        self.check_layout(other)?;
        for (a, b) in self.values.iter_mut().zip(other.values.iter()) {
            *a += b;
        }
        Ok(())
    }

    /// Multiplies band by band by another banded function of the same layout (for example a
    /// transmittance in [0, 1]; values must be finite and >= 0).
    pub fn multiply(&mut self, other: &Banded) -> Result<()> {
        self.check_layout(other)?;
        for (a, b) in self.values.iter_mut().zip(other.values.iter()) {
            *a *= b;
        }
        Ok(())
    }

    /// Multiplies every band by `factor` (finite, >= 0).
    pub fn scale(&mut self, factor: f64) -> Result<()> {
        non_negative("scale factor", factor)?;
        for v in self.values.iter_mut() {
            *v *= factor;
        }
        Ok(())
    }

    /// The paper's nearest-band Doppler shift (Algorithm 1): the value of each band moves,
    /// unchanged, into the band that contains `s` times its centre wavelength; values that
    /// land outside the range are lost, and bands that receive two values add them. This
    /// reproduces the paper's artefacts (Fig. 6/7): apparent emission lines where two bands
    /// land in one, apparent absorption lines where a band receives nothing.
    #[must_use]
    pub fn shift_nearest(&self, shift: WavelengthShift) -> Self {
        let mut out = Self::zero(self.layout);
        for (i, &v) in self.values.iter().enumerate() {
            if let Some(j) = self
                .layout
                .band_of(self.layout.band_centre_nm(i) * shift.value())
            {
                out.values[j] += v;
            }
        }
        out
    }

    /// Energy-conserving Doppler shift: each band, read as a box, is stretched to
    /// `[s a, s b)` (values transformed by `transform`) and its energy is distributed over the
    /// target bands in proportion to overlap. The result is the exact band projection of the
    /// shifted step function, so the in-range energy equals that of the exact shift (`s` times
    /// the input's with [`RadiometricTransform::None`]) and no apparent lines appear.
    #[must_use]
    pub fn shift_energy_conserving(
        &self,
        shift: WavelengthShift,
        transform: RadiometricTransform,
    ) -> Self {
        let s = shift.value();
        let f = transform.value_factor(shift);
        let mut out = Self::zero(self.layout);
        let w = self.layout.width_nm();
        for (i, &v) in self.values.iter().enumerate() {
            if v == 0.0 {
                continue;
            }
            let a = self.layout.band_start_nm(i) * s;
            let p = Piece {
                start_nm: a,
                end_nm: a + w * s,
                value_start: v * f,
                value_end: v * f,
            };
            out.add_piece_mean(&p, 1.0);
        }
        out
    }

    /// The step function as a piecewise-linear spectrum (one box per non-zero band).
    #[must_use]
    pub fn to_piecewise(&self) -> PiecewiseLinear {
        let l = self.layout;
        let pieces = self.values.iter().enumerate().map(|(i, &v)| Piece {
            start_nm: l.band_start_nm(i),
            end_nm: if i + 1 == l.bands {
                l.max_nm
            } else {
                l.band_start_nm(i + 1)
            },
            value_start: v,
            value_end: v,
        });
        PiecewiseLinear::from_pieces(pieces).expect("band boxes are valid pieces")
    }

    /// XYZ of the step function, exact against the piecewise-linear CMFs (each band's
    /// weight is the CMF integral over the band). Use [`BandWeights`] to convert many
    /// spectra of one layout.
    #[must_use]
    pub fn to_xyz_with(&self, cmf: &Cmf) -> Xyz {
        BandWeights::new(self.layout, cmf)
            .xyz(self)
            .expect("weights built for this layout")
    }
}

/// Precomputed per-band CMF integrals of a layout, for converting many banded spectra.
#[derive(Clone, Debug)]
pub struct BandWeights {
    layout: BandLayout,
    weights: Vec<[f64; 3]>,
}

impl BandWeights {
    /// The integral of each CMF over each band of `layout`.
    #[must_use]
    pub fn new(layout: BandLayout, cmf: &Cmf) -> Self {
        let weights = (0..layout.bands)
            .map(|i| {
                let a = layout.band_start_nm(i);
                cmf.trapezoid_xyz(a, a + layout.width_nm(), 1.0, 1.0)
                    .to_array()
            })
            .collect();
        Self { layout, weights }
    }

    /// The XYZ of a unit value in each band (the CMF integrals over each band), band by band.
    #[must_use]
    pub fn per_band(&self) -> &[[f64; 3]] {
        &self.weights
    }

    /// XYZ of a banded spectrum; refuses a spectrum of another layout.
    pub fn xyz(&self, spectrum: &Banded) -> Result<Xyz> {
        if self.layout != spectrum.layout {
            return Err(Error::LayoutMismatch {
                a: self.layout.to_string(),
                b: spectrum.layout.to_string(),
            });
        }
        let mut out = [0.0; 3];
        for (v, w) in spectrum.values.iter().zip(&self.weights) {
            for c in 0..3 {
                out[c] += v * w[c];
            }
        }
        Ok(Xyz::from_array(out))
    }
}
