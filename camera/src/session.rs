//! The render-session shape every engine shares.
//!
//! An engine (Woodcock/MDWT tracking, the marcher, Doppler, relativity, tone mapping, on
//! the CPU or a GPU) is a [`Session`]: built once from (scene, settings, device), which is
//! where tables, majorants and device buffers are made; [`Session::run`] renders under an
//! [`Observer`] that sees progress, each pass's image and noise estimate, and may cancel.
//! Edits (camera, transfer function, factors) go through the engine's own setters, which
//! rebuild only what the edit touches, and the session is run again.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

/// Where a running render stands.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Progress {
    /// Work items finished so far (rows over all passes, or passes).
    pub done: u64,
    /// Work items in the whole run (0 when unknown in advance).
    pub total: u64,
    /// Passes finished (1 for single-pass engines once done).
    pub pass: u32,
}

/// What a caller sees of a running render. Every method has a default that ignores the
/// event, so an observer implements only what it needs. Methods may be called from any
/// thread (hence `Sync`).
pub trait Observer<I: ?Sized>: Sync {
    /// Work finished: called once per finished work item (a row or a pass).
    fn progress(&self, _progress: Progress) {}
    /// A pass finished: the image so far (the running mean for Monte Carlo engines), its
    /// pass number (1-based) and, where the engine estimates it, the relative noise.
    fn pass(&self, _pass: u32, _image: &I, _noise: Option<f64>) {}
    /// A progressive level-of-detail run (HDR VolVis section 6.3: a first image from a coarse
    /// level, refined level by level) is about to render step `step` (1-based) from level
    /// `level` of the data (0: the finest, exact level).
    fn level(&self, _step: u32, _level: usize) {}
    /// Polled between work items; `true` stops the run, which returns the engine's
    /// `Cancelled` error.
    fn cancelled(&self) -> bool {
        false
    }
    /// Whether [`Observer::pass`] must see every pass. An observer that answers `false`
    /// (a progress bar) lets a Monte Carlo engine run several passes in one parallel sweep
    /// when nothing stops it between passes (no noise target): fewer thread wake-ups and
    /// serial steps per sample, the same image bit for bit, with `pass` and `progress`
    /// told after each sweep. The default, `true`, keeps one call per pass.
    fn every_pass(&self) -> bool {
        true
    }
}

/// An observer that ignores everything and never cancels.
#[derive(Clone, Copy, Debug, Default)]
pub struct Silent;

impl<I: ?Sized> Observer<I> for Silent {}

/// Forwards progress and cancellation to another observer, not its passes or levels: the
/// quick passes of a progressive render report their pass themselves, numbered by the
/// caller.
pub struct ProgressOnly<'a, I: ?Sized>(pub &'a dyn Observer<I>);

impl<I: ?Sized> std::fmt::Debug for ProgressOnly<'_, I> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("ProgressOnly")
    }
}

impl<I: ?Sized> Observer<I> for ProgressOnly<'_, I> {
    fn progress(&self, p: Progress) {
        self.0.progress(p);
    }
    fn cancelled(&self) -> bool {
        self.0.cancelled()
    }
}

/// An observer that forwards progress to a closure and, optionally, polls a cancel token.
pub struct OnProgress<F> {
    f: F,
    cancel: Option<CancelToken>,
}

impl<F> std::fmt::Debug for OnProgress<F> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("OnProgress")
            .field("cancel", &self.cancel)
            .finish_non_exhaustive()
    }
}

impl<F: Fn(Progress) + Sync> OnProgress<F> {
    /// Calls `f` on every progress event.
    pub fn new(f: F) -> Self {
        Self { f, cancel: None }
    }

    /// Also stops the run once `token` is cancelled.
    #[must_use]
    pub fn with_cancel(mut self, token: CancelToken) -> Self {
        self.cancel = Some(token);
        self
    }
}

