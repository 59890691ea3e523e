//! Output helpers shared by all verbs: checking output paths before any work, atomic file
//! writes (one file or a set), the one "wrote PATH" line per output, and error classes.
//!
//! # How outputs are written
//!
//! - **Temporary names.** Every file is first written under a temporary name in its
//!   destination folder, `.blueshift-<pid>-<random>.partial` (plus the output's extension
//!   after it, `.partial.exr`, for writers that pick the format from the name), and renamed
//!   over the destination once complete. The process id makes a temporary left by a killed
//!   run recognisable: `blueshift clean` removes those whose process is gone (or that are
//!   older than a day), and the signal handler of [`crate::signals`] removes this process's
//!   own on SIGINT/SIGTERM. Files are created with mode 0666 less the umask.
//! - **Sets (multi-file outputs).** [`OutputSet`] stages every file of an output that spans
//!   several files (a detached NRRD header and its data, an EXR and its PNG preview, a
//!   spectral cube's FITS, NRRD and moment maps) completely under temporary names first, and
//!   only then renames them, in the order staged: a data file before the header that names
//!   it, the preview before the EXR. The renames run under [`crate::signals::gate`], so
//!   SIGINT/SIGTERM either comes before the first rename (nothing replaced) or waits for the
//!   last (the whole new set). A kill -9 between two renames can still leave a new data file
//!   beside an old header: a detached NRRD header therefore records its data file's size and
//!   checksum (`blueshift data:=BYTES FNV1A64`), and the reader refuses a data file that does
//!   not match (`blueshift_volume::io::nrrd`).
//! - **Non-regular destinations.** An existing output that is not a regular file (a
//!   character device such as `/dev/null`, a FIFO, a socket, a block device), and any path
//!   under `/dev/` or `/proc/` (`/dev/stdout`), is never renamed over, removed or created:
//!   the output is staged in the system's temporary folder and then copied into it, as a
//!   shell redirection would. `-` is standard output (`--csv -`, `--png -`, `--out -`).
//! - **Inputs.** An output that is an input (the same canonical path, or the same device
//!   and inode: a hard link or a symlink) is refused, including every file a scene JSON or a
//!   detached header names ([`input_closure`]).

use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result};

/// An error that is blueshift's fault, not the user's (exit code 2).
#[derive(Debug)]
#[allow(dead_code)]
pub struct InternalError(pub String);

impl std::error::Error for InternalError {}

impl std::fmt::Display for InternalError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "internal error: {}", self.0)
    }
}

/// The start of every temporary file name this process makes: `.blueshift-<pid>-`.
pub fn temp_prefix() -> &'static str {
    static PREFIX: std::sync::OnceLock<String> = std::sync::OnceLock::new();
    PREFIX.get_or_init(|| format!(".blueshift-{}-", std::process::id()))
}

/// The process id in a blueshift temporary file name (`.blueshift-<pid>-<random>` followed
/// by dot-separated parts of which one is `partial`: `.partial`, `.partial.exr`,
/// `.bsv.partial`); `None` for any other name, which `blueshift clean` never touches.
pub fn temp_name_pid(name: &str) -> Option<u32> {
    let rest = name.strip_prefix(".blueshift-")?;
    let (pid, rest) = rest.split_once('-')?;
    if pid.is_empty() || !pid.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    let mut parts = rest.split('.');
    let random = parts.next()?;
    if random.is_empty() || !random.bytes().all(|b| b.is_ascii_alphanumeric()) {
        return None;
    }
    let parts: Vec<&str> = parts.collect();
    let ok = parts.contains(&"partial")
        && parts
            .iter()
            .all(|p| !p.is_empty() && p.bytes().all(|b| b.is_ascii_alphanumeric()));
    if !ok {
        return None;
    }
    pid.parse().ok()
}

