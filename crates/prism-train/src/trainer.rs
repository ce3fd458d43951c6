//! The training loop shared by every job (teacher pretraining, student distillation): a loop
//! over the run's steps, each one a [`TrainingStep`] (data-parallel forward and backward,
//! clipping, the non-finite guard, AdamW with the warm-up + cosine schedules) followed by the
//! run's [`Cadence`] (logging, validation, checkpoints).
//!
//! What differs between jobs is a [`Task`]: its per-device objective ([`StepLoss`]) and what it
//! does to the model before each step (the distillation schedule switches attention kinds).

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;

use burn::tensor::Device;
use prism_core::BackendKind;
use prism_core::backend::{is_cpu_device, is_served};
use prism_core::phases::{Phase, timed};
use prism_data::{DatasetReader, SampleDataset};
use prism_losses::ImageScores;
use prism_model::{Precision, Prism};
use prism_remote::{DeviceList, dataset_digest};
use serde_json::Value;

use crate::cadence::Cadence;
use crate::config::TrainingConfig;
use crate::data::{DataOrder, Prefetcher};
use crate::error::{Result, TrainError};
use crate::loss_scale::LossScaleConfig;
use crate::parallel::{TrainingDevice, cpu_shares, fingerprint, training_devices};
use crate::served::guarded;
use crate::start::{initial_model, prepare_run_folder};
use crate::step::StepLoss;
use crate::training_step::TrainingStep;

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

/// What a [`Task`] learns about the training data and the run when its objective is built.
#[derive(Clone, Debug, PartialEq)]
pub struct TaskData {
    /// The dataset's background colour, RGB in `[0, 1]` (`dataset.json`): what the 3DGS head
    /// composites its render over.
    pub background: [f32; 3],
    /// The precision the trained model's blocks compute in: a model the objective runs
    /// besides (distillation's frozen teacher) computes in it too.
    pub precision: Precision,
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
    /// Training devices (data parallel): local ones, or devices served by `prism serve`.
    pub devices: DeviceList,
    /// On one local device of a CPU backend: the shares of each step's batch computed at once
    /// on rayon's pool ([`crate::parallel::cpu_shares`]); `None`: two. 1 computes each batch
    /// whole.
    pub cpu_shares: Option<usize>,
    /// The credential the servers of `devices` check.
    pub token: Option<String>,
    /// Draw a progress bar (and print validations) on stderr.
    pub progress: bool,
    /// LPIPS weight file (default: the project's search order).
    pub lpips_weights: Option<PathBuf>,
    /// The precision the transformer blocks compute in (the parameters and the optimizer
    /// state stay `f32`; see [`prism_model::Prism::with_compute_precision`]); `None`: the
    /// resumed run's, f32 for a fresh one. Recorded in checkpoints.
    pub precision: Option<Precision>,
    /// Dynamic loss scaling (see [`crate::loss_scale`]); `None`: on with the defaults for f16
    /// (a resumed run continues its own), off for f32 and bf16. `Some`: on with these
    /// settings, whatever the precision.
    pub loss_scale: Option<LossScaleConfig>,
}

