//! The error type of prism-train.

use std::path::PathBuf;

use prism_data::DataError;
use prism_losses::LossError;
use prism_model::ModelError;

/// What can go wrong when configuring, running, checkpointing or resuming training.
#[derive(Debug, thiserror::Error)]
pub enum TrainError {
    /// The config file could not be read.
    #[error("cannot read config file {path}: {cause}")]
    ReadConfig {
        /// The file.
        path: PathBuf,
        /// Why.
        cause: std::io::Error,
    },
    /// A config file is not valid TOML or misses / mistypes a field.
    #[error("{path}: {message}")]
    ParseConfig {
        /// The file.
        path: PathBuf,
        /// The parser's message, with the line and the section.
        message: String,
    },
    /// A field has a value training cannot run with.
    #[error("{path}: invalid value of `{field}`: {message}")]
    InvalidConfig {
        /// The file.
        path: PathBuf,
        /// The field, as `section.field` (e.g. `train.steps`).
        field: String,
        /// What is wrong with it.
        message: String,
    },
    /// The `[model]` or `[distill]` section is invalid.
    #[error(transparent)]
    Model(#[from] ModelError),
    /// The dataset could not be opened, synthesised or read.
    #[error(transparent)]
    Data(#[from] DataError),
    /// The objective could not be built (e.g. LPIPS weights missing).
    #[error(transparent)]
    Loss(#[from] LossError),
    /// The backend cannot be used.
    #[error(transparent)]
    Backend(#[from] prism_core::BackendError),
    /// A file or folder of the run could not be read or written.
    #[error("{path}: {cause}")]
    Io {
        /// The file or folder.
        path: PathBuf,
        /// Why.
        cause: std::io::Error,
    },
    /// A checkpoint is missing, incomplete or unreadable.
    #[error("checkpoint {path}: {message}")]
    Checkpoint {
        /// The checkpoint folder or file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// A checkpoint was written by a run with another config.
    #[error(
        "checkpoint {path} was written with another config ({what}); resume with the config it \
         was trained with, or start a new run with --out"
    )]
    ConfigMismatch {
        /// The checkpoint folder.
        path: PathBuf,
        /// Which setting differs, with both values.
        what: String,
    },
    /// The run folder is not in the state the command needs.
    #[error("{path}: {message}")]
    RunFolder {
        /// The run folder.
        path: PathBuf,
        /// What is wrong and what to do.
        message: String,
    },
    /// Too many steps in a row had a non-finite loss or gradient.
    #[error(
        "training stopped at step {step}: {count} steps in a row had a non-finite loss or \
         gradient (last: {reason}); lower the learning rates or train.grad_clip_norm, then \
         resume from the last checkpoint"
    )]
    NonFinite {
        /// The step that hit the limit (1-based count of steps taken).
        step: usize,
        /// How many consecutive steps were skipped.
        count: usize,
        /// What was not finite at the last one.
        reason: String,
    },
    /// The backend cannot compute in the precision asked for.
    #[error(
        "the {backend} backend cannot compute in {precision} on this device; use --precision \
         f32, or a backend that has {precision} (flex has f16 and bf16; wgpu has f16 where the \
         adapter has it, and bf16 on Metal only: Vulkan gives bf16 conversions and dot products \
         but no bf16 arithmetic)"
    )]
    UnsupportedPrecision {
        /// The precision asked for.
        precision: prism_model::Precision,
        /// The backend.
        backend: String,
    },
    /// A plot of the training curves could not be drawn.
    #[error("{path}: cannot draw the plot: {message}")]
    Plot {
        /// The PNG being drawn.
        path: PathBuf,
        /// Why.
        message: String,
    },
    /// A device of `--devices` cannot be used.
    #[error(transparent)]
    Device(#[from] prism_remote::ConnectError),
    /// A training worker failed on one of the devices.
    #[error("training step failed: {0}")]
    Worker(String),
    /// An input given to an interactive command (`prism view`) cannot be used: what is wrong.
    #[error("{0}")]
    Input(String),
}

impl TrainError {
    /// A [`TrainError::Io`] for `path`.
    pub fn io(path: impl Into<PathBuf>, cause: std::io::Error) -> Self {
        Self::Io {
            path: path.into(),
            cause,
        }
    }

    /// A [`TrainError::Checkpoint`] for `path`.
    pub fn checkpoint(path: impl Into<PathBuf>, message: impl Into<String>) -> Self {
        Self::Checkpoint {
            path: path.into(),
            message: message.into(),
        }
    }
}

/// Results of prism-train.
pub type Result<T, E = TrainError> = std::result::Result<T, E>;
