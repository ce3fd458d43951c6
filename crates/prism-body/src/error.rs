//! Errors of the body model: files, keys, shapes and parameters, each naming what is wrong.

use std::path::PathBuf;

/// A body model or body parameters that cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum BodyError {
    /// The file cannot be read or written.
    #[error("{path}: {error}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The underlying error.
        error: std::io::Error,
    },
    /// A key the body model needs is not in the `.npz` file.
    #[error("{path}: missing key `{key}` (expected shape {expected})")]
    MissingKey {
        /// The file.
        path: PathBuf,
        /// The missing array.
        key: String,
        /// The shape the key should have.
        expected: String,
    },
    /// An array has the wrong shape.
    #[error("{path}: key `{key}` has shape {actual:?}, expected {expected}")]
    Shape {
        /// The file (or `<memory>` for a model built in memory).
        path: PathBuf,
        /// The array.
        key: String,
        /// The expected shape, e.g. `[V, 3, 486] with V = 4000`.
        expected: String,
        /// The shape found.
        actual: Vec<u64>,
    },
    /// An array has an element type that the body model cannot use.
    #[error("{path}: key `{key}` has element type `{dtype}`, expected {expected}")]
    DType {
        /// The file.
        path: PathBuf,
        /// The array.
        key: String,
        /// The element type found (numpy's type string).
        dtype: String,
        /// What is accepted.
        expected: &'static str,
    },
    /// The values of an array are unusable (a bad parent index, a face index out of range, ...).
    #[error("{path}: key `{key}`: {message}")]
    Value {
        /// The file.
        path: PathBuf,
        /// The array.
        key: String,
        /// What is wrong.
        message: String,
    },
    /// Body parameters (`body.json`) that are malformed or have the wrong lengths.
    #[error("{path}: {message}")]
    Params {
        /// The file (or `<memory>`).
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
}

/// The path shown for models and parameters that do not come from a file.
pub(crate) fn memory_path() -> PathBuf {
    PathBuf::from("<memory>")
}
