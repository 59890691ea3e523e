//! The viewer's error type.

/// What can go wrong starting or running the viewer, or handling one message.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// The address cannot be bound, the folder cannot be written, a socket failed.
    #[error("{what}: {source}")]
    Io {
        /// What was being done.
        what: String,
        /// The cause.
        source: std::io::Error,
    },
    /// A malformed or out-of-range message or setting.
    #[error("{0}")]
    Invalid(String),
    /// The tracking engine refused.
    #[error(transparent)]
    Tracking(#[from] blueshift_tracking::Error),
    /// The Doppler engine refused.
    #[error(transparent)]
    Doppler(#[from] blueshift_doppler::Error),
    /// The relativity engine refused.
    #[error(transparent)]
    Relativity(#[from] blueshift_relativity::Error),
    /// Tone mapping refused.
    #[error(transparent)]
    Tonemap(#[from] blueshift_tonemap::Error),
    /// A transfer function was refused.
    #[error(transparent)]
    Tf(#[from] blueshift_tfedit::Error),
    /// The camera was refused.
    #[error(transparent)]
    Camera(#[from] blueshift_camera::Error),
    /// The GPU refused.
    #[error(transparent)]
    Gpu(#[from] blueshift_gpu::Error),
    /// The render was cancelled by a newer edit (not shown to the user).
    #[error("cancelled")]
    Cancelled,
}

impl Error {
    /// An [`Error::Invalid`].
    pub fn invalid(msg: impl Into<String>) -> Self {
        Error::Invalid(msg.into())
    }

    /// An [`Error::Io`].
    pub fn io(what: impl Into<String>, source: std::io::Error) -> Self {
        Error::Io {
            what: what.into(),
            source,
        }
    }

    /// Whether this is a cancellation, from any engine.
    #[must_use]
    pub fn is_cancelled(&self) -> bool {
        matches!(
            self,
            Error::Cancelled
                | Error::Tracking(blueshift_tracking::Error::Cancelled)
                | Error::Doppler(blueshift_doppler::Error::Cancelled)
                | Error::Relativity(blueshift_relativity::Error::Cancelled)
                | Error::Gpu(blueshift_gpu::Error::Cancelled)
        )
    }
}

/// The viewer's result type.
pub type Result<T> = std::result::Result<T, Error>;
