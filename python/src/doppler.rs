//! Doppler scenes from scene-file JSON whose fields may name in-memory volumes: images,
//! picked spectra, traces and spectral cubes, with the settings of `blueshift doppler`.

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};

use blueshift_camera::{Camera, CancelToken, Observer, View};
use blueshift_doppler::{
    Broadening, ColourMatrix, CubeLineWidth, CubeMeta, CubeSpec, DisplayOptions, DopplerImage,
    DopplerScene, DopplerSession, DopplerSettings, Exposure, FitsValue, MemoryVolumes, SceneFile,
    SpectralAxis, SpectralCube, SpectralIntegrator,
};
use blueshift_gpu::DeviceChoice;
use blueshift_gpu::doppler::DopplerPrecision;
use blueshift_spectrum::{DopplerModel, PiecewiseLinear};
use glam::Vec3;
use numpy::prelude::*;
use numpy::{IntoPyArray, PyArray2, PyArray3};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};
use serde::Deserialize;

use crate::volume::PyVolume;
use crate::{BlueshiftError, Fail, fail, options, run_cancellable};

/// The keyword options of a render, a pick, a trace or a cube: `blueshift doppler`'s flags
/// by their Python names, with the CLI's defaults.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct Opts {
    width: Option<u32>,
    height: Option<u32>,
    integrator: Option<String>,
    doppler: Option<String>,
    invariant: Option<bool>,
    merge_tol: Option<f64>,
    piece_budget: Option<usize>,
    step: Option<f32>,
    line_width: Option<f64>,
    inclination: Option<f32>,
    axis: Option<String>,
    normal: Option<[f32; 3]>,
    cell_domain: Option<bool>,
    view: Option<String>,
    fov: Option<f32>,
    eye: Option<[f32; 3]>,
    target: Option<[f32; 3]>,
    up: Option<[f32; 3]>,
    zoom: Option<f32>,
    /// The orthographic view's height, world units (yt's camera width).
    ortho_height: Option<f32>,
    thermal: Option<bool>,
    /// km/s.
    line_sigma: Option<f64>,
    masses: Option<BTreeMap<String, f64>>,
    /// `cpu`, `gpu` or `auto` (images only; picks, traces and cubes run on the CPU).
    device: Option<String>,
    /// `auto`, `f32` or `f64` on the GPU.
    gpu_precision: Option<String>,
    /// A moving observer (`doppler --observer-velocity`): beta_x, beta_y, beta_z.
    observer_velocity: Option<[f64; 3]>,
    /// The observer's speed along `direction` (`--beta`).
    beta: Option<f64>,
    /// The direction of `beta` (`--direction`; default: the view direction).
    direction: Option<[f64; 3]>,
    // Display.
    matrix: Option<String>,
    exposure_scale: Option<String>,
    exposure: Option<f64>,
}

