//! The training loop shared by every job (teacher pretraining now, distillation next): data,
//! data-parallel forward and backward, the non-finite guard, gradient clipping, AdamW with the
//! warm-up + cosine schedules, logging, validation and checkpoints.
//!
//! What differs between jobs is a [`Task`]: its per-device objective ([`StepLoss`]) and what it
//! does to the model before each step (the distillation schedule switches attention kinds).

use std::fs;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use burn::module::Module;
use burn::optim::AdamWConfig;
use burn::tensor::Device;
use indicatif::ProgressBar;
use prism_core::BackendKind;
use prism_data::{DatasetReader, PrismBatcher, Sample, SampleDataset, SplitKind, TargetSelection};
use prism_losses::Lpips;
use prism_model::Prism;
use serde_json::{Value, json};

use crate::checkpoint::{
    CHECKPOINT_FORMAT, CHECKPOINT_VERSION, Checkpoint, CheckpointContents, CheckpointState,
    check_architecture, check_resumable, latest_checkpoint, remove_partial_checkpoints,
    save_checkpoint,
};
use crate::clip::clip_global_norm;
use crate::config::TrainingConfig;
use crate::data::{DataOrder, Prefetcher};
use crate::error::{Result, TrainError};
use crate::groups::learning_rates_with;
use crate::images::save_png;
use crate::log::MetricsLog;
use crate::parallel::{DataParallel, training_devices};
use crate::plot::plot_run;
use crate::schedule::WarmupCosine;
use crate::step::{StepLoss, StepValues, TrainItem, Trainee};
use crate::validate::Validator;
use prism_losses::ImageScores;

/// AdamW's first-moment decay.
pub const ADAM_BETA_1: f32 = 0.9;
/// AdamW's second-moment decay.
pub const ADAM_BETA_2: f32 = 0.999;
/// AdamW's epsilon (PyTorch's default).
pub const ADAM_EPSILON: f32 = 1e-8;
/// The run folder's copy of the config it was started with.
pub const RUN_CONFIG_FILE: &str = "config.toml";
/// The run folder's folder of validation sample grids.
pub const SAMPLES_DIR: &str = "samples";

/// A training job: what the shared loop of [`train`] needs to know about it.
pub trait Task {
    /// The job's name (`teacher`, `student`), recorded in checkpoints: a run is resumed only
    /// by the same job.
    fn name(&self) -> &str;

    /// The objective of a step on `device` (called once per training device, before the first
    /// step). Load what the objective needs (LPIPS, a frozen teacher) onto `device` here.
    ///
    /// # Errors
    /// When the objective cannot be built (missing weights, a config it cannot train).
    fn step_loss(
        &self,
        config: &TrainingConfig,
        data: &TaskData,
        device: &Device,
    ) -> Result<Arc<dyn StepLoss>>;

    /// Called before every step `step` (0-based) with the model on the main device, e.g. to set
    /// the attention kinds of the distillation schedule. Must be a pure function of the step
    /// (for exact resumption). What it returns (e.g. the blocks it switched) is written to
    /// `metrics.jsonl` with the step and printed. The default does nothing.
    fn before_step(&self, _model: &mut Prism, _step: usize) -> Option<Value> {
        None
    }
}

/// What a [`Task`] learns about the training data when its objective is built.
#[derive(Clone, Debug, PartialEq)]
pub struct TaskData {
    /// The dataset's background colour, RGB in `[0, 1]` (`dataset.json`): what the 3DGS head
    /// composites its render over.
    pub background: [f32; 3],
}

/// How to run: the command line's choices.
#[derive(Clone, Debug)]
pub struct RunOptions {
    /// The run folder.
    pub out: PathBuf,
    /// The dataset folder.
    pub data: PathBuf,
    /// Overrides `train.steps`.
    pub steps: Option<usize>,
    /// Continue from the run folder's latest checkpoint.
    pub resume: bool,
    /// Start from this checkpoint's weights (a checkpoint or run folder).
    pub init: Option<PathBuf>,
    /// The backend.
    pub backend: BackendKind,
    /// Training devices (data parallel).
    pub devices: usize,
    /// Draw a progress bar (and print validations) on stderr.
    pub progress: bool,
    /// LPIPS weight file (default: the project's search order).
    pub lpips_weights: Option<PathBuf>,
}

