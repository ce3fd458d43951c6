//! Losses and metrics of prism (paper Sec. 3.3 and the evaluation protocol).
//!
//! - Training objective: [`Objective`] with [`LossWeights`] (the `[losses]` config section)
//!   combines `L_nvs` and `L_gs` (MSE + LPIPS), [`point_loss`] (`L_pts`), [`smplx_loss`]
//!   (`L_smplx`), [`distill_loss`] (`L_distill`) and, beyond the paper, [`centres_loss`]
//!   (`L_centres`) and [`spread_loss`] (`L_spread`), and reports every term by name.
//! - Metrics: [`psnr()`], [`ssim()`] and [`Lpips::distance`] on `[B, 3, H, W]` tensors in [0, 1],
//!   per image. [`score_images`] is the one scoring pipeline (all three per image, and
//!   [`ImageScores::mean`]) of validation, evaluation and [`score_paths`] (image files or
//!   folders, `prism metrics`); [`ScoreTable`] is the one formatter of their tables.
//!   [`speckle_sums`] scores pixel-level noise where the truth is smooth (`prism evaluate`).
//!
//! LPIPS uses the real v0.1 AlexNet weights committed at `data/lpips_alex.safetensors`
//! (found by [`find_lpips_weights`]); nothing is ever downloaded.

pub mod centres;
pub mod distill;
pub mod error;
pub mod image_files;
pub mod lpips;
pub mod objective;
pub mod opacity;
pub mod point;
pub mod psnr;
pub mod region;
pub mod scores;
pub mod smplx;
pub mod speckle;
pub mod ssim;
pub mod table;
pub mod weights;

pub use centres::{centres_loss, spread_loss};
pub use distill::{DistillInputs, distill_layers, distill_loss};
pub use error::LossError;
pub use image_files::{FolderScores, Scores, load_image, score_files, score_paths};
pub use lpips::{LPIPS_MIN_SIDE, Lpips, LpipsReference};
pub use objective::{
    CentreInputs, LossInputs, LossTerms, LossWeights, Objective, OpacityInputs, PointInputs,
    SmplxInputs, holes_loss, mse_loss,
};
pub use opacity::{opacity_loss, pixel_rows};
pub use point::{POINT_LOSS_SCALES, PointLoss, point_loss};
pub use psnr::psnr;
pub use region::{psnr_region_filled, score_whole_and_region};
pub use scores::{GroundTruth, ImageScores, score_images};
pub use smplx::{SmplxParams, smplx_loss};
pub use speckle::{SMOOTH_LAPLACIAN, SpeckleSums, laplacian_magnitude, speckle_sums};
pub use ssim::{SSIM_WINDOW, ssim, ssim_map};
pub use table::{NO_VALUE, SCORE_COLUMNS, ScoreTable, score_cells};
pub use weights::{LPIPS_WEIGHTS_ENV, LPIPS_WEIGHTS_FILE, find_lpips_weights};
