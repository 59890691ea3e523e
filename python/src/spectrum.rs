//! Spectra: black bodies and emission lines, Doppler-shifted, with their colours.

use blueshift_spectrum::{
    Blackbody, Catalogue, DopplerModel, EmissionLine, LineProfile, Observer, PiecewiseLinear,
    RadiometricTransform, WavelengthShift, srgb_encode,
};
use numpy::{IntoPyArray, PyArray1, PyArray2, PyReadonlyArray1};
use pyo3::prelude::*;
use serde::Deserialize;

use crate::{BlueshiftError, options};

/// What `blueshift spectrum` builds, by its flags' Python names.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct Recipe {
    blackbody: Option<f64>,
    lines: Option<Vec<String>>,
    /// `[[nm, relative_intensity], ...]`.
    line_table: Option<Vec<[f64; 2]>>,
    line_strength: Option<f64>,
    line_width: Option<f64>,
    line_profile: Option<String>,
    shift: Option<f64>,
    radial_velocity: Option<f64>,
    doppler: Option<String>,
    radiometric: Option<String>,
    range: Option<(f64, f64)>,
    max_error: Option<f64>,
}

fn err(e: impl std::fmt::Display) -> PyErr {
    BlueshiftError::new_err(e.to_string())
}

/// A spectrum over an observed wavelength range (values: spectral radiance, W sr^-1 m^-2
/// nm^-1), exactly piecewise linear.
#[pyclass(module = "blueshift._native", name = "Spectrum", frozen)]
pub(crate) struct PySpectrum {
    observed: PiecewiseLinear,
    range: (f64, f64),
    shift: f64,
    observed_temperature_k: Option<f64>,
}

fn observer(name: &str) -> PyResult<&'static blueshift_spectrum::Cmf> {
    match name {
        "1931" | "cie1931" => Ok(Observer::Cie1931TwoDegree.cmf()),
        "1964" | "cie1964" => Ok(Observer::Cie1964TenDegree.cmf()),
        other => Err(err(format!("observer '{other}': one of 1931, 1964"))),
    }
}

#[pymethods]
impl PySpectrum {
    /// Builds a spectrum as `blueshift spectrum` does from the same options (JSON), with
    /// the GIL released.
    #[staticmethod]
    fn build(py: Python<'_>, recipe: &str) -> PyResult<Self> {
        let r: Recipe = options("spectrum", recipe)?;
        crate::run_cancellable(py, |_| Ok(Self::make(&r)))?
    }

    /// CIE XYZ over the range (observer `1931` or `1964`).
    #[pyo3(signature = (observer_name="1931"))]
    fn xyz(&self, observer_name: &str) -> PyResult<(f64, f64, f64)> {
        let cmf = observer(observer_name)?;
        let (lo, hi) = self.range;
        let (clo, chi) = cmf.range_nm();
        let a = lo.max(clo);
        let xyz = cmf
            .xyz_of_in(&self.observed, a, hi.min(chi).max(a + 1e-9))
            .map_err(err)?;
        Ok((xyz.x, xyz.y, xyz.z))
    }

    /// The display sRGB of the colour with Y normalised to 1 (clipped, encoded), as
    /// `blueshift spectrum` prints it; `display=False` gives linear sRGB of XYZ instead.
    #[pyo3(signature = (display=true, observer_name="1931"))]
    fn srgb(&self, display: bool, observer_name: &str) -> PyResult<(f64, f64, f64)> {
        let (x, y, z) = self.xyz(observer_name)?;
        let xyz = blueshift_spectrum::Xyz { x, y, z };
        let v = if !display {
            xyz.to_linear_srgb()
        } else if y > 0.0 {
            xyz.scaled(1.0 / y).to_linear_srgb().map(srgb_encode)
        } else {
            [0.0; 3]
        };
        Ok((v[0], v[1], v[2]))
    }

    /// Values at the wavelengths (nm).
    fn eval<'py>(
        &self,
        py: Python<'py>,
        wavelengths_nm: PyReadonlyArray1<'_, f64>,
    ) -> Bound<'py, PyArray1<f64>> {
        let v: Vec<f64> = wavelengths_nm
            .as_array()
            .iter()
            .map(|&w| self.observed.eval(w))
            .collect();
        v.into_pyarray(py)
    }

    /// The integral over `[lo, hi]` nm (default the range).
    #[pyo3(signature = (lo=None, hi=None))]
    fn integral(&self, lo: Option<f64>, hi: Option<f64>) -> PyResult<f64> {
        self.observed
            .integrate(lo.unwrap_or(self.range.0), hi.unwrap_or(self.range.1))
            .map_err(err)
    }

    /// The exact pieces, float64 `[n, 4]`: `(start_nm, end_nm, value_start, value_end)`.
    fn pieces<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        crate::doppler::pieces_array(py, &self.observed)
    }

    /// Observed wavelength range, nm.
    #[getter]
    fn range(&self) -> (f64, f64) {
        self.range
    }

    /// The wavelength ratio s = lambda_obs / lambda_emit applied.
    #[getter]
    fn shift(&self) -> f64 {
        self.shift
    }

    /// With the invariant transform: the observed black body's temperature (T / s).
    #[getter]
    fn observed_temperature_k(&self) -> Option<f64> {
        self.observed_temperature_k
    }
}

