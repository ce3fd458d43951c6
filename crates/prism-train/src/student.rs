//! Student distillation (`prism distill-student`, paper Sec. 3.4): a copy of the teacher whose
//! blocks switch to linear attention on the `[distill]` schedule, trained with the teacher's
//! objective plus `L_distill` against the frozen teacher's hidden states.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use burn::module::Module;
use burn::tensor::{Device, Tensor};
use prism_data::PrismBatch;
use prism_losses::LossTerms;
use prism_model::{AttentionKind, Prism, Views};
use serde_json::{Value, json};

use crate::checkpoint::{Checkpoint, check_architecture};
use crate::config::TrainingConfig;
use crate::error::{Result, TrainError};
use crate::step::StepLoss;
use crate::teacher::TeacherLoss;
use crate::trainer::{RunOptions, RunSummary, Task, TaskData, train};

/// The config a distillation run trains with: `config` with `[train]`'s run length, batch and
/// learning rates taken from `[distill]` (`steps`, `batch_size`, and `lr` as a fixed rate for
/// backbone and heads alike, without warm-up or annealing, as in the paper's supplement).
/// Everything else of `[train]` (weight decay, clipping, checkpoints, validation, seed) is kept.
pub fn student_config(config: &TrainingConfig) -> TrainingConfig {
    let mut student = config.clone();
    let distill = &config.distill;
    student.train.steps = distill.steps;
    student.train.batch_size = distill.batch_size;
    student.train.lr_backbone = distill.lr;
    student.train.lr_heads = distill.lr;
    student.train.min_lr = distill.lr;
    student.train.warmup_steps = 0;
    student
}

/// The distillation job: trains the student on the teacher's objective plus `L_distill`, and
/// sets its blocks' attention kinds before every step from [`prism_model::DistillConfig::kinds_at`].
///
/// The training loop starts the student from the teacher's weights (pass the teacher as
/// [`crate::RunOptions::init`] on a fresh run); the frozen teacher is loaded again by
/// [`StudentTask::step_loss`] on each training device, in inference mode, outside the
/// optimizer's reach.
#[derive(Clone, Debug)]
pub struct StudentTask {
    /// The teacher: a checkpoint folder, or a run folder (its latest checkpoint).
    pub teacher: PathBuf,
    /// The `[distill]` section (mode, schedule, layers) with the model's block count.
    pub config: TrainingConfig,
    /// LPIPS weight file (default: the project's search order).
    pub lpips_weights: Option<PathBuf>,
}

impl StudentTask {
    /// The job for `config` distilling `teacher`.
    ///
    /// # Errors
    /// An invalid `[distill]` section, or a teacher checkpoint that cannot be read or whose
    /// architecture differs from `config`'s model.
    pub fn new(
        config: &TrainingConfig,
        teacher: &Path,
        lpips_weights: Option<PathBuf>,
    ) -> Result<Self> {
        config
            .distill
            .validate(config.model.num_blocks())
            .map_err(|e| TrainError::InvalidConfig {
                path: PathBuf::from("config"),
                field: "distill".into(),
                message: e.to_string(),
            })?;
        let checkpoint = Checkpoint::read(teacher)?;
        check_architecture(&checkpoint, &config.model)?;
        Ok(Self {
            teacher: checkpoint.dir.clone(),
            config: config.clone(),
            lpips_weights,
        })
    }

    /// The attention kinds of the student at `step` (see [`prism_model::DistillConfig::kinds_at`]).
    pub fn kinds_at(&self, step: usize) -> Vec<AttentionKind> {
        self.config
            .distill
            .kinds_at(step, self.config.model.num_blocks())
    }
}

/// The student job (`prism distill-student`, and the quick start's student): trains the student
/// of `config` (through [`student_config`]) distilled from `teacher` (a run or checkpoint
/// folder); a fresh run starts from the teacher's weights, `options.resume` continues the run.
///
/// # Errors
/// As [`StudentTask::new`] and [`train`].
pub fn distill_student(
    config: &TrainingConfig,
    teacher: &Path,
    options: &RunOptions,
) -> Result<RunSummary> {
    let config = student_config(config);
    let task = StudentTask::new(&config, teacher, options.lpips_weights.clone())?;
    let options = RunOptions {
        init: (!options.resume).then(|| task.teacher.clone()),
        ..options.clone()
    };
    train(&config, &task, &options)
}

