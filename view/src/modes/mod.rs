//! The four things the viewer shows, each over its engine session: tracking scenes
//! (Woodcock, MDWT, marcher), Doppler scenes, the relativistic observer and HDR images.

use std::path::{Path, PathBuf};

use serde_json::{Value, json};

use crate::protocol::Incoming;
use crate::worker::{Ctx, Stage};
use crate::{Error, Result};

mod doppler;
mod hdr;
mod relativity;
mod tracking;

pub use doppler::{DopplerSource, PanelFn};
pub use hdr::HdrSource;
pub use relativity::RelativitySource;
pub use tracking::TrackingSource;

/// What `blueshift view` shows.
#[derive(Debug)]
pub enum Source {
    /// A volume scene rendered by Woodcock / MDWT / the marcher.
    Tracking(Box<TrackingSource>),
    /// A Doppler scene.
    Doppler(Box<DopplerSource>),
    /// An environment seen by a fast observer.
    Relativity(Box<RelativitySource>),
    /// An HDR image to tone-map.
    Hdr(Box<HdrSource>),
}

/// One tab's state over its session.
pub(crate) trait Mode: Send {
    /// The `info` message.
    fn info(&self) -> Value;
    /// Applies an edit or answers a request; returns what must be rendered again.
    fn handle(&mut self, msg: Incoming, ctx: &Ctx) -> Result<Option<Stage>>;
    /// Renders (preview and refinement as `stage` says), streaming frames.
    fn render(&mut self, stage: Stage, ctx: &Ctx) -> Result<()>;
    /// Forgets the last finished frame (the state changed since).
    fn invalidate(&mut self);
}

/// A tab's mode over its own copy of the source.
pub(crate) fn build(source: &Source) -> Result<Box<dyn Mode + '_>> {
    let (w, h) = match source {
        Source::Tracking(s) => (s.file.width.unwrap_or(512), s.file.height.unwrap_or(512)),
        Source::Doppler(s) => (s.settings.width, s.settings.height),
        Source::Relativity(s) => s.size,
        Source::Hdr(s) => (s.image.width(), s.image.height()),
    };
    check_view_size(w, h)?;
    Ok(match source {
        Source::Tracking(s) => Box::new(tracking::TrackingMode::new(s)?),
        Source::Doppler(s) => Box::new(doppler::DopplerMode::new(s)?),
        Source::Relativity(s) => Box::new(relativity::RelativityMode::new(s)?),
        Source::Hdr(s) => Box::new(hdr::HdrMode::new(s)?),
    })
}

/// Largest image the viewer renders, pixels (2048 x 2048: a tab's accumulation buffers
/// then stay under 300 MB; batch renders of any size are the CLI's).
pub const MAX_VIEW_PIXELS: u64 = 1 << 22;

/// Refuses an image size over [`MAX_VIEW_PIXELS`] (or empty).
pub(crate) fn check_view_size(width: u32, height: u32) -> Result<()> {
    if width == 0 || height == 0 || u64::from(width) * u64::from(height) > MAX_VIEW_PIXELS {
        return Err(Error::invalid(format!(
            "image size {width}x{height}: the viewer renders 1 to {MAX_VIEW_PIXELS} pixels (2048x2048); use the batch command for larger images"
        )));
    }
    Ok(())
}

/// The preview sizes shown before the full-resolution frame: a quarter of each edge, then
/// half for images of 256 x 256 pixels or more (so a slow full frame has a sharper
/// stand-in sooner).
pub(crate) fn preview_sizes(width: u32, height: u32) -> Vec<(u32, u32)> {
    let mut v = vec![(width.div_ceil(4).max(1), height.div_ceil(4).max(1))];
    if u64::from(width) * u64::from(height) >= 256 * 256 {
        v.push((width.div_ceil(2), height.div_ceil(2)));
    }
    v
}

/// A histogram of `n` bins of the finite values of `values` over their range.
pub(crate) fn histogram(values: impl Iterator<Item = f32> + Clone, n: usize) -> Value {
    let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
    for v in values.clone().filter(|v| v.is_finite()) {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    if lo > hi {
        return json!({ "lo": 0.0, "hi": 1.0, "counts": vec![0u64; n] });
    }
    let mut counts = vec![0u64; n];
    let width = f64::from(hi) - f64::from(lo);
    for v in values.filter(|v| v.is_finite()) {
        let f = if width > 0.0 {
            (f64::from(v) - f64::from(lo)) / width
        } else {
            0.0
        };
        counts[((f * n as f64) as usize).min(n - 1)] += 1;
    }
    json!({ "lo": lo, "hi": hi, "counts": counts })
}

/// A piecewise-linear spectrum as the points of its exact polyline (a jump appears as two
/// points at one wavelength; gaps drop to zero).
pub(crate) fn spectrum_points(s: &blueshift_spectrum::PiecewiseLinear) -> (Vec<f64>, Vec<f64>) {
    let (mut w, mut v) = (Vec::new(), Vec::new());
    let mut prev_end: Option<f64> = None;
    for p in s.pieces() {
        if prev_end != Some(p.start_nm) {
            if let Some(e) = prev_end {
                w.push(e);
                v.push(0.0);
            }
            w.push(p.start_nm);
            v.push(0.0);
        }
        w.push(p.start_nm);
        v.push(p.value_start);
        w.push(p.end_nm);
        v.push(p.value_end);
        prev_end = Some(p.end_nm);
    }
    if let Some(e) = prev_end {
        w.push(e);
        v.push(0.0);
    }
    (w, v)
}

/// The files of one save: a stem in the save folder, chosen so no existing file is
/// replaced unless this server wrote it, and no input named on the command line.
pub(crate) struct SaveSet<'a> {
    pub stem: PathBuf,
    /// The server's written files, locked for the whole save.
    written: std::sync::MutexGuard<'a, std::collections::HashSet<PathBuf>>,
}

