//! Volumes from arrays or files, and transfer functions.

use std::path::PathBuf;

use blueshift_tfedit::{ColorKnot, DataAxis, OpacityKnot, TransferFunction};
use blueshift_volume::{AnyGrid, Channel, Geometry, Grid, Volume};
use glam::Vec3;
use numpy::ndarray::{Array2, ArrayView1};
use numpy::prelude::*;
use numpy::{IntoPyArray, PyArray2, PyArrayDyn, PyReadonlyArray1, PyReadonlyArrayDyn};
use pyo3::prelude::*;

use crate::{BlueshiftError, Fail, run_cancellable};

/// A volume: one or more channels (scalar or 3-vector) on one regular grid.
#[pyclass(module = "blueshift._native", name = "Volume", frozen)]
#[derive(Clone)]
pub(crate) struct PyVolume {
    pub(crate) inner: Volume,
}

fn vec3(name: &str, v: [f64; 3]) -> PyResult<Vec3> {
    if v.iter().all(|c| c.is_finite()) {
        Ok(Vec3::new(v[0] as f32, v[1] as f32, v[2] as f32))
    } else {
        Err(BlueshiftError::new_err(format!(
            "{name} {v:?}: every component must be finite"
        )))
    }
}

/// A grid from a C-contiguous float32 array `[nz, ny, nx]` (scalar) or `[nz, ny, nx, 3]`.
fn grid_from_array(
    name: &str,
    a: &PyReadonlyArrayDyn<'_, f32>,
    spacing: Vec3,
    origin: Vec3,
) -> PyResult<AnyGrid> {
    let shape = a.shape().to_vec();
    let vector = match shape.len() {
        3 => false,
        4 if shape[3] == 3 => true,
        _ => {
            return Err(BlueshiftError::new_err(format!(
                "array '{name}': shape {shape:?}; expected [nx, ny, nz] or [nx, ny, nz, 3]"
            )));
        }
    };
    let data = crate::c_order(&format!("array '{name}'"), a)?;
    let geometry = Geometry {
        dims: [shape[2], shape[1], shape[0]],
        spacing,
        origin,
    };
    geometry
        .validate()
        .map_err(|e| BlueshiftError::new_err(format!("array '{name}': {e}")))?;
    let bad = |e: blueshift_volume::Error| BlueshiftError::new_err(format!("array '{name}': {e}"));
    Ok(if vector {
        let v: Vec<Vec3> = data
            .chunks_exact(3)
            .map(|c| Vec3::new(c[0], c[1], c[2]))
            .collect();
        AnyGrid::from(Grid::from_vec(geometry, v).map_err(bad)?)
    } else {
        AnyGrid::from(Grid::from_vec(geometry, data.to_vec()).map_err(bad)?)
    })
}

