//! The error type of `prism-losses`.

use std::path::PathBuf;

/// What can go wrong when loading the LPIPS weights, reading images or assembling the objective.
#[derive(Debug, thiserror::Error)]
pub enum LossError {
    /// No LPIPS weight file was found at any of the places searched.
    #[error(
        "LPIPS weights not found; tried {}; set PRISM_LPIPS_WEIGHTS (or pass --lpips-weights) to the path of lpips_alex.safetensors",
        .tried.iter().map(|p| format!("`{}`", p.display())).collect::<Vec<_>>().join(", ")
    )]
    WeightsNotFound {
        /// Every path that was tried, in order.
        tried: Vec<PathBuf>,
    },
    /// The LPIPS weight file exists but does not hold the expected tensors.
    #[error("cannot load LPIPS weights from `{path}`: {reason}")]
    WeightsInvalid {
        /// The weight file.
        path: PathBuf,
        /// What was wrong with it.
        reason: String,
    },
    /// A file could not be read or decoded as an image.
    #[error("`{path}` is not a readable image: {reason}")]
    NotAnImage {
        /// The offending file.
        path: PathBuf,
        /// The decoder's or the file system's message.
        reason: String,
    },
    /// A folder could not be listed.
    #[error("cannot list folder `{path}`: {reason}")]
    Folder {
        /// The folder.
        path: PathBuf,
        /// The file system's message.
        reason: String,
    },
    /// A path is neither a file nor a folder (or does not exist).
    #[error("`{0}` does not exist")]
    Missing(PathBuf),
    /// One of `--pred`/`--gt` is a file and the other a folder.
    #[error("`{pred}` and `{gt}` must both be image files or both be folders")]
    KindMismatch {
        /// The prediction path.
        pred: PathBuf,
        /// The ground-truth path.
        gt: PathBuf,
    },
    /// Two images that are compared have different sizes.
    #[error("image sizes differ: `{pred}` is {pred_size:?} (W x H) but `{gt}` is {gt_size:?}")]
    SizeMismatch {
        /// The prediction.
        pred: PathBuf,
        /// Its `[width, height]`.
        pred_size: [u32; 2],
        /// The ground truth.
        gt: PathBuf,
        /// Its `[width, height]`.
        gt_size: [u32; 2],
    },
    /// An image is too small for SSIM (11 x 11 window) or LPIPS (AlexNet needs 31 x 31).
    #[error("`{path}` is {width}x{height}: the metrics need images of at least {min}x{min} pixels")]
    TooSmall {
        /// The image.
        path: PathBuf,
        /// Its width.
        width: u32,
        /// Its height.
        height: u32,
        /// The minimum side length.
        min: u32,
    },
    /// Folder scoring found images in one folder without a counterpart in the other.
    #[error("images without a counterpart: {}", .0.join(", "))]
    MissingCounterpart(Vec<String>),
    /// A folder holds no image (png, jpg, jpeg).
    #[error("folder `{0}` holds no image (png, jpg, jpeg)")]
    EmptyFolder(PathBuf),
    /// The objective was asked for an LPIPS term without an LPIPS network.
    #[error("the loss weights ask for LPIPS (lpips = {0}) but no LPIPS network was given")]
    LpipsRequired(f64),
    /// The objective was evaluated with no term at all.
    #[error("the objective has no term: give at least one of nvs, gs, pts, smplx, distill")]
    NoTerms,
}
