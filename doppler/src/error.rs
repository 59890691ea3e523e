//! The crate's error type.

/// Everything that can go wrong in `blueshift-doppler`.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// The scene is inconsistent: species of different geometry, a velocity field of
    /// another shape, non-finite values. The message names the offending field.
    #[error("invalid scene: {0}")]
    Scene(String),
    /// A render parameter is out of range (a zero image size, a non-positive step, a
    /// wavelength range the wrong way round). The message names the parameter.
    #[error("invalid parameter: {0}")]
    Parameter(String),
    /// A scene file is unreadable or inconsistent; names the file.
    #[error("scene file {path}: {message}")]
    SceneFile {
        /// The scene file (or the data file it names).
        path: String,
        /// What is wrong.
        message: String,
    },
    /// A name that is not one of the accepted spellings (a colour matrix, a band shift);
    /// lists the accepted ones: `colour matrix: unknown 'x' (srgb, cie)`.
    #[error("{what}: unknown '{given}' ({})", accepted.join(", "))]
    UnknownName {
        /// What kind of name.
        what: &'static str,
        /// The spelling given.
        given: String,
        /// The accepted spellings.
        accepted: &'static [&'static str],
    },
    /// A FITS file that [`crate::read_fits`] cannot read: no `SIMPLE = T`, a missing or bad
    /// mandatory card, no `END`, or less data than the header announces.
    #[error("malformed FITS: {0}")]
    MalformedFits(String),
    /// The run was cancelled through its observer.
    #[error("cancelled")]
    Cancelled,
    /// An error from the camera crate (a degenerate camera).
    #[error(transparent)]
    Camera(#[from] blueshift_camera::Error),
    /// An error from the volume crate (grids, readers).
    #[error(transparent)]
    Volume(#[from] blueshift_volume::Error),
}

impl Error {
    pub(crate) fn scene(msg: impl Into<String>) -> Self {
        Error::Scene(msg.into())
    }
    pub(crate) fn parameter(msg: impl Into<String>) -> Self {
        Error::Parameter(msg.into())
    }
    /// An [`Error::UnknownName`].
    pub(crate) fn unknown(
        what: &'static str,
        given: &str,
        accepted: &'static [&'static str],
    ) -> Self {
        Error::UnknownName {
            what,
            given: given.to_owned(),
            accepted,
        }
    }
}

/// `Result` with this crate's [`Error`].
pub type Result<T> = std::result::Result<T, Error>;
