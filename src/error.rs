//! The one error type of the library. Errors are values: every stage returns
//! `Result<T, Error>`, nothing a user can influence panics.

use std::path::PathBuf;

/// What went wrong, with enough context (what and where) to fix the input.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// The input is malformed or out of range. `at` names the file, key or
    /// parameter; `what` says what was wrong with it.
    #[error("{at}: {what}")]
    InvalidInput { at: String, what: String },
    /// The request is well formed but this build or machine cannot do it
    /// (no GPU adapter, an operation a field type lacks, ...).
    #[error("not supported: {0}")]
    NotSupported(String),
    /// A plan would need more memory than the budget allows; refused before
    /// allocating (Linux overcommit makes failed allocations unreliable).
    #[error("out of memory: {what} needs {needed} bytes, budget is {budget} bytes")]
    OutOfMemory {
        what: String,
        needed: u64,
        budget: u64,
    },
    /// The GPU driver or runtime failed.
    #[error("GPU failure: {0}")]
    Gpu(String),
    /// Reading or writing a file failed.
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
}

/// Result with the library's [`Error`].
pub type Result<T> = std::result::Result<T, Error>;

impl Error {
    /// Shorthand for [`Error::InvalidInput`].
    pub fn invalid(at: impl Into<String>, what: impl Into<String>) -> Self {
        Error::InvalidInput {
            at: at.into(),
            what: what.into(),
        }
    }

    /// Shorthand for [`Error::Io`].
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Error::Io {
            path: path.into(),
            source,
        }
    }
}
