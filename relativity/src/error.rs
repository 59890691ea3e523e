//! The crate's error type.

use std::path::PathBuf;

/// Everything that can go wrong in `blueshift-relativity`, grouped by who has to act.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// The run was cancelled through its observer.
    #[error("cancelled")]
    Cancelled,
    /// A velocity that is not allowed: NaN/infinite components or `|beta| >= 1`.
    #[error("invalid velocity beta = ({x}, {y}, {z}): {reason}")]
    Velocity {
        /// x component of beta.
        x: f64,
        /// y component of beta.
        y: f64,
        /// z component of beta.
        z: f64,
        /// Why it was refused.
        reason: &'static str,
    },
    /// A numeric parameter out of its domain (field of view, image size, direction, ...).
    #[error("invalid {name} = {value}: {reason}")]
    Parameter {
        /// What the value is, with its unit.
        name: &'static str,
        /// The refused value.
        value: f64,
        /// Why it was refused.
        reason: &'static str,
    },
    /// A name in an effect list that is not an effect.
    #[error("unknown effect '{name}' (expected aberration, doppler, searchlight, all or none)")]
    Effect {
        /// The word given.
        name: String,
    },
    /// An environment map that cannot be used (wrong face sizes, empty, too large, missing faces).
    #[error("malformed environment map {path}: {reason}")]
    MalformedMap {
        /// The file or folder.
        path: PathBuf,
        /// What is wrong with it.
        reason: String,
    },
    /// A file could not be read or decoded, or written.
    #[error("cannot read or write image {path}: {source}")]
    Image {
        /// The file.
        path: PathBuf,
        /// The decoder's or encoder's error.
        #[source]
        source: image::ImageError,
    },
    /// An error from the spectrum crate (colour conversions).
    #[error(transparent)]
    Spectrum(#[from] blueshift_spectrum::Error),
    /// An OpenEXR or PFM file that could not be read (its message names the file).
    #[error(transparent)]
    Hdr(#[from] blueshift_tonemap::Error),
}

/// `Result` with this crate's [`Error`].
pub type Result<T> = std::result::Result<T, Error>;

impl Error {
    pub(crate) fn param(name: &'static str, value: f64, reason: &'static str) -> Self {
        Self::Parameter {
            name,
            value,
            reason,
        }
    }
    pub(crate) fn map(path: impl Into<PathBuf>, reason: impl Into<String>) -> Self {
        Self::MalformedMap {
            path: path.into(),
            reason: reason.into(),
        }
    }
}
