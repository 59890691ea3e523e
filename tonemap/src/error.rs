//! The crate's error type.

use std::path::PathBuf;

/// Everything that can go wrong in `blueshift-tonemap`, grouped by who has to act.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// The file is malformed or truncated (the user must supply a valid file).
    #[error("invalid {format} file: {message}: {path}")]
    Invalid {
        /// File format that was being read ("OpenEXR", "Radiance HDR", "PFM").
        format: &'static str,
        /// What is wrong.
        message: String,
        /// The file.
        path: PathBuf,
    },
    /// The file is valid but uses a feature this crate does not read.
    #[error("unsupported {format} file: {message}: {path}")]
    Unsupported {
        /// File format.
        format: &'static str,
        /// What is not supported.
        message: String,
        /// The file.
        path: PathBuf,
    },
    /// The image is larger than the configured limit (checked before allocating).
    #[error("image of {width} x {height} pixels exceeds the limit of {max_pixels} pixels")]
    Limits {
        /// Width in pixels.
        width: u64,
        /// Height in pixels.
        height: u64,
        /// The limit in pixels.
        max_pixels: u64,
    },
    /// Decoding the image would allocate more than [`crate::io::Limits::max_bytes`]
    /// (checked from the header, before decoding).
    #[error(
        "decoding {width} x {height} pixels needs {needed} bytes, more than the limit of {max_bytes} bytes"
    )]
    Memory {
        /// Width in pixels.
        width: u64,
        /// Height in pixels.
        height: u64,
        /// The estimated bytes.
        needed: u64,
        /// The limit in bytes.
        max_bytes: u64,
    },
    /// A parameter is out of its valid range (the caller must change it).
    #[error("invalid parameter: {0}")]
    Parameter(String),
    /// The operation does not exist for this operator (e.g. the inverse of a local operator).
    #[error("{0}")]
    NotInvertible(String),
    /// The image is empty (zero width or height).
    #[error("the image is empty (0 pixels)")]
    EmptyImage,
    /// An input/output error (disk, permissions).
    #[error("{message}: {path}")]
    Io {
        /// What was being done.
        message: String,
        /// The file.
        path: PathBuf,
        /// The underlying error.
        #[source]
        source: std::io::Error,
    },
}

/// `Result` with this crate's [`Error`].
pub type Result<T> = std::result::Result<T, Error>;

impl Error {
    pub(crate) fn parameter(message: impl Into<String>) -> Self {
        Error::Parameter(message.into())
    }
    pub(crate) fn invalid(
        format: &'static str,
        message: impl Into<String>,
        path: impl Into<PathBuf>,
    ) -> Self {
        Error::Invalid {
            format,
            message: message.into(),
            path: path.into(),
        }
    }
    pub(crate) fn io(
        message: impl Into<String>,
        path: impl Into<PathBuf>,
        source: std::io::Error,
    ) -> Self {
        Error::Io {
            message: message.into(),
            path: path.into(),
            source,
        }
    }
}
