//! One optimisation step of a run, the same for every job: the step's samples split into one
//! share per device, the data-parallel forward and backward of the job's objective (its loss
//! scaled when the blocks compute in f16, see [`crate::loss_scale`]), global-norm clipping,
//! the non-finite guard, and AdamW with the warm-up + cosine schedules of the backbone and the
//! heads. What a job adds is its [`Task`]: the objective of each device and
//! what it does to the model before a step.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use burn::optim::ModuleOptimizer;
use burn::optim::lr_scheduler::module_lr_scheduler::ModuleLrScheduler;
use burn::tensor::Device;
use prism_core::BackendKind;
use prism_data::{PrismBatch, PrismBatcher};
use prism_model::{Precision, Prism};
use prism_remote::ShardRequest;
use serde_json::Value;

use crate::adamw::FusedAdamW;
use crate::checkpoint::{
    CHECKPOINT_FORMAT, CHECKPOINT_VERSION, Checkpoint, CheckpointContents, CheckpointState,
    save_checkpoint,
};
use crate::clip::{clip_global_norm, scale_gradients};
use crate::config::TrainingConfig;
use crate::data::Share;
use crate::error::Result;
use crate::groups::learning_rates_with;
use crate::loss_scale::{LossScaler, ScaleChange};
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
    /// The global gradient norm before clipping (of the unscaled gradient).
    pub grad_norm: f64,
    /// The factor of the step's loss in its backward pass (dynamic loss scaling); `None` when
    /// the run does not scale its loss.
    pub loss_scale: Option<f64>,
    /// Why the step was skipped (its loss or gradient not finite); `None` when the optimizer
    /// stepped.
    pub skipped: Option<Skipped>,
}

/// A step skipped by the non-finite guard.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Skipped {
    /// [`NON_FINITE_LOSS`], [`NON_FINITE_GRADIENT`] or [`GRADIENT_OVERFLOW`].
    pub reason: &'static str,
    /// Non-finite steps in a row, this one included.
    pub in_row: usize,
    /// Whether `in_row` reached `train.max_non_finite_steps` on a step the loss scale could
    /// not absorb: the run stops.
    pub fatal: bool,
}

/// [`Skipped::reason`] of a step whose loss is not finite.
pub const NON_FINITE_LOSS: &str = "non-finite loss";
/// [`Skipped::reason`] of a step whose gradient is not finite.
pub const NON_FINITE_GRADIENT: &str = "non-finite gradient";
/// [`Skipped::reason`] of a step whose scaled gradient overflowed (in f16): the loss scale was
/// halved ([`crate::loss_scale`]), which is how dynamic scaling finds its scale, so such steps
/// do not stop the run.
pub const GRADIENT_OVERFLOW: &str = "gradient overflow, loss scale halved";

/// The non-finite guard's counters (kept in checkpoints, so a resumed run counts on).
#[derive(Clone, Copy, Debug)]
struct NonFiniteGuard {
    in_row: usize,
    skipped: usize,
    max_in_row: usize,
}

