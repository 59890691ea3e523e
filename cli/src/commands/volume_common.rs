//! Helpers shared by the volume verbs (`info`, `convert`, `synth`).

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use blueshift_volume::io::{DiskType, nrrd, raw};
use blueshift_volume::{Channel, Volume};

use crate::output;

/// Parses a voxel type name (`uint8`, `int16`, `float32`, `u16`, `float`, ...).
pub fn parse_disk_type(s: &str) -> Result<DiskType, String> {
    DiskType::from_scivis_name(s).ok_or_else(|| {
        format!(
            "unknown voxel type '{s}' (uint8, int8, uint16, int16, uint32, int32, float32, float64)"
        )
    })
}

/// The output formats chosen by extension.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum OutFormat {
    /// Attached NRRD.
    Nrrd,
    /// Detached NRRD header plus a `.raw` data file beside it.
    Nhdr,
    /// Headerless raw voxels.
    Raw,
    /// Bricked out-of-core file.
    Bricked,
}

/// Picks the output format from `path`'s extension.
pub fn out_format(path: &Path) -> Result<OutFormat> {
    let ext = path
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    Ok(match ext.as_str() {
        "nrrd" => OutFormat::Nrrd,
        "nhdr" => OutFormat::Nhdr,
        "raw" => OutFormat::Raw,
        "bsv" => OutFormat::Bricked,
        _ => anyhow::bail!(
            "cannot tell the output format from the extension of {} (use .nrrd, .nhdr, .raw or .bsv)",
            path.display()
        ),
    })
}

/// `dir/stem_suffix.ext` for extra channels written next to `path`.
pub fn sibling(path: &Path, suffix: &str) -> PathBuf {
    let stem = path
        .file_stem()
        .map(|s| s.to_string_lossy().to_string())
        .unwrap_or_default();
    let ext = path
        .extension()
        .map(|e| format!(".{}", e.to_string_lossy()))
        .unwrap_or_default();
    path.with_file_name(format!("{stem}_{}{ext}", file_safe(suffix)))
}

/// `s` with every character but ASCII letters, digits and `-` made `_`.
fn file_safe(s: &str) -> String {
    s.chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' {
                c
            } else {
                '_'
            }
        })
        .collect()
}

/// The file of channel `i` of those written to `path`: `path` itself for the first, a
/// [`sibling`] named after the channel for the others. Beside a raw file with an Open
/// SciVis name, the sibling gets one too, with this channel's size, components and type last
/// (`name_channel_XxYxZ[x3]_dtype.raw`), so it reads back by its name as the first does.
fn channel_path(path: &Path, i: usize, c: &Channel, opts: &nrrd::WriteOptions) -> PathBuf {
    if i == 0 {
        return path.to_path_buf();
    }
    let scivis =
        matches!(out_format(path), Ok(OutFormat::Raw)) && raw::parse_scivis_name(path).is_some();
    let stem = path
        .file_stem()
        .map(|s| s.to_string_lossy().to_string())
        .unwrap_or_default();
    // The name before `_XxYxZ_dtype`.
    if let Some(name) = stem.rsplitn(3, '_').nth(2).filter(|_| scivis) {
        let [x, y, z] = c.grid.geometry().dims;
        let vector = if c.grid.is_vector() { "x3" } else { "" };
        let disk = opts
            .disk
            .unwrap_or_else(|| blueshift_volume::io::output_type(c));
        return path.with_file_name(format!(
            "{name}_{}_{x}x{y}x{z}{vector}_{}.raw",
            file_safe(&c.name),
            disk.scivis_name()
        ));
    }
    sibling(path, &c.name)
}