impl Opts {
    /// The settings `blueshift doppler` makes from the same flags (in its order: the
    /// integrator and model, the inclination, the cube's view, the camera flags).
    pub(crate) fn settings(&self, scene: &DopplerScene) -> Result<DopplerSettings, Fail> {
        let (w, h) = (self.width.unwrap_or(256), self.height.unwrap_or(256));
        let mut st = DopplerSettings::default_for(scene, w, h);
        st.integrator = self
            .integrator
            .as_deref()
            .unwrap_or("pwl")
            .parse::<SpectralIntegrator>()
            .map_err(Fail::err)?;
        let model = self.doppler.as_deref().unwrap_or("classical");
        st.model = model.parse::<DopplerModel>().map_err(|_| {
            Fail::msg(format!(
                "doppler '{model}': one of {}",
                DopplerModel::NAMES.join(", ")
            ))
        })?;
        st.invariant = self.invariant.unwrap_or(false);
        if let Some(i) = self.inclination.filter(|i| *i != 0.0) {
            st.incline(scene, i)
                .map_err(|e| Fail::msg(format!("inclination: {e}")))?;
        }
        st.merge_tolerance = self.merge_tol.unwrap_or(1e-4);
        st.piece_budget = self.piece_budget.unwrap_or(4096);
        st.step = self.step;
        st.line_width_nm = self.line_width.unwrap_or(1.0);
        // The cube's view: cell domain, axis or normal.
        st.cell_domain = self.cell_domain.unwrap_or(false);
        let aspect = st.width as f32 / st.height.max(1) as f32;
        let normal = match (&self.axis, self.normal) {
            (Some(_), Some(_)) => return Err(Fail::msg("give axis or normal, not both")),
            (Some(a), None) => Some(match a.trim().to_ascii_lowercase().as_str() {
                "x" => Vec3::X,
                "y" => Vec3::Y,
                "z" => Vec3::Z,
                other => return Err(Fail::msg(format!("unknown axis '{other}' (x, y, z)"))),
            }),
            (None, Some(n)) => Some(Vec3::from(n)),
            (None, None) => None,
        };
        if let Some(n) = normal {
            st.camera = blueshift_doppler::los_camera(scene, n, aspect, st.cell_domain)
                .map_err(Fail::err)?;
        }
        // The camera flags.
        if let Some(v) = &self.view {
            if normal.is_some() || self.inclination.is_some_and(|i| i != 0.0) {
                return Err(Fail::msg("give one of view, axis, normal and inclination"));
            }
            let view = v.parse::<View>().map_err(Fail::err)?;
            st.camera = blueshift_doppler::los_camera(scene, view.normal(), aspect, st.cell_domain)
                .map_err(Fail::err)?;
        }
        if let Some(fov) = self.fov {
            let (lo, hi) = scene.frame_bounds(false);
            let back = st.camera.eye - st.camera.target;
            st.camera = Camera::framing(lo, hi, back, st.camera.up, aspect, false, fov)
                .map_err(|e| Fail::msg(format!("fov: {e}")))?;
        }
        let mut cam = st.camera.with_overrides(
            self.eye.map(Vec3::from),
            self.target.map(Vec3::from),
            self.up.map(Vec3::from),
        );
        if let Some(z) = self.zoom {
            cam = cam.zoomed(z).map_err(Fail::err)?;
        }
        if let Some(h) = self.ortho_height {
            cam.projection = blueshift_camera::Projection::Orthographic { height: h };
        }
        cam.validate()
            .map_err(|e| Fail::msg(format!("eye/target/up: {e}")))?;
        st.camera = cam;
        st.broadening = self.broadening()?;
        st.observer = self.observer(&st)?;
        Ok(st)
    }

    /// The moving observer of `observer_velocity`, or `beta` along `direction` (default the
    /// view direction), as `blueshift doppler` makes it; the searchlight follows `invariant`.
    fn observer(
        &self,
        st: &DopplerSettings,
    ) -> Result<Option<blueshift_relativity::MovingObserver>, Fail> {
        use blueshift_relativity::{MovingObserver, Velocity};
        let velocity = match (self.observer_velocity, self.beta) {
            (Some(_), Some(_)) => {
                return Err(Fail::msg("give observer_velocity or beta, not both"));
            }
            (Some(b), None) => Velocity::new(glam::DVec3::from_array(b))
                .map_err(|e| Fail::msg(format!("observer_velocity: {e}")))?,
            (None, Some(b)) => {
                let d = match self.direction {
                    Some(d) => glam::DVec3::from_array(d),
                    None => (st.camera.target - st.camera.eye).as_dvec3(),
                };
                Velocity::along(d, b).map_err(|e| Fail::msg(format!("beta {b}: {e}")))?
            }
            (None, None) if self.direction.is_some() => {
                return Err(Fail::msg("direction needs beta"));
            }
            (None, None) => return Ok(None),
        };
        Ok(Some(MovingObserver {
            velocity,
            searchlight: st.invariant,
        }))
    }