impl RunOptions {
    /// Options for a fresh run into `out` on the dataset `data` on `backend`, one device, no
    /// progress bar, the precision's default loss scaling (f32 unless resuming).
    pub fn new(out: impl Into<PathBuf>, data: impl Into<PathBuf>, backend: BackendKind) -> Self {
        Self {
            out: out.into(),
            data: data.into(),
            steps: None,
            resume: false,
            init: None,
            backend,
            devices: DeviceList::default(),
            cpu_shares: None,
            token: None,
            progress: false,
            lpips_weights: None,
            precision: None,
            loss_scale: None,
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
/// checkpoints, training curves) and returns a summary.
///
/// # Errors
/// Bad options or run folder state, unreadable data or checkpoints, a worker failure, or too
/// many non-finite steps in a row ([`TrainError::NonFinite`]).
pub fn train(config: &TrainingConfig, task: &dyn Task, options: &RunOptions) -> Result<RunSummary> {
    let config = with_steps(config, options)?;
    let resumed = prepare_run_folder(&options.out, &config, task, options)?;
    let reader = DatasetReader::open(&options.data)?;
    let train_set = training_set(&reader, &config)?;
    let digest = dataset_digest(&reader).map_err(|e| TrainError::io(reader.root(), e))?;
    let devices = training_devices(
        options.backend,
        &options.devices,
        options.token.as_deref(),
        &fingerprint(&config).with_data(digest),
    )?;
    let start = initial_model(&config, resumed.as_ref(), options, &devices[0].device)?;
    let first = start.step;
    check_unfinished(options, first, config.train.steps)?;
    let shares = step_shares(options, &devices);
    if let Some(state) = resumed.as_ref().map(|c| &c.state) {
        let now = shares.min(config.train.batch_size);
        let before = state
            .shares
            .unwrap_or(state.devices.min(config.train.batch_size));
        if state.devices != devices.len() || before != now {
            eprintln!(
                "resuming on {} devices (the run trained on {} so far): each step's batch is \
                 split into {now} shares instead of {before}; the result equals the run's up to \
                 float rounding, not bit for bit",
                devices.len(),
                state.devices,
            );
        }
    }
    for device in devices
        .iter()
        .filter(|d| is_served(&d.device) && !d.loads_shares)
    {
        eprintln!(
            "{}: its server has no --data, so this trainer sends it its share of every batch \
             (start it with --data at a copy of the dataset to load it there)",
            device.name
        );
    }
    let data = TaskData {
        background: reader.meta().background,
        precision: start.precision,
    };
    let served = (0..shares)
        .map(|i| devices[i % devices.len()].loads_shares)
        .collect();
    let mut step = TrainingStep::new(
        &config,
        start,
        resumed.as_ref(),
        task,
        &data,
        devices,
        shares,
    )?;
    let mut cadence = Cadence::start(&config, options, task, &reader, &step, resumed.as_ref())?;
    let mut prefetcher = prefetch(train_set, &config, first, served);
    while let Some((index, shares)) = timed(Phase::DataWait, || prefetcher.next_step()) {
        let began = Instant::now();
        let shares = shares?;
        cadence.prepared(index, step.prepare(index))?;
        guarded(&options.devices, || {
            let report = timed(Phase::Steps, || step.run(index, shares))?;
            cadence.after_step(&step, &report, began.elapsed().as_secs_f64())
        })?;
    }
    Ok(cadence.finish(&step))
}

/// Shares of each step's batch: one per device; on one device of this machine's CPU (not a
/// served one), [`cpu_shares`] of `options.cpu_shares`, computed at once.
fn step_shares(options: &RunOptions, devices: &[TrainingDevice]) -> usize {
    match devices {
        [device] if is_cpu_device(&device.device) => cpu_shares(options.cpu_shares),
        _ => devices.len(),
    }
}

/// `config` with `--steps` (`options.steps`) as its `train.steps`.
fn with_steps(config: &TrainingConfig, options: &RunOptions) -> Result<TrainingConfig> {
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
    Ok(config)
}

/// The run's training samples: the dataset's training subjects at the model's resolution,
/// `train.targets_per_sample` random target views each.
fn training_set(reader: &DatasetReader, config: &TrainingConfig) -> Result<Arc<SampleDataset>> {
    Ok(Arc::new(SampleDataset::training(
        reader.clone(),
        config.train.targets_per_sample,
        config.model.resolution as u32,
        config.train.seed,
    )?))
}

/// Refuses to run a run that has done its `total` steps (`start` done).
fn check_unfinished(options: &RunOptions, start: usize, total: usize) -> Result<()> {
    if start < total {
        return Ok(());
    }
    Err(TrainError::RunFolder {
        path: options.out.clone(),
        message: format!(
            "the run is complete ({start} steps, train.steps = {total}); pass --steps with more \
             steps to train longer"
        ),
    })
}

/// Loads the shares of steps `start..train.steps` ahead of training, in the run's
/// [`DataOrder`], for devices whose servers load their own shares or not (`served`).
fn prefetch(
    train_set: Arc<SampleDataset>,
    config: &TrainingConfig,
    start: usize,
    served: Vec<bool>,
) -> Prefetcher {
    let train = &config.train;
    let order = DataOrder {
        seed: train.seed,
        subjects: train_set.subjects().len(),
        batch_size: train.batch_size,
    };
    Prefetcher::start(
        train_set,
        order,
        start..train.steps,
        train.data_workers,
        served,
    )
}