/// Refuses to write `channel` as `disk` into a raw file whose Open SciVis name
/// (`name_XxYxZ_dtype.raw`) says another type, size or component count: a reader would take
/// the name at its word and read garbage.
fn check_scivis_name(path: &Path, channel: &Channel, disk: DiskType) -> Result<()> {
    let Some(n) = raw::parse_scivis_name(path) else {
        return Ok(());
    };
    if n.endian == blueshift_volume::io::Endian::Big {
        anyhow::bail!(
            "cannot write {}: its Open SciVis name says big-endian but raw files are written \
             little-endian (drop the type's 'be', or name it 'le')",
            path.display()
        );
    }
    let dims = channel.grid.geometry().dims;
    let components = if channel.grid.is_vector() { 3 } else { 1 };
    if n.disk != disk || n.dims != dims || n.components != components {
        let shape = |d: [usize; 3], c: usize, t: DiskType| {
            let extra = if c == 3 { "x3" } else { "" };
            format!("{}x{}x{}{extra} {}", d[0], d[1], d[2], t.scivis_name())
        };
        anyhow::bail!(
            "cannot write {}: its Open SciVis name says {} but the data is {} (rename it{})",
            path.display(),
            shape(n.dims, n.components, n.disk),
            shape(dims, components, disk),
            if n.disk == disk {
                String::new()
            } else {
                format!(" or pass --type {}", n.disk.scivis_name())
            }
        );
    }
    Ok(())
}

/// The detached data file beside a `.nhdr` header.
pub fn nhdr_data_path(path: &Path, gzip: bool) -> PathBuf {
    path.with_extension(if gzip { "raw.gz" } else { "raw" })
}

/// Stages one channel in an in-core format (NRRD, detached NRRD, raw) in `set`; a detached
/// header is staged after its data file, so it is renamed after it.
pub fn stage_channel(
    set: &mut output::OutputSet,
    path: &Path,
    channel: &Channel,
    fmt: OutFormat,
    opts: &nrrd::WriteOptions,
) -> Result<()> {
    let disk = opts
        .disk
        .unwrap_or_else(|| blueshift_volume::io::output_type(channel));
    match fmt {
        OutFormat::Nrrd => set.bytes(path, |w| {
            nrrd::write(w, channel, opts)
                .with_context(|| format!("cannot write {}", path.display()))?;
            Ok(())
        }),
        OutFormat::Raw => {
            check_scivis_name(path, channel, disk)?;
            set.bytes(path, |w| {
                raw::write_raw_as(w, channel, opts.disk)
                    .with_context(|| format!("cannot write {}", path.display()))?;
                Ok(())
            })
        }
        OutFormat::Nhdr => {
            let data_path = nhdr_data_path(path, opts.gzip);
            if !opts.gzip {
                check_scivis_name(&data_path, channel, disk)?;
            }
            let data_name = data_path
                .file_name()
                .map(|s| s.to_string_lossy().to_string())
                .unwrap_or_default();
            let mut header = Vec::new();
            let mut data = Vec::new();
            nrrd::write_detached(&mut header, &mut data, &data_name, channel, opts)
                .with_context(|| format!("cannot write {}", path.display()))?;
            set.put(&data_path, &data)?;
            set.put(path, &header)
        }
        OutFormat::Bricked => anyhow::bail!("internal: bricked output goes through convert"),
    }
}

/// The channels of `vol` that [`write_volume`] writes (all, or only `only`).
pub fn channels_to_write<'v>(vol: &'v Volume, only: Option<&str>) -> Result<Vec<&'v Channel>> {
    Ok(match only {
        Some(name) => vec![vol.channel(name).ok_or_else(|| {
            let names: Vec<&str> = vol.channels().iter().map(|c| c.name.as_str()).collect();
            anyhow::anyhow!("no channel '{name}' (channels: {})", names.join(", "))
        })?],
        None => vol.channels().iter().collect(),
    })
}

/// Every file [`write_volume`] writes for `vol` at `path`, data files before their headers.
pub fn volume_outputs(
    path: &Path,
    vol: &Volume,
    only: Option<&str>,
    opts: &nrrd::WriteOptions,
) -> Result<Vec<PathBuf>> {
    let fmt = out_format(path)?;
    let mut files = Vec::new();
    for (i, c) in channels_to_write(vol, only)?.iter().enumerate() {
        let p = channel_path(path, i, c, opts);
        if fmt == OutFormat::Nhdr {
            // The detached data file beside the header is an output too.
            files.push(nhdr_data_path(&p, opts.gzip));
        }
        files.push(p);
    }
    Ok(files)
}

/// Writes the channels of `vol` (or only `only`): the first to `path`, each further one to
/// `stem_<channel>.ext` beside it, all as one [`output::OutputSet`] (every file staged, then
/// renamed; a detached header after its data file). Returns the paths written.
pub fn write_volume(
    path: &Path,
    vol: &Volume,
    only: Option<&str>,
    opts: &nrrd::WriteOptions,
) -> Result<Vec<PathBuf>> {
    let fmt = out_format(path)?;
    let chans = channels_to_write(vol, only)?;
    let mut set = output::OutputSet::new();
    for (i, c) in chans.iter().enumerate() {
        let p = channel_path(path, i, c, opts);
        stage_channel(&mut set, &p, c, fmt, opts)?;
    }
    set.commit()?;
    volume_outputs(path, vol, only, opts)
}

