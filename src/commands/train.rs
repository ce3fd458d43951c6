//! `prism train-teacher`: teacher pretraining (paper Sec. 3.3 and the supplement's training
//! details).

use std::path::PathBuf;

use anyhow::Context;
use clap::Args;
use prism_data::BackendKind;
use prism_train::{RunOptions, TeacherTask, TrainingConfig, config_name, train};

/// Arguments of `prism train-teacher`.
#[derive(Args, Debug)]
pub struct TrainTeacherArgs {
    /// The config file (`[model]`, `[distill]`, `[losses]`, `[train]`, `[data]`), e.g.
    /// configs/small.toml.
    #[arg(long, value_name = "FILE")]
    config: PathBuf,
    /// Dataset folder (see FORMAT.md) [default: the config's `[data]` synthetic dataset,
    /// synthesised once into the cache folder ($PRISM_CACHE_DIR or ~/.cache/prism) and reused].
    #[arg(long, value_name = "DIR")]
    data: Option<PathBuf>,
    /// Run folder for the config copy, metrics.jsonl, sample grids and checkpoints
    /// [default: runs/teacher-<config name>].
    #[arg(long, value_name = "DIR")]
    out: Option<PathBuf>,
    /// Train this many steps instead of the config's `train.steps` (with --resume: the new
    /// total, to train longer).
    #[arg(long, value_name = "N")]
    steps: Option<usize>,
    /// Continue the run in the run folder from its latest checkpoint, exactly where it stopped.
    #[arg(long)]
    resume: bool,
    /// Start a new run from the weights of this checkpoint (a checkpoint folder or a run
    /// folder's latest), e.g. to fine-tune on another dataset.
    #[arg(long, value_name = "CKPT")]
    init: Option<PathBuf>,
    /// Backend: ndarray, flex or wgpu.
    #[arg(long, default_value = "flex")]
    backend: BackendKind,
    /// Devices to train on, data parallel (on the CPU backends: worker threads sharing the one
    /// CPU device).
    #[arg(long, default_value_t = 1, value_name = "N")]
    devices: usize,
    /// The LPIPS weight file [default: data/lpips_alex.safetensors or $PRISM_LPIPS_WEIGHTS].
    #[arg(long, value_name = "FILE")]
    lpips_weights: Option<PathBuf>,
    /// No progress bar.
    #[arg(long)]
    quiet: bool,
}

impl TrainTeacherArgs {
    /// Trains, then prints the final validation metrics and where the results are.
    pub fn run(self) -> anyhow::Result<()> {
        let config = TrainingConfig::load(&self.config)?;
        let out = self.out.clone().unwrap_or_else(|| {
            PathBuf::from("runs").join(format!("teacher-{}", config_name(&self.config)))
        });
        let options = RunOptions {
            out: out.clone(),
            data: self.data,
            steps: self.steps,
            resume: self.resume,
            init: self.init,
            backend: self.backend,
            devices: self.devices,
            progress: !self.quiet,
            lpips_weights: self.lpips_weights.clone(),
        };
        let task = TeacherTask {
            lpips_weights: self.lpips_weights,
        };
        let summary = train(&config, &task, &options)
            .with_context(|| format!("training into {}", out.display()))?;
        println!(
            "trained steps {}..{} on {} ({:.3} s per step)",
            summary.start_step,
            summary.steps,
            summary.data_dir.display(),
            summary.seconds_per_step
        );
        if let (Some(first), Some(last)) = (summary.first_loss, summary.last_loss) {
            println!("training loss {first:.5} -> {last:.5}");
        }
        if summary.skipped_steps > 0 {
            println!(
                "{} steps skipped (non-finite loss or gradient)",
                summary.skipped_steps
            );
        }
        let row = |name: &str, s: &prism_train::ValidationScores| {
            println!(
                "{name:<28} PSNR {:>7.3} dB  SSIM {:.4}  LPIPS {:.4}",
                s.psnr, s.ssim, s.lpips
            );
        };
        if let Some(s) = &summary.baseline {
            row("copy-the-source baseline", s);
        }
        if let Some(s) = &summary.initial {
            row("initial model", s);
        }
        if let Some(s) = &summary.last {
            row(&format!("validation at step {}", summary.steps), s);
        }
        if let Some(path) = &summary.last_samples {
            println!(
                "sample images (source | prediction | ground truth): {}",
                path.display()
            );
        }
        if let Some(path) = &summary.last_checkpoint {
            println!("checkpoint: {}", path.display());
        }
        println!("metrics: {}", out.join(prism_train::METRICS_FILE).display());
        if let Some(path) = &summary.plot {
            println!("training curves: {}", path.display());
        }
        Ok(())
    }
}
