//! Output helpers shared by all verbs: checking output paths before any work, atomic file
//! writes, the one "wrote PATH" line per output, and error classes.

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

/// Checks, before any work is done, that every output can be written: its folder exists, is
/// a folder and takes new files, the path itself is not a folder and not one of `inputs`.
/// The error is one line naming the output (a user error, exit code 1), so a missing folder
/// fails at once instead of after the render.
pub fn check_outputs(outputs: &[&Path], inputs: &[&Path]) -> Result<()> {
    let same = |a: &Path, b: &Path| match (std::fs::canonicalize(a), std::fs::canonicalize(b)) {
        (Ok(a), Ok(b)) => a == b,
        _ => false,
    };
    let mut dirs_checked: Vec<PathBuf> = Vec::new();
    for (i, out) in outputs.iter().enumerate() {
        let shown = out.display();
        if out.as_os_str().is_empty() {
            anyhow::bail!("an output path is empty");
        }
        if out.is_dir() {
            anyhow::bail!("cannot write {shown}: it is a folder (give a file name)");
        }
        if let Some(input) = inputs.iter().find(|input| same(out, input)) {
            anyhow::bail!(
                "cannot write {shown}: it is the input file {} (choose another output path)",
                input.display()
            );
        }
        if outputs[..i].iter().any(|o| o == out) {
            anyhow::bail!("cannot write {shown} twice (two outputs have the same path)");
        }
        let dir = folder_of(out);
        if dirs_checked.iter().any(|d| d == dir) {
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
        tempfile::Builder::new()
            .prefix(".blueshift-check-")
            .tempfile_in(dir)
            .with_context(|| {
                format!(
                    "cannot write {shown}: cannot create files in {}",
                    dir.display()
                )
            })?;
        dirs_checked.push(dir.to_path_buf());
    }
    Ok(())
}

/// [`check_outputs`] for one output and no inputs.
pub fn check_output(path: &Path) -> Result<()> {
    check_outputs(&[path], &[])
}

/// The one line every verb prints on stderr per output written: `wrote PATH`.
pub fn wrote(path: &Path) {
    eprintln!("wrote {}", path.display());
}

/// `wrote PATH (DETAIL)`, for the main output of a verb with something to say about it.
pub fn wrote_with(path: &Path, detail: &str) {
    eprintln!("wrote {} ({detail})", path.display());
}

/// The folder an output goes to (`.` for a bare file name).
fn folder_of(path: &Path) -> &Path {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    }
}

/// A temporary file in `dir` created with mode 0666 less the umask, the mode a plain
/// `File::create` gives (tempfile's own default is 0600), so the renamed output is as
/// readable as any other file the user makes.
pub fn temp_builder<'a>() -> tempfile::Builder<'a, 'a> {
    let mut b = tempfile::Builder::new();
    b.prefix(".blueshift-");
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        b.permissions(std::fs::Permissions::from_mode(0o666));
    }
    b
}

/// Writes a file atomically: the bytes go to a temporary file in the same folder, which is
/// renamed over `path` only once it is complete, so a failure never leaves half a file.
pub fn write_atomic(path: &Path, write: impl FnOnce(&mut dyn Write) -> Result<()>) -> Result<()> {
    let dir = folder_of(path);
    let mut tmp = temp_builder()
        .tempfile_in(dir)
        .with_context(|| format!("cannot create a temporary file in {}", dir.display()))?;
    {
        let mut buffered = std::io::BufWriter::new(tmp.as_file_mut());
        write(&mut buffered)?;
        buffered
            .flush()
            .with_context(|| format!("cannot write {}", path.display()))?;
    }
    tmp.persist(path)
        .map_err(|e| e.error)
        .with_context(|| format!("cannot write {}", path.display()))?;
    Ok(())
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
    let dir = folder_of(path);
    let ext = path
        .extension()
        .map(|e| format!(".{}", e.to_string_lossy()))
        .unwrap_or_default();
    let tmp = temp_builder()
        .suffix(&ext)
        .tempfile_in(dir)
        .with_context(|| format!("cannot create a temporary file in {}", dir.display()))?;
    let tmp_path = tmp.into_temp_path();
    write(&tmp_path)?;
    tmp_path
        .persist(path)
        .map_err(|e| e.error)
        .with_context(|| format!("cannot write {}", path.display()))?;
    Ok(())
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
    blueshift_tonemap::io::write_exr_f32_channels(path, width, height, channels, data, space)
        .map_err(anyhow::Error::from)
}
