//! `prism evaluate`: a trained model on the held-out subjects (the paper's protocol), or any
//! method's images against ground truth with the same metrics.

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use clap::Args;
use prism_data::BackendKind;
use prism_data::dataset::DatasetReader;
use prism_losses::{Lpips, score_paths};
use prism_train::evaluate::default_out;
use prism_train::images::save_text;
use prism_train::{EVALUATION_JSON, EvaluateOptions, REPORT_MD, evaluate, load_model};

/// Evaluate a checkpoint on the test subjects, or score predicted images against ground truth.
///
/// With --checkpoint: for each held-out subject of --data, view 0 is the source and views
/// 1..=100 the targets; PSNR, SSIM and LPIPS are averaged per subject, then over subjects (the
/// paper's protocol), with a breakdown by |yaw| and |pitch| (10-degree bins) and the frame rate
/// of the forward pass for one (source, target) pair (2 warm-up passes excluded, data loading
/// excluded). Writes evaluation.json, report.md and grids/SUBJECT.png (source, prediction, ground
/// truth, error map) into --out.
///
/// With --pred and --gt: two folders of images matched by file name (or two image files),
/// scored with the same metrics; JSON `{"mean": {..}, "images": {NAME: {..}}}`, so that
/// baselines are compared on equal terms.
#[derive(Args, Debug)]
pub struct EvaluateArgs {
    /// The model: a run folder (its latest checkpoint) or a checkpoint folder.
    #[arg(long, value_name = "RUN_OR_CKPT", conflicts_with_all = ["pred", "gt"])]
    checkpoint: Option<PathBuf>,
    /// Dataset folder (see FORMAT.md) whose test split is evaluated [default: the checkpoint's
    /// config's synthetic dataset, synthesised into the cache if needed].
    #[arg(long, value_name = "DIR", requires = "checkpoint")]
    data: Option<PathBuf>,
    /// Predicted images (a folder, or one image).
    #[arg(long, value_name = "DIR", requires = "gt")]
    pred: Option<PathBuf>,
    /// Ground-truth images with the same file names (a folder, or one image).
    #[arg(long, value_name = "DIR", requires = "pred")]
    gt: Option<PathBuf>,
    /// Also write the JSON result to this file.
    #[arg(long, value_name = "FILE")]
    json: Option<PathBuf>,
    /// Output folder for evaluation.json, report.md and grids/ [default: RUN_OR_CKPT/evaluation].
    #[arg(long, value_name = "DIR", requires = "checkpoint")]
    out: Option<PathBuf>,
    /// Target views per subject, evenly spread over 1..=100 (fewer for a quick look).
    #[arg(long, default_value_t = 100, value_name = "N")]
    views: usize,
    /// Views per subject drawn in its PNG grid.
    #[arg(long, default_value_t = 4, value_name = "N")]
    grid_views: usize,
    /// Backend: ndarray, flex, wgpu or cuda.
    #[arg(long, default_value = "flex")]
    backend: BackendKind,
    /// The LPIPS weight file [default: $PRISM_LPIPS_WEIGHTS, then data/lpips_alex.safetensors].
    #[arg(long, value_name = "FILE")]
    lpips_weights: Option<PathBuf>,
    /// No progress bar.
    #[arg(long)]
    quiet: bool,
}

impl EvaluateArgs {
    /// Evaluates and prints the means (and where the report is).
    pub fn run(self) -> anyhow::Result<()> {
        let device = self.backend.device()?;
        let lpips = Lpips::load_default(self.lpips_weights.as_deref(), &device)?;
        if let (Some(pred), Some(gt)) = (&self.pred, &self.gt) {
            let scores = score_paths(pred, gt, &lpips, &device)?;
            if let Some(path) = &self.json {
                write_json(path, &scores.to_json())?;
            }
            print!("{}", scores.to_table());
            return Ok(());
        }
        let Some(checkpoint) = &self.checkpoint else {
            bail!("pass --checkpoint RUN_OR_CKPT (with --data DIR), or --pred DIR --gt DIR");
        };
        if self.views == 0 || self.views > 100 {
            bail!("--views must be in 1..=100, got {}", self.views);
        }
        let (model, config) = load_model(checkpoint, &device)?;
        let data = match &self.data {
            Some(dir) => dir.clone(),
            None => prism_train::ensure_synthetic_dataset(&config.data, !self.quiet)?,
        };
        let reader = DatasetReader::open(&data)?;
        let out = self.out.clone().unwrap_or_else(|| default_out(checkpoint));
        let options = EvaluateOptions {
            views_per_subject: self.views,
            grid_views: self.grid_views,
            progress: !self.quiet,
            ..EvaluateOptions::default()
        };
        let evaluation = evaluate(
            &model,
            &reader,
            config.model.resolution as u32,
            Some(&lpips),
            &device,
            &options,
            Some(&out),
            &checkpoint.display().to_string(),
        )
        .with_context(|| format!("evaluating {} on {}", checkpoint.display(), data.display()))?;
        if let Some(path) = &self.json {
            write_json(path, &evaluation.to_json())?;
        }
        println!(
            "{} test subjects x {} views at {} px: PSNR {:.3} dB  SSIM {:.4}  LPIPS {:.4}  \
             {:.1} FPS ({})",
            evaluation.subjects.len(),
            evaluation.views_per_subject,
            evaluation.resolution,
            evaluation.psnr,
            evaluation.ssim,
            evaluation.lpips,
            evaluation.fps,
            self.backend_name(),
        );
        println!("report: {}", out.join(REPORT_MD).display());
        println!("json: {}", out.join(EVALUATION_JSON).display());
        Ok(())
    }

    fn backend_name(&self) -> String {
        format!("{:?}", self.backend).to_lowercase()
    }
}

/// Writes `text` to `path` atomically, creating its folder.
fn write_json(path: &Path, text: &str) -> anyhow::Result<()> {
    if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent).with_context(|| parent.display().to_string())?;
    }
    Ok(save_text(path, text)?)
}
