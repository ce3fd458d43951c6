//! Checkpoints: everything needed to continue a run exactly, or to use its model.
//!
//! A run folder holds `checkpoints/step-NNNNNNNN/` (the number of optimizer steps done, 8
//! digits) with:
//!
//! | file | what |
//! |---|---|
//! | `model.bpk` | the [`Prism`] weights (Burn's burnpack, `Module::save_file`) |
//! | `attention.json` | each block's attention kind, `["full", "linear", ...]` (not in the weights) |
//! | `optimizer.bpk` | the AdamW state (Burn's `OptimizerRecord`) |
//! | `scheduler.bpk` | the learning-rate schedulers' state (Burn's `LrSchedulerRecord`) |
//! | `state.json` | step, seed (the data order is a pure function of seed and step), counters, precision and loss scale |
//! | `config.toml` | the full training config of the run |
//!
//! A checkpoint is written into `step-NNNNNNNN.partial/` and moved in when complete by
//! [`prism_core::files::replace_dir`]: every file synced (the `.bpk` files Burn's recorder
//! writes included), then exchanged with a folder it replaces in one rename (where the file
//! system cannot, the old one is put aside as `.old` until the new one is in), and the old one
//! removed only once the new one is on the disk. So a run killed, or a machine losing power, at
//! any moment leaves a complete checkpoint, and never a half-written one under its final name;
//! the next run recovers the folder and removes the leftovers ([`recover_checkpoints`]).

use std::fs;
use std::path::{Path, PathBuf};

use burn::module::Module;
use burn::optim::lr_scheduler::LrSchedulerRecord;
use burn::optim::lr_scheduler::module_lr_scheduler::ModuleLrScheduler;
use burn::optim::{ModuleOptimizer, OptimizerRecord};
use burn::tensor::Device;
use prism_core::BackendKind;
use prism_core::files::{ASIDE_SUFFIX, STAGED_SUFFIX, recover_dir, replace_dir, with_suffix};
use prism_model::{AttentionKind, Precision, Prism, PrismConfig};
use serde::{Deserialize, Serialize};

use crate::config::TrainingConfig;
use crate::error::{Result, TrainError};
use crate::loss_scale::LossScaleState;

/// The folder of a run that holds its checkpoints.
pub const CHECKPOINTS_DIR: &str = "checkpoints";
/// Value of `state.json`'s `format` field.
pub const CHECKPOINT_FORMAT: &str = "prism-checkpoint";
/// Version of the checkpoint layout.
pub const CHECKPOINT_VERSION: u32 = 1;

/// File names inside a checkpoint folder.
pub mod files {
    /// The model weights.
    pub const MODEL: &str = "model.bpk";
    /// Each block's attention kind.
    pub const ATTENTION: &str = "attention.json";
    /// The optimizer state.
    pub const OPTIMIZER: &str = "optimizer.bpk";
    /// The learning-rate schedulers' state.
    pub const SCHEDULER: &str = "scheduler.bpk";
    /// Step, seed and counters.
    pub const STATE: &str = "state.json";
    /// The training config.
    pub const CONFIG: &str = "config.toml";
}

/// `state.json`: where the run stands.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CheckpointState {
    /// Always [`CHECKPOINT_FORMAT`].
    pub format: String,
    /// [`CHECKPOINT_VERSION`].
    pub version: u32,
    /// The job that wrote it (`teacher`, `student`, ...).
    pub task: String,
    /// Optimizer steps done: the run continues with step `step` (0-based).
    pub step: usize,
    /// Steps the run was started for.
    pub total_steps: usize,
    /// The run's seed: with `step` it fixes the data of every later step (see
    /// [`crate::DataOrder`]).
    pub seed: u64,
    /// Steps with a non-finite loss or gradient right before this checkpoint.
    pub non_finite_in_row: usize,
    /// Steps skipped for a non-finite loss or gradient since the run started.
    pub skipped_steps: usize,
    /// Devices the run trained on.
    pub devices: usize,
    /// Shares each step's batch was cut into: one per device, or on one CPU device those
    /// computed at once (`--cpu-shares`). Absent from checkpoints written before it was
    /// recorded, whose runs had one share per device.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shares: Option<usize>,
    /// Backend the run trained on.
    pub backend: String,
    /// Transformer blocks (global indices) that were newly initialised when the model was made
    /// from a pretrained one (`prism convert lvsm`, config blocks beyond LVSM's): like the
    /// geometry parts they train at `lr_heads`, in the run started from that checkpoint with
    /// `--init` and in its resumes. Empty (and not written) otherwise.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub new_blocks: Vec<usize>,
    /// The precision the transformer blocks computed in (`--precision`; the parameters are
    /// `f32` whatever it is): a resumed run continues in it. Checkpoints written before it was
    /// recorded were f32.
    #[serde(default)]
    pub precision: Precision,
    /// Where dynamic loss scaling stood (f16 runs; absent when the loss is not scaled): a
    /// resumed run continues with this scale.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub loss_scale: Option<LossScaleState>,
}

