//! The error type of prism-model.

use std::path::PathBuf;

/// What can go wrong when loading or checking a model configuration, building the model or
/// exporting its predictions.
#[derive(Debug, thiserror::Error)]
pub enum ModelError {
    /// The config file could not be read.
    #[error("cannot read config file {path}: {cause}")]
    Read {
        /// The file.
        path: PathBuf,
        /// Why.
        cause: std::io::Error,
    },
    /// The config file is not valid TOML or does not match the expected sections.
    #[error("{path}: {message}")]
    Parse {
        /// The file.
        path: PathBuf,
        /// The parser's message, with the line and the field.
        message: String,
    },
    /// A field has a value the model cannot be built with.
    #[error("invalid config value `{field}`: {message}")]
    Invalid {
        /// The field, as `section.field` (e.g. `model.heads`).
        field: String,
        /// What is wrong with it.
        message: String,
    },
    /// The body model named by `model.body_model` could not be loaded.
    #[error("body model: {0}")]
    Body(prism_body::BodyError),
    /// Exporting predicted Gaussians failed.
    #[error("{0}")]
    Render(#[from] prism_render::RenderError),
    /// An LVSM checkpoint that cannot be read, or does not fit the config (see `tools/lvsm.rs`).
    #[error("LVSM checkpoint {path}: {message}")]
    Lvsm {
        /// The checkpoint file.
        path: PathBuf,
        /// What is wrong: the first mismatch with the config, a tensor prism has no place for.
        message: String,
    },
    /// [`ModelError::Invalid`] found in a file.
    #[error("{path}: invalid value of `{field}`: {message}")]
    InvalidInFile {
        /// The file.
        path: PathBuf,
        /// The field, as `section.field`.
        field: String,
        /// What is wrong with it.
        message: String,
    },
}

impl ModelError {
    /// A [`ModelError::Invalid`] for `field`.
    pub fn invalid(field: impl Into<String>, message: impl Into<String>) -> Self {
        Self::Invalid {
            field: field.into(),
            message: message.into(),
        }
    }

    /// Attaches the file an [`ModelError::Invalid`] came from (other variants pass through).
    pub fn in_file(self, path: impl Into<PathBuf>) -> Self {
        match self {
            Self::Invalid { field, message } => Self::InvalidInFile {
                path: path.into(),
                field,
                message,
            },
            other => other,
        }
    }
}
