//! `prism evaluate`: a checkpoint on the test subjects of a dataset (the paper's protocol), or
//! any method's images against ground truth.

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use clap::Args;

use super::args::{DataArgs, JobArgs};
use prism_losses::{Lpips, score_paths};
use prism_model::Precision;
use prism_train::{EvaluateOptions, evaluate_checkpoint};

/// Evaluate novel view synthesis: PSNR (dB), SSIM and LPIPS.
///
/// With --checkpoint: for each test subject of the dataset, source view 0 and targets 1..=100;
/// the scores are averaged per subject, then over the subjects, and broken down by view angle
/// (10-degree bins of |yaw| and |pitch|); the forward pass of one (source, target) pair is
/// timed (FPS, warm-up and data loading excluded). The same scores are given for the "copy the
/// source view" baseline (`copy_source`: view 0 as the prediction of every target view) and, for
/// a model with a 3DGS head, for its render I_gs (`gs`); each gets a speckle score (`speckle`:
/// its mean absolute Laplacian over the truth's where the truth is smooth). Writes OUT/evaluation.json,
/// OUT/report.md, a PNG grid per subject (source | prediction | ground truth | error map) and
/// the run's training curves (OUT/training-curves.png).
///
/// With --pred and --gt: scores the images of any method (two files, or two folders matched by
/// file name) with the same metrics; JSON `{"mean": {..}, "images": {NAME: {..}}}`.
#[derive(Args, Debug)]
pub struct EvaluateArgs {
    /// A checkpoint folder, or a run folder (its latest checkpoint).
    #[arg(long, value_name = "RUN_OR_CKPT", conflicts_with_all = ["pred", "gt"])]
    checkpoint: Option<PathBuf>,
    /// With --checkpoint: the dataset [default: the checkpoint config's synthetic dataset].
    #[command(flatten)]
    data: DataArgs,
    /// Predicted image, or folder of predicted images (needs --gt).
    #[arg(long, value_name = "PATH", requires = "gt")]
    pred: Option<PathBuf>,
    /// Ground-truth image, or folder of ground-truth images with the same file names.
    #[arg(long, value_name = "PATH", requires = "pred")]
    gt: Option<PathBuf>,
    /// Also write the JSON scores to this file.
    #[arg(long, value_name = "FILE")]
    json: Option<PathBuf>,
    /// Folder for evaluation.json, report.md and grids/ [default: CHECKPOINT/evaluation].
    #[arg(long, value_name = "DIR", requires = "checkpoint")]
    out: Option<PathBuf>,
    /// Also write every predicted target view as DIR/SUBJECT/NNN.png (NNN the view index, 3
    /// digits), to score against other methods with --pred/--gt.
    #[arg(long, value_name = "DIR", requires = "checkpoint")]
    save_predictions: Option<PathBuf>,
    /// Target views per subject, evenly spread over 1..=100 (100 is the paper's protocol).
    #[arg(long, default_value_t = 100, value_name = "N", value_parser = clap::value_parser!(u16).range(1..=100))]
    views: u16,
    /// (source, target) pairs per forward pass.
    #[arg(long, default_value_t = 8, value_name = "N", value_parser = clap::value_parser!(u16).range(1..))]
    batch: u16,
    /// With --checkpoint: the precision of the transformer blocks, f32, f16 or bf16 (their
    /// weights cast to it; the rest of the model stays f32).
    #[arg(
        long,
        default_value = "f32",
        value_name = "f32|f16|bf16",
        requires = "checkpoint"
    )]
    precision: Precision,
    /// With --checkpoint: also draw the 3DGS head's Gaussians with one property at a time
    /// (depth, colour, opacity, scale) taken from the dataset's truth, and score each (a
    /// diagnostic: the "Oracle swaps" table of the report, `oracle` in the JSON).
    #[arg(long, requires = "checkpoint")]
    oracle: bool,
    #[command(flatten)]
    job: JobArgs,
}