/// What kind of non-regular file `path` is, when writing to it must not replace it: `-`
/// (standard output), an existing character device, block device, FIFO or socket (symlinks
/// followed), or any path under `/dev/` or `/proc/` (`/dev/stdout`). `None` for regular
/// files and new paths.
pub fn direct_target(path: &Path) -> Option<&'static str> {
    #[cfg(unix)]
    use std::os::unix::fs::FileTypeExt;
    if path == Path::new("-") {
        return Some("standard output");
    }
    let kind = match std::fs::metadata(path) {
        Ok(m) if m.is_file() || m.is_dir() => None,
        #[cfg(unix)]
        Ok(m) if m.file_type().is_char_device() => Some("a character device"),
        #[cfg(unix)]
        Ok(m) if m.file_type().is_block_device() => Some("a block device"),
        #[cfg(unix)]
        Ok(m) if m.file_type().is_fifo() => Some("a FIFO"),
        #[cfg(unix)]
        Ok(m) if m.file_type().is_socket() => Some("a socket"),
        Ok(_) => Some("not a regular file"),
        Err(_) => None,
    };
    kind.or_else(|| {
        let abs = std::path::absolute(path).ok()?;
        (abs.starts_with("/dev") || abs.starts_with("/proc")).then_some("a system file")
    })
}

/// `path` made absolute with its folder's symlinks resolved (the file itself too when it
/// exists), so two spellings of one output compare equal before it exists.
fn resolved(path: &Path) -> Option<PathBuf> {
    if let Ok(p) = std::fs::canonicalize(path) {
        return Some(p);
    }
    let name = path.file_name()?;
    let dir = std::fs::canonicalize(folder_of(path)).ok()?;
    Some(dir.join(name))
}

/// Whether `a` and `b` are the same file: the same canonical path, or (both existing) the
/// same device and inode, so hard links and symlinks count.
#[cfg(test)]
pub fn same_file(a: &Path, b: &Path) -> bool {
    FileKeys::of(a).meets(&FileKeys::of(b))
}

/// What identifies a file for [`same_file`]: its device and inode when it exists, and its
/// [`resolved`] path. Two paths are one file when either key is equal.
struct FileKeys {
    inode: Option<(u64, u64)>,
    path: Option<PathBuf>,
}

impl FileKeys {
    fn of(p: &Path) -> FileKeys {
        #[cfg(unix)]
        let inode = {
            use std::os::unix::fs::MetadataExt;
            std::fs::metadata(p).ok().map(|m| (m.dev(), m.ino()))
        };
        #[cfg(not(unix))]
        let inode = None;
        FileKeys {
            inode,
            path: resolved(p),
        }
    }

    #[cfg(test)]
    fn meets(&self, other: &FileKeys) -> bool {
        (self.inode.is_some() && self.inode == other.inode)
            || (self.path.is_some() && self.path == other.path)
    }
}

/// Files by their [`FileKeys`], so that "is this one of them" costs two lookups.
#[derive(Default)]
struct FileSet<'a> {
    by_inode: std::collections::HashMap<(u64, u64), &'a Path>,
    by_path: std::collections::HashMap<PathBuf, &'a Path>,
}

impl<'a> FileSet<'a> {
    fn insert(&mut self, keys: FileKeys, p: &'a Path) {
        if let Some(i) = keys.inode {
            self.by_inode.entry(i).or_insert(p);
        }
        if let Some(r) = keys.path {
            self.by_path.entry(r).or_insert(p);
        }
    }

    fn find(&self, keys: &FileKeys) -> Option<&'a Path> {
        keys.inode
            .and_then(|i| self.by_inode.get(&i))
            .or_else(|| keys.path.as_ref().and_then(|r| self.by_path.get(r)))
            .copied()
    }
}

/// The largest scene or header file [`input_closure`] reads for the file names in it.
const MAX_NAMING_FILE: u64 = 16 << 20;

/// `inputs` and every file they name: the volumes, transfer functions and other files a
/// scene JSON names (any string in it that names an existing file beside the scene or from
/// the working folder), and the data file of a detached NRRD header or a MetaImage header.
/// Over-inclusive on purpose: an output that is any of these is refused.
pub fn input_closure(inputs: &[&Path]) -> Vec<PathBuf> {
    let mut out: Vec<PathBuf> = Vec::new();
    let mut seen = std::collections::HashSet::new();
    let mut queue: Vec<(PathBuf, u32)> = inputs.iter().map(|p| (p.to_path_buf(), 0)).collect();
    while let Some((p, depth)) = queue.pop() {
        if !seen.insert(p.clone()) {
            continue;
        }
        out.push(p.clone());
        if depth >= 3 {
            continue;
        }
        for named in named_files(&p) {
            queue.push((named, depth + 1));
        }
    }
    out
}