impl RunOptions {
    /// Options for a fresh run into `out` on the dataset `data` on `backend`, one device, no
    /// progress bar.
    pub fn new(out: impl Into<PathBuf>, data: impl Into<PathBuf>, backend: BackendKind) -> Self {
        Self {
            out: out.into(),
            data: data.into(),
            steps: None,
            resume: false,
            init: None,
            backend,
            devices: 1,
            progress: false,
            lpips_weights: None,
        }
    }
}

/// What a run did.
#[derive(Clone, Debug)]
pub struct RunSummary {
    /// The run folder.
    pub run_dir: PathBuf,
    /// The dataset folder trained on.
    pub data_dir: PathBuf,
    /// The step the run started at (0, or the resumed checkpoint's).
    pub start_step: usize,
    /// Steps done at the end.
    pub steps: usize,
    /// The copy-the-source baseline (fresh runs only).
    pub baseline: Option<ImageScores>,
    /// The validation of the initial model (fresh runs only).
    pub initial: Option<ImageScores>,
    /// The last validation.
    pub last: Option<ImageScores>,
    /// The PNG grid of the last validation.
    pub last_samples: Option<PathBuf>,
    /// The last checkpoint written.
    pub last_checkpoint: Option<PathBuf>,
    /// The training curves ([`crate::plot::PLOT_FILE`]), drawn at each validation; the last
    /// one is the whole run's.
    pub plot: Option<PathBuf>,
    /// Steps skipped for a non-finite loss or gradient (over the whole run).
    pub skipped_steps: usize,
    /// Mean wall-clock seconds of a training step (data, forward, backward, optimizer;
    /// validation and checkpoints excluded).
    pub seconds_per_step: f64,
    /// The first and the last training loss of this invocation.
    pub first_loss: Option<f64>,
    /// See `first_loss`.
    pub last_loss: Option<f64>,
}