#[pymethods]
impl PyVolume {
    /// Builds a volume from named float32 arrays, each C-contiguous `[nz, ny, nx]` or
    /// `[nz, ny, nx, 3]` (the Python layer's `Volume.from_arrays` takes `[x, y, z]`).
    #[staticmethod]
    #[pyo3(signature = (channels, spacing, origin))]
    fn from_arrays(
        channels: Vec<(String, PyReadonlyArrayDyn<'_, f32>)>,
        spacing: [f64; 3],
        origin: [f64; 3],
    ) -> PyResult<Self> {
        let spacing = vec3("spacing", spacing)?;
        let origin = vec3("origin", origin)?;
        if spacing.min_element() <= 0.0 {
            return Err(BlueshiftError::new_err(format!(
                "spacing {spacing:?}: every component must be > 0"
            )));
        }
        let Some((first, _)) = channels.first() else {
            return Err(BlueshiftError::new_err("a volume needs at least one array"));
        };
        let mut vol: Option<Volume> = None;
        for (name, a) in &channels {
            let grid = grid_from_array(name, a, spacing, origin)?;
            match &mut vol {
                None => {
                    vol =
                        Some(Volume::single(name.clone(), grid).map_err(|e| {
                            BlueshiftError::new_err(format!("array '{first}': {e}"))
                        })?);
                }
                Some(v) => v
                    .push(name.clone(), grid)
                    .map_err(|e| BlueshiftError::new_err(format!("array '{name}': {e}")))?,
            }
        }
        Ok(Self {
            inner: vol.expect("at least one channel"),
        })
    }

    /// Reads a volume file (NRRD/.nhdr, MetaImage, VTK, raw with a header, .bsv).
    #[staticmethod]
    fn read(py: Python<'_>, path: PathBuf) -> PyResult<Self> {
        let inner = run_cancellable(py, |_| blueshift_volume::read(&path).map_err(Fail::err))?;
        Ok(Self { inner })
    }

    /// Voxels per axis, `(nx, ny, nz)`.
    #[getter]
    fn dims(&self) -> (usize, usize, usize) {
        let d = self.inner.geometry().dims;
        (d[0], d[1], d[2])
    }

    /// Voxel spacing, world units.
    #[getter]
    fn spacing(&self) -> (f32, f32, f32) {
        self.inner.geometry().spacing.into()
    }

    /// Centre of voxel (0, 0, 0), world units.
    #[getter]
    fn origin(&self) -> (f32, f32, f32) {
        self.inner.geometry().origin.into()
    }

    /// The channels' names, in order.
    #[getter]
    fn channel_names(&self) -> Vec<String> {
        self.inner
            .channels()
            .iter()
            .map(|c| c.name.clone())
            .collect()
    }

    /// A channel as a float32 array `[nz, ny, nx]` or `[nz, ny, nx, 3]` (a copy).
    fn array<'py>(&self, py: Python<'py>, name: &str) -> PyResult<Bound<'py, PyArrayDyn<f32>>> {
        let ch = self.channel(name)?;
        let [nx, ny, nz] = ch.grid.geometry().dims;
        let (data, shape) = match &ch.grid {
            AnyGrid::Vec3(g) => (
                g.data()
                    .iter()
                    .flat_map(|v| v.to_array())
                    .collect::<Vec<f32>>(),
                vec![nz, ny, nx, 3],
            ),
            other => (other.to_f32_vec(), vec![nz, ny, nx]),
        };
        data.into_pyarray(py).reshape(shape)
    }

    /// Writes one channel as NRRD (`.nhdr` + `.raw` or `.nrrd`), refusing to replace a file.
    fn write_nrrd(&self, py: Python<'_>, name: &str, path: PathBuf) -> PyResult<()> {
        let ch = self.channel(name)?.clone();
        run_cancellable(py, |_| {
            use blueshift_volume::io::nrrd;
            // `.nhdr`: a detached header naming `<stem>.raw` beside it; `.nrrd` attached.
            let ext = path
                .extension()
                .map(|e| e.to_string_lossy().to_ascii_lowercase());
            let detached = match ext.as_deref() {
                Some("nhdr") => true,
                Some("nrrd") => false,
                _ => {
                    return Err(Fail::msg(format!(
                        "{}: write_nrrd writes .nrrd (attached) or .nhdr (with its .raw)",
                        path.display()
                    )));
                }
            };
            let data_path = path.with_extension("raw");
            let targets: Vec<&PathBuf> = if detached {
                vec![&data_path, &path]
            } else {
                vec![&path]
            };
            for t in &targets {
                if t.symlink_metadata().is_ok() {
                    return Err(Fail::msg(format!(
                        "{} exists: blueshift never replaces a file",
                        t.display()
                    )));
                }
            }
            let fail = |e: &dyn std::fmt::Display| Fail::msg(format!("{}: {e}", path.display()));
            let mut files: Vec<Vec<u8>> = Vec::new();
            if detached {
                let (mut header, mut data) = (Vec::new(), Vec::new());
                let name = data_path
                    .file_name()
                    .map(|n| n.to_string_lossy().into_owned())
                    .unwrap_or_default();
                nrrd::write_detached(&mut header, &mut data, &name, &ch, &Default::default())
                    .map_err(|e| fail(&crate::chain(&e)))?;
                files.push(data);
                files.push(header);
            } else {
                let mut b = Vec::new();
                nrrd::write(&mut b, &ch, &Default::default())
                    .map_err(|e| fail(&crate::chain(&e)))?;
                files.push(b);
            }
            // Each file complete before it takes its name, never replacing one
            // (`write_new`); a header that cannot take its name takes its data file with it.
            for (k, (t, bytes)) in targets.iter().zip(&files).enumerate() {
                if let Err(e) = crate::doppler::write_new(t, bytes, false) {
                    for d in &targets[..k] {
                        let _ = std::fs::remove_file(d);
                    }
                    return Err(e);
                }
            }
            Ok(())
        })
    }

    fn __repr__(&self) -> String {
        let g = self.inner.geometry();
        format!(
            "Volume(dims={:?}, spacing={:?}, origin={:?}, channels={:?})",
            g.dims,
            g.spacing.to_array(),
            g.origin.to_array(),
            self.channel_names()
        )
    }
}

impl PyVolume {
    fn channel(&self, name: &str) -> PyResult<&Channel> {
        self.inner.channel(name).ok_or_else(|| {
            BlueshiftError::new_err(format!(
                "no channel '{name}' (the volume has {:?})",
                self.channel_names()
            ))
        })
    }
}

/// A transfer function: colour and opacity knots over a data domain, on a linear or
/// logarithmic data axis, with the HDR VolVis global opacity alpha_g.
#[pyclass(module = "blueshift._native", name = "TransferFunction", frozen)]
#[derive(Clone)]
pub(crate) struct PyTransferFunction {
    pub(crate) inner: TransferFunction,
}

fn tf_err(e: blueshift_tfedit::Error) -> PyErr {
    BlueshiftError::new_err(crate::chain(&e))
}

