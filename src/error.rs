//! Typed errors of the library. Every variant names what was wrong and, for files, the path.

use std::path::PathBuf;

/// Result alias for the library.
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// Everything that can go wrong in the library.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A file could not be opened, read or written. The OS error is part of the message and not
    /// also a `source`, so an error chain prints it once.
    #[error("{path}: {cause}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The underlying error.
        cause: std::io::Error,
    },
    /// A file was read but its content is not what was expected (corrupt, truncated, wrong channels).
    #[error("{path}: {message}")]
    Format {
        /// The file.
        path: PathBuf,
        /// What was wrong, naming the field and what was expected.
        message: String,
    },
    /// A parameter is out of its valid range.
    #[error("invalid {name}: {message}")]
    Invalid {
        /// The parameter (flag or field) name.
        name: &'static str,
        /// What was given and what was expected.
        message: String,
    },
    /// Two inputs disagree (e.g. image and depth sizes).
    #[error("mismatch: {0}")]
    Mismatch(String),
    /// A scene, method or option name that is not known.
    #[error("unknown {kind} '{name}' (expected one of: {expected})")]
    Unknown {
        /// What kind of thing (scene, method, ...).
        kind: &'static str,
        /// The name given.
        name: String,
        /// The valid names.
        expected: String,
    },
}

impl Error {
    /// Shorthand for [`Error::Invalid`].
    pub fn invalid(name: &'static str, message: impl Into<String>) -> Self {
        Error::Invalid {
            name,
            message: message.into(),
        }
    }

    /// Shorthand for [`Error::Format`].
    pub fn format(path: impl Into<PathBuf>, message: impl Into<String>) -> Self {
        Error::Format {
            path: path.into(),
            message: message.into(),
        }
    }

    /// Shorthand for [`Error::Io`].
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Error::Io {
            path: path.into(),
            cause: source,
        }
    }
}
