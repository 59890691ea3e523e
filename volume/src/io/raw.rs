//! Headerless raw voxels, with size and type from arguments or from the Open SciVis file-name
//! convention `name_XxYxZ_dtype.raw` (e.g. `skull_256x256x256_uint8.raw`).
//!
//! Raw data is x fastest, then y, then z; little-endian unless told otherwise. Geometry is
//! unit spacing and zero origin (a raw file carries none).

use std::io::{Seek, SeekFrom, Write};
use std::path::Path;

use super::{DiskType, Encoding, Endian, Layout, ReadOptions, decode, finish, open, read_payload};
use crate::grid::Geometry;
use crate::volume::{Channel, Volume};
use crate::{Error, Result};

/// Size and type parsed from an Open SciVis file name.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SciVisName {
    /// Voxels along x, y, z.
    pub dims: [usize; 3],
    /// Voxel type.
    pub disk: DiskType,
    /// Components per voxel (`name_XxYxZx3_float32.raw` gives 3, otherwise 1).
    pub components: usize,
    /// Byte order: big-endian where the type ends in `be` (`int16be`), little otherwise.
    pub endian: Endian,
}

/// Parses `name_XxYxZ_dtype.raw` (also `name_XxYxZx3_dtype.raw` for interleaved vectors, and
/// a trailing `le`/`be` on the type, e.g. `int16le`). Returns `None` if the name does not
/// follow the convention.
#[must_use]
pub fn parse_scivis_name(path: &Path) -> Option<SciVisName> {
    let name = path.file_name()?.to_str()?;
    let stem = name
        .strip_suffix(".raw")
        .or_else(|| name.strip_suffix(".RAW"))?;
    let mut parts = stem.rsplitn(3, '_');
    let dtype = parts.next()?;
    let size = parts.next()?;
    let _name = parts.next()?;
    let endian = if dtype.ends_with("be") {
        Endian::Big
    } else {
        Endian::Little
    };
    let dtype = dtype
        .strip_suffix("le")
        .or_else(|| dtype.strip_suffix("be"))
        .filter(|t| DiskType::from_scivis_name(t).is_some())
        .unwrap_or(dtype);
    let disk = DiskType::from_scivis_name(dtype)?;
    let nums: Vec<usize> = size
        .split('x')
        .map(|s| s.parse().ok())
        .collect::<Option<_>>()?;
    let (dims, components) = match nums.as_slice() {
        [x, y, z] => ([*x, *y, *z], 1),
        [x, y, z, 3] => ([*x, *y, *z], 3),
        _ => return None,
    };
    if dims.contains(&0) {
        return None;
    }
    Some(SciVisName {
        dims,
        disk,
        components,
        endian,
    })
}

impl SciVisName {
    /// Bytes of voxels the name describes (`None` if that overflows).
    #[must_use]
    pub fn byte_len(&self) -> Option<u64> {
        self.dims
            .iter()
            .try_fold(self.components as u64, |n, &d| n.checked_mul(d as u64))?
            .checked_mul(self.disk.size_bytes() as u64)
    }

    /// Refuses a file of `file_len` bytes that is not exactly the size its name gives: the
    /// name is the file's only description, so a longer file was misnamed (or appended to)
    /// and reading it by the name would silently drop or misplace voxels.
    ///
    /// # Errors
    /// [`Error::Invalid`] naming both sizes and the file.
    pub fn check_len(&self, file_len: u64, path: &Path) -> Result<()> {
        match self.byte_len() {
            Some(want) if want == file_len => Ok(()),
            want => Err(Error::invalid(format!(
                "raw: its Open SciVis name says {}x{}x{}{} {} = {} bytes, the file holds {file_len}: {}",
                self.dims[0],
                self.dims[1],
                self.dims[2],
                if self.components == 3 { "x3" } else { "" },
                self.disk.scivis_name(),
                want.map_or_else(|| "too many".to_string(), |w| w.to_string()),
                path.display()
            ))),
        }
    }
}

/// The Open SciVis file name for a volume: `{name}_{X}x{Y}x{Z}_{dtype}.raw`.
#[must_use]
pub fn scivis_file_name(name: &str, dims: [usize; 3], disk: DiskType) -> String {
    format!(
        "{name}_{}x{}x{}_{}.raw",
        dims[0],
        dims[1],
        dims[2],
        disk.scivis_name()
    )
}

/// Reads a raw file whose name follows the Open SciVis convention (little-endian unless
/// the type ends in `be`).
pub fn read_scivis(path: &Path, opts: &ReadOptions) -> Result<Volume> {
    let n = parse_scivis_name(path).ok_or_else(|| {
        Error::invalid(format!(
            "raw file name does not follow name_XxYxZ_dtype.raw: {}",
            path.display()
        ))
    })?;
    n.check_len(open(path)?.1, path)?;
    read_raw(path, n.dims, n.disk, n.endian, n.components, 0, opts)
}

/// Reads `dims` voxels of `disk` type from `path`, starting `offset` bytes in. The file must
/// hold at least that many bytes (more is allowed, as for files with a trailer).
pub fn read_raw(
    path: &Path,
    dims: [usize; 3],
    disk: DiskType,
    endian: Endian,
    components: usize,
    offset: u64,
    opts: &ReadOptions,
) -> Result<Volume> {
    if components != 1 && components != 3 {
        return Err(Error::parameter(format!(
            "{components} components (1 or 3)"
        )));
    }
    let layout = Layout {
        dims,
        disk,
        endian,
        components,
        flip: [false; 3],
    };
    let len = layout.byte_len(&opts.limits)?;
    let (mut f, file_len) = open(path)?;
    let avail = file_len.saturating_sub(offset);
    if (len as u64) > avail {
        return Err(Error::invalid(format!(
            "raw: {dims:?} x {} x {} bytes need {len} bytes, the file holds {avail}: {}",
            components,
            disk.size_bytes(),
            path.display()
        )));
    }
    f.seek(SeekFrom::Start(offset))?;
    let mut bytes = read_payload(std::io::BufReader::new(f), Encoding::Raw, len)?;
    let grid = decode(&mut bytes, &layout, Geometry::unit(dims))?;
    let name = if components == 3 {
        "vectors"
    } else {
        "scalars"
    };
    finish(name, grid, disk, opts)
}

/// Writes a channel as headerless little-endian voxels of [`super::output_type`]; returns the
/// type written (which the caller needs for the file name).
pub fn write_raw(w: &mut dyn Write, channel: &Channel) -> Result<DiskType> {
    write_raw_as(w, channel, None)
}

/// Writes a channel as headerless little-endian voxels of `disk` (or
/// [`super::output_type`] for `None`); integer targets round to nearest and saturate.
pub fn write_raw_as(
    w: &mut dyn Write,
    channel: &Channel,
    disk: Option<DiskType>,
) -> Result<DiskType> {
    let disk = disk.unwrap_or_else(|| super::output_type(channel));
    w.write_all(&super::encode(&channel.grid, disk))?;
    Ok(disk)
}
