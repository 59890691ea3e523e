//! Progress of long jobs on stderr: an indicatif bar on a terminal, and plain lines in a log.
//!
//! indicatif hides its bar when stderr is not a terminal, which left a 27 s render silent in
//! logs. Off a terminal [`Progress`] prints one line such as
//! `render: 12/64 passes (18 %), noise 0.0123, 5.1 s` at most every
//! [`PLAIN_INTERVAL`] (the environment variable `BLUESHIFT_PROGRESS_SECS` changes it; `0`
//! prints every update).

use std::io::IsTerminal;
use std::sync::Mutex;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

/// The shortest time between two plain progress lines off a terminal.
pub const PLAIN_INTERVAL: Duration = Duration::from_secs(5);

/// The progress of one job of `len` steps of `unit` (passes, rows, slices).
#[derive(Debug)]
pub struct Progress {
    bar: indicatif::ProgressBar,
    plain: Option<Plain>,
}

#[derive(Debug)]
struct Plain {
    what: String,
    unit: String,
    len: AtomicU64,
    pos: AtomicU64,
    start: Instant,
    every: Duration,
    /// When the last line was printed, and the message shown with the position.
    state: Mutex<(Instant, String)>,
}

impl Progress {
    /// A bar drawn with the indicatif `template` on a terminal; plain `what: pos/len unit`
    /// lines otherwise.
    pub fn new(len: u64, template: &str, what: &str, unit: &str) -> Self {
        let bar = indicatif::ProgressBar::new(len);
        bar.set_style(
            indicatif::ProgressStyle::with_template(template)
                .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
        );
        let plain = (!std::io::stderr().is_terminal()).then(|| {
            let every = std::env::var("BLUESHIFT_PROGRESS_SECS")
                .ok()
                .and_then(|v| v.trim().parse::<f64>().ok())
                .filter(|s| *s >= 0.0)
                // Beyond what a Duration holds (1e30, inf): no line before the last.
                .map(|s| Duration::try_from_secs_f64(s).unwrap_or(Duration::MAX))
                .unwrap_or(PLAIN_INTERVAL);
            let now = Instant::now();
            Plain {
                what: what.to_owned(),
                unit: unit.to_owned(),
                len: AtomicU64::new(len),
                pos: AtomicU64::new(0),
                start: now,
                every,
                state: Mutex::new((now, String::new())),
            }
        });
        Self { bar, plain }
    }

    /// Sets the number of steps.
    pub fn set_length(&self, len: u64) {
        self.bar.set_length(len);
        if let Some(p) = &self.plain {
            p.len.store(len, Ordering::Relaxed);
        }
    }

    /// Sets the steps done.
    pub fn set_position(&self, pos: u64) {
        // Once SIGINT/SIGTERM is in, the bar stays still so nothing is drawn over the
        // "interrupted" line while the signal watcher cleans up.
        if crate::signals::cancelled() {
            return;
        }
        self.bar.set_position(pos);
        if let Some(p) = &self.plain {
            p.pos.store(pos, Ordering::Relaxed);
            p.tick();
        }
    }

    /// Adds `n` steps done.
    pub fn inc(&self, n: u64) {
        if crate::signals::cancelled() {
            return;
        }
        self.bar.inc(n);
        if let Some(p) = &self.plain {
            p.pos.fetch_add(n, Ordering::Relaxed);
            p.tick();
        }
    }

    /// The message shown after the position (e.g. `noise 0.0123`).
    pub fn set_message(&self, msg: String) {
        if let Some(p) = &self.plain
            && let Ok(mut s) = p.state.lock()
        {
            s.1.clone_from(&msg);
        }
        self.bar.set_message(msg);
    }

    /// Removes the bar (the caller prints its own summary).
    pub fn finish(&self) {
        self.bar.finish_and_clear();
    }
}

impl Plain {
    /// Prints a line when the interval has passed since the last one.
    fn tick(&self) {
        let Ok(mut s) = self.state.lock() else {
            return;
        };
        let now = Instant::now();
        if now.duration_since(s.0) < self.every {
            return;
        }
        s.0 = now;
        let (pos, len) = (
            self.pos.load(Ordering::Relaxed),
            self.len.load(Ordering::Relaxed),
        );
        let pct = if len > 0 {
            format!(" ({:.0} %)", 100.0 * pos as f64 / len as f64)
        } else {
            String::new()
        };
        let msg = if s.1.is_empty() {
            String::new()
        } else {
            format!(", {}", s.1)
        };
        errln!(
            "{}: {pos}/{len} {}{pct}{msg}, {:.1} s",
            self.what,
            self.unit,
            now.duration_since(self.start).as_secs_f64()
        );
    }
}
