//! `prism infer`: novel views of a person from one photo (or a folder of video frames).

use std::path::PathBuf;

use anyhow::Context;
use clap::Args;
use prism_core::BackendKind;
use prism_model::Precision;
use prism_train::{Framing, InferOptions, Sweep, infer};

/// Synthesise novel views of a person from one photo.
///
/// The photo gets the viewing protocol's frontal camera; the person is found from --mask or
/// the photo's alpha channel (with neither, the whole photo is used, with a warning), then
/// centred and scaled like the training data. Writes OUT/input.png (the framed input), one PNG
/// per view of a +-30 degree sweep and OUT/sweep.gif. A folder of video frames is processed
/// frame by frame into OUT/FRAME_NAME/.
#[derive(Args, Debug)]
pub struct InferArgs {
    /// A checkpoint folder, or a run folder (its latest checkpoint).
    #[arg(long, value_name = "RUN_OR_CKPT")]
    checkpoint: PathBuf,
    /// The photo (png, jpg), or a folder of video frames.
    #[arg(long, value_name = "PHOTO")]
    image: PathBuf,
    /// Foreground mask of the photo (same size; white is the person).
    #[arg(long, value_name = "MASK")]
    mask: Option<PathBuf>,
    /// Output folder.
    #[arg(long, value_name = "DIR")]
    out: PathBuf,
    /// Views to synthesise: yaw, pitch or grid (both), within +-30 degrees.
    #[arg(long, default_value = "yaw")]
    sweep: Sweep,
    /// Degrees between the views of the sweep.
    #[arg(long, default_value_t = 10.0, value_name = "DEG")]
    step: f32,
    /// Also save the 3DGS head's Gaussians of the photo as a standard 3DGS PLY.
    #[arg(long, value_name = "FILE")]
    export_ply: Option<PathBuf>,
    /// (source, target) pairs per forward pass.
    #[arg(long, default_value_t = 8, value_name = "N")]
    batch: usize,
    /// Backend: ndarray, flex or wgpu.
    #[arg(long, default_value = "flex")]
    backend: BackendKind,
    /// The precision of the transformer blocks: f32, f16 or bf16 (the rest of the model stays
    /// f32; bf16 on the CPU: bf16 matrix products, see the README).
    #[arg(long, default_value = "f32", value_name = "f32|f16|bf16")]
    precision: Precision,
    /// No progress bar.
    #[arg(long)]
    quiet: bool,
}

impl InferArgs {
    /// Runs inference and prints where the views are.
    pub fn run(self) -> anyhow::Result<()> {
        if !(self.step > 0.0 && self.step <= 60.0) {
            anyhow::bail!("--step must be in (0, 60] degrees, got {}", self.step);
        }
        let options = InferOptions {
            sweep: self.sweep,
            step_deg: self.step,
            batch: self.batch.max(1),
            progress: !self.quiet,
            precision: self.precision,
            ..InferOptions::default()
        };
        let results = infer(
            &self.checkpoint,
            &self.image,
            self.mask.as_deref(),
            &self.out,
            self.backend,
            self.export_ply.as_deref(),
            &options,
        )
        .with_context(|| format!("inferring views of {}", self.image.display()))?;
        for r in &results {
            if r.framing == Framing::WholeImage {
                eprintln!(
                    "warning: {} has no mask and no alpha channel: the whole photo is used as \
                     the input (give --mask for a framing like the training data)",
                    r.input.display()
                );
            }
            println!(
                "{}: {} views in {}, animation {}",
                r.input.display(),
                r.views.len(),
                r.dir.display(),
                r.gif.display()
            );
        }
        if let Some(ply) = &self.export_ply {
            println!("Gaussians (3DGS PLY): {}", ply.display());
        }
        Ok(())
    }
}