    fn broadening(&self) -> Result<Broadening, Fail> {
        let sigma = self.line_sigma.unwrap_or(0.0);
        if !(sigma.is_finite() && sigma >= 0.0) {
            return Err(Fail::msg(format!(
                "line_sigma {sigma} must be finite and >= 0"
            )));
        }
        let mut masses = Vec::new();
        for (n, &m) in self.masses.iter().flatten() {
            if !(m.is_finite() && m > 0.0) {
                return Err(Fail::msg(format!(
                    "masses['{n}'] = {m} must be finite and > 0"
                )));
            }
            masses.push((n.clone(), m));
        }
        Ok(Broadening {
            thermal: self.thermal.unwrap_or(false),
            sigma_m_per_s: sigma * 1e3,
            masses_amu: masses,
        })
    }

    /// The display mapping (`matrix`, `exposure_scale`) with `exposure` stops over it.
    fn display(&self, img: &DopplerImage) -> Result<DisplayOptions, Fail> {
        let m = self.matrix.as_deref().unwrap_or("srgb");
        let matrix = m.parse::<ColourMatrix>().map_err(|_| {
            Fail::msg(format!(
                "matrix '{m}': one of {}",
                ColourMatrix::NAMES.join(", ")
            ))
        })?;
        let exposure = match &self.exposure_scale {
            None => Exposure::Percentile(99.0),
            Some(e) => e.parse::<Exposure>().map_err(Fail::err)?,
        };
        let stops = self.exposure.unwrap_or(0.0);
        if !stops.is_finite() {
            return Err(Fail::msg("exposure: expected a finite number of stops"));
        }
        if exposure == Exposure::PerPixel && stops != 0.0 {
            return Err(Fail::msg(
                "exposure: per-pixel scaling maps every pixel to Y = 1; stops do not apply",
            ));
        }
        Ok(DisplayOptions { matrix, exposure }.with_stops(stops, img))
    }
}

/// A Doppler scene: species, black body, temperature and velocity on one grid.
#[pyclass(module = "blueshift._native", name = "DopplerScene", frozen)]
pub(crate) struct PyDopplerScene {
    pub(crate) scene: DopplerScene,
}

/// A spectrum's pieces and the wavelength range.
type Pieces<'py> = (Bound<'py, PyArray2<f64>>, (f64, f64));

struct Cancel<'a>(&'a CancelToken);

impl Observer<DopplerImage> for Cancel<'_> {
    fn cancelled(&self) -> bool {
        self.0.is_cancelled()
    }
}

pub(crate) fn pieces_array<'py>(
    py: Python<'py>,
    s: &PiecewiseLinear,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let flat: Vec<f64> = s
        .pieces()
        .flat_map(|p| [p.start_nm, p.end_nm, p.value_start, p.value_end])
        .collect();
    let n = flat.len() / 4;
    flat.into_pyarray(py).reshape([n, 4])
}

impl PyDopplerScene {
    fn session(&self, opts: &Opts) -> Result<DopplerSession, Fail> {
        let st = opts.settings(&self.scene)?;
        let mut s = DopplerSession::new(self.scene.clone(), st).map_err(Fail::err)?;
        s.set_keep_samples(false);
        Ok(s)
    }

    fn check_pixel(x: u32, y: u32, s: &DopplerSettings) -> Result<(), Fail> {
        if x >= s.width || y >= s.height {
            return Err(Fail::msg(format!(
                "pixel {x},{y} is outside the {}x{} image",
                s.width, s.height
            )));
        }
        Ok(())
    }
}

#[pymethods]
impl PyDopplerScene {
    /// Loads a scene from scene-file JSON (`base`: the folder its relative paths start
    /// from); a field's `"file"` naming a key of `volumes` takes that volume.
    #[new]
    #[pyo3(signature = (scene_json, base=None, volumes=HashMap::new(), select=None))]
    fn new(
        py: Python<'_>,
        scene_json: &str,
        base: Option<PathBuf>,
        volumes: HashMap<String, PyRef<'_, PyVolume>>,
        select: Option<Vec<String>>,
    ) -> PyResult<Self> {
        let base = base.unwrap_or_else(|| PathBuf::from("."));
        let file = SceneFile::parse(scene_json, &base)
            .map_err(|e| BlueshiftError::new_err(crate::chain(&e)))?;
        let memory: MemoryVolumes = volumes
            .into_iter()
            .map(|(k, v)| (k, v.inner.clone()))
            .collect();
        let scene = run_cancellable(py, |_| {
            let sel: Option<Vec<&str>> = select
                .as_ref()
                .map(|v| v.iter().map(String::as_str).collect());
            file.load_with(sel.as_deref(), &memory).map_err(Fail::err)
        })?;
        Ok(Self { scene })
    }

