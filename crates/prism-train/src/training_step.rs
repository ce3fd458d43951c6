//! One optimisation step of a run, the same for every job: the step's samples split into one
//! share per device, the data-parallel forward and backward of the job's objective, global-norm
//! clipping, the non-finite guard, and AdamW with the warm-up + cosine schedules of the
//! backbone and the heads. What a job adds is its [`Task`]: the objective of each device and
//! what it does to the model before a step.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use burn::optim::lr_scheduler::module_lr_scheduler::ModuleLrScheduler;
use burn::optim::{AdamWConfig, ModuleOptimizer};
use burn::tensor::Device;
use prism_core::BackendKind;
use prism_data::{PrismBatch, PrismBatcher};
use prism_model::Prism;
use prism_remote::ShardRequest;
use serde_json::Value;

use crate::checkpoint::{
    CHECKPOINT_FORMAT, CHECKPOINT_VERSION, Checkpoint, CheckpointContents, CheckpointState,
    save_checkpoint,
};
use crate::clip::clip_global_norm;
use crate::config::TrainingConfig;
use crate::data::Share;
use crate::error::Result;
use crate::groups::learning_rates_with;
use crate::parallel::{DataParallel, TrainingDevice};
use crate::schedule::WarmupCosine;
use crate::start::Start;
use crate::step::{StepLoss, StepValues, TrainItem, Trainee};
use crate::trainer::{Task, TaskData};

/// AdamW's first-moment decay.
pub const ADAM_BETA_1: f32 = 0.9;
/// AdamW's second-moment decay.
pub const ADAM_BETA_2: f32 = 0.999;
/// AdamW's epsilon (PyTorch's default).
pub const ADAM_EPSILON: f32 = 1e-8;

/// What one step did: its losses and statistics.
#[derive(Clone, Debug)]
pub struct StepReport {
    /// Steps done after this one (the step's 1-based number).
    pub done: usize,
    /// The loss terms of the whole batch, `total` last.
    pub values: StepValues,
    /// The backbone's learning rate of the step.
    pub lr_backbone: f64,
    /// The heads' learning rate of the step.
    pub lr_heads: f64,
    /// The global gradient norm before clipping.
    pub grad_norm: f64,
    /// Why the step was skipped (its loss or gradient not finite); `None` when the optimizer
    /// stepped.
    pub skipped: Option<Skipped>,
}

/// A step skipped by the non-finite guard.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Skipped {
    /// `"non-finite loss"` or `"non-finite gradient"`.
    pub reason: &'static str,
    /// Non-finite steps in a row, this one included.
    pub in_row: usize,
    /// Whether `in_row` reached `train.max_non_finite_steps`: the run stops.
    pub fatal: bool,
}

/// The non-finite guard's counters (kept in checkpoints, so a resumed run counts on).
#[derive(Clone, Copy, Debug)]
struct NonFiniteGuard {
    in_row: usize,
    skipped: usize,
    max_in_row: usize,
}

impl NonFiniteGuard {
    /// Counts a step of `loss` and `grad_norm`: `None` when both are finite (the counter of
    /// steps in a row is reset), else why the step is skipped.
    fn check(&mut self, loss: f64, grad_norm: f64) -> Option<Skipped> {
        let reason = if !loss.is_finite() {
            "non-finite loss"
        } else if !grad_norm.is_finite() {
            "non-finite gradient"
        } else {
            self.in_row = 0;
            return None;
        };
        self.in_row += 1;
        self.skipped += 1;
        Some(Skipped {
            reason,
            in_row: self.in_row,
            fatal: self.in_row >= self.max_in_row,
        })
    }
}

/// The optimisation step of a run: the model, its optimizer and schedules, the devices with
/// their objectives, and the non-finite guard.
pub struct TrainingStep<'a> {
    /// The model; taken out only while the optimizer steps it (so that its parameters are
    /// updated in place, held once).
    trainee: Option<Trainee>,
    optimizer: ModuleOptimizer,
    scheduler: ModuleLrScheduler,
    backbone: WarmupCosine,
    heads: WarmupCosine,
    parallel: DataParallel,
    losses: Vec<Arc<dyn StepLoss>>,
    task: &'a dyn Task,
    grad_clip_norm: f64,
    guard: NonFiniteGuard,
    new_blocks: Vec<usize>,
    /// What a served device's share is asked for with (its items left empty).
    shard: ShardRequest,
}