/// Letters of a list of kinds, `"LLFLLF"`.
pub fn kinds_letters(kinds: &[AttentionKind]) -> String {
    kinds.iter().map(|k| k.letter()).collect()
}

impl Task for StudentTask {
    fn name(&self) -> &str {
        "student"
    }

    fn step_loss(
        &self,
        config: &TrainingConfig,
        data: &TaskData,
        device: &Device,
    ) -> Result<Arc<dyn StepLoss>> {
        let objective = TeacherLoss::new(
            config,
            data.background,
            self.lpips_weights.as_deref(),
            device,
        )?;
        // Without L_distill (the "no distillation" ablation) the teacher is neither loaded nor
        // run.
        let teacher = if config.losses.distill == 0.0 {
            None
        } else {
            let layers = config
                .distill
                .layer_indices(config.model.num_blocks())
                .map_err(|e| TrainError::InvalidConfig {
                    path: PathBuf::from("config"),
                    field: "distill.layers".into(),
                    message: e.to_string(),
                })?;
            let model = Checkpoint::read(&self.teacher)?
                .load_model(&device.clone().inner())?
                .valid()
                .with_block_precision(data.precision);
            Some(FrozenTeacher { model, layers })
        };
        Ok(Arc::new(StudentLoss {
            objective,
            teacher,
            background: data.background,
        }))
    }

    /// Sets the schedule's kinds for `step`; reports the blocks that switched since `step - 1`
    /// (and the whole list at the first step of a run or a resumption).
    fn before_step(&self, model: &mut Prism, step: usize) -> Option<Value> {
        let kinds = self.kinds_at(step);
        let current = model.attention_kinds();
        if current == kinds {
            return None;
        }
        let switched: Vec<usize> = (0..kinds.len())
            .filter(|&i| kinds[i] != current[i])
            .collect();
        model.set_attention_kinds(&kinds);
        let linear = kinds
            .iter()
            .filter(|&&k| k == AttentionKind::Linear)
            .count();
        Some(json!({
            "attention": kinds_letters(&kinds),
            "switched_blocks": switched,
            "linear_blocks": linear,
        }))
    }
}

/// The student's objective on one device (paper Sec. 3.4): the teacher's objective
/// ([`TeacherLoss`]: NVS, 3DGS, point and SMPL-X terms) plus
/// `l_distill L_distill = l_distill / |S| sum_{l in S} ||h_l^student - h_l^teacher||^2` over the
/// hidden states of the configured layers `S`, the teacher's being constants.
pub struct StudentLoss {
    objective: TeacherLoss,
    /// The frozen teacher and its distillation layers; `None` when `L_distill` is off.
    teacher: Option<FrozenTeacher>,
    background: [f32; 3],
}

/// The frozen teacher of [`StudentLoss`].
struct FrozenTeacher {
    /// An inference model on this device's inner (non-autodiff) backend.
    model: Prism,
    /// The distillation layers `S`.
    layers: Vec<usize>,
}

impl FrozenTeacher {
    /// The hidden states of the distillation layers on `batch`, without autodiff (constants
    /// for the student's graph).
    fn hidden(&self, batch: &PrismBatch, background: [f32; 3]) -> Vec<Tensor<3>> {
        let inner = inner_batch(batch);
        let views = Views::of_batch(&inner, background);
        self.model
            .hidden_states(
                inner.source_image,
                inner.source_rays,
                inner.target_rays,
                &views,
                &self.layers,
            )
            .into_iter()
            .map(Tensor::from_inner)
            .collect()
    }
}