/// A checkpoint read from disk (its small files; the weights are loaded on demand).
#[derive(Clone, Debug)]
pub struct Checkpoint {
    /// The checkpoint folder.
    pub dir: PathBuf,
    /// `state.json`.
    pub state: CheckpointState,
    /// `config.toml`.
    pub config: TrainingConfig,
    /// `attention.json`.
    pub attention: Vec<AttentionKind>,
}

impl Checkpoint {
    /// Reads a checkpoint folder, or the latest checkpoint of a run folder.
    ///
    /// # Errors
    /// A folder that is neither, missing or malformed files.
    pub fn read(path: &Path) -> Result<Self> {
        let dir = if path.join(files::STATE).is_file() {
            path.to_path_buf()
        } else if path.join(CHECKPOINTS_DIR).is_dir() {
            latest_checkpoint(path)?.ok_or_else(|| {
                TrainError::checkpoint(path, "the run folder holds no complete checkpoint")
            })?
        } else if with_suffix(path, ASIDE_SUFFIX).join(files::STATE).is_file() {
            return Err(TrainError::checkpoint(
                path,
                format!(
                    "missing: a replace of this checkpoint was interrupted, and its previous \
                     version is {} (rename it back)",
                    with_suffix(path, ASIDE_SUFFIX).display()
                ),
            ));
        } else {
            return Err(TrainError::checkpoint(
                path,
                format!(
                    "not a checkpoint folder (no {}) nor a run folder (no {CHECKPOINTS_DIR}/)",
                    files::STATE
                ),
            ));
        };
        let state_path = dir.join(files::STATE);
        let state: CheckpointState = read_json(&state_path)?;
        if state.format != CHECKPOINT_FORMAT || state.version != CHECKPOINT_VERSION {
            return Err(TrainError::checkpoint(
                &state_path,
                format!(
                    "format `{}` version {} is not supported (this prism reads `{CHECKPOINT_FORMAT}` \
                     version {CHECKPOINT_VERSION})",
                    state.format, state.version
                ),
            ));
        }
        let config = TrainingConfig::load_stored(dir.join(files::CONFIG))?;
        let attention: Vec<AttentionKind> = read_json(&dir.join(files::ATTENTION))?;
        if attention.len() != config.model.num_blocks() {
            return Err(TrainError::checkpoint(
                dir.join(files::ATTENTION),
                format!(
                    "{} attention kinds for a model of {} blocks",
                    attention.len(),
                    config.model.num_blocks()
                ),
            ));
        }
        for file in [files::MODEL, files::OPTIMIZER, files::SCHEDULER] {
            if !dir.join(file).is_file() {
                return Err(TrainError::checkpoint(&dir, format!("{file} is missing")));
            }
        }
        Ok(Self {
            dir,
            state,
            config,
            attention,
        })
    }

    /// The checkpoint's model on `device`, with its weights and attention kinds.
    ///
    /// # Errors
    /// When the weights cannot be read or do not fit the config.
    pub fn load_model(&self, device: &Device) -> Result<Prism> {
        load_weights(&self.config.model, &self.dir.join(files::MODEL), device).map(|mut m| {
            m.set_attention_kinds(&self.attention);
            m
        })
    }

    /// `optim` with the checkpoint's optimizer state.
    ///
    /// # Errors
    /// When the file cannot be read.
    pub fn load_optimizer(&self, optim: ModuleOptimizer) -> Result<ModuleOptimizer> {
        let path = self.dir.join(files::OPTIMIZER);
        let record = OptimizerRecord::load(&path)
            .map_err(|e| TrainError::checkpoint(&path, e.to_string()))?;
        Ok(optim.load_record(record))
    }

    /// `scheduler` with the checkpoint's scheduler state.
    ///
    /// # Errors
    /// When the file cannot be read.
    pub fn load_scheduler(&self, scheduler: ModuleLrScheduler) -> Result<ModuleLrScheduler> {
        let path = self.dir.join(files::SCHEDULER);
        let record = LrSchedulerRecord::load(&path)
            .map_err(|e| TrainError::checkpoint(&path, e.to_string()))?;
        Ok(scheduler.load_record(record))
    }
}