impl<I: ?Sized, F: Fn(Progress) + Sync> Observer<I> for OnProgress<F> {
    fn progress(&self, progress: Progress) {
        (self.f)(progress);
    }
    fn cancelled(&self) -> bool {
        self.cancel.as_ref().is_some_and(CancelToken::is_cancelled)
    }
}

/// A cancel flag shared between a running session and whoever may stop it (a viewer's
/// edit, Ctrl-C, a Python KeyboardInterrupt). Cloning shares the flag.
#[derive(Clone, Debug, Default)]
pub struct CancelToken(Arc<AtomicBool>);

impl CancelToken {
    /// A token that is not cancelled.
    #[must_use]
    pub fn new() -> Self {
        Self::default()
    }
    /// Asks every run polling this token to stop.
    pub fn cancel(&self) {
        self.0.store(true, Ordering::Relaxed);
    }
    /// Clears the flag (before the next run).
    pub fn reset(&self) {
        self.0.store(false, Ordering::Relaxed);
    }
    /// Whether [`CancelToken::cancel`] was called since the last reset.
    #[must_use]
    pub fn is_cancelled(&self) -> bool {
        self.0.load(Ordering::Relaxed)
    }
}

/// Tells `observer` that a single-pass render (a deterministic image of `rows` rows)
/// finished with `image`: one progress event with every row done, then the pass.
pub fn single_pass_done<I: ?Sized>(observer: &dyn Observer<I>, rows: u64, image: &I) {
    observer.progress(Progress {
        done: rows,
        total: rows,
        pass: 1,
    });
    observer.pass(1, image, None);
}

/// The device a session runs on.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum DeviceKind {
    /// The CPU reference (bit-reproducible on any thread count).
    Cpu,
    /// A wgpu adapter (a hardware GPU or lavapipe).
    Gpu,
}

impl std::fmt::Display for DeviceKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            DeviceKind::Cpu => "cpu",
            DeviceKind::Gpu => "gpu",
        })
    }
}

/// A render session: built once from (scene, settings, device), run any number of times.
///
/// Building validates everything and makes what every run needs (tables, majorants,
/// device buffers), so `run` only renders. Engines add setters for the edits they support
/// (camera, transfer function, factors, operator parameters) that rebuild only what the edit
/// touches.
pub trait Session {
    /// What observers see after each pass (the accumulation buffer, the XYZ image, ...).
    type Image: ?Sized;
    /// What a run returns (an HDR image, an XYZ image with statistics, ...).
    type Output;
    /// The engine's error type (it has a `Cancelled` case for a cancelled run).
    type Error;

    /// Renders under `observer` and returns the result. A cancelled run returns the
    /// engine's `Cancelled` error; the session stays usable.
    fn run(&mut self, observer: &dyn Observer<Self::Image>) -> Result<Self::Output, Self::Error>;

    /// The device this session runs on.
    fn device(&self) -> DeviceKind;
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::AtomicU64;

    #[test]
    fn cancel_token_is_shared_by_clones() {
        let a = CancelToken::new();
        let b = a.clone();
        assert!(!b.is_cancelled());
        a.cancel();
        assert!(b.is_cancelled());
        b.reset();
        assert!(!a.is_cancelled());
    }

    #[test]
    fn on_progress_forwards_and_polls() {
        let n = AtomicU64::new(0);
        let token = CancelToken::new();
        let obs = OnProgress::new(|p: Progress| {
            n.fetch_add(p.done, Ordering::Relaxed);
        })
        .with_cancel(token.clone());
        let o: &dyn Observer<[f32]> = &obs;
        o.progress(Progress {
            done: 3,
            total: 4,
            pass: 1,
        });
        assert_eq!(n.load(Ordering::Relaxed), 3);
        assert!(!o.cancelled());
        token.cancel();
        assert!(o.cancelled());
        assert!(!Observer::<[f32]>::cancelled(&Silent));
    }
}