    /// Reads a scene file; its `.bsv` fields are read out of core through one brick cache
    /// of `cache_mb` MiB (default: a quarter of physical memory).
    #[staticmethod]
    #[pyo3(signature = (path, select=None, cache_mb=None))]
    fn read(
        py: Python<'_>,
        path: PathBuf,
        select: Option<Vec<String>>,
        cache_mb: Option<u64>,
    ) -> PyResult<Self> {
        let cache = match cache_mb {
            Some(0) => return Err(BlueshiftError::new_err("cache_mb must be at least 1")),
            Some(mb) => usize::try_from(mb.saturating_mul(1 << 20)).unwrap_or(usize::MAX),
            None => blueshift_volume::cache::default_budget(),
        };
        let scene = run_cancellable(py, |_| {
            let file = SceneFile::read(&path).map_err(Fail::err)?;
            let sel: Option<Vec<&str>> = select
                .as_ref()
                .map(|v| v.iter().map(String::as_str).collect());
            file.load_out_of_core(
                sel.as_deref(),
                &MemoryVolumes::new(),
                Some(blueshift_volume::BrickCache::new(cache)),
            )
            .map_err(Fail::err)
        })?;
        Ok(Self { scene })
    }

    /// Voxels per axis of every level of detail, finest first, when every field is a `.bsv`
    /// file (bricked alike); `None` for a scene in memory.
    #[getter]
    fn levels(&self) -> Option<Vec<(usize, usize, usize)>> {
        self.scene.levels().map(|g| {
            g.iter()
                .map(|g| (g.dims[0], g.dims[1], g.dims[2]))
                .collect()
        })
    }

    /// The same scene sampled at level of detail `level` (0: this, the finest).
    fn at_level(&self, level: usize) -> PyResult<Self> {
        let scene = self
            .scene
            .at_level(level)
            .map_err(|e| BlueshiftError::new_err(crate::chain(&e)))?;
        Ok(Self { scene })
    }

    /// Voxels per axis `(nx, ny, nz)`.
    #[getter]
    fn dims(&self) -> (usize, usize, usize) {
        let d = self.scene.geometry().dims;
        (d[0], d[1], d[2])
    }

    /// The species' names.
    #[getter]
    fn species(&self) -> Vec<String> {
        self.scene
            .species()
            .iter()
            .map(|s| s.name.clone())
            .collect()
    }

    /// Whether the scene has a black body.
    #[getter]
    fn has_blackbody(&self) -> bool {
        self.scene.blackbody().is_some()
    }

