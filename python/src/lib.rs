//! `blueshift._native`: the compiled half of the `blueshift` Python package.
//!
//! The pure-Python layer (`python/blueshift/`) converts units, dtypes and layouts, names
//! arguments and documents them; this module takes C-contiguous `float32` arrays in the
//! library's units and runs the engines with the GIL released. Volumes cross as arrays
//! indexed `[z, y, x]` (x fastest in memory, as `blueshift_volume::Grid` stores them; the
//! Python layer hands yt's `[x, y, z]` arrays over as their transposes); images come back
//! as `[row, column, channel]` arrays that own the engine's buffer (no copy).
//!
//! Every engine call goes through [`run_cancellable`]: the work runs on a thread of its own
//! while the calling thread, without the GIL, waits for it and checks for Ctrl-C every 50
//! ms; an interrupt raises the engine's cancel flag and `KeyboardInterrupt`. Errors become
//! `blueshift.BlueshiftError` (a `ValueError`) carrying the library's message; a panic in
//! the work becomes a `RuntimeError` instead of aborting the interpreter.

use std::time::Duration;

use blueshift_camera::CancelToken;
use pyo3::exceptions::{PyKeyboardInterrupt, PyRuntimeError};
use pyo3::prelude::*;

mod doppler;
mod images;
mod spectrum;
mod tracking;
mod viewer;
mod volume;

pyo3::create_exception!(
    _native,
    BlueshiftError,
    pyo3::exceptions::PyValueError,
    "An error reported by the blueshift library (bad input, a bad setting, an unreadable file)."
);

/// Why a piece of work did not finish.
#[derive(Debug)]
pub(crate) enum Fail {
    /// Ctrl-C (the engine saw its cancel flag).
    Cancelled,
    /// The library's message.
    Message(String),
}

impl Fail {
    /// A failure with this message.
    pub(crate) fn msg(m: impl std::fmt::Display) -> Self {
        Fail::Message(m.to_string())
    }

    /// A failure with a library error's message and its causes.
    pub(crate) fn err<E: std::error::Error>(e: E) -> Self {
        Fail::Message(chain(&e))
    }
}

/// An error's message followed by its causes, `what: why: deeper why`.
pub(crate) fn chain(e: &dyn std::error::Error) -> String {
    let mut m = e.to_string();
    let mut cause = e.source();
    while let Some(c) = cause {
        let s = c.to_string();
        if !m.contains(&s) {
            m.push_str(": ");
            m.push_str(&s);
        }
        cause = c.source();
    }
    m
}

/// What the engine crates' `Cancelled` errors say (each crate has its own variant).
fn is_cancel_message(m: &str) -> bool {
    m.contains("cancelled")
}

impl From<blueshift_gpu::Error> for Fail {
    fn from(e: blueshift_gpu::Error) -> Self {
        Fail::err(e)
    }
}

impl From<Fail> for PyErr {
    fn from(f: Fail) -> PyErr {
        match f {
            Fail::Cancelled => PyKeyboardInterrupt::new_err("render cancelled"),
            Fail::Message(m) => BlueshiftError::new_err(m),
        }
    }
}

/// Maps a library error to a [`Fail`] (`Cancelled` when the token was raised).
pub(crate) fn fail(token: &CancelToken) -> impl Fn(&dyn std::error::Error) -> Fail + '_ {
    move |e| {
        let m = chain(e);
        if token.is_cancelled() && is_cancel_message(&m) {
            Fail::Cancelled
        } else {
            Fail::Message(m)
        }
    }
}

