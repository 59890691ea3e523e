//! The crate's error type.

/// Everything that can go wrong in `blueshift-tracking`.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// The scene is inconsistent: no channels, channels of different geometry, a vector
    /// channel, a non-finite density scale. The message names the offending field.
    #[error("invalid scene: {0}")]
    Scene(String),
    /// A render or integrator parameter is out of range (zero samples per pixel, a zero
    /// image size, a non-positive step, weights that do not match the channel count).
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
    /// The run was cancelled through its observer.
    #[error("cancelled")]
    Cancelled,
    /// An error from the camera crate (a degenerate camera).
    #[error(transparent)]
    Camera(#[from] blueshift_camera::Error),
    /// An error from the volume crate (macrocells, grids).
    #[error(transparent)]
    Volume(#[from] blueshift_volume::Error),
    /// An error from the transfer-function crate.
    #[error(transparent)]
    TransferFunction(#[from] blueshift_tfedit::Error),
}

impl Error {
    pub(crate) fn scene(msg: impl Into<String>) -> Self {
        Error::Scene(msg.into())
    }
    pub(crate) fn parameter(msg: impl Into<String>) -> Self {
        Error::Parameter(msg.into())
    }
}

/// `Result` with this crate's [`Error`].
pub type Result<T> = std::result::Result<T, Error>;