/// The model of a checkpoint (a checkpoint folder, or a run folder's latest checkpoint) on
/// `device`, with its config: what evaluation, inference and distillation load.
///
/// # Errors
/// As [`Checkpoint::read`] and [`Checkpoint::load_model`].
pub fn load_model(path: &Path, device: &Device) -> Result<(Prism, TrainingConfig)> {
    let checkpoint = Checkpoint::read(path)?;
    let model = checkpoint.load_model(device)?;
    Ok((model, checkpoint.config))
}

/// [`load_model`] for inference on `backend`'s `device`, with the transformer blocks in
/// `precision` ([`Prism::with_block_precision`]): what evaluation, inference and the viewer
/// load.
///
/// # Errors
/// As [`load_model`], and a precision the device does not compute in.
pub fn load_inference_model(
    path: &Path,
    backend: BackendKind,
    device: &Device,
    precision: Precision,
) -> Result<(Prism, TrainingConfig)> {
    if !precision.supported_on(device) {
        return Err(TrainError::UnsupportedPrecision {
            precision,
            backend: backend.to_string(),
        });
    }
    let (model, config) = load_model(path, device)?;
    Ok((model.with_block_precision(precision), config))
}

/// A model built from `config` with the weights of a burnpack file.
fn load_weights(config: &PrismConfig, path: &Path, device: &Device) -> Result<Prism> {
    config
        .init(device)
        .try_load_file(path)
        .map_err(|e| TrainError::checkpoint(path, format!("cannot load the weights: {e}")))
}

/// The folder of the checkpoint after `step` steps in run folder `run`.
pub fn checkpoint_dir(run: &Path, step: usize) -> PathBuf {
    run.join(CHECKPOINTS_DIR).join(format!("step-{step:08}"))
}

/// The complete checkpoints of a run folder, oldest first, as (step, folder).
///
/// # Errors
/// When the folder cannot be listed.
pub fn list_checkpoints(run: &Path) -> Result<Vec<(usize, PathBuf)>> {
    let dir = run.join(CHECKPOINTS_DIR);
    if !dir.is_dir() {
        return Ok(Vec::new());
    }
    let mut out = Vec::new();
    for entry in fs::read_dir(&dir).map_err(|e| TrainError::io(&dir, e))? {
        let entry = entry.map_err(|e| TrainError::io(&dir, e))?;
        let name = entry.file_name().to_string_lossy().into_owned();
        if let Some(step) = name
            .strip_prefix("step-")
            .filter(|n| n.len() == 8 && n.bytes().all(|b| b.is_ascii_digit()))
            .and_then(|n| n.parse::<usize>().ok())
        {
            out.push((step, entry.path()));
        }
    }
    out.sort();
    Ok(out)
}

/// The latest complete checkpoint of a run folder.
///
/// # Errors
/// When the folder cannot be listed.
pub fn latest_checkpoint(run: &Path) -> Result<Option<PathBuf>> {
    Ok(list_checkpoints(run)?.pop().map(|(_, p)| p))
}

/// Recovers the checkpoints of a run killed while it saved one: a checkpoint whose replace was
/// interrupted gets its complete folder back under its name, and half-written folders are
/// removed (see [`recover_dir`]).
///
/// # Errors
/// I/O errors.
pub fn recover_checkpoints(run: &Path) -> Result<()> {
    let dir = run.join(CHECKPOINTS_DIR);
    if !dir.is_dir() {
        return Ok(());
    }
    for entry in fs::read_dir(&dir).map_err(|e| TrainError::io(&dir, e))? {
        let entry = entry.map_err(|e| TrainError::io(&dir, e))?;
        let name = entry.file_name().to_string_lossy().into_owned();
        if let Some(base) = name
            .strip_suffix(STAGED_SUFFIX)
            .or_else(|| name.strip_suffix(ASIDE_SUFFIX))
        {
            let checkpoint = dir.join(base);
            recover_dir(&checkpoint).map_err(|e| TrainError::io(&checkpoint, e))?;
        }
    }
    Ok(())
}

/// Writes a checkpoint folder `dir` through `write` (into `dir.partial`), then replaces `dir`
/// with it (see [`replace_dir`]), after recovering a replace of `dir` that a crash interrupted.
fn write_checkpoint_dir(dir: &Path, write: impl FnOnce(&Path) -> Result<()>) -> Result<()> {
    recover_dir(dir).map_err(|e| TrainError::io(dir, e))?;
    let staged = with_suffix(dir, STAGED_SUFFIX);
    write(&staged)?;
    replace_dir(&staged, dir).map_err(|e| TrainError::io(dir, e))
}