impl PySpectrum {
    fn make(r: &Recipe) -> PyResult<Self> {
        let (lo, hi) = r.range.unwrap_or((360.0, 830.0));
        if !(lo.is_finite() && hi.is_finite() && lo > 0.0 && lo < hi) {
            return Err(err(format!("range ({lo}, {hi}): need 0 < min < max")));
        }
        let table_lines = r.line_table.as_ref().is_some_and(|t| !t.is_empty());
        if r.blackbody.is_none() && r.lines.as_ref().is_none_or(Vec::is_empty) && !table_lines {
            return Err(err(
                "nothing to build: give blackbody (K) and/or lines or a line table",
            ));
        }
        let model = match r.doppler.as_deref().unwrap_or("classical") {
            "classical" => DopplerModel::Classical,
            "relativistic" => DopplerModel::Relativistic,
            other => return Err(err(format!("doppler '{other}': classical or relativistic"))),
        };
        let shift = match (r.shift, r.radial_velocity) {
            (Some(_), Some(_)) => return Err(err("give shift or radial_velocity, not both")),
            (Some(s), None) => WavelengthShift::new(s).map_err(|e| err(format!("shift: {e}")))?,
            (None, Some(v)) => WavelengthShift::from_radial_velocity(model, v)
                .map_err(|e| err(format!("radial_velocity: {e}")))?,
            (None, None) => WavelengthShift::IDENTITY,
        };
        let transform = match r.radiometric.as_deref().unwrap_or("none") {
            "none" => RadiometricTransform::None,
            "invariant" => RadiometricTransform::Invariant,
            other => return Err(err(format!("radiometric '{other}': none or invariant"))),
        };
        let width = r.line_width.unwrap_or(1.0);
        let profile = match r.line_profile.as_deref().unwrap_or("box") {
            "box" => LineProfile::Box { width_nm: width },
            "triangle" => LineProfile::Triangle { fwhm_nm: width },
            other => return Err(err(format!("line_profile '{other}': box or triangle"))),
        };
        let strength = r.line_strength.unwrap_or(1.0);
        let s = shift.value();
        let mut rest = PiecewiseLinear::new();
        let mut bb = None;
        if let Some(t) = r.blackbody {
            let b = Blackbody::new(t).map_err(|e| err(format!("blackbody: {e}")))?;
            let approx = b
                .to_piecewise(lo / s, hi / s, r.max_error.unwrap_or(1e-4))
                .map_err(|e| err(format!("max_error: {e}")))?;
            rest.add(&approx);
            bb = Some(b);
        }
        let mut all: Vec<EmissionLine> = Vec::new();
        for name in r.lines.iter().flatten() {
            all.extend(
                Catalogue::parse(name)
                    .map_err(|e| err(format!("lines: {e}")))?
                    .lines(),
            );
        }
        for &[nm, rel] in r.line_table.iter().flatten() {
            all.push(EmissionLine::new(nm, rel).map_err(|e| err(format!("line_table: {e}")))?);
        }
        for line in &all {
            line.add_to(&mut rest, profile, strength)
                .map_err(|e| err(format!("line_strength/line_width: {e}")))?;
        }
        let observed = rest.shifted(shift, transform);
        let observed_temperature_k = bb.and_then(|b| match transform {
            RadiometricTransform::Invariant => Some(b.shifted(shift).temperature_k()),
            RadiometricTransform::None => None,
        });
        Ok(Self {
            observed,
            range: (lo, hi),
            shift: s,
            observed_temperature_k,
        })
    }
}

/// The wavelength ratio s of a radial velocity (m/s, positive receding).
#[pyfunction]
#[pyo3(signature = (radial_velocity_m_per_s, model="classical"))]
fn doppler_shift(radial_velocity_m_per_s: f64, model: &str) -> PyResult<f64> {
    let m = model
        .parse::<DopplerModel>()
        .map_err(|_| err(format!("model '{model}': classical or relativistic")))?;
    Ok(
        WavelengthShift::from_radial_velocity(m, radial_velocity_m_per_s)
            .map_err(err)?
            .value(),
    )
}

/// A built-in line catalogue (`H`, `He`, `C`): `(wavelength_nm, relative_intensity)` rows.
#[pyfunction]
fn catalogue(name: &str) -> PyResult<Vec<(f64, f64)>> {
    let c = Catalogue::parse(name).map_err(err)?;
    Ok(c.lines()
        .iter()
        .map(|l| (l.centre_nm, l.strength))
        .collect())
}

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PySpectrum>()?;
    m.add_function(wrap_pyfunction!(doppler_shift, m)?)?;
    m.add_function(wrap_pyfunction!(catalogue, m)?)?;
    Ok(())
}