impl EvaluateArgs {
    /// Runs the evaluation and prints the scores and where the files are.
    pub fn run(self) -> anyhow::Result<()> {
        match (&self.checkpoint, &self.pred, &self.gt) {
            (Some(checkpoint), None, None) => self.run_checkpoint(checkpoint),
            (None, Some(_), Some(_)) if self.data.data.is_some() => {
                bail!("--data goes with --checkpoint; --pred and --gt are scored as they are")
            }
            (None, Some(pred), Some(gt)) => self.run_images(pred, gt),
            _ => bail!("give --checkpoint (with --data), or --pred and --gt"),
        }
    }

    fn run_checkpoint(&self, checkpoint: &Path) -> anyhow::Result<()> {
        let out = self
            .out
            .clone()
            .unwrap_or_else(|| checkpoint.join("evaluation"));
        let options = EvaluateOptions {
            views: usize::from(self.views),
            batch: usize::from(self.batch),
            progress: !self.job.quiet,
            save_predictions: self.save_predictions.clone(),
            precision: self.precision,
            oracle: self.oracle,
            ..EvaluateOptions::default()
        };
        let (e, files) = evaluate_checkpoint(
            checkpoint,
            &self
                .data
                .resolve_for_checkpoint(checkpoint, !self.job.quiet)?,
            &out,
            self.job.backend,
            self.job.lpips_weights.as_deref(),
            &options,
        )
        .with_context(|| format!("evaluating {}", checkpoint.display()))?;
        if let Some(json) = &self.json {
            write_atomic(json, &prism_train::evaluation_json(&e))?;
        }
        println!(
            "{} subjects x {} views: PSNR {:.3} dB  SSIM {:.4}  LPIPS {:.4}  FPS {:.2} ({}, \
             blocks in {})",
            e.subjects.len(),
            e.views_per_subject,
            e.psnr,
            e.ssim,
            e.lpips,
            e.fps,
            self.job.backend,
            self.precision
        );
        if let Some(gs) = &e.gs {
            println!(
                "  3DGS head (I_gs):     PSNR {:.3} dB  SSIM {:.4}  LPIPS {:.4}",
                gs.psnr, gs.ssim, gs.lpips
            );
        }
        let c = &e.copy_source;
        println!(
            "  copy source (view 0): PSNR {:.3} dB  SSIM {:.4}  LPIPS {:.4}",
            c.psnr, c.ssim, c.lpips
        );
        let s = &e.speckle;
        println!(
            "  speckle (1 = as smooth as the truth): model {:.2}{}  copy source {:.2}  \
             true-depth warp {:.2}",
            s.model,
            s.gs.map(|g| format!("  I_gs {g:.2}")).unwrap_or_default(),
            s.copy_source,
            s.true_depth_warp
        );
        if let Some(d) = &e.depth_error {
            println!(
                "  3DGS depth error (source foreground): mean {:.2} cm, median {:.2}, 90th \
                 percentile {:.2}, bias {:+.2}",
                d.mean * 100.0,
                d.median * 100.0,
                d.p90 * 100.0,
                d.bias * 100.0
            );
        }
        if let Some(dir) = &self.save_predictions {
            println!("predictions: {}", dir.display());
        }
        println!("report: {}", files.report.display());
        println!("scores: {}", files.json.display());
        if let Some(grid) = files.grids.first() {
            println!(
                "sample grids (source | prediction | ground truth | error): {}",
                grid.parent().unwrap_or(&out).display()
            );
        }
        if let Some(path) = &files.training_curves {
            println!("training curves: {}", path.display());
        }
        Ok(())
    }

    fn run_images(&self, pred: &Path, gt: &Path) -> anyhow::Result<()> {
        let device = self.job.backend.device()?;
        let lpips = Lpips::load_default(self.job.lpips_weights.as_deref(), &device)?;
        let scores = score_paths(pred, gt, &lpips, &device)?;
        if let Some(json) = &self.json {
            write_atomic(json, &(scores.to_json() + "\n"))?;
        }
        print!("{}", scores.to_table());
        Ok(())
    }
}

/// Writes `text` to `path` atomically.
fn write_atomic(path: &Path, text: &str) -> anyhow::Result<()> {
    prism_core::files::write_bytes(path, text.as_bytes())
        .with_context(|| format!("writing {}", path.display()))
}