/// Trains `task` with `config` as `options` say: a fresh run, a resumed one, or a fine-tuning
/// from a checkpoint's weights. Writes the run folder (config, `metrics.jsonl`, samples,
/// checkpoints) and returns a summary.
///
/// # Errors
/// Bad options or run folder state, unreadable data or checkpoints, a worker failure, or too
/// many non-finite steps in a row ([`TrainError::NonFinite`]).
pub fn train(config: &TrainingConfig, task: &dyn Task, options: &RunOptions) -> Result<RunSummary> {
    let mut config = config.clone();
    if let Some(steps) = options.steps {
        if steps == 0 {
            return Err(TrainError::RunFolder {
                path: options.out.clone(),
                message: "--steps must be at least 1".into(),
            });
        }
        config.train.steps = steps;
    }
    let run = options.out.as_path();
    let resumed = prepare_run_folder(run, &config, task, options)?;
    let data_dir = options.data.clone();
    let reader = DatasetReader::open(&data_dir)?;
    let resolution = config.model.resolution as u32;
    let train = &config.train;
    let train_set = Arc::new(SampleDataset::new(
        reader.clone(),
        SplitKind::Train,
        TargetSelection::Random {
            count: train.targets_per_sample,
            repeats: 1,
        },
        Some((resolution, resolution)),
        train.seed,
    )?);

    let devices = training_devices(options.backend, options.devices)?;
    let main = devices[0].clone();
    let inference = main.clone().inner();
    let (prism, start, new_blocks) = initial_model(&config, resumed.as_ref(), options, &main)?;
    let total = train.steps;
    if start >= total {
        return Err(TrainError::RunFolder {
            path: run.to_path_buf(),
            message: format!(
                "the run is complete ({start} steps, train.steps = {total}); pass --steps with \
                 more steps to train longer"
            ),
        });
    }
    let mut trainee = Trainee {
        prism,
        background: reader.meta().background,
    };
    let mut optimizer = AdamWConfig::new()
        .with_beta_1(ADAM_BETA_1)
        .with_beta_2(ADAM_BETA_2)
        .with_epsilon(ADAM_EPSILON)
        .with_weight_decay(train.weight_decay as f32)
        .init();
    let backbone = WarmupCosine::new(train.lr_backbone, train.min_lr, train.warmup_steps, total);
    let heads = WarmupCosine::new(train.lr_heads, train.min_lr, train.warmup_steps, total);
    let mut scheduler =
        learning_rates_with(backbone, heads, &new_blocks, config.model.stage_one_blocks);
    if let Some(checkpoint) = &resumed {
        optimizer = checkpoint.load_optimizer(optimizer)?;
        scheduler = checkpoint.load_scheduler(scheduler)?;
    }

    let parallel = DataParallel::new(devices.clone());
    let task_data = TaskData {
        background: reader.meta().background,
    };
    let losses = devices
        .iter()
        .map(|d| task.step_loss(&config, &task_data, d))
        .collect::<Result<Vec<_>>>()?;
    let lpips = Lpips::load_default(options.lpips_weights.as_deref(), &inference)?;
    let validator = Validator::new(
        &reader,
        resolution,
        train.validation_views,
        Some(lpips),
        &inference,
    )?;
    let mut log = MetricsLog::open(run, resumed.as_ref().map(|c| c.state.step))?;
    let samples_dir = run.join(SAMPLES_DIR);
    fs::create_dir_all(&samples_dir).map_err(|e| TrainError::io(&samples_dir, e))?;

    let bar = progress_bar(options.progress, start, total, task.name());
    let mut summary = RunSummary {
        run_dir: run.to_path_buf(),
        data_dir: data_dir.clone(),
        start_step: start,
        steps: start,
        baseline: None,
        initial: None,
        last: None,
        last_samples: None,
        last_checkpoint: None,
        plot: None,
        skipped_steps: resumed.as_ref().map_or(0, |c| c.state.skipped_steps),
        seconds_per_step: f64::NAN,
        first_loss: None,
        last_loss: None,
    };
    if resumed.is_none() {
        let baseline = validator.copy_source_baseline();
        log.write(&json!({
            "step": 0,
            "copy_source_psnr": baseline.psnr,
            "copy_source_ssim": baseline.ssim,
            "copy_source_lpips": baseline.lpips,
        }))?;
        bar.println(format!(
            "copy-the-source baseline: PSNR {:.2} dB, SSIM {:.4}, LPIPS {:.4}",
            baseline.psnr, baseline.ssim, baseline.lpips
        ));
        summary.baseline = Some(baseline);
        let (scores, path) = run_validation(&validator, &trainee, 0, &samples_dir, &mut log, &bar)?;
        summary.initial = Some(scores);
        summary.last = Some(scores);
        summary.last_samples = Some(path);
        summary.plot = refresh_plot(run, &bar);
    }

    let order = DataOrder {
        seed: train.seed,
        subjects: train_set.subjects().len(),
        batch_size: train.batch_size,
    };
    let mut prefetcher = Prefetcher::start(train_set, order, start..total, train.data_workers);
    let mut in_row = resumed.as_ref().map_or(0, |c| c.state.non_finite_in_row);
    let mut step_seconds = 0.0;
    let mut steps_timed = 0usize;
    while let Some((step, samples)) = prefetcher.next_step() {
        let began = Instant::now();
        let samples = samples?;
        if let Some(event) = task.before_step(&mut trainee.prism, step) {
            let mut line = json!({ "step": step });
            if let (Some(line), Value::Object(fields)) = (line.as_object_mut(), &event) {
                line.extend(fields.clone());
            }
            bar.println(format!("before step {}: {event}", step + 1));
            log.write(&line)?;
        }
        let lr = scheduler.step();
        let (lr_backbone, lr_heads) = (backbone.lr_at(step), heads.lr_at(step));
        let shares = split_into_shares(&samples, parallel.devices(), &losses, step);
        let (grads, values) = parallel.forward_backward(&trainee, shares)?;
        let loss = values.total();
        let (grads, grad_norm) = clip_global_norm(&trainee, grads, train.grad_clip_norm);
        let done = step + 1;
        let mut line = step_line(done, &values, lr_backbone, lr_heads, grad_norm);
        let problem = if !loss.is_finite() {
            Some("non-finite loss")
        } else if !grad_norm.is_finite() {
            Some("non-finite gradient")
        } else {
            None
        };
        if let Some(reason) = problem {
            in_row += 1;
            summary.skipped_steps += 1;
            line["skipped"] = json!(true);
            line["reason"] = json!(reason);
            log.write(&line)?;
            bar.println(format!(
                "step {done}: {reason}, step skipped ({in_row} in a row)"
            ));
            if in_row >= train.max_non_finite_steps {
                bar.abandon();
                return Err(TrainError::NonFinite {
                    step: done,
                    count: in_row,
                    reason: reason.into(),
                });
            }
        } else {
            trainee = optimizer.step(lr, trainee, grads);
            in_row = 0;
            let seconds = began.elapsed().as_secs_f64();
            line["seconds"] = json!(seconds);
            log.write(&line)?;
            step_seconds += seconds;
            steps_timed += 1;
            summary.first_loss.get_or_insert(loss);
            summary.last_loss = Some(loss);
        }
        summary.steps = done;
        bar.set_message(progress_message(&values, lr_backbone));
        bar.inc(1);

        let last = done == total;
        if last || (train.validate_every > 0 && done.is_multiple_of(train.validate_every)) {
            let (scores, path) =
                run_validation(&validator, &trainee, done, &samples_dir, &mut log, &bar)?;
            summary.last = Some(scores);
            summary.last_samples = Some(path);
            summary.plot = refresh_plot(run, &bar);
        }
        if last || done.is_multiple_of(train.checkpoint_every) {
            let state = CheckpointState {
                format: CHECKPOINT_FORMAT.into(),
                version: CHECKPOINT_VERSION,
                task: task.name().into(),
                step: done,
                total_steps: total,
                seed: train.seed,
                non_finite_in_row: in_row,
                skipped_steps: summary.skipped_steps,
                devices: devices.len(),
                backend: options.backend.to_string(),
                new_blocks: new_blocks.clone(),
            };
            let contents = CheckpointContents {
                state: &state,
                config: &config,
                model: &trainee.prism,
                optimizer: &optimizer,
                scheduler: &scheduler,
            };
            summary.last_checkpoint =
                Some(save_checkpoint(run, &contents, train.keep_checkpoints)?);
        }
    }
    bar.finish_and_clear();
    summary.seconds_per_step = step_seconds / steps_timed.max(1) as f64;
    Ok(summary)
}