impl<'a> SaveSet<'a> {
    /// Picks the stem: `name`, or the first free `view-NNN`.
    pub(crate) fn new(
        ctx: &'a Ctx,
        name: Option<&str>,
        suffixes: &[&str],
        inputs: &[PathBuf],
    ) -> Result<Self> {
        let written = ctx.written.lock().unwrap_or_else(|e| e.into_inner());
        // A named save may replace this server's own files of that name; an unnamed one
        // always takes a fresh name.
        let replace_own = name.is_some();
        let free = |stem: &Path| -> Result<bool> {
            for s in suffixes {
                let p = with_suffix(stem, s);
                if inputs.iter().any(|i| same_file(i, &p)) {
                    return Err(Error::invalid(format!(
                        "save: {} is an input of this viewer; choose another name",
                        p.display()
                    )));
                }
                // `symlink_metadata`: a dangling link is a file this viewer did not write.
                if p.symlink_metadata().is_ok() && !(replace_own && written.contains(&p)) {
                    return Ok(false);
                }
            }
            Ok(true)
        };
        let stem = match name {
            Some(n) => {
                let stem = ctx.save_dir.join(n);
                if !free(&stem)? {
                    return Err(Error::invalid(format!(
                        "save: files named {n}.* already exist in {} and were not written by this viewer; choose another name",
                        ctx.save_dir.display()
                    )));
                }
                stem
            }
            None => {
                let mut found = None;
                for i in 1..10_000 {
                    let stem = ctx.save_dir.join(format!("view-{i:03}"));
                    if free(&stem)? {
                        found = Some(stem);
                        break;
                    }
                }
                found.ok_or_else(|| Error::invalid("save: no free view-NNN name left"))?
            }
        };
        Ok(Self { stem, written })
    }

    /// The path of one file of the set.
    pub(crate) fn path(&self, suffix: &str) -> PathBuf {
        with_suffix(&self.stem, suffix)
    }

    /// Records the files as written by this server (a later save may replace them).
    pub(crate) fn commit(mut self, files: &[PathBuf]) {
        self.written.extend(files.iter().cloned());
    }
}

fn with_suffix(stem: &Path, suffix: &str) -> PathBuf {
    let mut s = stem.as_os_str().to_owned();
    s.push(suffix);
    PathBuf::from(s)
}

/// Whether two paths name the same existing file.
fn same_file(a: &Path, b: &Path) -> bool {
    match (std::fs::canonicalize(a), std::fs::canonicalize(b)) {
        (Ok(x), Ok(y)) => x == y,
        _ => false,
    }
}

/// Writes bytes atomically (a temporary file in the same folder, then a rename).
pub(crate) fn write_file(path: &Path, bytes: &[u8]) -> Result<()> {
    blueshift_tonemap::io::write_atomic(path, |w| {
        std::io::Write::write_all(w, bytes).map_err(|e| blueshift_tonemap::Error::Io {
            message: "cannot write".into(),
            path: path.to_path_buf(),
            source: e,
        })
    })
    .map_err(Error::from)
}

/// Writes an 8-bit PNG atomically.
pub(crate) fn write_png(path: &Path, img: &image::RgbImage) -> Result<()> {
    blueshift_tonemap::io::write_rgb8_png(path, img).map_err(Error::from)
}

/// Quotes one argument for a POSIX shell when it needs it.
pub(crate) fn shell_quote(s: &str) -> String {
    let plain = !s.is_empty()
        && s.bytes()
            .all(|b| b.is_ascii_alphanumeric() || b"-_./,:=+@%".contains(&b));
    if plain {
        s.to_owned()
    } else {
        format!("'{}'", s.replace('\'', "'\\''"))
    }
}

/// A command line from its arguments.
pub(crate) fn command_line(args: &[String]) -> String {
    args.iter()
        .map(|a| shell_quote(a))
        .collect::<Vec<_>>()
        .join(" ")
}

/// Three f32 as `X,Y,Z` (shortest round-trip spelling).
pub(crate) fn triple(v: [f32; 3]) -> String {
    format!("{},{},{}", v[0], v[1], v[2])
}

/// The `saved` reply.
pub(crate) fn saved_reply(files: &[PathBuf], command: &str, scene: Option<&Path>) -> Value {
    json!({
        "type": "saved",
        "files": files.iter().map(|p| p.display().to_string()).collect::<Vec<_>>(),
        "command": command,
        "scene": scene.map(|p| p.display().to_string()),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shell_quoting_leaves_plain_words_alone() {
        assert_eq!(shell_quote("--eye"), "--eye");
        assert_eq!(shell_quote("1.5,-2,3e-5"), "1.5,-2,3e-5");
        assert_eq!(shell_quote("a b"), "'a b'");
        assert_eq!(shell_quote("it's"), "'it'\\''s'");
    }
}