impl StepLoss for StudentLoss {
    fn loss(&self, model: &Prism, batch: &PrismBatch, _step: usize) -> LossTerms {
        let layers = self.teacher.as_ref().map_or(&[][..], |t| &t.layers);
        let out = self.objective.forward(model, batch, layers);
        let inputs = self.objective.inputs(model, batch, &out);
        match &self.teacher {
            None => self.objective.terms(inputs),
            Some(teacher) => {
                let hidden = teacher.hidden(batch, self.background);
                self.objective
                    .terms(inputs.with_distill(out.hidden.clone(), hidden))
            }
        }
    }
}

/// `batch` with its tensors off autodiff (on the device's inner backend).
fn inner_batch(batch: &PrismBatch) -> PrismBatch {
    PrismBatch {
        source_image: batch.source_image.clone().inner(),
        source_rays: batch.source_rays.clone().inner(),
        source_mask: batch.source_mask.clone().inner(),
        source_points: batch.source_points.clone().inner(),
        target_rays: batch.target_rays.clone().inner(),
        target_image: batch.target_image.clone().inner(),
        target_mask: batch.target_mask.clone().inner(),
        ..batch.clone()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::configs_dir;
    use prism_core::BackendKind;

    fn tiny() -> TrainingConfig {
        TrainingConfig::load(configs_dir().join("tiny.toml")).unwrap()
    }

    #[test]
    fn student_config_trains_at_the_fixed_distillation_rate() {
        let config = tiny();
        let student = student_config(&config);
        assert_eq!(student.train.steps, config.distill.steps);
        assert_eq!(student.train.batch_size, config.distill.batch_size);
        let rate = crate::schedule::WarmupCosine::new(
            student.train.lr_backbone,
            student.train.min_lr,
            student.train.warmup_steps,
            student.train.steps,
        );
        for step in [0, 1, student.train.steps / 2, student.train.steps - 1] {
            assert!(
                (rate.lr_at(step) - config.distill.lr).abs() < 1e-15,
                "step {step}"
            );
        }
        assert_eq!(student.train.lr_heads, config.distill.lr);
    }

    #[test]
    fn the_frozen_teacher_is_loaded_only_when_l_distill_is_weighted() {
        let mut config = tiny();
        config.losses.lpips = 0.0;
        let device = BackendKind::Ndarray.device().unwrap().autodiff();
        let data = TaskData {
            background: [1.0; 3],
            precision: prism_model::Precision::F32,
        };
        let missing = std::env::temp_dir().join("prism-no-such-teacher");
        let loss = |config: &TrainingConfig| {
            let task = StudentTask {
                teacher: missing.clone(),
                config: config.clone(),
                lpips_weights: None,
            };
            task.step_loss(config, &data, &device).map(|_| ())
        };
        let err = loss(&config).unwrap_err().to_string();
        assert!(err.contains("prism-no-such-teacher"), "{err}");
        config.losses.distill = 0.0;
        loss(&config).unwrap();
    }

    #[test]
    fn before_step_switches_on_the_schedule_and_reports_the_switched_blocks() {
        let config = tiny();
        let task = StudentTask {
            teacher: PathBuf::new(),
            config: config.clone(),
            lpips_weights: None,
        };
        let mut model = config.model.init(&BackendKind::Ndarray.device().unwrap());
        assert_eq!(task.before_step(&mut model, 0), None);
        assert_eq!(task.before_step(&mut model, 3), None);
        let event = task.before_step(&mut model, 4).unwrap();
        assert_eq!(event["attention"], "LFFLFF");
        assert_eq!(event["switched_blocks"], json!([0, 3]));
        assert_eq!(event["linear_blocks"], 2);
        assert_eq!(kinds_letters(&model.attention_kinds()), "LFFLFF");
        assert_eq!(task.before_step(&mut model, 5), None);
        // A resumed run at step 20 jumps straight to the schedule's kinds there.
        let mut fresh = config.model.init(&BackendKind::Ndarray.device().unwrap());
        let event = task.before_step(&mut fresh, 20).unwrap();
        assert_eq!(event["switched_blocks"], json!([0, 1, 3, 4]));
        assert_eq!(kinds_letters(&fresh.attention_kinds()), "LLFLLF");
    }
}
