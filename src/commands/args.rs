//! The flags several commands share, as clap `Args` structs flattened into each command, and
//! the one place where a command turns "no `--data`" into the config's synthetic dataset.

use std::path::{Path, PathBuf};

use anyhow::Context;
use clap::Args;
use prism_core::BackendKind;
use prism_data::SynthOptions;
use prism_losses::ImageScores;
use prism_model::Precision;
use prism_remote::{DeviceList, read_token};
use prism_synth::ensure_synthetic_dataset;
use prism_train::{Checkpoint, LossScaleConfig, RunOptions, RunSummary};

/// Where a command's dataset comes from.
#[derive(Args, Clone, Debug)]
pub struct DataArgs {
    /// Dataset folder (see FORMAT.md) [default: the config's `[data]` synthetic dataset,
    /// synthesised once into the cache folder ($PRISM_CACHE_DIR or ~/.cache/prism) and reused].
    #[arg(long, value_name = "DIR")]
    pub data: Option<PathBuf>,
}

impl DataArgs {
    /// The `--data` folder, or the synthetic dataset `synth` describes (synthesised into the
    /// cache the first time, with a progress bar when `progress`).
    ///
    /// # Errors
    /// Synthesis errors, naming the file.
    pub fn resolve(&self, synth: &SynthOptions, progress: bool) -> anyhow::Result<PathBuf> {
        match &self.data {
            Some(dir) => Ok(dir.clone()),
            None => ensure_synthetic_dataset(synth, progress)
                .context("synthesising the config's default dataset"),
        }
    }

    /// As [`DataArgs::resolve`], with the `[data]` section of the config a checkpoint (or a run
    /// folder's latest) was trained with.
    ///
    /// # Errors
    /// An unreadable checkpoint, or synthesis errors.
    pub fn resolve_for_checkpoint(
        &self,
        checkpoint: &Path,
        progress: bool,
    ) -> anyhow::Result<PathBuf> {
        if let Some(dir) = &self.data {
            return Ok(dir.clone());
        }
        let config = Checkpoint::read(checkpoint)?.config;
        self.resolve(&config.data, progress)
    }
}

/// Backend, LPIPS weights and progress: what every job that runs the model takes.
#[derive(Args, Clone, Debug)]
pub struct JobArgs {
    /// Backend: ndarray, flex or wgpu.
    #[arg(long, default_value = "flex")]
    pub backend: BackendKind,
    /// The LPIPS weight file [default: $PRISM_LPIPS_WEIGHTS, then data/lpips_alex.safetensors].
    #[arg(long, value_name = "FILE")]
    pub lpips_weights: Option<PathBuf>,
    /// No progress bar.
    #[arg(long)]
    pub quiet: bool,
}

/// The flags of a training run, shared by `train-teacher` and `distill-student`.
#[derive(Args, Clone, Debug)]
pub struct RunArgs {
    #[command(flatten)]
    pub data: DataArgs,
    /// Run folder for the config copy, metrics.jsonl, sample grids and checkpoints
    /// [default: runs/<job>-<config name>].
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// Train this many steps instead of the config's (with --resume: the new total, to train
    /// longer).
    #[arg(long, value_name = "N")]
    pub steps: Option<usize>,
    /// Continue the run in the run folder from its latest checkpoint, exactly where it stopped.
    #[arg(long)]
    pub resume: bool,
    /// Devices to train on, data parallel: a count of local devices (on the CPU backends:
    /// worker threads sharing the one CPU device), or a comma list of `local`,
    /// `remote:ws://HOST:PORT` and `remote:iroh:NODE_ID[@HOST:PORT]` (devices served by
    /// `prism serve`; the first device is the main one).
    // Parsed in `options`, not by clap: one error line naming the entry at fault.
    #[arg(long, default_value = "1", value_name = "N|LIST")]
    pub devices: String,
    /// On a CPU backend with one device: the shares of each step's batch computed at once on
    /// the CPU's threads, each on its own copy of the model's graph, their gradients summed as
    /// with several devices: about a tenth faster on two cores. 1 computes each batch whole
    /// [default: 2].
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u64).range(1..))]
    pub cpu_shares: Option<u64>,
    /// The file holding the token of the servers in --devices [default: $PRISM_TOKEN].
    #[arg(long, value_name = "FILE")]
    pub token_file: Option<PathBuf>,
    /// The precision the transformer blocks compute in: f32, f16 or bf16. Mixed precision: the
    /// parameters and AdamW's state stay f32, and the geometry parts, heads and losses compute
    /// in f32; f16 scales the loss dynamically. Recorded in the checkpoints [default: the
    /// resumed run's, else f32].
    #[arg(long, value_name = "f32|f16|bf16")]
    pub precision: Option<Precision>,
    /// Dynamic loss scaling (on by default with f16): finite steps in a row after which the
    /// scale doubles [default: 2000, or the resumed run's]. Given with f32 or bf16, it scales
    /// their loss too.
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u64).range(1..))]
    pub loss_scale_growth: Option<u64>,
    #[command(flatten)]
    pub job: JobArgs,
}

impl RunArgs {
    /// Whether the run trains on one device (`--devices 1`, or a list of one). A list that
    /// does not parse counts as one: [`RunArgs::options`] reports it.
    pub fn single_device(&self) -> bool {
        self.devices
            .parse::<DeviceList>()
            .map_or(true, |list| list.len() == 1)
    }

    /// The trainer's options: the run folder (`--out` or `default_out`) and the dataset
    /// (`--data` or `synth`'s, synthesised if needed).
    ///
    /// # Errors
    /// Synthesis errors.
    pub fn options(
        &self,
        default_out: PathBuf,
        synth: &SynthOptions,
    ) -> anyhow::Result<RunOptions> {
        let progress = !self.job.quiet;
        let devices: DeviceList = self.devices.parse()?;
        let token = if devices.has_remote() {
            Some(read_token(self.token_file.as_deref())?)
        } else {
            None
        };
        Ok(RunOptions {
            steps: self.steps,
            resume: self.resume,
            devices,
            cpu_shares: self.cpu_shares.map(|n| n as usize),
            token,
            progress,
            lpips_weights: self.job.lpips_weights.clone(),
            precision: self.precision,
            loss_scale: self.loss_scale_growth.map(|n| LossScaleConfig {
                growth_interval: n as usize,
                ..LossScaleConfig::default()
            }),
            ..RunOptions::new(
                self.out.clone().unwrap_or(default_out),
                self.data.resolve(synth, progress)?,
                self.job.backend,
            )
        })
    }
}

/// Prints what a training run did: steps and speed, the loss, the validations (`rows`: the
/// labels of the baseline, initial and last one), the sample grid, checkpoint and curves.
pub fn print_summary(summary: &RunSummary, labels: [&str; 2]) {
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
    let row = |name: &str, s: &ImageScores| {
        println!(
            "{name:<28} PSNR {:>7.3} dB  SSIM {:.4}  LPIPS {:.4}",
            s.psnr, s.ssim, s.lpips
        );
    };
    let [baseline, initial] = labels;
    if let Some(s) = &summary.baseline {
        row(baseline, s);
    }
    if let Some(s) = &summary.initial {
        row(initial, s);
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
    println!(
        "metrics: {}",
        summary.run_dir.join(prism_train::METRICS_FILE).display()
    );
    if let Some(path) = &summary.plot {
        println!("training curves: {}", path.display());
    }
}
