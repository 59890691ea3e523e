//! The crate's error type.

/// Everything that can go wrong in blueshift-spectrum. Each variant names the offending value
/// and where it came from, so a caller can print it as one line.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// A numeric parameter is out of its domain (NaN, infinite, negative, zero, |beta| >= 1, ...).
    #[error("invalid {name} = {value}: {reason}")]
    Parameter {
        /// What the value is, with its unit (for example `temperature_k`).
        name: &'static str,
        /// The value that was refused.
        value: f64,
        /// Why it was refused.
        reason: &'static str,
    },
    /// A wavelength interval that is empty, reversed or not finite.
    #[error("invalid {name} [{min_nm}, {max_nm}] nm: {reason}")]
    Range {
        /// What the interval is (for example `wavelength range`).
        name: &'static str,
        /// Lower end in nm.
        min_nm: f64,
        /// Upper end in nm.
        max_nm: f64,
        /// Why it was refused.
        reason: &'static str,
    },
    /// Two banded spectra of different layouts were combined.
    #[error("band layouts differ: {a} and {b}")]
    LayoutMismatch {
        /// The first layout, as text.
        a: String,
        /// The second layout, as text.
        b: String,
    },
    /// A malformed row of a text table (a line list, a spectrum CSV).
    #[error("{source_name}, line {line}: {message}")]
    Parse {
        /// The file name or another label of where the text came from.
        source_name: String,
        /// 1-based line number.
        line: usize,
        /// What is wrong with it.
        message: String,
    },
    /// An unknown catalogue or observer name.
    #[error("unknown {what} {name:?} (known: {known})")]
    UnknownName {
        /// What kind of name (for example `line catalogue`).
        what: &'static str,
        /// The name that was given.
        name: String,
        /// The names that exist.
        known: &'static str,
    },
    /// Reading a file failed.
    #[error("cannot read {path}: {source}")]
    Io {
        /// The path that was read.
        path: String,
        /// The underlying error.
        #[source]
        source: std::io::Error,
    },
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
}

/// Checks that `value` is finite and strictly positive.
pub(crate) fn positive(name: &'static str, value: f64) -> Result<f64> {
    if value.is_finite() && value > 0.0 {
        Ok(value)
    } else {
        Err(Error::param(name, value, "must be finite and > 0"))
    }
}

/// Checks that `value` is finite and not negative.
pub(crate) fn non_negative(name: &'static str, value: f64) -> Result<f64> {
    if value.is_finite() && value >= 0.0 {
        Ok(value)
    } else {
        Err(Error::param(name, value, "must be finite and >= 0"))
    }
}

/// Checks a wavelength interval: finite, `min < max`.
pub(crate) fn range(name: &'static str, min_nm: f64, max_nm: f64) -> Result<(f64, f64)> {
    if !(min_nm.is_finite() && max_nm.is_finite()) {
        return Err(Error::Range {
            name,
            min_nm,
            max_nm,
            reason: "ends must be finite",
        });
    }
    if min_nm >= max_nm {
        return Err(Error::Range {
            name,
            min_nm,
            max_nm,
            reason: "must have min < max",
        });
    }
    Ok((min_nm, max_nm))
}