/// The files `path` names (see [`input_closure`]); empty for other files.
fn named_files(path: &Path) -> Vec<PathBuf> {
    let small = std::fs::metadata(path).is_ok_and(|m| m.is_file() && m.len() <= MAX_NAMING_FILE);
    if !small {
        return Vec::new();
    }
    let ext = path
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    let dir = folder_of(path);
    let existing = |name: &str| -> Vec<PathBuf> {
        let name = name.trim();
        if name.is_empty() {
            return Vec::new();
        }
        [dir.join(name), PathBuf::from(name)]
            .into_iter()
            .filter(|c| c.is_file())
            .collect()
    };
    match ext.as_str() {
        "json" => {
            let Ok(text) = std::fs::read_to_string(path) else {
                return Vec::new();
            };
            let Ok(value) = serde_json::from_str::<serde_json::Value>(&text) else {
                return Vec::new();
            };
            let mut strings = Vec::new();
            collect_strings(&value, &mut strings);
            strings.iter().flat_map(|s| existing(s)).collect()
        }
        "nrrd" | "nhdr" | "mhd" => {
            // Headers are small: the first 64 KiB hold the data file line.
            let mut bytes = Vec::new();
            let read = std::fs::File::open(path).and_then(|f| {
                std::io::Read::read_to_end(&mut std::io::Read::take(f, 1 << 16), &mut bytes)
            });
            if read.is_err() {
                return Vec::new();
            }
            // The header only: up to the first blank line (attached NRRD data follows it).
            let end = bytes
                .windows(2)
                .position(|w| w == b"\n\n")
                .unwrap_or(bytes.len());
            let text = String::from_utf8_lossy(&bytes[..end]);
            text.lines()
                .filter_map(|l| {
                    let (k, v) = l.split_once(':').or_else(|| l.split_once('='))?;
                    let k = k.trim().to_ascii_lowercase();
                    matches!(k.as_str(), "data file" | "datafile" | "elementdatafile")
                        .then(|| v.trim_start_matches('=').trim().to_owned())
                })
                .flat_map(|v| existing(&v))
                .collect()
        }
        _ => Vec::new(),
    }
}

fn collect_strings(v: &serde_json::Value, out: &mut Vec<String>) {
    match v {
        serde_json::Value::String(s) if out.len() < 10_000 => out.push(s.clone()),
        serde_json::Value::Array(a) => a.iter().for_each(|x| collect_strings(x, out)),
        serde_json::Value::Object(o) => o.values().for_each(|x| collect_strings(x, out)),
        _ => {}
    }
}

/// Checks, before any work is done, that every output can be written: its folder exists, is
/// a folder and takes new files, the path itself is not a folder, not one of `inputs` nor a
/// file they name ([`input_closure`]; canonical paths and inodes compared), and no two
/// outputs are one file. A non-regular output ([`direct_target`]) is written into, not
/// replaced, so its folder is not probed. The error is one line naming the output (a user
/// error, exit code 1), so a missing folder fails at once instead of after the render.
pub fn check_outputs(outputs: &[&Path], inputs: &[&Path]) -> Result<()> {
    let inputs = input_closure(inputs);
    let mut input_set = FileSet::default();
    for p in &inputs {
        input_set.insert(FileKeys::of(p), p);
    }
    let mut written = FileSet::default();
    let mut dirs_checked: std::collections::HashSet<PathBuf> = std::collections::HashSet::new();
    for out in outputs {
        let shown = out.display();
        if out.as_os_str().is_empty() {
            anyhow::bail!("an output path is empty");
        }
        if out.is_dir() {
            anyhow::bail!("cannot write {shown}: it is a folder (give a file name)");
        }
        let keys = FileKeys::of(out);
        if let Some(input) = input_set.find(&keys) {
            anyhow::bail!(
                "cannot write {shown}: it is the input file {} (choose another output path)",
                input.display()
            );
        }
        let direct = direct_target(out);
        if direct.is_some() {
            continue;
        }
        // An output whose folder does not resolve has no path key, but the folder check
        // below refuses it before a second one is looked up.
        if written.find(&keys).is_some() {
            anyhow::bail!("cannot write {shown} twice (two outputs are the same file)");
        }
        written.insert(keys, out);
        let dir = folder_of(out);
        if !dirs_checked.insert(dir.to_path_buf()) {
            continue;
        }
        match std::fs::metadata(dir) {
            Err(_) => anyhow::bail!(
                "cannot write {shown}: the folder {} does not exist",
                dir.display()
            ),
            Ok(m) if !m.is_dir() => {
                anyhow::bail!("cannot write {shown}: {} is not a folder", dir.display())
            }
            Ok(_) => {}
        }
        // Whether the folder takes new files is what the final rename needs; a probe file
        // answers it exactly (permissions, read-only mounts, ACLs).
        crate::signals::watch_dir(dir);
        let _gate = crate::signals::gate();
        temp_builder().tempfile_in(dir).with_context(|| {
            format!(
                "cannot write {shown}: cannot create files in {}",
                dir.display()
            )
        })?;
    }
    Ok(())
}

