//! The `blueshift` command-line tool.
//!
//! Each verb lives in its own module under `commands/`. Errors are printed as one line on
//! stderr; the exit code is 0 on success, 1 for a user error (bad input, bad flags) and 2 for
//! an internal error.

use std::process::ExitCode;

use clap::{Parser, Subcommand};

/// `println!` for the command's results on stdout: a closed pipe (`blueshift tonemap ... |
/// head -0`) is not an error (std's `println!` panics on it); any other write error is
/// one line on stderr.
macro_rules! outln {
    ($($arg:tt)*) => {
        $crate::stdout_text(&format!("{}\n", format_args!($($arg)*)))
    };
}

/// `print!` counterpart of [`outln!`].
macro_rules! out {
    ($($arg:tt)*) => {
        $crate::stdout_text(&format!($($arg)*))
    };
}

/// `eprintln!` that ignores a failed write (stderr a closed pipe, `2>&1 | head -1`), where
/// std's panics: messages and progress are best effort, the exit code says the outcome.
macro_rules! errln {
    ($($arg:tt)*) => {{
        use std::io::Write as _;
        let _ = writeln!(std::io::stderr(), $($arg)*);
    }};
}

/// `eprint!` counterpart of [`errln!`].
macro_rules! errout {
    ($($arg:tt)*) => {{
        use std::io::Write as _;
        let _ = write!(std::io::stderr(), $($arg)*);
    }};
}

mod commands;
mod dist;
mod figure;
mod limits;
mod output;
mod plot;
mod progress;
mod signals;

/// blueshift: physically based scientific volume rendering.
#[derive(Debug, Parser)]
#[command(name = "blueshift", version, about, long_about = None)]
struct Cli {
    /// Memory budget every large allocation is checked against before it is made: bytes
    /// or a size such as 8G, 512M [env: BLUESHIFT_MAX_MEMORY; default: 3/4 of physical
    /// memory].
    #[arg(long, global = true, value_name = "SIZE")]
    max_memory: Option<String>,
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Build a spectrum (black body, emission lines, Doppler shift) and report its colour.
    Spectrum(commands::spectrum::Args),
    /// Tone-map an HDR image (EXR, Radiance .hdr, PFM) for display; print its dynamic range.
    Tonemap(Box<commands::tonemap::Args>),
    /// Transfer functions: draw the editor view, convert ParaView presets, write lookup tables.
    Tf(commands::tf::Args),
    /// Render what a fast observer sees: aberration, Doppler colour shift, searchlight.
    Relativity(commands::relativity::Args),
    /// Print dimensions, type, spacing, value range and a histogram of a volume file.
    Info(commands::info::Args),
    /// Convert a volume between formats (.nrrd, .nhdr, .raw) or into the bricked .bsv layout.
    Convert(commands::convert::Args),
    /// Write a synthetic dataset (galaxy, hydrogen-shell, three-cubes, ...) as NRRD.
    Synth(commands::synth::Args),
    /// Render a volume scene (Woodcock, multi-density Woodcock N-DDA/1-DDA, ray marcher) to EXR.
    Render(Box<commands::render::Args>),
    /// Doppler volume rendering (banded or piecewise-linear spectra) of a synthetic dataset.
    Doppler(Box<commands::doppler::Args>),
    /// Render the galaxy with Doppler on and off side by side, with picked spectra.
    Demo(commands::doppler::DemoArgs),
    /// Print the wgpu adapter blueshift would use: backend, features, limits (--json).
    GpuInfo(commands::gpu_info::Args),
    /// Remove the temporary files (.blueshift-PID-*.partial) that killed runs left in DIR.
    Clean(commands::clean::Args),
    /// Explore a scene in the browser: a local server streams progressive renders to a page
    /// with the transfer-function editor, camera, Doppler picks and saving (prints the URL).
    View(Box<commands::view::Args>),
}

/// Points `XDG_RUNTIME_DIR` at a fresh private folder (removed when the returned guard drops)
/// when it is unset or unusable, so the Vulkan loader does not print "XDG_RUNTIME_DIR is
/// invalid or not set" on the user's terminal when a command creates its wgpu instance.
#[allow(unsafe_code)]
fn private_runtime_dir() -> Option<tempfile::TempDir> {
    blueshift_gpu::runtime_dir_problem()?;
    // tempfile creates folders with mode 0700.
    let dir = tempfile::Builder::new()
        .prefix("blueshift-runtime-")
        .tempdir()
        .ok()?;
    signals::remove_on_signal(dir.path());
    // SAFETY: called first in `main`, before any other thread exists, so nothing reads or
    // writes the environment at the same time.
    unsafe { std::env::set_var("XDG_RUNTIME_DIR", dir.path()) };
    Some(dir)
}

