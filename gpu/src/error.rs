//! The crate's error type: every wgpu failure becomes one of these variants.

/// Errors of the GPU backends. Every wgpu failure is turned into one of these; nothing in
/// this crate panics on a GPU error.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// No adapter matched the request (none at all, or none of the kind asked for).
    #[error("no wgpu adapter: {0}")]
    NoAdapter(String),
    /// The adapter refused to create a device.
    #[error("requesting a wgpu device failed: {0}")]
    RequestDevice(String),
    /// The device was lost (driver reset, out of resources, destroyed).
    #[error("wgpu device lost: {0}")]
    DeviceLost(String),
    /// The device ran out of memory.
    #[error("GPU out of memory: {0}")]
    OutOfMemory(String),
    /// A wgpu validation error (bad shader, bad binding, bad dispatch).
    #[error("wgpu validation error: {0}")]
    Validation(String),
    /// An internal wgpu / driver error.
    #[error("wgpu internal error: {0}")]
    Internal(String),
    /// A request exceeds one of the device's limits; checked before anything is created.
    #[error("{what} needs {requested} but the device limit {limit} is {max}")]
    LimitExceeded {
        /// What was being created (a buffer label, a dispatch).
        what: String,
        /// The name of the `wgpu::Limits` field.
        limit: &'static str,
        /// The amount requested.
        requested: u64,
        /// The device's limit.
        max: u64,
    },
    /// Mapping a buffer for readback failed.
    #[error("mapping a GPU buffer failed: {0}")]
    Map(String),
    /// Waiting for the device (poll) failed.
    #[error("waiting for the GPU failed: {0}")]
    Poll(String),
    /// Invalid input to a GPU pipeline (bad parameters, bad sizes, non-finite values).
    #[error("invalid input: {0}")]
    InvalidInput(String),
    /// The operation has no GPU implementation (the caller may fall back to the CPU).
    #[error("not supported on the GPU: {0}")]
    Unsupported(String),
    /// The run was cancelled through its observer.
    #[error("cancelled")]
    Cancelled,
    /// An error of the CPU tone-mapping crate (parameters are validated by it).
    #[error(transparent)]
    Tonemap(#[from] blueshift_tonemap::Error),
    /// An error of the CPU relativity crate (parameters are validated by it).
    #[error(transparent)]
    Relativity(#[from] blueshift_relativity::Error),
}

impl From<blueshift_volume::Error> for Error {
    /// A brick of an out-of-core (`.bsv`) field the GPU's brick pool could not read: the
    /// job is unsupported here, so `--device auto` renders it on the CPU, which reports
    /// the read error itself.
    fn from(e: blueshift_volume::Error) -> Self {
        Error::Unsupported(format!(
            "reading an out-of-core brick for the GPU's brick pool: {e}"
        ))
    }
}

impl From<blueshift_doppler::Error> for Error {
    /// The Doppler crate's errors in a GPU render: cancellation stays cancellation; the
    /// rest are the CPU's messages for bad input.
    fn from(e: blueshift_doppler::Error) -> Self {
        match e {
            blueshift_doppler::Error::Cancelled => Error::Cancelled,
            other => Error::InvalidInput(other.to_string()),
        }
    }
}

impl Error {
    /// Converts a wgpu error (from an error scope or the uncaptured-error handler).
    pub fn from_wgpu(err: &wgpu::Error) -> Self {
        match err {
            wgpu::Error::OutOfMemory { .. } => Error::OutOfMemory(err.to_string()),
            wgpu::Error::Validation { description, .. } => Error::Validation(description.clone()),
            wgpu::Error::Internal { description, .. } => Error::Internal(description.clone()),
        }
    }
}

/// Result with this crate's [`Error`].
pub type Result<T> = std::result::Result<T, Error>;