/// Checks the run folder against the options; returns the checkpoint to resume from.
fn prepare_run_folder(
    run: &Path,
    config: &TrainingConfig,
    task: &dyn Task,
    options: &RunOptions,
) -> Result<Option<Checkpoint>> {
    let fail = |message: String| {
        Err(TrainError::RunFolder {
            path: run.to_path_buf(),
            message,
        })
    };
    if options.resume && options.init.is_some() {
        return fail(
            "--resume and --init cannot be combined: --resume continues the run's own checkpoint"
                .into(),
        );
    }
    remove_partial_checkpoints(run)?;
    let latest = latest_checkpoint(run)?;
    if !options.resume {
        if let Some(latest) = latest {
            return fail(format!(
                "already holds a run (latest checkpoint {}); pass --resume to continue it or \
                 choose another --out",
                latest.display()
            ));
        }
        fs::create_dir_all(run).map_err(|e| TrainError::io(run, e))?;
        let path = run.join(RUN_CONFIG_FILE);
        prism_core::files::write_bytes(&path, config.to_toml().as_bytes())
            .map_err(|e| TrainError::io(&path, e))?;
        return Ok(None);
    }
    let Some(latest) = latest else {
        return fail("holds no checkpoint to resume from; start the run without --resume".into());
    };
    let checkpoint = Checkpoint::read(&latest)?;
    if checkpoint.state.task != task.name() {
        return Err(TrainError::ConfigMismatch {
            path: checkpoint.dir.clone(),
            what: format!(
                "it is a {} run, this is a {} run",
                checkpoint.state.task,
                task.name()
            ),
        });
    }
    check_resumable(&checkpoint, config)?;
    Ok(Some(checkpoint))
}

/// The model to start from, its step and its newly initialised blocks (which train at
/// `lr_heads`, see [`CheckpointState::new_blocks`]): the resumed checkpoint's, `--init`'s
/// weights, or a fresh initialisation seeded by `train.seed`.
fn initial_model(
    config: &TrainingConfig,
    resumed: Option<&Checkpoint>,
    options: &RunOptions,
    device: &Device,
) -> Result<(Prism, usize, Vec<usize>)> {
    if let Some(checkpoint) = resumed {
        return Ok((
            checkpoint.load_model(device)?,
            checkpoint.state.step,
            checkpoint.state.new_blocks.clone(),
        ));
    }
    if let Some(init) = &options.init {
        let checkpoint = Checkpoint::read(init)?;
        check_architecture(&checkpoint, &config.model)?;
        return Ok((
            checkpoint.load_model(device)?,
            0,
            checkpoint.state.new_blocks.clone(),
        ));
    }
    device.seed(config.train.seed);
    Ok((config.model.init(device), 0, Vec::new()))
}

