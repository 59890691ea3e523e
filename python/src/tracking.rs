//! Woodcock, MDWT and marcher renders of scenes given as scene-file JSON whose channels may
//! name in-memory volumes and transfer functions.

use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::Mutex;
use std::sync::mpsc::{Receiver, SyncSender};

use blueshift_camera::{CancelToken, Observer};
use blueshift_gpu::DeviceChoice;
use blueshift_gpu::tracking::GpuTrackingSession;
use blueshift_tracking::{
    Preloaded, Progressive, RenderSceneFile, Scene, TrackingOutput, TrackingSession,
};
use numpy::prelude::*;
use numpy::{IntoPyArray, PyArray2, PyArray3};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::volume::{PyTransferFunction, PyVolume};
use crate::{BlueshiftError, Fail, fail, run_cancellable};

/// A scene file's JSON with its base folder and the in-memory objects it names.
pub(crate) fn scene_file(
    json: &str,
    base: Option<PathBuf>,
    volumes: HashMap<String, PyRef<'_, PyVolume>>,
    tfs: HashMap<String, PyRef<'_, PyTransferFunction>>,
) -> PyResult<(RenderSceneFile, Preloaded)> {
    let mut file: RenderSceneFile =
        serde_json::from_str(json).map_err(|e| BlueshiftError::new_err(format!("scene: {e}")))?;
    file.base = base;
    let memory = Preloaded {
        volumes: volumes
            .into_iter()
            .map(|(k, v)| (k, v.inner.clone()))
            .collect(),
        tfs: tfs.into_iter().map(|(k, v)| (k, v.inner.clone())).collect(),
        cache: None,
        budget: None,
    };
    Ok((file, memory))
}

/// The mean image as float32 `[height, width, 4]` (the buffer moves into the array).
fn mean_array<'py>(py: Python<'py>, acc: &Progressive) -> PyResult<Bound<'py, PyArray3<f32>>> {
    let img = acc.mean_image();
    let (w, h) = (img.width() as usize, img.height() as usize);
    img.into_raw().into_pyarray(py).reshape([h, w, 4])
}

/// The result dict of a render: `image`, `noise`, `spp` and the heat maps asked for.
fn output<'py>(
    py: Python<'py>,
    acc: &Progressive,
    file: &RenderSceneFile,
) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("image", mean_array(py, acc)?)?;
    let noise = acc.noise();
    d.set_item("noise", noise.is_finite().then_some(noise))?;
    d.set_item("spp", acc.samples())?;
    let heat = PyDict::new(py);
    let (w, h) = (
        acc.mean_image().width() as usize,
        acc.mean_image().height() as usize,
    );
    for map in file.heatmaps() {
        if let Some(v) = acc.heatmap(map) {
            let a: Bound<'py, PyArray2<f32>> = v.into_pyarray(py).reshape([h, w])?;
            heat.set_item(map.name(), a)?;
        }
    }
    d.set_item("heatmaps", heat)?;
    Ok(d)
}

/// Builds the session of a scene (files read, majorants built) under the token.
fn session(file: &RenderSceneFile, memory: &Preloaded) -> Result<TrackingSession, Fail> {
    let (scene, integrator, settings): (Scene, _, _) =
        file.build_with(memory).map_err(Fail::err)?;
    TrackingSession::new(scene, integrator, settings).map_err(Fail::err)
}

struct Cancel<'a>(&'a CancelToken);

impl Observer<Progressive> for Cancel<'_> {
    fn cancelled(&self) -> bool {
        self.0.is_cancelled()
    }
}

/// Renders a scene: `{"image", "noise", "spp", "heatmaps", "device", "fallback"}`, on
/// the device `blueshift render --device` names (`cpu`, `gpu`, `auto`) with its fallback
/// rule.
#[pyfunction]
#[pyo3(signature = (scene_json, base=None, volumes=HashMap::new(), tfs=HashMap::new(), device="cpu"))]
fn render_tracking<'py>(
    py: Python<'py>,
    scene_json: &str,
    base: Option<PathBuf>,
    volumes: HashMap<String, PyRef<'_, PyVolume>>,
    tfs: HashMap<String, PyRef<'_, PyTransferFunction>>,
    device: &str,
) -> PyResult<Bound<'py, PyDict>> {
    let choice: DeviceChoice = device
        .parse()
        .map_err(|e: String| BlueshiftError::new_err(format!("device: {e}")))?;
    let (file, memory) = scene_file(scene_json, base, volumes, tfs)?;
    let ran = run_cancellable(py, |token| {
        let (scene, integrator, settings) = file.build_with(&memory).map_err(Fail::err)?;
        let supported = blueshift_gpu::tracking::supports(&scene, &settings);
        // `gpu` hands the scene to the device; `auto` keeps it for the CPU in case the
        // adapter cannot run this render (as `blueshift render` does).
        let slot = std::cell::RefCell::new(Some(scene));
        let ran = blueshift_gpu::run_with_fallback(
            choice,
            || supported.clone(),
            |ctx| {
                let scene = match choice {
                    DeviceChoice::Auto => slot.borrow().clone(),
                    _ => slot.borrow_mut().take(),
                }
                .ok_or_else(|| blueshift_gpu::Error::InvalidInput("no scene".into()))?;
                GpuTrackingSession::new(ctx, scene, integrator.clone(), settings.clone())?
                    .render(&Cancel(token))
            },
            || -> Result<TrackingOutput, Fail> {
                let scene = slot
                    .borrow_mut()
                    .take()
                    .ok_or_else(|| Fail::msg("no scene"))?;
                let s = TrackingSession::new(scene, integrator.clone(), settings.clone())
                    .map_err(Fail::err)?;
                s.render(&Cancel(token)).map_err(|e| fail(token)(&e))
            },
        );
        match ran {
            Err(Fail::Message(m)) if token.is_cancelled() && m.contains("cancelled") => {
                Err(Fail::Cancelled)
            }
            other => other,
        }
    })?;
    let d = output(py, &ran.value.image, &file)?;
    d.set_item("device", ran.device.to_string())?;
    d.set_item("fallback", ran.fallback)?;
    Ok(d)
}