/// What a checkpoint saves.
pub struct CheckpointContents<'a> {
    /// `state.json`.
    pub state: &'a CheckpointState,
    /// The run's config.
    pub config: &'a TrainingConfig,
    /// The model.
    pub model: &'a Prism,
    /// The optimizer.
    pub optimizer: &'a ModuleOptimizer,
    /// The learning-rate schedulers.
    pub scheduler: &'a ModuleLrScheduler,
}

/// Writes the files of a checkpoint (see the module docs) into the folder `dir`, created if
/// needed.
///
/// # Errors
/// I/O or serialisation errors, naming the file.
pub fn write_checkpoint_files(dir: &Path, contents: &CheckpointContents<'_>) -> Result<()> {
    fs::create_dir_all(dir).map_err(|e| TrainError::io(dir, e))?;
    let record_error = |file: &str, e: burn::store::RecordError| {
        TrainError::checkpoint(dir.join(file), e.to_string())
    };
    contents
        .model
        .clone()
        .save_file(dir.join(files::MODEL))
        .map_err(|e| record_error(files::MODEL, e))?;
    contents
        .optimizer
        .to_record()
        .save(dir.join(files::OPTIMIZER))
        .map_err(|e| record_error(files::OPTIMIZER, e))?;
    contents
        .scheduler
        .to_record()
        .save(dir.join(files::SCHEDULER))
        .map_err(|e| record_error(files::SCHEDULER, e))?;
    write_json(
        &dir.join(files::ATTENTION),
        &contents.model.attention_kinds(),
    )?;
    write_json(&dir.join(files::STATE), contents.state)?;
    let config_path = dir.join(files::CONFIG);
    prism_core::files::write_bytes(&config_path, contents.config.to_toml().as_bytes())
        .map_err(|e| TrainError::io(&config_path, e))?;
    Ok(())
}

/// Writes a checkpoint folder `dir` holding `model` as step 0 of a run of `config` (fresh
/// optimizer and schedulers; `new_blocks` as [`CheckpointState::new_blocks`]), for `task`
/// (e.g. a converted pretrained model): what
/// `evaluate`, `infer` and `train-teacher --init` read. Written into `DIR.partial` and moved in,
/// replacing `dir` (see [`replace_dir`]).
///
/// # Errors
/// I/O or serialisation errors.
pub fn save_model_checkpoint(
    dir: &Path,
    config: &TrainingConfig,
    model: &Prism,
    task: &str,
    backend: &str,
    new_blocks: &[usize],
) -> Result<()> {
    let train = &config.train;
    let state = CheckpointState {
        format: CHECKPOINT_FORMAT.to_string(),
        version: CHECKPOINT_VERSION,
        task: task.to_string(),
        step: 0,
        total_steps: train.steps,
        seed: train.seed,
        non_finite_in_row: 0,
        skipped_steps: 0,
        devices: 1,
        shares: None,
        backend: backend.to_string(),
        new_blocks: new_blocks.to_vec(),
        precision: Precision::F32,
        loss_scale: None,
    };
    let optimizer = burn::optim::AdamWConfig::new().init();
    let backbone = crate::schedule::WarmupCosine::new(
        train.lr_backbone,
        train.min_lr,
        train.warmup_steps,
        train.steps,
    );
    let heads = crate::schedule::WarmupCosine::new(
        train.lr_heads,
        train.min_lr,
        train.warmup_steps,
        train.steps,
    );
    let scheduler = crate::groups::learning_rates_with(
        backbone,
        heads,
        new_blocks,
        config.model.stage_one_blocks,
    );
    write_checkpoint_dir(dir, |staged| {
        write_checkpoint_files(
            staged,
            &CheckpointContents {
                state: &state,
                config,
                model,
                optimizer: &optimizer,
                scheduler: &scheduler,
            },
        )
    })
}

/// Writes the checkpoint of `contents.state.step` into `run` atomically, then keeps only the
/// newest `keep` checkpoints. Returns the checkpoint folder.
///
/// # Errors
/// I/O or serialisation errors, naming the file.
pub fn save_checkpoint(
    run: &Path,
    contents: &CheckpointContents<'_>,
    keep: usize,
) -> Result<PathBuf> {
    let dir = checkpoint_dir(run, contents.state.step);
    write_checkpoint_dir(&dir, |staged| write_checkpoint_files(staged, contents))?;
    let all = list_checkpoints(run)?;
    for (_, old) in all.iter().take(all.len().saturating_sub(keep.max(1))) {
        fs::remove_dir_all(old).map_err(|e| TrainError::io(old, e))?;
    }
    Ok(dir)
}