    /// Renders: `{"xyz": float64 [h, w, 3], "rgb8": uint8 [h, w, 3], "pieces": {...},
    /// "device": "cpu" | "gpu", "fallback": why auto stayed on the CPU}`, on the device
    /// `blueshift doppler --device` names, with its fallback rule.
    fn render<'py>(&self, py: Python<'py>, opts: &str) -> PyResult<Bound<'py, PyDict>> {
        let o: Opts = options("render", opts)?;
        let choice: DeviceChoice = o
            .device
            .as_deref()
            .unwrap_or("cpu")
            .parse()
            .map_err(|e: String| BlueshiftError::new_err(format!("device: {e}")))?;
        let precision: DopplerPrecision = o
            .gpu_precision
            .as_deref()
            .unwrap_or("auto")
            .parse()
            .map_err(|e| BlueshiftError::new_err(format!("gpu_precision: {e}")))?;
        let (img, rgb, ran_on, fallback) = run_cancellable(py, |token| {
            let (w, h) = (o.width.unwrap_or(256), o.height.unwrap_or(256));
            crate::budget()?
                .check(format_args!("this image ({w}x{h})"), image_bytes(w, h))
                .map_err(Fail::err)?;
            let s = self.session(&o)?;
            let (scene, st) = (s.scene(), s.settings());
            // A precision the adapter lacks is the caller's error, as in the CLI.
            if let Some(ctx) = choice.context()?
                && blueshift_gpu::doppler::supports(scene, st).is_ok()
            {
                precision.is_double_on(ctx)?;
            }
            let ran = blueshift_gpu::run_with_fallback(
                choice,
                || blueshift_gpu::doppler::supports(scene, st),
                |ctx| blueshift_gpu::doppler::render_doppler_gpu_with(ctx, scene, st, precision),
                || s.render(&Cancel(token)).map_err(|e| fail(token)(&e)),
            )?;
            let img = ran.value;
            let disp = o.display(&img)?;
            let rgb = disp.to_rgb8(&img);
            Ok((img, rgb, ran.device, ran.fallback))
        })?;
        let (w, h) = (img.width as usize, img.height as usize);
        let d = PyDict::new(py);
        let xyz: Vec<f64> = img.xyz.iter().flatten().copied().collect();
        let xyz: Bound<'py, PyArray3<f64>> = xyz.into_pyarray(py).reshape([h, w, 3])?;
        let rgb: Bound<'py, PyArray3<u8>> = rgb.into_pyarray(py).reshape([h, w, 3])?;
        d.set_item("xyz", xyz)?;
        d.set_item("rgb8", rgb)?;
        let p = PyDict::new(py);
        p.set_item("mean", img.pieces.mean)?;
        p.set_item("max", img.pieces.max)?;
        p.set_item("fallback_rays", img.pieces.fallback_rays)?;
        d.set_item("pieces", p)?;
        d.set_item("device", ran_on.to_string())?;
        d.set_item("fallback", fallback)?;
        Ok(d)
    }

    /// The spectrum reaching pixel (x, y): its pieces, float64 `[n, 4]` rows of
    /// `(start_nm, end_nm, value_start, value_end)`, and the wavelength range.
    fn spectrum<'py>(&self, py: Python<'py>, x: u32, y: u32, opts: &str) -> PyResult<Pieces<'py>> {
        let o: Opts = options("spectrum", opts)?;
        let (s, range) = run_cancellable(py, |_| {
            let session = self.session(&o)?;
            Self::check_pixel(x, y, session.settings())?;
            let s = session.pixel_spectrum(x, y).map_err(Fail::err)?;
            Ok((s, session.settings().range_nm))
        })?;
        Ok((pieces_array(py, &s)?, range))
    }

    /// The ray of pixel (x, y) step by step: a list of `(t, radial_velocity_m_per_s,
    /// pieces)`, the spectrum after each segment, front last.
    fn trace<'py>(
        &self,
        py: Python<'py>,
        x: u32,
        y: u32,
        opts: &str,
    ) -> PyResult<(Bound<'py, PyList>, (f64, f64))> {
        let o: Opts = options("trace", opts)?;
        let (steps, range) = run_cancellable(py, |_| {
            let session = self.session(&o)?;
            Self::check_pixel(x, y, session.settings())?;
            let steps = session.trace(x, y).map_err(Fail::err)?;
            Ok((steps, session.settings().range_nm))
        })?;
        let list = PyList::empty(py);
        for s in &steps {
            list.append((
                s.t,
                s.radial_velocity_m_per_s,
                pieces_array(py, &s.spectrum)?,
            ))?;
        }
        Ok((list, range))
    }

    /// A spectral cube of one line: `cube_json` holds `line` (name or nm), `velocity_bins`
    /// `[vmin_kms, vmax_kms, n]` or `wavelength_bins` `[min_nm, max_nm, n]`, `spectral_axis`.
    fn cube(&self, py: Python<'_>, opts: &str, cube_json: &str) -> PyResult<PyCube> {
        let o: Opts = options("cube", opts)?;
        let c: CubeOpts = options("cube", cube_json)?;
        let (cube, meta) = run_cancellable(py, |token| {
            let spec = c.spec()?;
            // The cube (f32) and its FITS bytes, with the image's own memory.
            let (w, h) = (o.width.unwrap_or(256), o.height.unwrap_or(256));
            let values = blueshift_volume::budget::image_bytes(
                w.into(),
                h.into(),
                (spec.channels as u64).saturating_mul(8),
            );
            crate::budget()?
                .check(
                    format_args!("this cube ({w}x{h}x{} channels)", spec.channels),
                    values.saturating_add(image_bytes(w, h)),
                )
                .map_err(Fail::err)?;
            let session = self.session(&o)?;
            spec.validate(session.settings().range_nm)
                .map_err(Fail::err)?;
            let cube = session
                .cube(&spec, &Cancel(token))
                .map_err(|e| fail(token)(&e))?;
            Ok((cube, c.meta()?))
        })?;
        Ok(PyCube { cube, meta })
    }
}