/// One pass of a progressive render, as the iterator hands it over.
type PassMsg = Result<(u32, Vec<f32>, Option<f64>), Fail>;

/// Sends each pass's mean image to the iterator (blocking while the iterator has not taken
/// the last one, so a slow consumer holds the render instead of queuing images).
struct Sender {
    tx: SyncSender<PassMsg>,
    token: CancelToken,
}

impl Observer<Progressive> for Sender {
    fn pass(&self, pass: u32, image: &Progressive, noise: Option<f64>) {
        let data = image.mean_image().into_raw();
        if self.tx.send(Ok((pass, data, noise))).is_err() {
            self.token.cancel();
        }
    }
    fn cancelled(&self) -> bool {
        self.token.is_cancelled()
    }
}

/// A progressive render: iterating yields `(pass, image, noise)` after every pass (the
/// image the mean so far, float32 `[height, width, 4]`). Dropping or `close()` cancels it.
#[pyclass(module = "blueshift._native", name = "TrackingRun")]
struct TrackingRun {
    rx: Mutex<Option<Receiver<PassMsg>>>,
    token: CancelToken,
    thread: Mutex<Option<std::thread::JoinHandle<()>>>,
    size: (usize, usize),
}

#[pymethods]
impl TrackingRun {
    #[new]
    #[pyo3(signature = (scene_json, base=None, volumes=HashMap::new(), tfs=HashMap::new()))]
    fn new(
        py: Python<'_>,
        scene_json: &str,
        base: Option<PathBuf>,
        volumes: HashMap<String, PyRef<'_, PyVolume>>,
        tfs: HashMap<String, PyRef<'_, PyTransferFunction>>,
    ) -> PyResult<Self> {
        let (file, memory) = scene_file(scene_json, base, volumes, tfs)?;
        let s = run_cancellable(py, |_| session(&file, &memory))?;
        let size = (s.settings().width as usize, s.settings().height as usize);
        let (tx, rx) = std::sync::mpsc::sync_channel::<PassMsg>(1);
        let token = CancelToken::new();
        let sender = Sender {
            tx: tx.clone(),
            token: token.clone(),
        };
        let thread = std::thread::Builder::new()
            .name("blueshift-render".into())
            .spawn(move || {
                if let Err(e) = s.render(&sender) {
                    let f = fail(&sender.token)(&e);
                    let _ = tx.send(Err(f));
                }
            })
            .map_err(|e| BlueshiftError::new_err(format!("cannot start the render: {e}")))?;
        Ok(Self {
            rx: Mutex::new(Some(rx)),
            token,
            thread: Mutex::new(Some(thread)),
            size,
        })
    }

    fn __iter__(slf: PyRef<'_, Self>) -> PyRef<'_, Self> {
        slf
    }

    fn __next__<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, pyo3::types::PyTuple>>> {
        let mut guard = self.rx.lock().unwrap_or_else(|e| e.into_inner());
        let Some(mut rx) = guard.take() else {
            return Ok(None);
        };
        // Wait without the GIL, 50 ms at a time, so Ctrl-C reaches Python.
        let msg = loop {
            let (back, got) = py.detach(move || {
                let got = rx.recv_timeout(std::time::Duration::from_millis(50));
                (rx, got)
            });
            rx = back;
            match got {
                Ok(m) => break Some(m),
                Err(std::sync::mpsc::RecvTimeoutError::Disconnected) => break None,
                Err(std::sync::mpsc::RecvTimeoutError::Timeout) => {
                    if let Err(e) = py.check_signals() {
                        drop(rx);
                        drop(guard);
                        self.close(py);
                        return Err(e);
                    }
                }
            }
        };
        *guard = Some(rx);
        match msg {
            None => {
                *guard = None;
                Ok(None)
            }
            Some(Err(f)) => {
                *guard = None;
                Err(f.into())
            }
            Some(Ok((pass, data, noise))) => {
                let (w, h) = self.size;
                let img = data.into_pyarray(py).reshape([h, w, 4])?;
                let t = pyo3::types::PyTuple::new(
                    py,
                    [
                        pass.into_pyobject(py)?.into_any(),
                        img.into_any(),
                        noise.into_pyobject(py)?.into_any(),
                    ],
                )?;
                Ok(Some(t))
            }
        }
    }

    /// Cancels the render and waits for it to stop.
    fn close(&self, py: Python<'_>) {
        self.token.cancel();
        // Dropping the receiver unblocks a render waiting to hand over a pass.
        self.rx.lock().unwrap_or_else(|e| e.into_inner()).take();
        let t = self.thread.lock().unwrap_or_else(|e| e.into_inner()).take();
        if let Some(t) = t {
            py.detach(|| {
                let _ = t.join();
            });
        }
    }
}

impl Drop for TrackingRun {
    fn drop(&mut self) {
        self.token.cancel();
        self.rx.get_mut().unwrap_or_else(|e| e.into_inner()).take();
        if let Some(t) = self
            .thread
            .get_mut()
            .unwrap_or_else(|e| e.into_inner())
            .take()
        {
            let _ = t.join();
        }
    }
}

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(render_tracking, m)?)?;
    m.add_class::<TrackingRun>()?;
    Ok(())
}