/// Runs `work` on its own thread while this one waits without the GIL, checking for
/// Ctrl-C every 50 ms (an interrupt raises the token the work polls and waits for it to
/// stop). A panic in the work becomes a `RuntimeError`.
pub(crate) fn run_cancellable<T: Send>(
    py: Python<'_>,
    work: impl FnOnce(&CancelToken) -> Result<T, Fail> + Send,
) -> PyResult<T> {
    let token = CancelToken::new();
    let caller = std::thread::current();
    std::thread::scope(|s| {
        let handle = s.spawn(|| {
            let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| work(&token)));
            caller.unpark();
            r
        });
        let mut interrupted: Option<PyErr> = None;
        while !handle.is_finished() {
            py.detach(|| std::thread::park_timeout(Duration::from_millis(50)));
            if interrupted.is_none()
                && let Err(e) = py.check_signals()
            {
                token.cancel();
                interrupted = Some(e);
            }
        }
        let out = match handle.join() {
            Ok(r) => r,
            Err(_) => return Err(PyRuntimeError::new_err("blueshift: the work thread failed")),
        };
        if let Some(e) = interrupted {
            return Err(e);
        }
        match out {
            Ok(r) => r.map_err(PyErr::from),
            Err(p) => {
                let what = p
                    .downcast_ref::<String>()
                    .cloned()
                    .or_else(|| p.downcast_ref::<&str>().map(|s| (*s).to_owned()))
                    .unwrap_or_else(|| "unknown".into());
                Err(PyRuntimeError::new_err(format!(
                    "blueshift internal error (a bug, please report it): {what}"
                )))
            }
        }
    })
}

/// Parses keyword options the Python layer sent as JSON (unknown keys refused by the
/// target type, so a misspelt keyword is an error naming it).
pub(crate) fn options<T: serde::de::DeserializeOwned>(what: &str, json: &str) -> PyResult<T> {
    serde_json::from_str(json).map_err(|e| BlueshiftError::new_err(format!("{what}: {e}")))
}

/// Panics inside the work thread: the tests' proof that a panic becomes a
/// `RuntimeError` instead of aborting the interpreter.
#[pyfunction]
fn _panic_in_work(py: Python<'_>) -> PyResult<()> {
    run_cancellable(py, |_| -> Result<(), Fail> {
        panic!("deliberate test panic")
    })
}

#[pymodule]
fn _native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add("BlueshiftError", m.py().get_type::<BlueshiftError>())?;
    m.add_function(wrap_pyfunction!(_panic_in_work, m)?)?;
    volume::register(m)?;
    tracking::register(m)?;
    doppler::register(m)?;
    spectrum::register(m)?;
    images::register(m)?;
    viewer::register(m)?;
    Ok(())
}

/// The values of `a` in C order (last axis fastest), as the native functions read them; a
/// Fortran-ordered or strided array is refused (the Python layer passes
/// `numpy.ascontiguousarray`), never read in its memory order.
pub(crate) fn c_order<'a, T: numpy::Element, D: numpy::ndarray::Dimension>(
    name: &str,
    a: &'a numpy::PyReadonlyArray<'_, T, D>,
) -> PyResult<&'a [T]> {
    use numpy::PyUntypedArrayMethods as _;
    let refused = || {
        BlueshiftError::new_err(format!(
            "{name}: not a C-ordered contiguous array (pass numpy.ascontiguousarray({name}))"
        ))
    };
    if !a.is_c_contiguous() {
        return Err(refused());
    }
    a.as_slice().map_err(|_| refused())
}

/// The memory budget of this process's renders: `BLUESHIFT_MAX_MEMORY` (as the CLI reads
/// it) when set, else 3/4 of physical memory. A result beyond it is refused with a
/// `BlueshiftError` before any work, as the CLI refuses it.
pub(crate) fn budget() -> Result<blueshift_volume::MemoryBudget, Fail> {
    use blueshift_volume::MemoryBudget;
    use blueshift_volume::budget::ENV_VAR;
    match std::env::var(ENV_VAR) {
        Ok(s) if !s.trim().is_empty() => Ok(MemoryBudget::new(
            MemoryBudget::parse_size(&s).map_err(|e| Fail::msg(format!("{ENV_VAR} {e}")))?,
            ENV_VAR,
        )),
        _ => Ok(MemoryBudget::machine_default()),
    }
}
