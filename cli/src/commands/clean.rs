//! `blueshift clean [DIR]`: removes the temporary files of blueshift runs that were killed
//! (kill -9, a crash, a power cut) before they could clean up.
//!
//! Only files named as blueshift names its temporaries are considered,
//! `.blueshift-<pid>-<random>` followed by parts of which one is `partial` (`.partial`,
//! `.partial.exr`, `.bsv.partial`; [`crate::output::temp_name_pid`]), regular files only
//! (never a symlink or a folder), in DIR itself (not below it). One is stale when no process
//! with its pid is running (`/proc/<pid>`) or it was last modified more than `--older-than`
//! hours ago (the pid may have been reused); a running blueshift's own temporaries are kept.

use std::path::PathBuf;
use std::time::{Duration, SystemTime};

use anyhow::{Context, Result};

/// Arguments of `blueshift clean`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// The folder to look in (default: the working folder).
    #[arg(default_value = ".")]
    pub dir: PathBuf,
    /// List the stale temporary files without removing them.
    #[arg(long)]
    pub dry_run: bool,
    /// Also count as stale a temporary file older than this many hours whose pid is running.
    #[arg(long, default_value_t = 24.0)]
    pub older_than: f64,
}

/// Whether a process with this id is running (Linux: `/proc/<pid>` exists; elsewhere
/// unknown, so only the age counts).
fn alive(pid: u32) -> bool {
    if pid == std::process::id() {
        return true;
    }
    let proc = std::path::Path::new("/proc");
    !proc.join("self").exists() || proc.join(pid.to_string()).exists()
}

/// Runs `blueshift clean`.
pub fn run(args: Args) -> Result<()> {
    if !(args.older_than.is_finite() && args.older_than >= 0.0) {
        anyhow::bail!(
            "--older-than {}: must be a number of hours >= 0",
            args.older_than
        );
    }
    // Ages beyond what a Duration holds (about 5e15 hours) mean "never".
    let max_age = Duration::try_from_secs_f64(args.older_than * 3600.0).unwrap_or(Duration::MAX);
    let entries = std::fs::read_dir(&args.dir)
        .with_context(|| format!("cannot list {}", args.dir.display()))?;
    let mut found = 0usize;
    for e in entries.flatten() {
        let name = e.file_name();
        let Some(pid) = name.to_str().and_then(crate::output::temp_name_pid) else {
            continue;
        };
        // DirEntry::metadata does not follow symlinks.
        let Ok(meta) = e.metadata() else { continue };
        if !meta.is_file() {
            continue;
        }
        let age = meta
            .modified()
            .ok()
            .and_then(|m| SystemTime::now().duration_since(m).ok())
            .unwrap_or_default();
        let why = if !alive(pid) {
            format!("process {pid} is not running")
        } else if age > max_age && pid != std::process::id() {
            format!("{:.1} h old", age.as_secs_f64() / 3600.0)
        } else {
            continue;
        };
        let path = e.path();
        found += 1;
        if args.dry_run {
            errln!("stale {} ({why}, {} bytes)", path.display(), meta.len());
        } else {
            std::fs::remove_file(&path)
                .with_context(|| format!("cannot remove {}", path.display()))?;
            errln!("removed {} ({why}, {} bytes)", path.display(), meta.len());
        }
    }
    if found == 0 {
        errln!(
            "no stale blueshift temporary files in {}",
            args.dir.display()
        );
    }
    Ok(())
}
