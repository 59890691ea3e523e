//! SIGINT and SIGTERM: a long render, a huge `--spp`, `--frames` or `--warmup`, stops at
//! once and cleanly.
//!
//! The handler itself only records the signal (an atomic store, all a signal handler may
//! do). A watcher thread sees it, takes [`gate`] (so an [`crate::output::OutputSet`] being
//! renamed is finished first and no new temporary file appears after), removes this
//! process's temporary files (`.blueshift-<pid>-*` in every folder outputs go to, including
//! the `.bsv` converter's) and the private runtime folder, prints one line `blueshift:
//! interrupted` (not in an MPI rank that knows another rank failed: mpirun is ending the
//! job for that failure, which the failing rank reported) and exits with 130 (SIGINT) or
//! 143 (SIGTERM), as a shell reports a process
//! killed by that signal. No partial output is left: outputs are only ever renamed into
//! place complete. The viewer (`blueshift view`) keeps its own Ctrl-C handling.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicI32, Ordering};
use std::sync::{Mutex, MutexGuard};
use std::time::Duration;

/// The signal received (0: none).
static SIGNAL: AtomicI32 = AtomicI32::new(0);
/// Held while temporary files are created and while a set of outputs is renamed; the
/// watcher takes it for good before cleaning up.
static GATE: Mutex<()> = Mutex::new(());
/// Folders this process makes temporary files in.
static DIRS: Mutex<Vec<PathBuf>> = Mutex::new(Vec::new());
/// Folders this process created and removes whole on a signal (the private runtime folder).
static OWN_DIRS: Mutex<Vec<PathBuf>> = Mutex::new(Vec::new());

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// Holds off the signal watcher's clean-up while the guard lives.
pub fn gate() -> MutexGuard<'static, ()> {
    lock(&GATE)
}

/// Records that this process makes temporary files in `dir`.
pub fn watch_dir(dir: &Path) {
    let dir = dir.to_path_buf();
    let mut dirs = lock(&DIRS);
    if !dirs.contains(&dir) {
        dirs.push(dir);
    }
}

/// Records a folder this process created, removed whole on a signal.
pub fn remove_on_signal(dir: &Path) {
    lock(&OWN_DIRS).push(dir.to_path_buf());
}

/// Whether SIGINT or SIGTERM has been received (progress stops drawing).
pub fn cancelled() -> bool {
    SIGNAL.load(Ordering::SeqCst) != 0
}

/// Waits for the watcher to end the process: for the main thread once a render loop has
/// stopped on [`cancelled`], so its "cancelled" error does not race the watcher's exit code.
pub fn wait_for_exit() -> ! {
    loop {
        std::thread::sleep(Duration::from_secs(1));
    }
}

/// Installs the handlers for SIGINT and SIGTERM and starts the watcher thread.
#[allow(unsafe_code)]
pub fn install() {
    #[cfg(unix)]
    for sig in [libc::SIGINT, libc::SIGTERM] {
        // SAFETY: the action is one atomic store, which is async-signal-safe; it allocates
        // nothing and takes no lock.
        let _ = unsafe {
            signal_hook_registry::register(sig, move || SIGNAL.store(sig, Ordering::SeqCst))
        };
    }
    let _ = std::thread::Builder::new()
        .name("blueshift-signals".into())
        .spawn(watch);
}

fn watch() {
    let sig = loop {
        let s = SIGNAL.load(Ordering::SeqCst);
        if s != 0 {
            break s;
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    // Held until the exit: nothing is renamed or created after the clean-up.
    let _gate = gate();
    remove_own_temps();
    for d in lock(&OWN_DIRS).iter() {
        let _ = std::fs::remove_dir_all(d);
    }
    if std::io::IsTerminal::is_terminal(&std::io::stderr()) {
        // Past the progress bar and the echoed ^C.
        errln!();
    }
    // A rank of an MPI job that knows another rank failed is being ended by mpirun because
    // of that failure, which the failing rank has said in its one line: no second line.
    if !crate::dist::peer_failed() {
        errln!("blueshift: interrupted");
    }
    std::process::exit(128 + sig);
}

/// Removes this process's temporary files (`.blueshift-<pid>-...partial...`) in every
/// folder recorded with [`watch_dir`].
fn remove_own_temps() {
    let me = std::process::id();
    for dir in lock(&DIRS).iter() {
        let Ok(entries) = std::fs::read_dir(dir) else {
            continue;
        };
        for e in entries.flatten() {
            let name = e.file_name();
            let ours = name
                .to_str()
                .and_then(crate::output::temp_name_pid)
                .is_some_and(|pid| pid == me);
            if ours && e.file_type().is_ok_and(|t| t.is_file()) {
                let _ = std::fs::remove_file(e.path());
            }
        }
    }
}
