//! Errors of scan loading: each names the file and, for syntax errors, the line.

use std::path::PathBuf;

use thiserror::Error;

/// Why a scan could not be loaded or normalised.
#[derive(Debug, Error)]
pub enum ScanError {
    /// The file could not be read.
    #[error("cannot read {}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The operating system's reason.
        source: std::io::Error,
    },
    /// A line of a text format (OBJ, MTL) does not parse.
    #[error("{}:{line}: {message}", path.display())]
    Syntax {
        /// The file.
        path: PathBuf,
        /// Line number, from 1.
        line: usize,
        /// What is wrong.
        message: String,
    },
    /// The file parses but holds nothing to render, or a glTF file is invalid.
    #[error("{}: {message}", path.display())]
    Invalid {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// The mesh cannot be normalised (no extent along the up axis).
    #[error("{0}")]
    Degenerate(String),
    /// The file's extension names no supported format.
    #[error("{}: unsupported mesh format (expected .obj, .glb or .gltf)", path.display())]
    Unsupported {
        /// The file.
        path: PathBuf,
    },
}

impl ScanError {
    /// A syntax error at `line` of `path`.
    pub(crate) fn syntax(path: &std::path::Path, line: usize, message: impl Into<String>) -> Self {
        Self::Syntax {
            path: path.to_path_buf(),
            line,
            message: message.into(),
        }
    }

    /// An invalid-content error for `path`.
    pub(crate) fn invalid(path: &std::path::Path, message: impl Into<String>) -> Self {
        Self::Invalid {
            path: path.to_path_buf(),
            message: message.into(),
        }
    }
}