/// A clap usage error as one line, as every other error: the message, any list under it
/// (missing arguments, possible values) joined with commas, and clap's "tip:" suggestion;
/// the usage and "For more information" lines are dropped (`--help` shows them).
fn usage_error_line(rendered: &str) -> String {
    let mut head = String::new();
    let mut list: Vec<&str> = Vec::new();
    let mut tips: Vec<&str> = Vec::new();
    for line in rendered.lines() {
        let t = line.trim();
        if t.starts_with("Usage:") || t.starts_with("For more information") {
            break;
        }
        if t.is_empty() {
            continue;
        }
        if let Some(msg) = t.strip_prefix("error:") {
            head = msg.trim().to_owned();
        } else if t.starts_with("tip:") {
            tips.push(t);
        } else {
            list.push(t);
        }
    }
    let mut out = head;
    if !list.is_empty() {
        let sep = if out.ends_with(':') { " " } else { ": " };
        out = format!("{out}{sep}{}", list.join(", "));
    }
    for tip in tips {
        out = format!("{out} ({tip})");
    }
    out
}

fn main() -> ExitCode {
    let _runtime_dir = private_runtime_dir();
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        Err(err) => {
            // Help and version go to stdout with success; usage errors are user errors (1).
            if !err.use_stderr() {
                let _ = err.print();
                return ExitCode::SUCCESS;
            }
            errln!("blueshift: {}", usage_error_line(&err.render().to_string()));
            return ExitCode::from(1);
        }
    };
    // The viewer keeps its own Ctrl-C handling (it shuts its server down).
    if !matches!(cli.command, Command::View(_)) {
        signals::install();
    }
    let result = crate::limits::init(cli.max_memory.as_deref()).and_then(|()| match cli.command {
        Command::Spectrum(args) => commands::spectrum::run(args),
        Command::Tonemap(args) => commands::tonemap::run(*args),
        Command::Tf(args) => commands::tf::run(args),
        Command::Relativity(args) => commands::relativity::run(args),
        Command::Info(args) => commands::info::run(args),
        Command::Convert(args) => commands::convert::run(args),
        Command::Synth(args) => commands::synth::run(args),
        Command::Render(args) => commands::render::run(*args),
        Command::Doppler(args) => commands::doppler::run(*args),
        Command::Demo(args) => commands::doppler::run_demo(args),
        Command::GpuInfo(args) => commands::gpu_info::run(args),
        Command::View(args) => commands::view::run(*args),
        Command::Clean(args) => commands::clean::run(args),
    });
    // Every rank of an MPI job finalises (nothing when MPI was not used).
    dist::finalize();
    match result {
        // A command's results that could not all be written to stdout (a full disk under a
        // redirect) fail the run; its one line was printed when the write failed.
        Ok(()) if STDOUT_FAILED.load(std::sync::atomic::Ordering::Relaxed) => ExitCode::from(1),
        Ok(()) => ExitCode::SUCCESS,
        // Another rank failed and said why: exit 1 without a second message.
        Err(err) if err.downcast_ref::<dist::Quiet>().is_some() || dist::peer_failed() => {
            // mpirun may end this rank meanwhile: its signal watcher stays silent.
            dist::mark_peer_failed();
            // The rank that failed says why: leave it the time to, before this exit makes
            // mpirun end the job (and signal that rank).
            std::thread::sleep(std::time::Duration::from_millis(500));
            ExitCode::from(1)
        }
        // A loop stopped on SIGINT/SIGTERM: the watcher is cleaning up and sets the exit code.
        Err(_) if signals::cancelled() => signals::wait_for_exit(),
        Err(err) => {
            // One line: the chain of contexts joined by ": ".
            errln!("blueshift: {err:#}");
            let internal = err.downcast_ref::<output::InternalError>().is_some();
            ExitCode::from(if internal { 2 } else { 1 })
        }
    }
}

/// Set when a write to stdout failed other than on a closed pipe: the run then exits 1.
static STDOUT_FAILED: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

/// Writes `text` to stdout for [`outln!`] and [`out!`].
fn stdout_text(text: &str) {
    use std::io::Write;
    let mut out = std::io::stdout().lock();
    if let Err(e) = out.write_all(text.as_bytes()).and_then(|()| out.flush())
        && e.kind() != std::io::ErrorKind::BrokenPipe
        && !STDOUT_FAILED.swap(true, std::sync::atomic::Ordering::Relaxed)
    {
        errln!("blueshift: cannot write to stdout: {e}");
    }
}