/// [`check_outputs`] for one output and no inputs.
pub fn check_output(path: &Path) -> Result<()> {
    check_outputs(&[path], &[])
}

/// The one line every verb prints on stderr per output written: `wrote PATH`.
pub fn wrote(path: &Path) {
    errln!("wrote {}", path.display());
}

/// `wrote PATH (DETAIL)`, for the main output of a verb with something to say about it.
pub fn wrote_with(path: &Path, detail: &str) {
    errln!("wrote {} ({detail})", path.display());
}

/// The folder an output goes to (`.` for a bare file name).
fn folder_of(path: &Path) -> &Path {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    }
}

/// A temporary file named `.blueshift-<pid>-<random>.partial` created with mode 0666 less
/// the umask, the mode a plain `File::create` gives (tempfile's own default is 0600), so the
/// renamed output is as readable as any other file the user makes.
pub fn temp_builder<'b>() -> tempfile::Builder<'static, 'b> {
    let mut b = tempfile::Builder::new();
    b.prefix(temp_prefix());
    b.suffix(".partial");
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        b.permissions(std::fs::Permissions::from_mode(0o666));
    }
    b
}

/// One file of an [`OutputSet`], complete under its temporary name.
#[derive(Debug)]
struct Staged {
    tmp: tempfile::TempPath,
    dest: PathBuf,
    /// Copy into `dest` instead of renaming ([`direct_target`]).
    direct: bool,
}

/// Files written as one output: each is staged completely under a temporary name, then
/// [`OutputSet::commit`] renames them all, in the order staged (stage a data file before
/// the file that names it). Dropping an uncommitted set removes its temporary files.
#[derive(Debug, Default)]
pub struct OutputSet {
    staged: Vec<Staged>,
}

impl OutputSet {
    /// An empty set.
    pub fn new() -> Self {
        Self::default()
    }

    /// A new temporary file for `dest` (with `ext` after `.partial`): in `dest`'s folder,
    /// or in the system's temporary folder for a non-regular destination.
    fn temp_for(dest: &Path, ext: &str) -> Result<(tempfile::NamedTempFile, bool)> {
        let direct = direct_target(dest).is_some();
        let dir = if direct {
            std::env::temp_dir()
        } else {
            folder_of(dest).to_path_buf()
        };
        crate::signals::watch_dir(&dir);
        let suffix = format!(".partial{ext}");
        let _gate = crate::signals::gate();
        let tmp = temp_builder()
            .suffix(&suffix)
            .tempfile_in(&dir)
            .with_context(|| format!("cannot create a temporary file in {}", dir.display()))?;
        Ok((tmp, direct))
    }

    /// Stages `dest` from a closure that writes its bytes.
    pub fn bytes(
        &mut self,
        dest: &Path,
        write: impl FnOnce(&mut dyn Write) -> Result<()>,
    ) -> Result<()> {
        let (mut tmp, direct) = Self::temp_for(dest, "")?;
        {
            let mut buffered = std::io::BufWriter::new(tmp.as_file_mut());
            write(&mut buffered)?;
            buffered
                .flush()
                .with_context(|| format!("cannot write {}", dest.display()))?;
        }
        self.staged.push(Staged {
            tmp: tmp.into_temp_path(),
            dest: dest.to_path_buf(),
            direct,
        });
        Ok(())
    }

    /// Stages `dest` from bytes in memory.
    pub fn put(&mut self, dest: &Path, bytes: &[u8]) -> Result<()> {
        self.bytes(dest, |w| {
            w.write_all(bytes)
                .with_context(|| format!("cannot write {}", dest.display()))
        })
    }