/// Bytes a `w` x `h` Doppler image holds: its XYZ (f64), display RGB (f32) and sRGB bytes,
/// rounded up (the CLI's estimate).
fn image_bytes(w: u32, h: u32) -> u64 {
    blueshift_volume::budget::image_bytes(w.into(), h.into(), 64)
}

/// The cube's channels and labels.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct CubeOpts {
    line: LineName,
    velocity_bins: Option<(f64, f64, usize)>,
    wavelength_bins: Option<(f64, f64, usize)>,
    spectral_axis: Option<String>,
    bunit: Option<String>,
    /// `(unit, scale)`: one world length is `scale` `unit`.
    world_unit: Option<(String, f64)>,
    object: Option<String>,
}

#[derive(Debug, Deserialize)]
#[serde(untagged)]
enum LineName {
    Nm(f64),
    Name(String),
}

fn bins(what: &str, (a, b, n): (f64, f64, usize)) -> Result<(f64, f64, usize), Fail> {
    if !(a.is_finite() && b.is_finite()) || a >= b {
        return Err(Fail::msg(format!(
            "{what} ({a}, {b}, {n}): the range is empty (min must be below max)"
        )));
    }
    if n == 0 {
        return Err(Fail::msg(format!("{what}: zero channels")));
    }
    Ok((a, b, n))
}

impl CubeOpts {
    fn spec(&self) -> Result<CubeSpec, Fail> {
        let rest_nm = match &self.line {
            LineName::Nm(v) if v.is_finite() && *v > 0.0 => *v,
            LineName::Nm(v) => {
                return Err(Fail::msg(format!(
                    "line {v}: a wavelength must be finite and > 0 nm"
                )));
            }
            LineName::Name(n) => match n.trim().parse::<f64>() {
                Ok(v) if v.is_finite() && v > 0.0 => v,
                _ => {
                    blueshift_spectrum::named_line(n)
                        .map_err(Fail::err)?
                        .line
                        .centre_nm
                }
            },
        };
        let line_width = CubeLineWidth::OneChannel;
        match (self.velocity_bins, self.wavelength_bins) {
            (Some(_), Some(_)) => Err(Fail::msg("give velocity_bins or wavelength_bins, not both")),
            (Some(v), None) => {
                let (a, b, n) = bins("velocity_bins", v)?;
                let axis: SpectralAxis = self
                    .spectral_axis
                    .as_deref()
                    .unwrap_or("vrad")
                    .parse()
                    .map_err(Fail::err)?;
                if axis == SpectralAxis::Wavelength {
                    return Err(Fail::msg("spectral_axis wave needs wavelength_bins"));
                }
                Ok(CubeSpec {
                    rest_nm,
                    axis,
                    min: a * 1e3,
                    max: b * 1e3,
                    channels: n,
                    line_width,
                })
            }
            (None, Some(w)) => {
                let (a, b, n) = bins("wavelength_bins", w)?;
                Ok(CubeSpec {
                    rest_nm,
                    axis: SpectralAxis::Wavelength,
                    min: a,
                    max: b,
                    channels: n,
                    line_width,
                })
            }
            (None, None) => Err(Fail::msg(
                "a cube needs velocity_bins (vmin_kms, vmax_kms, n) or wavelength_bins",
            )),
        }
    }