impl<'a> TrainingStep<'a> {
    /// The step of `task` with `config`, from `start` (with the optimizer and scheduler state
    /// of `resumed`, when resuming), on `devices` (the first is the main device, where `start`'s
    /// model is); each device's objective is built here.
    ///
    /// # Errors
    /// Unreadable optimizer or scheduler state; an objective that cannot be built.
    pub fn new(
        config: &TrainingConfig,
        start: Start,
        resumed: Option<&Checkpoint>,
        task: &'a dyn Task,
        data: &TaskData,
        devices: Vec<TrainingDevice>,
    ) -> Result<Self> {
        let train = &config.train;
        let total = train.steps;
        let mut optimizer = AdamWConfig::new()
            .with_beta_1(ADAM_BETA_1)
            .with_beta_2(ADAM_BETA_2)
            .with_epsilon(ADAM_EPSILON)
            .with_weight_decay(train.weight_decay as f32)
            .init();
        let backbone =
            WarmupCosine::new(train.lr_backbone, train.min_lr, train.warmup_steps, total);
        let heads = WarmupCosine::new(train.lr_heads, train.min_lr, train.warmup_steps, total);
        let mut scheduler = learning_rates_with(
            backbone,
            heads,
            &start.new_blocks,
            config.model.stage_one_blocks,
        );
        if let Some(checkpoint) = resumed {
            optimizer = checkpoint.load_optimizer(optimizer)?;
            scheduler = checkpoint.load_scheduler(scheduler)?;
        }
        let losses = devices
            .iter()
            .map(|d| task.step_loss(config, data, &d.device))
            .collect::<Result<Vec<_>>>()?;
        Ok(Self {
            trainee: Some(Trainee {
                prism: start.model,
                background: data.background,
            }),
            optimizer,
            scheduler,
            backbone,
            heads,
            parallel: DataParallel::new(devices),
            losses,
            task,
            grad_clip_norm: train.grad_clip_norm,
            guard: NonFiniteGuard {
                in_row: resumed.map_or(0, |c| c.state.non_finite_in_row),
                skipped: resumed.map_or(0, |c| c.state.skipped_steps),
                max_in_row: train.max_non_finite_steps,
            },
            new_blocks: start.new_blocks,
            shard: ShardRequest {
                targets: train.targets_per_sample,
                resolution: config.model.resolution as u32,
                seed: train.seed,
                items: Vec::new(),
            },
        })
    }

    /// The model being trained (on the main device, with autodiff).
    pub fn model(&self) -> &Prism {
        &self.trainee().prism
    }

    fn trainee(&self) -> &Trainee {
        self.trainee
            .as_ref()
            .expect("the model is back after every step")
    }

    /// The main training device (where the model and the optimizer live).
    pub fn main_device(&self) -> &Device {
        self.parallel.main_device()
    }

    /// Steps skipped by the non-finite guard over the whole run.
    pub fn skipped_steps(&self) -> usize {
        self.guard.skipped
    }

    /// The task's preparation of the model for step `step` (0-based), e.g. the distillation
    /// schedule's attention kinds; what it reports.
    pub fn prepare(&mut self, step: usize) -> Option<Value> {
        let trainee = self
            .trainee
            .as_mut()
            .expect("the model is back after every step");
        self.task.before_step(&mut trainee.prism, step)
    }

    /// Step `step` (0-based) on `shares` (one per device, see [`crate::data::share_ranges`]):
    /// forward and backward on every device, clipping, and the optimizer's step unless the
    /// loss or the gradient is not finite.
    ///
    /// # Errors
    /// A worker failure, or a server that cannot load its share.
    pub fn run(&mut self, step: usize, shares: Vec<Share>) -> Result<StepReport> {
        let lr = self.scheduler.step();
        let shares = self.items(shares, step)?;
        let (grads, values) = self.parallel.forward_backward(self.trainee(), shares)?;
        let (grads, grad_norm) = clip_global_norm(self.trainee(), grads, self.grad_clip_norm);
        let skipped = self.guard.check(values.total(), grad_norm);
        if skipped.is_none()
            && let Some(trainee) = self.trainee.take()
        {
            self.trainee = Some(self.optimizer.step(lr, trainee, grads));
        }
        Ok(StepReport {
            done: step + 1,
            values,
            lr_backbone: self.backbone.lr_at(step),
            lr_heads: self.heads.lr_at(step),
            grad_norm,
            skipped,
        })
    }

    /// The step's shares as the devices' training items, each batched on its device (by its
    /// server, for a device that loads its own share) and weighted by its fraction of the
    /// pairs.
    fn items(&self, shares: Vec<Share>, step: usize) -> Result<Vec<TrainItem>> {
        let devices = self.parallel.devices();
        let pairs: usize = shares.iter().map(Share::pairs).sum();
        shares
            .into_iter()
            .enumerate()
            .map(|(i, share)| {
                let weight = share.pairs() as f64 / pairs as f64;
                let batch = match share {
                    Share::Loaded(samples) => PrismBatcher.batch_samples(&samples, &devices[i]),
                    Share::Served { items, metas } => {
                        let request = ShardRequest {
                            items,
                            ..self.shard.clone()
                        };
                        let planes = prism_remote::shard::load(&devices[i], &request)
                            .map_err(|why| self.parallel.failure(i, &why))?;
                        PrismBatch::assemble(&metas, planes)
                    }
                };
                Ok(TrainItem {
                    batch,
                    loss: self.losses[i].clone(),
                    weight,
                    step,
                    share: i,
                })
            })
            .collect()
    }

    /// Saves the checkpoint of `done` steps of the run `config` on `backend` into `run`,
    /// keeping the newest `train.keep_checkpoints`; returns its folder.
    ///
    /// # Errors
    /// I/O or serialisation errors, naming the file.
    pub fn save_checkpoint(
        &self,
        run: &Path,
        config: &TrainingConfig,
        backend: BackendKind,
        done: usize,
    ) -> Result<PathBuf> {
        let state = CheckpointState {
            format: CHECKPOINT_FORMAT.into(),
            version: CHECKPOINT_VERSION,
            task: self.task.name().into(),
            step: done,
            total_steps: config.train.steps,
            seed: config.train.seed,
            non_finite_in_row: self.guard.in_row,
            skipped_steps: self.guard.skipped,
            devices: self.parallel.devices().len(),
            backend: backend.to_string(),
            new_blocks: self.new_blocks.clone(),
        };
        let contents = CheckpointContents {
            state: &state,
            config,
            model: self.model(),
            optimizer: &self.optimizer,
            scheduler: &self.scheduler,
        };
        save_checkpoint(run, &contents, config.train.keep_checkpoints)
    }
}
