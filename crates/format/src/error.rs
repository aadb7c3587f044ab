//! The crate's one error type, shaped by what the caller does next.

use std::path::PathBuf;

/// What went wrong, by what the caller can do about it.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// The input breaks the format (truncated, inconsistent, out of range): fix or
    /// re-export the asset. `what` names the object, e.g. `texture 0 level 1 channel C03`.
    #[error("invalid {what}")]
    Invalid {
        /// What is invalid and why.
        what: String,
    },
    /// The input is well formed but uses something this version does not implement
    /// (a newer extension version, an unknown architecture or dtype): show the fallback.
    #[error("not supported: {what}")]
    NotSupported {
        /// The unsupported feature.
        what: String,
    },
    /// A size read from the input exceeds the configured [`crate::Limits`]: raise the
    /// limit if the input is trusted.
    #[error("{what} is {value}, above the limit of {limit}")]
    LimitExceeded {
        /// The quantity, e.g. `texture side`.
        what: String,
        /// The value found.
        value: u64,
        /// The limit in force.
        limit: u64,
    },
    /// Reading or writing a file failed.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The underlying error.
        source: std::io::Error,
    },
}

/// Result with this crate's [`Error`].
pub type Result<T, E = Error> = std::result::Result<T, E>;

impl Error {
    /// Shorthand for [`Error::Invalid`].
    pub fn invalid(what: impl Into<String>) -> Self {
        Error::Invalid { what: what.into() }
    }

    /// Shorthand for [`Error::NotSupported`].
    pub fn not_supported(what: impl Into<String>) -> Self {
        Error::NotSupported { what: what.into() }
    }

    /// Shorthand for [`Error::Io`].
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Error::Io {
            path: path.into(),
            source,
        }
    }
}
