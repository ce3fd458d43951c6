//! Training for prism: the loop shared by teacher pretraining and distillation, and the
//! teacher's job (`prism train-teacher`).
//!
//! - Config: [`TrainingConfig`] composes the `[model]`, `[distill]`, `[losses]`, `[train]`
//!   ([`TrainConfig`]) and `[data]` (`prism_data::SynthOptions`) sections of a TOML file.
//! - Loop: [`train`] prepares the run ([`prepare_run_folder`], [`initial_model`]), then runs a
//!   [`TrainingStep`] per step (its [`Task`]'s per-device [`StepLoss`], AdamW, the
//!   [`WarmupCosine`] schedules of the backbone and the [`HEAD_MODULES`], global-norm clipping,
//!   a non-finite guard, data parallelism through Burn ([`DataParallel`]); the blocks in f16
//!   or bf16 with f32 master weights when [`RunOptions::precision`] says so, the loss scaled
//!   for f16 by a [`LossScaler`]) followed by its
//!   [`Cadence`]: `metrics.jsonl` ([`MetricsLog`]), validation ([`Validator`]), training
//!   curves and atomic checkpoints ([`save_checkpoint`], [`Checkpoint`], [`load_model`]).
//! - Data: [`DataOrder`] makes each step's samples a pure function of (seed, step), so a
//!   resumed run continues exactly. The trainer receives a dataset folder; the commands choose
//!   it (`--data`, or the config's synthetic dataset from `prism_synth`'s cache).
//! - Teacher: [`TeacherTask`] / [`TeacherLoss`].
//! - Student: [`StudentTask`] / [`StudentLoss`] with [`student_config`] (distillation).
//! - Evaluation ([`evaluate()`]: the paper's protocol, per-angle breakdown, FPS; the report in
//!   [`report`]) and inference from a photo ([`infer()`]), both through [`predict`]; images in
//!   [`images`]. Validation and evaluation score views with `prism_losses::score_images` and
//!   average them per subject, then over the subjects, with a [`Tally`]; beside the model,
//!   the copy of the source and the true-depth warp ([`warp`]) are scored on the same views.
//! - Ablations ([`ablate()`]): the paper's ablation rows ([`AblationRow`]) trained at one budget
//!   and scored on the same views, as a table and a bar chart.
//! - Budget curve ([`budget_curve`]): the quick start at several multiples of its steps.
//! - Training curves: [`plot_run`] draws a run's `metrics.jsonl` into its [`PLOT_FILE`].

pub mod ablate;
pub mod adamw;
pub mod baselines;
pub mod budget;
pub mod cadence;
pub mod checkpoint;
mod chunk_scores;
pub mod clip;
pub mod config;
pub mod convert;
pub mod data;
pub mod error;
pub mod evaluate;
pub mod groups;
pub mod images;
pub mod infer;
pub mod log;
pub mod loss_scale;
pub mod oracle;
pub mod parallel;
pub mod plot;
pub mod predict;
pub mod provenance;
pub mod quickstart;
pub mod report;
pub mod schedule;
pub mod served;
pub mod start;
pub mod step;
pub mod student;
pub mod tally;
pub mod teacher;
pub mod trainer;
pub mod training_step;
pub mod validate;
pub mod viewer;
pub mod warp;

pub use ablate::{
    Ablation, AblationFiles, AblationPlan, AblationRow, RowResult, ablate, ablation_markdown,
};
pub use budget::{BudgetPoint, budget_curve, budget_markdown};
pub use cadence::{Cadence, SAMPLES_DIR};
pub use checkpoint::{
    CHECKPOINTS_DIR, Checkpoint, CheckpointContents, CheckpointState, checkpoint_dir,
    latest_checkpoint, list_checkpoints, load_inference_model, load_model, save_checkpoint,
    save_model_checkpoint, write_checkpoint_files,
};
pub use clip::{clip_global_norm, global_norm, parameter_values};
pub use config::{TrainConfig, TrainingConfig, config_name, configs_dir};
pub use convert::{LVSM_TASK, convert_lvsm};
pub use data::{DataOrder, Prefetcher, Share, share_ranges};
pub use error::TrainError;
pub use evaluate::{EvaluateOptions, Evaluation, SubjectGrid, evaluate, evaluate_checkpoint};
pub use groups::{
    HEAD_MODULES, heads_group, heads_group_with, heads_pattern, heads_pattern_with, is_head,
    learning_rates, learning_rates_with,
};
pub use infer::{
    Framing, InferOptions, InferredPhoto, Sweep, frame_photo, frontal_camera, infer, read_photo,
    sweep_views,
};
pub use log::{METRICS_FILE, MetricsLog, read_metrics};
pub use loss_scale::{LossScaleConfig, LossScaleState, LossScaler};
pub use parallel::{DataParallel, TrainingDevice, cpu_shares, fingerprint, training_devices};
pub use plot::{PLOT_FILE, PLOT_SIZE, TrainingCurves, plot_metrics, plot_run};
pub use predict::{Pairs, forward_pairs, inference_model, synthesise};
pub use provenance::Provenance;
pub use quickstart::{
    ModelPhases, PHASES_FILE, PipelineOptions, QuickstartModel, QuickstartPlan, QuickstartReport,
    STUDENT_RUN, StudentJob, TEACHER_RUN, compress_schedule, phase_table, phases_json, quickstart,
    quickstart_table, remove_run,
};
pub use report::{EvaluationFiles, evaluation_json, markdown_report, write_evaluation};
pub use schedule::WarmupCosine;
pub use start::{
    RUN_CONFIG_FILE, Start, initial_model, loss_scaler, prepare_run_folder, run_precision,
};
pub use step::{Prediction, StepLoss, StepValues, TRAINEE_FIELD, TrainItem, Trainee};
pub use student::{StudentLoss, StudentTask, distill_student, kinds_letters, student_config};
pub use tally::{AngleBin, MeanScores, MethodScores, PerAngle, Tally};
pub use teacher::{TeacherLoss, TeacherTask};
pub use trainer::{RunOptions, RunSummary, Task, TaskData, train};
pub use training_step::{
    GRADIENT_OVERFLOW, NON_FINITE_GRADIENT, NON_FINITE_LOSS, Skipped, StepReport, TrainingStep,
};
pub use validate::{Validator, validation_views};
