//! The interactive viewer of `blueshift view`, served from the Python process (the
//! notebook embeds its page in an iframe).

use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::Mutex;

use blueshift_doppler::{ColourMatrix, DisplayOptions, Exposure};
use blueshift_view::{Config, DopplerSource, Running, Server, Source, TrackingSource};
use pyo3::prelude::*;

use crate::doppler::PyDopplerScene;
use crate::tracking::scene_file;
use crate::volume::{PyTransferFunction, PyVolume};
use crate::{BlueshiftError, Fail, options, run_cancellable};

/// A viewer serving on loopback until `stop()`.
#[pyclass(module = "blueshift._native", name = "Viewer")]
struct Viewer {
    url: String,
    running: Mutex<Option<Running>>,
}

#[pymethods]
impl Viewer {
    /// The page's URL, with its token.
    #[getter]
    fn url(&self) -> String {
        self.url.clone()
    }

    /// Whether it still serves.
    #[getter]
    fn running(&self) -> bool {
        self.running
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .as_ref()
            .is_some_and(Running::is_running)
    }

    /// Stops serving (open pages lose their connection).
    fn stop(&self, py: Python<'_>) -> PyResult<()> {
        let r = self
            .running
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .take();
        if let Some(mut r) = r {
            py.detach(|| r.stop())
                .map_err(|e| BlueshiftError::new_err(crate::chain(&e)))?;
        }
        Ok(())
    }
}

fn config(port: u16, save_dir: PathBuf) -> Config {
    Config {
        port,
        save_dir,
        ..Config::default()
    }
}

fn start(py: Python<'_>, source: Source, cfg: Config) -> PyResult<Viewer> {
    let running = run_cancellable(py, |_| {
        let server = Server::bind(source, cfg).map_err(Fail::err)?;
        server.spawn().map_err(Fail::err)
    })?;
    Ok(Viewer {
        url: running.url().to_owned(),
        running: Mutex::new(Some(running)),
    })
}

/// Serves a Doppler scene with `blueshift doppler`'s options (JSON).
#[pyfunction]
#[pyo3(signature = (scene, opts, port=0, save_dir=PathBuf::from(".")))]
fn serve_doppler(
    py: Python<'_>,
    scene: PyRef<'_, PyDopplerScene>,
    opts: &str,
    port: u16,
    save_dir: PathBuf,
) -> PyResult<Viewer> {
    let o: crate::doppler::Opts = options("view", opts)?;
    let settings = o.settings(&scene.scene).map_err(PyErr::from)?;
    let source = Source::Doppler(Box::new(DopplerSource {
        scene: scene.scene.clone(),
        settings,
        // A scene built in Python has no file to name: a save's command says so.
        base_args: vec![
            "--scene".into(),
            "<the Python scene, saved with Scene.save()>".into(),
        ],
        inputs: Vec::new(),
        display: DisplayOptions {
            matrix: ColourMatrix::Srgb,
            exposure: Exposure::Percentile(99.0),
        },
        exposure: 0.0,
        panel: None,
    }));
    start(py, source, config(port, save_dir))
}

/// Serves a tracking scene (scene-file JSON with in-memory volumes and TFs).
#[pyfunction]
#[pyo3(signature = (scene_json, base=None, volumes=HashMap::new(), tfs=HashMap::new(), port=0, save_dir=PathBuf::from(".")))]
fn serve_tracking(
    py: Python<'_>,
    scene_json: &str,
    base: Option<PathBuf>,
    volumes: HashMap<String, PyRef<'_, PyVolume>>,
    tfs: HashMap<String, PyRef<'_, PyTransferFunction>>,
    port: u16,
    save_dir: PathBuf,
) -> PyResult<Viewer> {
    let (file, memory) = scene_file(scene_json, base, volumes, tfs)?;
    let (scene, _, _) = run_cancellable(py, |_| file.build_with(&memory).map_err(Fail::err))?;
    let source = Source::Tracking(Box::new(TrackingSource {
        file,
        scene,
        inputs: Vec::new(),
        tonemap: "linear".into(),
        exposure: 0.0,
        device: blueshift_gpu::DeviceChoice::Cpu,
    }));
    start(py, source, config(port, save_dir))
}

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<Viewer>()?;
    m.add_function(wrap_pyfunction!(serve_doppler, m)?)?;
    m.add_function(wrap_pyfunction!(serve_tracking, m)?)?;
    Ok(())
}