    fn meta(&self) -> Result<CubeMeta, Fail> {
        if let Some((_, k)) = &self.world_unit
            && !(k.is_finite() && *k > 0.0)
        {
            return Err(Fail::msg(format!(
                "world_unit scale {k} must be finite and > 0"
            )));
        }
        Ok(CubeMeta {
            bunit: self.bunit.clone().unwrap_or_default(),
            object: self.object.clone().unwrap_or_default(),
            world_unit: self.world_unit.clone(),
        })
    }
}

/// A position-position-velocity cube.
#[pyclass(module = "blueshift._native", name = "Cube", frozen)]
pub(crate) struct PyCube {
    cube: SpectralCube,
    meta: CubeMeta,
}

#[pymethods]
impl PyCube {
    /// The values, float32 `[channel, y, x]` with y = 0 at the bottom (FITS order).
    fn data<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray3<f32>>> {
        let c = &self.cube;
        c.data
            .clone()
            .into_pyarray(py)
            .reshape([c.spec.channels, c.ny, c.nx])
    }

    /// Channel centres in the axis' unit (m/s for velocity axes, nm for wavelength).
    fn centres(&self) -> Vec<f64> {
        (0..self.cube.spec.channels)
            .map(|k| self.cube.spec.centre(k))
            .collect()
    }

    /// Channel centres as wavelengths, nm.
    fn centres_nm(&self) -> Vec<f64> {
        let s = &self.cube.spec;
        (0..s.channels)
            .map(|k| 0.5 * (s.edge_nm(k) + s.edge_nm(k + 1)))
            .collect()
    }

    /// The axis: `VRAD`, `VOPT` or `WAVE`.
    #[getter]
    fn ctype(&self) -> &'static str {
        self.cube.spec.axis.ctype()
    }

    /// Pixel size, world units.
    #[getter]
    fn pixel_world(&self) -> (f64, f64) {
        self.cube.pixel_world
    }

    /// Moment maps 0, 1 and 2, each float32 `[y, x]` with y = 0 at the bottom.
    fn moments<'py>(&self, py: Python<'py>) -> PyResult<[Bound<'py, PyArray2<f32>>; 3]> {
        let m = self.cube.moments();
        let (nx, ny) = (m.nx, m.ny);
        Ok([
            m.m0.into_pyarray(py).reshape([ny, nx])?,
            m.m1.into_pyarray(py).reshape([ny, nx])?,
            m.m2.into_pyarray(py).reshape([ny, nx])?,
        ])
    }

    /// The FITS file's bytes.
    fn fits_bytes<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, pyo3::types::PyBytes>> {
        let b = blueshift_doppler::fits_bytes(&self.cube, &self.meta)
            .map_err(|e| BlueshiftError::new_err(crate::chain(&e)))?;
        Ok(pyo3::types::PyBytes::new(py, &b))
    }

    /// The FITS header's valued cards in file order, as `(key, value)` pairs.
    fn header(&self) -> PyResult<Vec<(String, Py<PyAny>)>> {
        let b = blueshift_doppler::fits_bytes(&self.cube, &self.meta)
            .map_err(|e| BlueshiftError::new_err(crate::chain(&e)))?;
        let h = blueshift_doppler::read_fits(&b)
            .map_err(|e| BlueshiftError::new_err(crate::chain(&e)))?;
        Python::attach(|py| {
            h.cards
                .into_iter()
                .map(|(k, v)| {
                    let o: Py<PyAny> = match v {
                        FitsValue::Logical(b) => {
                            b.into_pyobject(py)?.to_owned().into_any().unbind()
                        }
                        FitsValue::Integer(i) => i.into_pyobject(py)?.into_any().unbind(),
                        FitsValue::Real(r) => r.into_pyobject(py)?.into_any().unbind(),
                        FitsValue::Text(t) => t.into_pyobject(py)?.into_any().unbind(),
                    };
                    Ok((k, o))
                })
                .collect()
        })
    }

    /// Writes the FITS file (atomically; an existing file is replaced only with
    /// `overwrite=True`).
    #[pyo3(signature = (path, overwrite=false))]
    fn to_fits(&self, py: Python<'_>, path: PathBuf, overwrite: bool) -> PyResult<()> {
        let b = blueshift_doppler::fits_bytes(&self.cube, &self.meta)
            .map_err(|e| BlueshiftError::new_err(crate::chain(&e)))?;
        run_cancellable(py, |_| write_new(&path, &b, overwrite))
    }
}

