//! The crate's error type.

/// Everything that can go wrong in `blueshift-tfedit`, grouped by who has to act.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// A transfer function, preset or file content is malformed: unsorted or empty knots,
    /// opacities outside [0, 1], NaN, a truncated JSON file. The message names the entry.
    #[error("invalid transfer function: {0}")]
    Invalid(String),
    /// A parameter passed by the caller is out of range: an absurd LUT length, a focus
    /// region that leaves no room for the context (M_min <= 0), overlapping foci.
    #[error("invalid parameter: {0}")]
    Parameter(String),
    /// Something the format allows but this crate does not support (ParaView categorical
    /// `IndexedColors` maps, for example).
    #[error("unsupported: {0}")]
    Unsupported(String),
    /// Reading or writing a file failed.
    #[error("{context}: {source}")]
    Io {
        /// What was being done, with the file path last.
        context: String,
        /// The underlying I/O error.
        #[source]
        source: std::io::Error,
    },
}

impl Error {
    pub(crate) fn invalid(msg: impl Into<String>) -> Self {
        Error::Invalid(msg.into())
    }
    pub(crate) fn parameter(msg: impl Into<String>) -> Self {
        Error::Parameter(msg.into())
    }
}

/// `Result` with this crate's [`Error`].
pub type Result<T> = std::result::Result<T, Error>;
