//! The crate's error type.

/// Everything that can go wrong in `blueshift-camera`.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// A camera or session parameter is out of range (eye and target coincide, a field of
    /// view outside (0, 180) degrees, ...). The message names the parameter.
    #[error("invalid parameter: {0}")]
    Parameter(String),
}

impl Error {
    /// An [`Error::Parameter`] with `msg`.
    pub fn parameter(msg: impl Into<String>) -> Self {
        Error::Parameter(msg.into())
    }
}

/// `Result` with this crate's [`Error`].
pub type Result<T> = std::result::Result<T, Error>;
