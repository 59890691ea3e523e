//! HDR images: tone mapping, sRGB encoding, reading, and the relativistic observer.

use std::path::PathBuf;

use blueshift_relativity::{Camera as RelCamera, Checker, Effects, Environment, Velocity};
use blueshift_tonemap::{Operator, TonemapSession};
use glam::DVec3;
use image::Rgb32FImage;
use numpy::prelude::*;
use numpy::{IntoPyArray, PyArray3, PyReadonlyArray3};
use pyo3::prelude::*;

use crate::{BlueshiftError, Fail, run_cancellable};

fn err(e: impl std::fmt::Display) -> PyErr {
    BlueshiftError::new_err(e.to_string())
}

/// An RGB image from a C-contiguous float32 `[h, w, 3]` array.
fn rgb_image(name: &str, a: &PyReadonlyArray3<'_, f32>) -> PyResult<Rgb32FImage> {
    let s = a.shape();
    if s[2] != 3 || s[0] == 0 || s[1] == 0 {
        return Err(err(format!(
            "{name}: shape {s:?}; expected [height, width, 3] with at least one pixel"
        )));
    }
    let data = crate::c_order(name, a)?.to_vec();
    Rgb32FImage::from_raw(s[1] as u32, s[0] as u32, data)
        .ok_or_else(|| err(format!("{name}: {}x{} is too large", s[1], s[0])))
}

fn image_array<'py>(py: Python<'py>, img: Rgb32FImage) -> PyResult<Bound<'py, PyArray3<f32>>> {
    let (w, h) = (img.width() as usize, img.height() as usize);
    img.into_raw().into_pyarray(py).reshape([h, w, 3])
}

/// Tone-maps a linear HDR image with an operator given as its serde JSON
/// (`{"Drago": {...}}`): the display-linear result, float32 `[h, w, 3]` (1 the display's
/// white; brighter values clip when encoded).
#[pyfunction]
fn tonemap<'py>(
    py: Python<'py>,
    image: PyReadonlyArray3<'_, f32>,
    operator_json: &str,
) -> PyResult<Bound<'py, PyArray3<f32>>> {
    let op: Operator =
        serde_json::from_str(operator_json).map_err(|e| err(format!("tonemap: {e}")))?;
    op.validate().map_err(err)?;
    let img = rgb_image("image", &image)?;
    let out = run_cancellable(py, |_| {
        let mut s = TonemapSession::new(img, op).map_err(Fail::err)?;
        // `linear` without a white maps the 99th percentile of the lit luminance to 1, as
        // `blueshift tonemap --op linear` does.
        if let Operator::Linear(p) = s.operator()
            && p.white.is_none()
        {
            let mut p = p.clone();
            p.white = blueshift_tonemap::default_linear_white(&s.clean().image);
            s.set_operator(Operator::Linear(p)).map_err(Fail::err)?;
        }
        s.run().map_err(Fail::err)
    })?;
    image_array(py, out)
}

/// The defaults of an operator's parameters as serde JSON (`{"Drago": {...}}`).
#[pyfunction]
fn tonemap_defaults(name: &str) -> PyResult<String> {
    let op = blueshift_view::display::operator(name, 0.0)
        .map_err(err)?
        .ok_or_else(|| err(format!("tonemap: '{name}' has no parameters")))?;
    serde_json::to_string(&op).map_err(err)
}

/// 8-bit sRGB of a display-linear image (values clamped to [0, 1], NaN as 0), as the
/// CLI's PNGs encode it.
#[pyfunction]
fn encode_srgb8<'py>(
    py: Python<'py>,
    display: PyReadonlyArray3<'_, f32>,
) -> PyResult<Bound<'py, PyArray3<u8>>> {
    let s = display.shape().to_vec();
    let v: Vec<u8> = crate::c_order("display", &display)?
        .iter()
        .map(|&c| (blueshift_tonemap::io::srgb_encode(c) * 255.0).round() as u8)
        .collect();
    v.into_pyarray(py).reshape([s[0], s[1], s[2]])
}

