//! `prism distill-student`: the linear-attention student distilled from a trained teacher
//! (paper Sec. 3.4), or one of the paper's ablations (`[distill] mode`).

use std::path::PathBuf;

use anyhow::Context;
use clap::Args;
use prism_data::BackendKind;
use prism_model::DistillMode;
use prism_train::{RunOptions, TrainingConfig, config_name, distill_student, kinds_letters};

/// Arguments of `prism distill-student`.
#[derive(Args, Debug)]
pub struct DistillStudentArgs {
    /// The config file; its `[distill]` section sets the mode (progressive, all_at_once,
    /// fully_linear, teacher), the schedule (group_size, start, interval), the L_distill layers,
    /// steps, batch_size and the fixed learning rate lr; e.g. configs/small.toml.
    #[arg(long, value_name = "FILE")]
    config: PathBuf,
    /// The teacher: a run folder of `prism train-teacher` (its latest checkpoint) or a
    /// checkpoint folder. The student starts as its copy; it stays frozen.
    #[arg(long, value_name = "RUN_OR_CKPT")]
    teacher: PathBuf,
    /// Override `[distill] mode`: progressive, all_at_once, fully_linear or teacher.
    #[arg(long, value_name = "MODE")]
    mode: Option<DistillMode>,
    /// Dataset folder (see FORMAT.md) [default: the config's `[data]` synthetic dataset].
    #[arg(long, value_name = "DIR")]
    data: Option<PathBuf>,
    /// Run folder [default: runs/student-<config name>-<mode>].
    #[arg(long, value_name = "DIR")]
    out: Option<PathBuf>,
    /// Train this many steps instead of `[distill] steps` (the schedule does not change).
    #[arg(long, value_name = "N")]
    steps: Option<usize>,
    /// Continue the run in the run folder from its latest checkpoint (weights, optimizer and
    /// every block's attention kind).
    #[arg(long)]
    resume: bool,
    /// Backend: ndarray, flex or wgpu.
    #[arg(long, default_value = "flex")]
    backend: BackendKind,
    /// Devices to train on, data parallel.
    #[arg(long, default_value_t = 1, value_name = "N")]
    devices: usize,
    /// The LPIPS weight file [default: data/lpips_alex.safetensors or $PRISM_LPIPS_WEIGHTS].
    #[arg(long, value_name = "FILE")]
    lpips_weights: Option<PathBuf>,
    /// No progress bar.
    #[arg(long)]
    quiet: bool,
}

impl DistillStudentArgs {
    /// Distils, then prints the schedule, the final validation and where the results are.
    pub fn run(self) -> anyhow::Result<()> {
        let mut config = TrainingConfig::load(&self.config)?;
        if let Some(mode) = self.mode {
            config.distill.mode = mode;
        }
        let mode = config.distill.mode;
        let out = self.out.clone().unwrap_or_else(|| {
            PathBuf::from("runs").join(format!("student-{}-{mode}", config_name(&self.config)))
        });
        let options = RunOptions {
            out: out.clone(),
            data: self.data,
            steps: self.steps,
            resume: self.resume,
            init: None,
            backend: self.backend,
            devices: self.devices,
            progress: !self.quiet,
            lpips_weights: self.lpips_weights,
        };
        let blocks = config.model.num_blocks();
        println!(
            "distilling {} ({mode}): {} steps at lr {:.1e}, final attention {}",
            self.teacher.display(),
            self.steps.unwrap_or(config.distill.steps),
            config.distill.lr,
            kinds_letters(&config.distill.final_kinds(blocks)),
        );
        let summary = distill_student(&config, &self.teacher, &options).with_context(|| {
            format!(
                "distilling {} into {}",
                self.teacher.display(),
                out.display()
            )
        })?;
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
        let row = |name: &str, s: &prism_train::ValidationScores| {
            println!(
                "{name:<28} PSNR {:>7.3} dB  SSIM {:.4}  LPIPS {:.4}",
                s.psnr, s.ssim, s.lpips
            );
        };
        if let Some(s) = &summary.initial {
            row("teacher (initial student)", s);
        }
        if let Some(s) = &summary.last {
            row(&format!("student at step {}", summary.steps), s);
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