/// Writes `bytes` to `path` through a temporary file in the same folder (readers never
/// see half a file), named `.blueshift-<pid>-<random>.partial` as the CLI's (so `blueshift
/// clean` finds one a killed process left) and with the mode a new file gets (0666 less the
/// umask); an existing `path` is kept unless `overwrite`. An existing non-regular file (a
/// FIFO, `/dev/null`) is written into with `overwrite`, never replaced.
pub(crate) fn write_new(path: &Path, bytes: &[u8], overwrite: bool) -> Result<(), Fail> {
    use std::io::Write as _;
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    let shown = path.display();
    let err = |e: std::io::Error| Fail::msg(format!("cannot write {shown}: {e}"));
    if path.is_dir() {
        return Err(Fail::msg(format!(
            "cannot write {shown}: it is a folder (give a file name)"
        )));
    }
    if let Ok(m) = std::fs::metadata(path) {
        if !overwrite {
            return Err(Fail::msg(format!(
                "{shown} exists (pass overwrite=True to replace it)"
            )));
        }
        if !m.is_file() {
            // A FIFO without a reader would block the open (and Ctrl-C) forever: probe it
            // without blocking first (ENXIO: no reader), then write through a plain open.
            // The probe stays open until the plain open is made, so a reader never sees
            // the end of the stream in between.
            #[cfg(target_os = "linux")]
            let _probe = {
                use std::os::unix::fs::OpenOptionsExt as _;
                const O_NONBLOCK: i32 = 0o4000;
                const ENXIO: i32 = 6;
                match std::fs::OpenOptions::new()
                    .write(true)
                    .custom_flags(O_NONBLOCK)
                    .open(path)
                {
                    Err(e) if e.raw_os_error() == Some(ENXIO) => {
                        return Err(Fail::msg(format!(
                            "cannot write {shown}: it is a FIFO that no one reads"
                        )));
                    }
                    Err(e) => return Err(err(e)),
                    Ok(f) => f,
                }
            };
            let mut f = std::fs::OpenOptions::new()
                .write(true)
                .open(path)
                .map_err(err)?;
            return f.write_all(bytes).and_then(|()| f.flush()).map_err(err);
        }
    }
    if !dir.is_dir() {
        return Err(Fail::msg(format!(
            "cannot write {shown}: the folder {} does not exist",
            dir.display()
        )));
    }
    let prefix = format!(".blueshift-{}-", std::process::id());
    let mut builder = tempfile::Builder::new();
    builder.prefix(&prefix).suffix(".partial");
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        builder.permissions(std::fs::Permissions::from_mode(0o666));
    }
    let mut tmp = builder.tempfile_in(dir).map_err(err)?;
    tmp.write_all(bytes).map_err(err)?;
    tmp.flush().map_err(err)?;
    if overwrite {
        tmp.persist(path).map_err(|e| err(e.error))?;
    } else {
        tmp.persist_noclobber(path).map_err(|e| err(e.error))?;
    }
    Ok(())
}

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyDopplerScene>()?;
    m.add_class::<PyCube>()?;
    Ok(())
}
