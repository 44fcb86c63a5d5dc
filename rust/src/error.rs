//! The one error type of the core. Bindings turn `InvalidArgument` into `ValueError`,
//! `Io`/`Parse` into `OSError`/`ValueError` and `OutOfMemory` into `MemoryError`, always
//! naming what was wrong.

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
    /// The buffers a call needs for `what` (e.g. a camera's pixels) could not be allocated.
    #[error(
        "{what}: needs {:.1} GiB of buffers, which could not be allocated (use a smaller size)",
        *bytes as f64 / (1u64 << 30) as f64
    )]
    OutOfMemory { what: String, bytes: usize },
    /// Work stopped at the caller's request (e.g. [`crate::visibility::VisibilityCache::request_stop`]),
    /// leaving its objects as they were before the unfinished step.
    #[error("{what}: interrupted")]
    Interrupted { what: String },
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

/// Kept here for the callers that check a total before starting; see [`crate::alloc`].
pub use crate::alloc::check_memory;

/// Bytes per pixel a call's buffers take at most: the G-buffer and its per-ray staging
/// (about 120 B), per-pixel sums of a render (128 B) and its RGB outputs (36 B), rounded up.
pub const BYTES_PER_PIXEL: usize = 320;

/// Result with the core's [`Error`].
pub type Result<T> = std::result::Result<T, Error>;

/// Fails, naming `name`, unless `lo <= value <= hi`.
pub fn check_range<T: PartialOrd + std::fmt::Display>(
    name: &str,
    value: T,
    lo: T,
    hi: T,
) -> Result<()> {
    if lo <= value && value <= hi {
        Ok(())
    } else {
        Err(Error::invalid(
            name,
            format!("must lie in [{lo}, {hi}], got {value}"),
        ))
    }
}

/// Fails, naming `time_budget`, unless the budget is absent or a finite, positive number of
/// seconds.
pub fn check_time_budget(time_budget: Option<f64>) -> Result<()> {
    match time_budget {
        Some(b) if !(b.is_finite() && b > 0.0) => Err(Error::invalid(
            "time_budget",
            format!("must be a positive number of seconds, got {b}"),
        )),
        _ => Ok(()),
    }
}
