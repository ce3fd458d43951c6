//! One training step on one device: the model wrapped as a Burn [`TrainStep`], and the loss it
//! minimises as a pluggable [`StepLoss`] (the teacher's objective here; distillation's objective
//! with a frozen teacher in `prism distill-student`).

use std::sync::Arc;

use burn::module::Module;
use burn::tensor::{ExecutionError, Tensor};
use burn_train::metric::ItemLazy;
use burn_train::{InferenceStep, TrainOutput, TrainStep};
use prism_data::PrismBatch;
use prism_losses::LossTerms;
use prism_model::Prism;

/// The field name of the model inside [`Trainee`]: the first component of every parameter path
/// the optimizer sees (see [`crate::heads_pattern`]).
pub const TRAINEE_FIELD: &str = "prism";

/// What the optimizer trains: the [`Prism`] model, as a Burn module that implements
/// [`TrainStep`] so that Burn's multi-device step can run it on every device.
#[derive(Module, Debug)]
pub struct Trainee {
    /// The model being trained.
    pub prism: Prism,
    /// The dataset's background colour (what the 3DGS head composites over).
    #[module(skip)]
    pub background: [f32; 3],
}

/// The objective of one step on one device's share of a batch.
///
/// Implementations hold what the loss needs on their device (the LPIPS network, a frozen
/// teacher, ...): the training loop asks its [`crate::Task`] for one per device.
pub trait StepLoss: Send + Sync {
    /// The loss terms of `model` on `batch` at training step `step` (0-based). `total` is what
    /// is minimised; the terms are logged by name.
    fn loss(&self, model: &Prism, batch: &PrismBatch, step: usize) -> LossTerms;
}

/// The input of one [`Trainee`] step: one device's share of the step's batch.
#[derive(Clone)]
pub struct TrainItem {
    /// The pairs of this device, on this device.
    pub batch: PrismBatch,
    /// The objective, built for this device.
    pub loss: Arc<dyn StepLoss>,
    /// This share's fraction of the step's pairs: the loss is scaled by it before the backward
    /// pass, so that the gradients summed over the devices are the gradient of the mean loss of
    /// the whole batch.
    pub weight: f64,
    /// The factor of the loss in the backward pass (dynamic loss scaling, 1 without): the
    /// gradients come back multiplied by it, and the training step divides them by it.
    pub loss_scale: f64,
    /// The training step (0-based).
    pub step: usize,
    /// The share's index in the step (its device's index): shares are summed in this order, so
    /// the result does not depend on which worker finishes first.
    pub share: usize,
}

/// What one [`Trainee`] step reports: its terms read back as numbers, scaled by the share's
/// weight (so that the shares of a step add up to the batch's values).
#[derive(Clone, Debug, Default)]
pub struct StepValues {
    /// Weighted term values by name, in the objective's order; `total` last.
    pub terms: Vec<(&'static str, f64)>,
    /// The share these values come from ([`TrainItem::share`]).
    pub share: usize,
}

impl StepValues {
    /// The sum of several shares (terms matched by name, in the first share's order).
    pub fn sum(parts: &[StepValues]) -> StepValues {
        let mut terms: Vec<(&'static str, f64)> = Vec::new();
        for part in parts {
            for &(name, value) in &part.terms {
                match terms.iter_mut().find(|(n, _)| *n == name) {
                    Some((_, acc)) => *acc += value,
                    None => terms.push((name, value)),
                }
            }
        }
        StepValues { terms, share: 0 }
    }

    /// The value of a term (`"total"` for the loss).
    pub fn get(&self, name: &str) -> Option<f64> {
        self.terms.iter().find(|(n, _)| *n == name).map(|&(_, v)| v)
    }

    /// The total loss (NaN when missing).
    pub fn total(&self) -> f64 {
        self.get("total").unwrap_or(f64::NAN)
    }
}

impl ItemLazy for StepValues {
    fn sync(self) -> Result<Self, ExecutionError> {
        Ok(self)
    }
}

impl TrainStep for Trainee {
    type Input = TrainItem;
    type Output = StepValues;

    /// Forward, loss and backward on one device's share:
    /// `grad((weight * loss_scale * L).backward())` (the values reported unscaled).
    fn step(&self, item: TrainItem) -> TrainOutput<StepValues> {
        let terms = item.loss.loss(&self.prism, &item.batch, item.step);
        let values = StepValues {
            terms: terms
                .values()
                .into_iter()
                .map(|(name, v)| (name, v * item.weight))
                .collect(),
            share: item.share,
        };
        let total = terms.total.mul_scalar(item.weight);
        // A separate product by the scale (a power of two) keeps the scaled gradients exactly
        // `loss_scale` times the unscaled ones.
        let total = if item.loss_scale == 1.0 {
            total
        } else {
            total.mul_scalar(item.loss_scale)
        };
        let grads = total.backward();
        TrainOutput::new(self, grads, values)
    }
}

/// The model's prediction of a batch's target views, `[P, 3, H, W]`.
#[derive(Clone, Debug)]
pub struct Prediction {
    /// The synthesised target views.
    pub image: Tensor<4>,
}

impl ItemLazy for Prediction {
    fn sync(self) -> Result<Self, ExecutionError> {
        Ok(self)
    }
}

impl InferenceStep for Trainee {
    type Input = PrismBatch;
    type Output = Prediction;

    /// The NVS decoder's images of the batch's target views (the 3DGS head, a training signal,
    /// is skipped unless the decoder corrects its render).
    fn step(&self, batch: PrismBatch) -> Prediction {
        let model = self.prism.clone().without_training_heads();
        let out = model.forward_batch(&batch, self.background, &[]);
        Prediction { image: out.image }
    }
}