/// Splits a step's samples into one share per device (consecutive samples, sizes differing by
/// at most one), each batched on its device and weighted by its fraction of the pairs.
fn split_into_shares(
    samples: &[Sample],
    devices: &[Device],
    losses: &[Arc<dyn StepLoss>],
    step: usize,
) -> Vec<TrainItem> {
    let shares = devices.len().min(samples.len()).max(1);
    let pairs: usize = samples.iter().map(|s| s.targets.len()).sum();
    let (base, extra) = (samples.len() / shares, samples.len() % shares);
    let mut start = 0;
    (0..shares)
        .map(|i| {
            let len = base + usize::from(i < extra);
            let chunk = &samples[start..start + len];
            start += len;
            let chunk_pairs: usize = chunk.iter().map(|s| s.targets.len()).sum();
            TrainItem {
                batch: PrismBatcher.batch_samples(chunk, &devices[i]),
                loss: losses[i].clone(),
                weight: chunk_pairs as f64 / pairs as f64,
                step,
                share: i,
            }
        })
        .collect()
}

/// Validates, writes the sample grid and the log line.
fn run_validation(
    validator: &Validator,
    trainee: &Trainee,
    step: usize,
    samples_dir: &Path,
    log: &mut MetricsLog,
    bar: &ProgressBar,
) -> Result<(ImageScores, PathBuf)> {
    let model = trainee.prism.valid();
    let (scores, grid) = validator.validate(&model);
    let name = format!("step-{step:08}.png");
    let path = samples_dir.join(&name);
    save_png(&path, &grid)?;
    log.write(&json!({
        "step": step,
        "val_psnr": scores.psnr,
        "val_ssim": scores.ssim,
        "val_lpips": scores.lpips,
        "samples": format!("{SAMPLES_DIR}/{name}"),
    }))?;
    bar.println(format!(
        "step {step}: validation PSNR {:.2} dB, SSIM {:.4}, LPIPS {:.4} ({} views)",
        scores.psnr,
        scores.ssim,
        scores.lpips,
        validator.len()
    ));
    Ok((scores, path))
}

/// Draws the run's training curves from its `metrics.jsonl`. A plot that cannot be drawn is
/// reported on the progress bar, not fatal: the run goes on.
fn refresh_plot(run: &Path, bar: &ProgressBar) -> Option<PathBuf> {
    match plot_run(run) {
        Ok(path) => Some(path),
        Err(e) => {
            bar.println(format!("warning: training curves not drawn: {e}"));
            None
        }
    }
}

/// The log line of a step: `step`, `loss`, every term, learning rates and gradient norm.
fn step_line(step: usize, values: &StepValues, lr: f64, lr_heads: f64, grad_norm: f64) -> Value {
    let mut line = json!({ "step": step, "loss": values.total() });
    for &(name, value) in values.terms.iter().filter(|(n, _)| *n != "total") {
        line[name] = json!(value);
    }
    line["lr"] = json!(lr);
    line["lr_heads"] = json!(lr_heads);
    line["grad_norm"] = json!(grad_norm);
    line
}

fn progress_bar(enabled: bool, start: usize, total: usize, name: &str) -> ProgressBar {
    let bar = prism_core::progress::progress_bar(
        enabled,
        total as u64,
        "{prefix} {bar:30} {pos}/{len} [{elapsed_precise} < {eta_precise}, {per_sec}] {msg}",
    );
    bar.set_prefix(name.to_string());
    bar.set_position(start as u64);
    bar.reset_eta();
    bar
}

fn progress_message(values: &StepValues, lr: f64) -> String {
    let mut msg = format!("loss {:.4}", values.total());
    for &(name, value) in values.terms.iter().filter(|(n, _)| *n != "total") {
        msg.push_str(&format!(" {name} {value:.4}"));
    }
    msg.push_str(&format!(" lr {lr:.2e}"));
    msg
}