    /// Stages `dest` through a library function that wants a path (image, EXR writers): it
    /// gets a temporary path ending in `dest`'s extension.
    pub fn via_path(&mut self, dest: &Path, write: impl FnOnce(&Path) -> Result<()>) -> Result<()> {
        let ext = dest
            .extension()
            .map(|e| format!(".{}", e.to_string_lossy()))
            .unwrap_or_default();
        let (tmp, direct) = Self::temp_for(dest, &ext)?;
        let tmp = tmp.into_temp_path();
        write(&tmp)?;
        self.staged.push(Staged {
            tmp,
            dest: dest.to_path_buf(),
            direct,
        });
        Ok(())
    }

    /// Renames every staged file over its destination in the order staged, with
    /// SIGINT/SIGTERM held off until the last rename is done; then copies the files for
    /// non-regular destinations into them (outside the hold: opening a FIFO waits for its
    /// reader, and Ctrl-C must still work meanwhile).
    pub fn commit(self) -> Result<()> {
        let (direct, renamed): (Vec<Staged>, Vec<Staged>) =
            self.staged.into_iter().partition(|s| s.direct);
        {
            let _gate = crate::signals::gate();
            let n = renamed.len();
            for (i, s) in renamed.into_iter().enumerate() {
                s.tmp
                    .persist(&s.dest)
                    .map_err(|e| e.error)
                    .with_context(|| format!("cannot write {}", s.dest.display()))?;
                if i + 1 < n {
                    rename_delay_for_tests();
                }
            }
        }
        for s in direct {
            copy_into(&s.tmp, &s.dest)?;
        }
        Ok(())
    }
}

/// Copies the staged file `tmp` into the non-regular `dest` (`-`: standard output), as a
/// shell redirection would: opened for writing, never created, renamed or removed.
fn copy_into(tmp: &Path, dest: &Path) -> Result<()> {
    let what = || {
        if dest == Path::new("-") {
            "cannot write to standard output".to_owned()
        } else {
            format!("cannot write {}", dest.display())
        }
    };
    let mut src = std::fs::File::open(tmp).with_context(what)?;
    if dest == Path::new("-") {
        let mut out = std::io::stdout().lock();
        return std::io::copy(&mut src, &mut out)
            .and_then(|_| out.flush())
            .with_context(what);
    }
    let mut dst = std::fs::OpenOptions::new()
        .write(true)
        .truncate(true)
        .open(dest)
        .with_context(what)?;
    std::io::copy(&mut src, &mut dst)
        .and_then(|_| dst.flush())
        .with_context(what)
}

/// In debug builds, `BLUESHIFT_TEST_RENAME_DELAY_MS=N` sleeps N ms between the renames of
/// an [`OutputSet`], so a test can kill the process between two of them.
fn rename_delay_for_tests() {
    #[cfg(debug_assertions)]
    if let Some(ms) = std::env::var("BLUESHIFT_TEST_RENAME_DELAY_MS")
        .ok()
        .and_then(|v| v.parse::<u64>().ok())
    {
        std::thread::sleep(std::time::Duration::from_millis(ms));
    }
}

/// Writes a file atomically: the bytes go to a temporary file in the same folder, which is
/// renamed over `path` only once it is complete, so a failure never leaves half a file.
pub fn write_atomic(path: &Path, write: impl FnOnce(&mut dyn Write) -> Result<()>) -> Result<()> {
    let mut set = OutputSet::new();
    set.bytes(path, write)?;
    set.commit()
}

/// Writes a file atomically from bytes already in memory.
#[allow(dead_code)]
pub fn write_bytes_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    write_atomic(path, |w| {
        w.write_all(bytes)
            .with_context(|| format!("cannot write {}", path.display()))
    })
}

/// Writes through a library function that wants a path (image, exr writers): it writes to a
/// temporary path with the same extension in the same folder, then renames.
#[allow(dead_code)]
pub fn write_via_temp_path(path: &Path, write: impl FnOnce(&Path) -> Result<()>) -> Result<()> {
    let mut set = OutputSet::new();
    set.via_path(path, write)?;
    set.commit()
}

/// What the three colour channels of an EXR hold.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum ExrSpace {
    /// CIE 1931 XYZ in the R, G, B channels, with the `chromaticities` attribute for XYZ
    /// (red (1, 0), green (0, 1), blue (0, 0), white (1/3, 1/3)), so that colour-managed
    /// readers show the right colours.
    Xyz,
    /// Linear sRGB (Rec. 709 primaries, D65): the OpenEXR default, no attribute written.
    LinearSrgb,
}

