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
    /// A name that is not one of the accepted spellings (a method, blend, precision, camera or
    /// DDA mode); lists the accepted ones: `method: unknown 'x' (woodcock, mdwt-ndda, ...)`.
    #[error("{what}: unknown '{given}' ({})", accepted.join(", "))]
    UnknownName {
        /// What kind of name (`method`, `blend`, `precision`, ...).
        what: &'static str,
        /// The spelling given.
        given: String,
        /// The accepted spellings.
        accepted: &'static [&'static str],
    },
    /// A field of a render scene (a scene file or the flags that set it) is wrong. `field`
    /// names it as the scene file spells it (`channels[1].volume`, `channels[0].tf 'x.json'`,
    /// `light.direction`, `alpha_g`); `message` says what is wrong and `source`, if any, is
    /// the underlying error (a volume reader's, a transfer function's).
    #[error("{field}{}", message.as_deref().map(|m| format!(": {m}")).unwrap_or_default())]
    Field {
        /// The field.
        field: String,
        /// What is wrong, if more than the source says.
        message: Option<String>,
        /// The underlying error.
        #[source]
        source: Option<Box<dyn std::error::Error + Send + Sync + 'static>>,
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
    /// An [`Error::Field`] with a message and no source.
    pub(crate) fn field(field: impl Into<String>, message: impl Into<String>) -> Self {
        Error::Field {
            field: field.into(),
            message: Some(message.into()),
            source: None,
        }
    }
    /// An [`Error::Field`] caused by `source` (with an optional message before it).
    pub(crate) fn field_from(
        field: impl Into<String>,
        message: Option<String>,
        source: impl std::error::Error + Send + Sync + 'static,
    ) -> Self {
        Error::Field {
            field: field.into(),
            message,
            source: Some(Box::new(source)),
        }
    }
}

/// `Result` with this crate's [`Error`].
pub type Result<T> = std::result::Result<T, Error>;