/// PNG bytes of an 8-bit RGB image, uint8 `[h, w, 3]` (for `_repr_png_`).
#[pyfunction]
fn png_bytes<'py>(
    py: Python<'py>,
    rgb8: PyReadonlyArray3<'_, u8>,
) -> PyResult<Bound<'py, pyo3::types::PyBytes>> {
    let s = rgb8.shape();
    if s[2] != 3 {
        return Err(err(format!(
            "rgb8: shape {s:?}; expected [height, width, 3]"
        )));
    }
    let data = crate::c_order("rgb8", &rgb8)?.to_vec();
    let img = image::RgbImage::from_raw(s[1] as u32, s[0] as u32, data)
        .ok_or_else(|| err("rgb8: bad size"))?;
    let b = blueshift_view::display::png_bytes(&img).map_err(err)?;
    Ok(pyo3::types::PyBytes::new(py, &b))
}

/// Reads an HDR image (`.exr`, `.hdr`, `.pfm`) as linear float32 `[h, w, 3]`.
#[pyfunction]
fn read_hdr<'py>(py: Python<'py>, path: PathBuf) -> PyResult<Bound<'py, PyArray3<f32>>> {
    let img = run_cancellable(py, |_| {
        blueshift_tonemap::io::read_hdr_image(&path)
            .map_err(|e| Fail::msg(format!("{}: {}", path.display(), crate::chain(&e))))
    })?;
    image_array(py, img)
}

fn dvec(name: &str, v: [f64; 3]) -> PyResult<DVec3> {
    let d = DVec3::from_array(v);
    if !d.is_finite() || d.length() == 0.0 {
        return Err(err(format!(
            "{name} {v:?} must be a finite non-zero vector"
        )));
    }
    Ok(d)
}

/// The view of an observer moving at `beta` (units of c) along `direction`: float32
/// `[h, w, 3]` linear RGB. `env` is a file path, `"checker"`, or an equirectangular float32
/// `[h, w, 3]` array.
#[pyfunction]
#[pyo3(signature = (env, beta, direction, look, up, fov, width, height, effects))]
#[allow(clippy::too_many_arguments)]
fn relativity_render<'py>(
    py: Python<'py>,
    env: &Bound<'py, PyAny>,
    beta: f64,
    direction: [f64; 3],
    look: [f64; 3],
    up: [f64; 3],
    fov: f64,
    width: u32,
    height: u32,
    effects: &str,
) -> PyResult<Bound<'py, PyArray3<f32>>> {
    let effects = Effects::parse(effects).map_err(err)?;
    let cam = RelCamera {
        look: dvec("look", look)?,
        up: dvec("up", up)?,
        fov_y_deg: fov,
        width,
        height,
    };
    blueshift_relativity::CameraFrame::new(&cam).map_err(err)?;
    let v = Velocity::along(dvec("direction", direction)?, beta).map_err(err)?;
    let environment = if let Ok(p) = env.extract::<PathBuf>() {
        if p.as_os_str() == "checker" {
            Environment::Checker(Checker::default())
        } else {
            run_cancellable(py, |_| {
                Environment::load(&p)
                    .map_err(|e| Fail::msg(format!("{}: {}", p.display(), crate::chain(&e))))
            })?
        }
    } else {
        let a: PyReadonlyArray3<'_, f32> = env.extract().map_err(|_| {
            err("env: a path, \"checker\" or a float32 [h, w, 3] equirectangular array")
        })?;
        // By its aspect ratio, as a file is read: a 2:1 equirectangular map, a cube strip or
        // cross; anything else refused rather than stretched over the sphere.
        Environment::from_single_image(rgb_image("env", &a)?).map_err(err)?
    };
    let img = run_cancellable(py, |_| {
        blueshift_relativity::render(&environment, &cam, v, effects, None).map_err(Fail::err)
    })?;
    image_array(py, img)
}

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(tonemap, m)?)?;
    m.add_function(wrap_pyfunction!(tonemap_defaults, m)?)?;
    m.add_function(wrap_pyfunction!(encode_srgb8, m)?)?;
    m.add_function(wrap_pyfunction!(read_hdr, m)?)?;
    m.add_function(wrap_pyfunction!(png_bytes, m)?)?;
    m.add_function(wrap_pyfunction!(relativity_render, m)?)?;
    Ok(())
}