#[pymethods]
impl PyTransferFunction {
    /// A built-in map (`blueshift tf --list`), over `domain` (default its own, [0, 1]).
    #[staticmethod]
    #[pyo3(signature = (name, domain=None))]
    fn builtin(name: &str, domain: Option<[f64; 2]>) -> PyResult<Self> {
        let inner = match domain {
            Some(d) => blueshift_tfedit::builtin_over(name, d),
            None => blueshift_tfedit::builtin(name),
        }
        .map_err(tf_err)?;
        Ok(Self { inner })
    }

    /// Reads a blueshift JSON or ParaView preset file.
    #[staticmethod]
    fn load(path: PathBuf) -> PyResult<Self> {
        Ok(Self {
            inner: blueshift_tfedit::load(&path)
                .map_err(|e| BlueshiftError::new_err(format!("{}: {e}", path.display())))?,
        })
    }

    /// Parses blueshift JSON or a ParaView preset.
    #[staticmethod]
    fn from_json(text: &str) -> PyResult<Self> {
        Ok(Self {
            inner: blueshift_tfedit::parse_any(text).map_err(tf_err)?.0,
        })
    }

    /// From knots: colour `(x, r, g, b)` rows and opacity `(x, alpha)` rows in data units.
    #[staticmethod]
    #[pyo3(signature = (domain, color, opacity, log=false, alpha_g=1.0, name=None))]
    fn from_knots(
        domain: [f64; 2],
        color: Vec<[f64; 4]>,
        opacity: Vec<[f64; 2]>,
        log: bool,
        alpha_g: f32,
        name: Option<String>,
    ) -> PyResult<Self> {
        let color: Vec<ColorKnot> = color
            .iter()
            .map(|k| ColorKnot {
                x: k[0],
                rgb: [k[1] as f32, k[2] as f32, k[3] as f32],
            })
            .collect();
        let opacity: Vec<OpacityKnot> = opacity
            .iter()
            .map(|k| OpacityKnot::new(k[0], k[1] as f32))
            .collect();
        let mut tf = TransferFunction::new(domain, color, opacity).map_err(tf_err)?;
        if log {
            tf = tf.with_data_axis(DataAxis::Log).map_err(tf_err)?;
        }
        tf = tf.with_alpha_g(alpha_g).map_err(tf_err)?;
        if let Some(n) = name {
            tf = tf.with_name(n);
        }
        Ok(Self { inner: tf })
    }

    /// The blueshift JSON of this transfer function.
    fn to_json(&self) -> String {
        self.inner.to_json_string()
    }

    /// The data domain `(lo, hi)`.
    #[getter]
    fn domain(&self) -> (f64, f64) {
        let d = self.inner.domain();
        (d[0], d[1])
    }

    /// The name.
    #[getter]
    fn name(&self) -> String {
        self.inner.name().to_owned()
    }

    /// Whether the data axis is logarithmic.
    #[getter]
    fn log(&self) -> bool {
        self.inner.data_axis() == DataAxis::Log
    }

    /// The global opacity alpha_g.
    #[getter]
    fn alpha_g(&self) -> f32 {
        self.inner.alpha_g()
    }

    /// The same knots stretched over a new domain.
    fn rescaled(&self, lo: f64, hi: f64) -> PyResult<Self> {
        Ok(Self {
            inner: self.inner.rescaled([lo, hi]).map_err(tf_err)?,
        })
    }

    /// The same with another alpha_g.
    fn with_alpha_g(&self, alpha_g: f32) -> PyResult<Self> {
        Ok(Self {
            inner: self.inner.clone().with_alpha_g(alpha_g).map_err(tf_err)?,
        })
    }

    /// RGBA at each value (float32 `[n, 4]`; opacity with alpha_g applied).
    fn eval<'py>(
        &self,
        py: Python<'py>,
        values: PyReadonlyArray1<'_, f64>,
    ) -> Bound<'py, PyArray2<f32>> {
        let v: ArrayView1<f64> = values.as_array();
        let mut out = Array2::<f32>::zeros((v.len(), 4));
        for (i, &x) in v.iter().enumerate() {
            let c = self.inner.eval(x);
            for k in 0..4 {
                out[[i, k]] = c[k];
            }
        }
        PyArray2::from_owned_array(py, out)
    }

    /// A lookup table of `entries` RGBA rows over the domain (float32 `[entries, 4]`).
    fn lut<'py>(&self, py: Python<'py>, entries: usize) -> PyResult<Bound<'py, PyArray2<f32>>> {
        let lut = self.inner.lut(entries).map_err(tf_err)?;
        lut.into_rgba().into_pyarray(py).reshape([entries, 4])
    }

    fn __repr__(&self) -> String {
        let d = self.inner.domain();
        format!(
            "TransferFunction(name={:?}, domain=({}, {}), log={}, alpha_g={}, color_knots={}, opacity_knots={})",
            self.inner.name(),
            d[0],
            d[1],
            self.log(),
            self.inner.alpha_g(),
            self.inner.color_knots().len(),
            self.inner.opacity_knots().len()
        )
    }
}

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyVolume>()?;
    m.add_class::<PyTransferFunction>()?;
    Ok(())
}
