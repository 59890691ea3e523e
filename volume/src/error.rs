//! The crate's one error type and the allocation limits every reader checks.

/// Everything that can go wrong in `blueshift-volume`, grouped by who has to act.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// The file or argument is malformed: a bad header, truncated data, inconsistent sizes.
    /// The message names the format and the offending field.
    #[error("invalid data: {0}")]
    Invalid(String),
    /// The file is well formed but uses a feature this crate does not read (an unknown
    /// voxel type, a rotated space direction, an encoding other than raw/gzip/zlib).
    #[error("unsupported: {0}")]
    Unsupported(String),
    /// The header asks for more voxels or bytes than [`Limits`] allows. Nothing was allocated.
    #[error("limits exceeded: {0}")]
    Limits(String),
    /// A caller-supplied parameter is out of range (zero macrocell size, unknown channel).
    #[error("invalid parameter: {0}")]
    Parameter(String),
    /// NaN or infinite voxel values where the caller asked for them to be rejected.
    #[error("non-finite voxel value {value} at voxel [{x}, {y}, {z}]")]
    NonFinite {
        /// The offending value (NaN or ±Inf).
        value: f32,
        /// Voxel index along x.
        x: usize,
        /// Voxel index along y.
        y: usize,
        /// Voxel index along z.
        z: usize,
    },
    /// An operating-system I/O error (file not found, permission denied, disk full).
    #[error(transparent)]
    Io(std::io::Error),
    /// The operation's memory estimate exceeds the [`crate::budget::MemoryBudget`]. Nothing
    /// was allocated.
    #[error(transparent)]
    Budget(#[from] crate::budget::BudgetError),
}

impl Error {
    pub(crate) fn invalid(msg: impl Into<String>) -> Self {
        Error::Invalid(msg.into())
    }
    pub(crate) fn unsupported(msg: impl Into<String>) -> Self {
        Error::Unsupported(msg.into())
    }
    pub(crate) fn parameter(msg: impl Into<String>) -> Self {
        Error::Parameter(msg.into())
    }
    /// The same error, of the same kind, with `context` before its message ("NRRD: ..."):
    /// wrapping the whole error in another would print its kind twice.
    pub(crate) fn context(self, context: &str) -> Self {
        match self {
            Error::Invalid(m) => Error::Invalid(format!("{context}: {m}")),
            Error::Unsupported(m) => Error::Unsupported(format!("{context}: {m}")),
            Error::Limits(m) => Error::Limits(format!("{context}: {m}")),
            Error::Parameter(m) => Error::Parameter(format!("{context}: {m}")),
            other => other,
        }
    }
}

impl From<std::io::Error> for Error {
    /// `UnexpectedEof` is a truncated file, which is [`Error::Invalid`]; the rest stays `Io`.
    fn from(e: std::io::Error) -> Self {
        if e.kind() == std::io::ErrorKind::UnexpectedEof {
            Error::Invalid("truncated file: unexpected end of data".into())
        } else if e.kind() == std::io::ErrorKind::InvalidData {
            Error::Invalid(format!("corrupt compressed data: {e}"))
        } else {
            Error::Io(e)
        }
    }
}

/// `Result` with this crate's [`Error`].
pub type Result<T> = std::result::Result<T, Error>;

/// Caps that readers check before they allocate (like `image::Limits`).
///
/// Header dimensions are multiplied with `checked_mul` and compared with these caps, and with
/// the size of the file, before any buffer is reserved, so a lying header cannot exhaust
/// memory.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Limits {
    /// Largest number of voxels (per channel, vector voxels count once).
    pub max_voxels: u64,
    /// Largest number of bytes a reader may allocate for one channel (in memory, after
    /// conversion to the in-memory type).
    pub max_alloc_bytes: u64,
}

impl Default for Limits {
    /// 2^31 voxels and 8 GiB per channel.
    fn default() -> Self {
        Limits {
            max_voxels: 1 << 31,
            max_alloc_bytes: 8 << 30,
        }
    }
}

impl Limits {
    /// No caps at all (only the file size still bounds what is read).
    #[must_use]
    pub fn no_limits() -> Self {
        Limits {
            max_voxels: u64::MAX,
            max_alloc_bytes: u64::MAX,
        }
    }

    /// Checks `dims` (with `bytes_per_voxel` in memory) against the caps.
    pub fn check(&self, dims: [usize; 3], bytes_per_voxel: usize) -> Result<u64> {
        let n = (dims[0] as u64)
            .checked_mul(dims[1] as u64)
            .and_then(|n| n.checked_mul(dims[2] as u64))
            .ok_or_else(|| Error::Limits(format!("dimensions {dims:?} overflow")))?;
        if n > self.max_voxels {
            return Err(Error::Limits(format!(
                "{n} voxels ({dims:?}) exceed the limit of {} voxels",
                self.max_voxels
            )));
        }
        let bytes = n
            .checked_mul(bytes_per_voxel as u64)
            .ok_or_else(|| Error::Limits(format!("dimensions {dims:?} overflow")))?;
        if bytes > self.max_alloc_bytes {
            return Err(Error::Limits(format!(
                "{bytes} bytes for {dims:?} exceed the allocation limit of {} bytes",
                self.max_alloc_bytes
            )));
        }
        Ok(n)
    }
}
