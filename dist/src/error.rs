//! The crate's error type.

/// What can go wrong in a distributed render.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// A bad parameter (rank count, image size, decomposition).
    #[error("{0}")]
    Parameter(String),
    /// The communicator failed (a peer went away, a message of the wrong size).
    #[error("communication: {0}")]
    Comm(String),
    /// Another rank failed in the phase named; that rank reports its own error.
    #[error("another rank failed during {0} (its error is reported there)")]
    PeerFailed(&'static str),
    /// The tracking engine refused or failed.
    #[error(transparent)]
    Tracking(#[from] blueshift_tracking::Error),
    /// The Doppler engine refused or failed.
    #[error(transparent)]
    Doppler(#[from] blueshift_doppler::Error),
}

impl Error {
    pub(crate) fn parameter(msg: impl Into<String>) -> Self {
        Error::Parameter(msg.into())
    }
    pub(crate) fn comm(msg: impl Into<String>) -> Self {
        Error::Comm(msg.into())
    }
}

/// `Result` with this crate's [`Error`].
pub type Result<T> = std::result::Result<T, Error>;
