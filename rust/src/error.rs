//! The one error type of the core. Bindings turn `InvalidArgument` into `ValueError` and
//! `Io`/`Parse` into `OSError`/`ValueError`, always naming what was wrong.

use std::path::PathBuf;

/// Everything that can go wrong in the core. Every variant carries enough text to tell the
/// user which argument or file was at fault.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// An argument failed validation: `name` is the argument, `reason` what was wrong.
    #[error("{name}: {reason}")]
    InvalidArgument { name: String, reason: String },
    /// A file could not be read.
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// A file was read but its contents are malformed.
    #[error("{}: {reason}", path.display())]
    Parse { path: PathBuf, reason: String },
}

impl Error {
    /// Shorthand for [`Error::InvalidArgument`].
    pub fn invalid(name: impl Into<String>, reason: impl Into<String>) -> Self {
        Error::InvalidArgument {
            name: name.into(),
            reason: reason.into(),
        }
    }
}

/// Result with the core's [`Error`].
pub type Result<T> = std::result::Result<T, Error>;