/// Flags describing a headerless raw input whose name does not follow the Open SciVis
/// convention, plus reader checks.
#[derive(Debug, Clone, clap::Args)]
pub struct InputArgs {
    /// Read the input as headerless raw voxels with these dimensions, "X,Y,Z".
    #[arg(long, value_parser = parse_dims, requires = "raw_type")]
    pub raw_dims: Option<[usize; 3]>,
    /// Voxel type of the raw input (uint8, int8, uint16, int16, uint32, int32, float32, float64).
    #[arg(long, value_parser = parse_disk_type, requires = "raw_dims")]
    pub raw_type: Option<DiskType>,
    /// Byte order of the raw input.
    #[arg(long, default_value = "little", value_parser = ["little", "big"])]
    pub raw_endian: String,
    /// Components per raw voxel: 1 (scalars) or 3 (interleaved vectors).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u8).range(1..=3))]
    pub raw_components: u8,
    /// Bytes to skip at the start of the raw input.
    #[arg(long, default_value_t = 0)]
    pub raw_offset: u64,
    /// Refuse inputs holding NaN or infinite voxels.
    #[arg(long)]
    pub reject_non_finite: bool,
}

fn parse_dims(s: &str) -> Result<[usize; 3], String> {
    let v: Vec<usize> = s
        .split([',', 'x'])
        .map(|c| {
            c.trim()
                .parse::<usize>()
                .map_err(|_| format!("'{c}' is not a positive integer"))
        })
        .collect::<Result<_, _>>()?;
    match v.as_slice() {
        [x, y, z] if v.iter().all(|&d| d > 0) => Ok([*x, *y, *z]),
        _ => Err(format!("'{s}' must be three positive integers X,Y,Z")),
    }
}

impl InputArgs {
    /// The reader options these flags ask for.
    pub fn read_options(&self) -> Result<blueshift_volume::ReadOptions> {
        let raw = match (self.raw_dims, self.raw_type) {
            (Some(dims), Some(disk)) => {
                if self.raw_components == 2 {
                    anyhow::bail!("--raw-components must be 1 or 3");
                }
                Some(blueshift_volume::RawSpec {
                    dims,
                    disk,
                    endian: if self.raw_endian == "big" {
                        blueshift_volume::io::Endian::Big
                    } else {
                        blueshift_volume::io::Endian::Little
                    },
                    components: usize::from(self.raw_components),
                    offset: self.raw_offset,
                })
            }
            _ => None,
        };
        // Every channel a reader allocates is also checked against --max-memory (a gzip
        // NRRD or a whole .bsv level read in core).
        let mut limits = blueshift_volume::Limits::default();
        limits.max_alloc_bytes = limits.max_alloc_bytes.min(crate::limits::budget().bytes());
        Ok(blueshift_volume::ReadOptions {
            raw,
            reject_non_finite: self.reject_non_finite,
            limits,
        })
    }

    /// Reads `path` with these options; errors end with the path.
    pub fn read(&self, path: &Path) -> Result<Volume> {
        blueshift_volume::read_with(path, &self.read_options()?).map_err(|e| read_error(&e, path))
    }
}

/// A read's error for the user: the path last, and the setting to change where the volume
/// does not fit `--max-memory`.
pub fn read_error(e: &blueshift_volume::Error, path: &Path) -> anyhow::Error {
    match e {
        blueshift_volume::Error::Limits(_) => anyhow::anyhow!(
            "{} (--max-memory; a .bsv file renders within --cache-mb)",
            with_path(e, path)
        ),
        e => with_path(e, path),
    }
}

/// The error's message with the file path last (once, even if the message already ends with it).
pub fn with_path(e: &dyn std::fmt::Display, path: &Path) -> anyhow::Error {
    let msg = e.to_string();
    let p = path.display().to_string();
    if msg.ends_with(&p) {
        anyhow::anyhow!("{msg}")
    } else {
        anyhow::anyhow!("{msg}: {p}")
    }
}
