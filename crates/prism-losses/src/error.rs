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
    /// `PRISM_LPIPS_WEIGHTS` names a file that does not exist.
    #[error("PRISM_LPIPS_WEIGHTS is `{}`, which is not a file", .0.display())]
    WeightsEnvMissing(PathBuf),
    /// The LPIPS weight file exists but does not hold the expected tensors.
    #[error("cannot load LPIPS weights from `{}`: {reason}", .path.display())]
    WeightsInvalid {
        /// The weight file.
        path: PathBuf,
        /// What was wrong with it.
        reason: String,
    },
    /// A file could not be read or decoded as an image.
    #[error("`{}` is not a readable image: {reason}", .path.display())]
    NotAnImage {
        /// The offending file.
        path: PathBuf,
        /// The decoder's or the file system's message.
        reason: String,
    },
    /// A folder could not be listed.
    #[error("cannot list folder `{}`: {reason}", .path.display())]
    Folder {
        /// The folder.
        path: PathBuf,
        /// The file system's message.
        reason: String,
    },
    /// A path is neither a file nor a folder (or does not exist).
    #[error("`{}` does not exist", .0.display())]
    Missing(PathBuf),
    /// One of `--pred`/`--gt` is a file and the other a folder.
    #[error("`{}` and `{}` must both be image files or both be folders", .pred.display(), .gt.display())]
    KindMismatch {
        /// The prediction path.
        pred: PathBuf,
        /// The ground-truth path.
        gt: PathBuf,
    },
    /// Two images that are compared have different sizes.
    #[error(
        "image sizes differ: `{}` is {}x{} but `{}` is {}x{}",
        .pred.display(), .pred_size[0], .pred_size[1], .gt.display(), .gt_size[0], .gt_size[1]
    )]
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
    #[error("`{}` is {width}x{height}: the metrics need images of at least {min}x{min} pixels", .path.display())]
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
    #[error("folder `{}` holds no image (png, jpg, jpeg)", .0.display())]
    EmptyFolder(PathBuf),
    /// The objective was asked for an LPIPS term without an LPIPS network.
    #[error("the loss weights ask for LPIPS (lpips = {0}) but no LPIPS network was given")]
    LpipsRequired(f64),
    /// The objective was given an image to score without the target view.
    #[error("the objective has an image to score but no target view (LossInputs::with_target)")]
    NoTarget,
    /// The objective was evaluated with no term at all.
    #[error("the objective has no term: give at least one of nvs, gs, pts, smplx, distill")]
    NoTerms,
}