/// Writes an OpenEXR of 32-bit float channels atomically: `data` holds `width x height`
/// pixels row by row with `channels` values each (3: RGB, 4: RGBA). The blocks are
/// compressed one after the other, so the same picture always gives the same bytes (the
/// `image` crate's writer compresses them on several threads and writes them in the order
/// they finish, so two runs of the same render differed in their bytes).
pub fn write_exr_f32(
    path: &Path,
    width: u32,
    height: u32,
    channels: usize,
    data: &[f32],
) -> Result<()> {
    write_exr_f32_in(path, width, height, channels, data, ExrSpace::LinearSrgb)
}

/// [`write_exr_f32`] for channels in `space` (XYZ gets its `chromaticities` attribute):
/// blueshift-tonemap's writer, so the viewer's saved frames are the same bytes.
pub fn write_exr_f32_in(
    path: &Path,
    width: u32,
    height: u32,
    channels: usize,
    data: &[f32],
    space: ExrSpace,
) -> Result<()> {
    let space = match space {
        ExrSpace::Xyz => blueshift_tonemap::io::ExrSpace::Xyz,
        ExrSpace::LinearSrgb => blueshift_tonemap::io::ExrSpace::LinearSrgb,
    };
    write_via_temp_path(path, |p| {
        blueshift_tonemap::io::write_exr_f32_channels(p, width, height, channels, data, space)
            .with_context(|| format!("cannot write {}", path.display()))
    })
}

/// Writes an EXR straight to `path` (blueshift-tonemap's block-after-block writer); for
/// [`OutputSet::via_path`].
pub fn exr_file(
    path: &Path,
    (width, height): (u32, u32),
    channels: usize,
    data: &[f32],
    space: ExrSpace,
) -> Result<()> {
    let space = match space {
        ExrSpace::Xyz => blueshift_tonemap::io::ExrSpace::Xyz,
        ExrSpace::LinearSrgb => blueshift_tonemap::io::ExrSpace::LinearSrgb,
    };
    blueshift_tonemap::io::write_exr_f32_channels(path, width, height, channels, data, space)
        .map_err(anyhow::Error::from)
}

/// Stages [`write_exr_f32`] in `set`.
pub fn stage_exr_f32(
    set: &mut OutputSet,
    path: &Path,
    (width, height): (u32, u32),
    channels: usize,
    data: &[f32],
) -> Result<()> {
    set.via_path(path, |p| {
        blueshift_tonemap::io::write_exr_f32_channels(
            p,
            width,
            height,
            channels,
            data,
            blueshift_tonemap::io::ExrSpace::LinearSrgb,
        )
        .with_context(|| format!("cannot write {}", path.display()))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn temp_names_are_recognised_and_nothing_else() {
        let me = std::process::id();
        let made = temp_builder().tempfile_in(std::env::temp_dir()).unwrap();
        let name = made
            .path()
            .file_name()
            .unwrap()
            .to_str()
            .unwrap()
            .to_owned();
        assert_eq!(temp_name_pid(&name), Some(me), "{name}");
        for (name, pid) in [
            (".blueshift-12-aZ09.partial", Some(12)),
            (".blueshift-12-aZ09.partial.exr", Some(12)),
            (".blueshift-12-aZ09.bsv.partial", Some(12)),
            (".blueshift-12-aZ09.exr", None),
            (".blueshift-check-aZ09.partial", None),
            (".blueshift-12-.partial", None),
            (".blueshift-12-a/b.partial", None),
            (".blueshift-12-ab.partial..x", None),
            ("blueshift-12-ab.partial", None),
            ("out.partial", None),
        ] {
            assert_eq!(temp_name_pid(name), pid, "{name}");
        }
    }

    #[test]
    fn same_file_sees_links_and_spellings() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        std::fs::write(d.join("a"), b"x").unwrap();
        std::fs::hard_link(d.join("a"), d.join("b")).unwrap();
        std::os::unix::fs::symlink(d.join("a"), d.join("c")).unwrap();
        assert!(same_file(&d.join("a"), &d.join("b")));
        assert!(same_file(&d.join("a"), &d.join("c")));
        assert!(same_file(&d.join("new"), &d.join(".").join("new")));
        assert!(!same_file(&d.join("a"), &d.join("new")));
    }
}
