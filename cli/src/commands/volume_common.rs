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
    let safe: String = suffix
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' {
                c
            } else {
                '_'
            }
        })
        .collect();
    path.with_file_name(format!("{stem}_{safe}{ext}"))
}

/// Writes one channel in an in-core format (NRRD, detached NRRD, raw), atomically.
pub fn write_channel(
    path: &Path,
    channel: &Channel,
    fmt: OutFormat,
    opts: &nrrd::WriteOptions,
) -> Result<()> {
    match fmt {
        OutFormat::Nrrd => output::write_atomic(path, |w| {
            nrrd::write(w, channel, opts)
                .with_context(|| format!("cannot write {}", path.display()))?;
            Ok(())
        }),
        OutFormat::Raw => output::write_atomic(path, |w| {
            raw::write_raw_as(w, channel, opts.disk)
                .with_context(|| format!("cannot write {}", path.display()))?;
            Ok(())
        }),
        OutFormat::Nhdr => {
            let data_path = path.with_extension(if opts.gzip { "raw.gz" } else { "raw" });
            let data_name = data_path
                .file_name()
                .map(|s| s.to_string_lossy().to_string())
                .unwrap_or_default();
            let mut header = Vec::new();
            let mut data = Vec::new();
            nrrd::write_detached(&mut header, &mut data, &data_name, channel, opts)
                .with_context(|| format!("cannot write {}", path.display()))?;
            output::write_bytes_atomic(&data_path, &data)?;
            output::write_bytes_atomic(path, &header)
        }
        OutFormat::Bricked => anyhow::bail!("internal: bricked output goes through convert"),
    }
}

/// Writes the channels of `vol` (or only `only`): the first to `path`, each further one to
/// `stem_<channel>.ext` beside it. Returns the paths written (a detached header after its
/// data file).
pub fn write_volume(
    path: &Path,
    vol: &Volume,
    only: Option<&str>,
    opts: &nrrd::WriteOptions,
) -> Result<Vec<PathBuf>> {
    let fmt = out_format(path)?;
    let chans: Vec<&Channel> = match only {
        Some(name) => vec![vol.channel(name).ok_or_else(|| {
            let names: Vec<&str> = vol.channels().iter().map(|c| c.name.as_str()).collect();
            anyhow::anyhow!("no channel '{name}' (channels: {})", names.join(", "))
        })?],
        None => vol.channels().iter().collect(),
    };
    let mut written = Vec::new();
    for (i, c) in chans.iter().enumerate() {
        let p = if i == 0 {
            path.to_path_buf()
        } else {
            sibling(path, &c.name)
        };
        write_channel(&p, c, fmt, opts)?;
        if fmt == OutFormat::Nhdr {
            // The detached data file beside the header is an output too.
            written.push(p.with_extension(if opts.gzip { "raw.gz" } else { "raw" }));
        }
        written.push(p);
    }
    Ok(written)
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
        Ok(blueshift_volume::ReadOptions {
            raw,
            reject_non_finite: self.reject_non_finite,
            ..Default::default()
        })
    }

    /// Reads `path` with these options; errors end with the path.
    pub fn read(&self, path: &Path) -> Result<Volume> {
        blueshift_volume::read_with(path, &self.read_options()?).map_err(|e| with_path(&e, path))
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