impl NonFiniteGuard {
    /// Counts a step of `loss` and `grad_norm`: `None` when both are finite (the counter of
    /// steps in a row is reset), else why the step is skipped. `absorbed`: the loss scale was
    /// halved for this step's non-finite gradient (never fatal).
    fn check(&mut self, loss: f64, grad_norm: f64, absorbed: bool) -> Option<Skipped> {
        let reason = if !loss.is_finite() {
            NON_FINITE_LOSS
        } else if !grad_norm.is_finite() {
            if absorbed {
                GRADIENT_OVERFLOW
            } else {
                NON_FINITE_GRADIENT
            }
        } else {
            self.in_row = 0;
            return None;
        };
        self.in_row += 1;
        self.skipped += 1;
        Some(Skipped {
            reason,
            in_row: self.in_row,
            fatal: !absorbed && self.in_row >= self.max_in_row,
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
    /// The precision the blocks compute in (recorded in checkpoints).
    precision: Precision,
    /// Dynamic loss scaling; `None`: the loss is not scaled.
    scaler: Option<LossScaler>,
    /// What a served device's share is asked for with (its items left empty).
    shard: ShardRequest,
}

impl<'a> TrainingStep<'a> {
    /// The step of `task` with `config`, from `start` (its model, precision and loss scaling;
    /// with the optimizer and scheduler state of `resumed`, when resuming), on `devices` (the
    /// first is the main device, where `start`'s model is), each step's batch cut into
    /// `shares` shares when there is one device ([`DataParallel::new`]); each device's
    /// objective is built here.
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
        shares: usize,
    ) -> Result<Self> {
        let train = &config.train;
        let total = train.steps;
        let mut optimizer = FusedAdamW::module_optimizer(
            ADAM_BETA_1,
            ADAM_BETA_2,
            ADAM_EPSILON,
            train.weight_decay as f32,
        );
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
            parallel: DataParallel::new(devices, shares),
            losses,
            task,
            grad_clip_norm: train.grad_clip_norm,
            guard: NonFiniteGuard {
                in_row: resumed.map_or(0, |c| c.state.non_finite_in_row),
                skipped: resumed.map_or(0, |c| c.state.skipped_steps),
                max_in_row: train.max_non_finite_steps,
            },
            new_blocks: start.new_blocks,
            precision: start.precision,
            scaler: start.loss_scale,
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
    /// forward and backward on every device (of the loss times the loss scale, the gradients
    /// divided by it after), clipping, and the optimizer's step unless the loss or the
    /// gradient is not finite; then the loss scale's update.
    ///
    /// On a CPU backend the step runs with rayon's workers kept awake between its kernels
    /// ([`prism_kernels::warm`]).
    ///
    /// # Errors
    /// A worker failure, or a server that cannot load its share.
    pub fn run(&mut self, step: usize, shares: Vec<Share>) -> Result<StepReport> {
        let device = self.parallel.main_device().clone();
        prism_kernels::warm(&device, || self.step(step, shares))
    }

    /// [`TrainingStep::run`]'s work.
    fn step(&mut self, step: usize, shares: Vec<Share>) -> Result<StepReport> {
        let lr = self.scheduler.step();
        let loss_scale = self.scaler.as_ref().map(LossScaler::scale);
        let shares = self.items(shares, step, loss_scale.unwrap_or(1.0))?;
        let (grads, values) = self.parallel.forward_backward(self.trainee(), shares)?;
        // The scale is a power of two: dividing by it is exact.
        let grads = match loss_scale {
            Some(scale) if scale != 1.0 => scale_gradients(self.trainee(), grads, 1.0 / scale),
            _ => grads,
        };
        let (grads, grad_norm) = clip_global_norm(self.trainee(), grads, self.grad_clip_norm);
        // A non-finite loss is the forward pass's, which no scale of the backward pass helps.
        let change = self
            .scaler
            .as_mut()
            .filter(|_| values.total().is_finite())
            .map(|s| s.update(grad_norm.is_finite()));
        let absorbed = change == Some(ScaleChange::Halved);
        let skipped = self.guard.check(values.total(), grad_norm, absorbed);
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
            loss_scale,
            skipped,
        })
    }

    /// The step's shares as the devices' training items, each batched on its device (by its
    /// server, for a device that loads its own share) and weighted by its fraction of the
    /// pairs, their losses to be scaled by `loss_scale` in the backward pass.
    fn items(&self, shares: Vec<Share>, step: usize, loss_scale: f64) -> Result<Vec<TrainItem>> {
        let devices = self.parallel.devices();
        let pairs: usize = shares.iter().map(Share::pairs).sum();
        shares
            .into_iter()
            .enumerate()
            .map(|(i, share)| {
                let weight = share.pairs() as f64 / pairs as f64;
                let device = self.parallel.device_of(i);
                let batch = match share {
                    Share::Loaded(samples) => {
                        PrismBatcher.batch_samples(&samples, &devices[device])
                    }
                    Share::Served { items, metas } => {
                        let request = ShardRequest {
                            items,
                            ..self.shard.clone()
                        };
                        let planes = prism_remote::shard::load(&devices[device], &request)
                            .map_err(|why| self.parallel.failure(device, &why))?;
                        PrismBatch::assemble(&metas, planes)
                    }
                };
                Ok(TrainItem {
                    batch,
                    loss: self.losses[device].clone(),
                    weight,
                    loss_scale,
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
            shares: Some(self.parallel.shares().min(config.train.batch_size)),
            backend: backend.to_string(),
            new_blocks: self.new_blocks.clone(),
            precision: self.precision,
            loss_scale: self.scaler.as_ref().map(LossScaler::state),
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
