//! `prism metrics`: PSNR, SSIM and LPIPS of rendered images against ground truth.

use std::path::PathBuf;

use clap::Args;
use prism_core::BackendKind;
use prism_losses::{Lpips, score_paths};

/// Score images against ground truth: PSNR (dB), SSIM and LPIPS (v0.1, AlexNet).
///
/// `--pred` and `--gt` are two image files, or two folders whose images (png, jpg, jpeg) are
/// matched by file name. 8-bit images are read as values / 255 (RGB, alpha dropped).
#[derive(Args, Debug)]
pub struct MetricsArgs {
    /// Predicted image, or folder of predicted images.
    #[arg(long)]
    pred: PathBuf,
    /// Ground-truth image, or folder of ground-truth images with the same file names.
    #[arg(long)]
    gt: PathBuf,
    /// Print one JSON object: `{"psnr","ssim","lpips"}` for a pair, or
    /// `{"mean": {..}, "images": {NAME: {..}}}` for folders.
    #[arg(long)]
    json: bool,
    /// Backend to compute on (ndarray, flex, wgpu).
    #[arg(long, default_value = "flex")]
    backend: BackendKind,
    /// LPIPS weight file (default: $PRISM_LPIPS_WEIGHTS, then data/lpips_alex.safetensors).
    #[arg(long)]
    lpips_weights: Option<PathBuf>,
}

impl MetricsArgs {
    /// Loads LPIPS, scores the images and prints the result.
    pub fn run(self) -> anyhow::Result<()> {
        let device = self.backend.device()?;
        let lpips = Lpips::load_default(self.lpips_weights.as_deref(), &device)?;
        // The library's errors name the offending file; no extra context needed.
        let scores = score_paths(&self.pred, &self.gt, &lpips, &device)?;
        if self.json {
            println!("{}", scores.to_json());
        } else {
            print!("{}", scores.to_table());
        }
        Ok(())
    }
}
