//! The error type of prism-render.

use std::path::PathBuf;

/// Everything that can go wrong in prism-render.
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    /// Tensor shapes or cameras that do not fit together.
    #[error("invalid render input: {0}")]
    Input(String),
    /// A value given by the user (such as a background colour) is not valid.
    #[error("{0}")]
    Value(String),
    /// A file could not be read or written.
    #[error("{path}: {error}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The underlying error (part of the message, so not also a `source`).
        error: std::io::Error,
    },
    /// A file was read but its content is not what it should be.
    #[error("{path}: {message}")]
    Format {
        /// The file.
        path: PathBuf,
        /// What is wrong with it.
        message: String,
    },
}

impl RenderError {
    /// An [`RenderError::Io`] for `path`.
    pub fn io(path: impl Into<PathBuf>, error: std::io::Error) -> Self {
        Self::Io {
            path: path.into(),
            error,
        }
    }

    /// A [`RenderError::Format`] for `path`.
    pub fn format(path: impl Into<PathBuf>, message: impl Into<String>) -> Self {
        Self::Format {
            path: path.into(),
            message: message.into(),
        }
    }
}