/// The settings whose change makes a checkpoint another run's: everything but the run length
/// and the bookkeeping frequencies, as dotted keys (`train.lr_backbone`) with JSON values.
fn run_identity(config: &TrainingConfig) -> Vec<(String, serde_json::Value)> {
    const FREE: [&str; 6] = [
        "train.steps",
        "train.data_workers",
        "train.checkpoint_every",
        "train.keep_checkpoints",
        "train.validate_every",
        "train.validation_views",
    ];
    let mut out = Vec::new();
    flatten(
        "",
        &serde_json::to_value(config).expect("config serialises"),
        &mut out,
    );
    out.retain(|(k, _)| !FREE.contains(&k.as_str()));
    out
}

fn flatten(prefix: &str, value: &serde_json::Value, out: &mut Vec<(String, serde_json::Value)>) {
    match value {
        serde_json::Value::Object(map) => {
            for (k, v) in map {
                let key = if prefix.is_empty() {
                    k.clone()
                } else {
                    format!("{prefix}.{k}")
                };
                flatten(&key, v, out);
            }
        }
        other => out.push((prefix.to_string(), other.clone())),
    }
}

/// The first setting in which `now` differs from `then`, described as
/// `field: X in the checkpoint, Y now`.
fn first_difference(
    then: &[(String, serde_json::Value)],
    now: &[(String, serde_json::Value)],
) -> Option<String> {
    for (key, value) in now {
        match then.iter().find(|(k, _)| k == key) {
            Some((_, old)) if old == value => {}
            Some((_, old)) => return Some(format!("{key}: {old} in the checkpoint, {value} now")),
            None => return Some(format!("{key}: absent in the checkpoint, {value} now")),
        }
    }
    then.iter()
        .find(|(k, _)| !now.iter().any(|(n, _)| n == k))
        .map(|(k, v)| format!("{k}: {v} in the checkpoint, absent now"))
}

/// Checks that `checkpoint` belongs to a run with `config` (all settings but the run length and
/// bookkeeping frequencies must match) before resuming it.
///
/// # Errors
/// [`TrainError::ConfigMismatch`] naming the first differing setting.
pub fn check_resumable(checkpoint: &Checkpoint, config: &TrainingConfig) -> Result<()> {
    match first_difference(&run_identity(&checkpoint.config), &run_identity(config)) {
        None => Ok(()),
        Some(what) => Err(TrainError::ConfigMismatch {
            path: checkpoint.dir.clone(),
            what,
        }),
    }
}

/// Checks that `checkpoint`'s model has the architecture of `model` (width, heads, patch,
/// blocks, MLP ratio), so that its weights can initialise it (`--init`).
///
/// # Errors
/// [`TrainError::ConfigMismatch`] naming the first differing field.
pub fn check_architecture(checkpoint: &Checkpoint, model: &PrismConfig) -> Result<()> {
    let theirs = &checkpoint.config.model;
    let fields = [
        ("model.width", theirs.width, model.width),
        ("model.heads", theirs.heads, model.heads),
        ("model.patch_size", theirs.patch_size, model.patch_size),
        (
            "model.stage_one_blocks",
            theirs.stage_one_blocks,
            model.stage_one_blocks,
        ),
        (
            "model.stage_three_blocks",
            theirs.stage_three_blocks,
            model.stage_three_blocks,
        ),
        ("model.mlp_ratio", theirs.mlp_ratio, model.mlp_ratio),
    ];
    match fields.iter().find(|(_, a, b)| a != b) {
        None => Ok(()),
        Some((field, a, b)) => Err(TrainError::ConfigMismatch {
            path: checkpoint.dir.clone(),
            what: format!("{field}: {a} in the checkpoint, {b} now"),
        }),
    }
}

fn read_json<T: serde::de::DeserializeOwned>(path: &Path) -> Result<T> {
    let text = fs::read_to_string(path).map_err(|e| TrainError::io(path, e))?;
    serde_json::from_str(&text).map_err(|e| TrainError::checkpoint(path, e.to_string()))
}

fn write_json<T: Serialize + ?Sized>(path: &Path, value: &T) -> Result<()> {
    prism_core::files::write_json(path, value).map_err(|e| TrainError::io(path, e))
}
