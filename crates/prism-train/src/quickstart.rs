//! `prism quickstart`: the whole pipeline on the shipped configs in one command. Synthesises
//! the default dataset, trains the teacher, distils the student from it, evaluates both and
//! tabulates PSNR, SSIM, LPIPS and FPS, beside the scores of their 3DGS heads' renders `I_gs`
//! and of the "copy the source view" baseline. Where each model's training and evaluation spent
//! their time ([`prism_core::phases`]) is in its [`ModelPhases`], tabulated by [`phase_table`].
//!
//! The step counts are scaled down from the configs' so the whole job fits a time budget on a
//! 2-core CPU ([`QuickstartPlan::standard`]: the small config, 4.6 to 5.3 minutes measured on
//! an AMD EPYC Zen 4, more on slower hosts: the README's table; [`QuickstartPlan::fast`]: the
//! tiny config on 30 people, 3.0 to 3.3 minutes measured there); the distillation schedule is
//! compressed to the student's steps ([`compress_schedule`]).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use prism_core::BackendKind;
use prism_core::phases::{Phase, PhaseTimes, phase_totals, timed};
use prism_core::steal::{StealProbe, percent};
use prism_losses::{NO_VALUE, ScoreTable};
use serde_json::{Map, Value, json};

use crate::checkpoint::{Checkpoint, check_resumable, list_checkpoints};
use crate::config::TrainingConfig;
use crate::error::{Result, TrainError};
use crate::evaluate::{EvaluateOptions, Evaluation, evaluate_checkpoint};
use crate::report::EvaluationFiles;
use crate::student::student_config;
use crate::teacher::TeacherTask;
use crate::trainer::{RunOptions, RunSummary, train};

/// The small config (128 px), shipped in the binary so quickstart runs from any folder.
pub const SMALL_CONFIG: &str = include_str!("../../../configs/small.toml");
/// The tiny config (64 px).
pub const TINY_CONFIG: &str = include_str!("../../../configs/tiny.toml");

/// The teacher's run folder inside a quickstart's folder.
pub const TEACHER_RUN: &str = "teacher";
/// The student's run folder inside a quickstart's folder.
pub const STUDENT_RUN: &str = "student";

/// The phase timings' file (the JSON of [`phases_json`]) `prism quickstart` writes into its
/// folder.
pub const PHASES_FILE: &str = "phases.json";

/// People in the `--fast` plan's synthetic dataset.
pub const FAST_SUBJECTS: usize = 30;

/// What a quickstart runs: the config, the step counts and the evaluation's size.
#[derive(Clone, Debug)]
pub struct QuickstartPlan {
    /// Name of the config (`small` or `tiny`), used in run folder names.
    pub name: String,
    /// The config both runs start from.
    pub config: TrainingConfig,
    /// Teacher training steps.
    pub teacher_steps: usize,
    /// Student distillation steps.
    pub student_steps: usize,
    /// Target views per test subject in the evaluations (evenly spread over 1..=100).
    pub eval_views: usize,
}

impl QuickstartPlan {
    /// The default plan: the small config, 300 teacher and 150 student steps (the config's
    /// 600 teacher steps alone take about 6 minutes on the 2-core AMD EPYC Zen 4), the
    /// protocol's 100 views per test subject (the two evaluations take about 40 s there).
    ///
    /// # Errors
    /// Never for the shipped config; a parse error otherwise.
    pub fn standard() -> Result<Self> {
        Ok(Self {
            name: "small".into(),
            config: TrainingConfig::parse(SMALL_CONFIG, Path::new("configs/small.toml"))?,
            teacher_steps: 300,
            student_steps: 150,
            eval_views: 100,
        })
    }

    /// `--fast`: the tiny config on [`FAST_SUBJECTS`] synthetic people (3 held out) instead of
    /// its 6, 960 teacher and 720 student steps, the student distilled at `lr = 3e-4`, 10
    /// views per test subject. On the tiny config's 5 training people the model memorises them
    /// and barely beats copy-source on a new one (BENCHMARKS.md, "The tiny config against
    /// copy-source"). At 480 + 360 steps and the tiny config's distillation `lr = 1e-3` (the
    /// plan until the kernels made it 2.7x faster), the student's LPIPS ended above
    /// copy-source's; at this plan both models score under it at two training seeds
    /// (BENCHMARKS.md, "The `--fast` quick start re-planned").
    ///
    /// # Errors
    /// Never for the shipped config; a parse error otherwise.
    pub fn fast() -> Result<Self> {
        let mut config = TrainingConfig::parse(TINY_CONFIG, Path::new("configs/tiny.toml"))?;
        config.data.subjects = FAST_SUBJECTS;
        config.data.test_fraction = 0.1;
        config.distill.lr = 3e-4;
        Ok(Self {
            name: "tiny".into(),
            config,
            teacher_steps: 960,
            student_steps: 720,
            eval_views: 10,
        })
    }
}

/// The `[distill]` schedule squeezed into `steps` student steps: the first switch to linear
/// attention after `steps / (group_size + 1)` steps, then one more block per group at the same
/// interval, so every block is linear for the last `steps / (group_size + 1)` steps.
pub fn compress_schedule(config: &mut TrainingConfig, steps: usize) {
    let interval = (steps / (config.distill.group_size + 1)).max(1);
    config.distill.start = interval;
    config.distill.interval = interval;
}

/// The student job: distils a student from the teacher run `teacher` with `config`, into
/// `options.out` (`options.steps` set), training with [`student_config`] of `config` as
/// [`crate::distill_student`] does (a finished run is recognised by that config).
/// `prism distill-student`'s library call.
pub type StudentJob<'a> = &'a dyn Fn(&TrainingConfig, &Path, &RunOptions) -> Result<RunSummary>;

/// How a pipeline of runs (the quick start, an ablation) trains and evaluates.
#[derive(Clone, Debug)]
pub struct PipelineOptions {
    /// Folder of the runs and evaluations (one folder per run, each with `evaluation/`).
    pub out: PathBuf,
    /// The dataset trained and evaluated on.
    pub data: PathBuf,
    /// Backend of training and evaluation.
    pub backend: BackendKind,
    /// LPIPS weight file (default: the project's search order).
    pub lpips_weights: Option<PathBuf>,
    /// Progress bars on stderr.
    pub progress: bool,
}

/// The options of the run of `steps` steps with `config` in `dir` that continues what a killed
/// job left there (`config` as the run stores it: for a distillation, [`student_config`] of the
/// job's): `None` when `dir` holds this config's finished run (a checkpoint at `steps`),
/// a resuming run when it holds an earlier checkpoint (the trainer checks its config), else a
/// fresh run (the folder cleared of anything written before a first checkpoint). Long jobs made
/// of runs (an ablation's rows, the quick starts of a budget curve) train each run once however
/// often they are interrupted.
///
/// # Errors
/// A checkpoint past `steps`, or a finished run made with another config (another job's run:
/// it must not be cut short, mixed in or reused), I/O.
pub(crate) fn continue_run(
    dir: &Path,
    steps: usize,
    config: &TrainingConfig,
    options: &PipelineOptions,
) -> Result<Option<RunOptions>> {
    let latest = list_checkpoints(dir)?.pop();
    if let Some((done, checkpoint)) = &latest
        && *done == steps
    {
        return match check_resumable(&Checkpoint::read(checkpoint)?, config) {
            Ok(()) => Ok(None),
            Err(TrainError::ConfigMismatch { what, .. }) => Err(TrainError::RunFolder {
                path: dir.to_path_buf(),
                message: format!(
                    "holds a finished run made with another config ({what}): use another \
                     --out, or remove the folder to train it again"
                ),
            }),
            Err(e) => Err(e),
        };
    }
    let done = latest.map(|(step, _)| step);
    match done {
        Some(done) if done > steps => {
            return Err(TrainError::RunFolder {
                path: dir.to_path_buf(),
                message: format!(
                    "holds a run of {done} steps, more than the {steps} asked: use another \
                     --out, or remove the folder to train it again"
                ),
            });
        }
        Some(done) if options.progress => {
            eprintln!("continuing {} from step {done}", dir.display());
        }
        Some(_) => {}
        None => remove_run(dir)?,
    }
    Ok(Some(RunOptions {
        steps: Some(steps),
        resume: done.is_some(),
        progress: options.progress,
        lpips_weights: options.lpips_weights.clone(),
        ..RunOptions::new(dir, &options.data, options.backend)
    }))
}

/// Removes the run folder `dir` if there is one.
///
/// # Errors
/// I/O errors other than the folder being absent.
pub fn remove_run(dir: &Path) -> Result<()> {
    match std::fs::remove_dir_all(dir) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => Err(TrainError::io(dir, e)),
        _ => Ok(()),
    }
}

/// One trained and evaluated model of the quickstart.
#[derive(Clone, Debug)]
pub struct QuickstartModel {
    /// The run folder.
    pub run: PathBuf,
    /// Training steps.
    pub steps: usize,
    /// Wall-clock seconds this call spent training it (0 for a finished run found in the
    /// folder and kept).
    pub train_seconds: f64,
    /// Where this call's training and evaluation of it spent their time.
    pub phases: ModelPhases,
    /// The evaluation.
    pub evaluation: Evaluation,
    /// The evaluation's files (JSON, report, grids).
    pub files: EvaluationFiles,
}

/// Where the training and the evaluation of one quick start model spent their wall time
/// ([`prism_core::phases`]; a finished run kept has no training phases).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ModelPhases {
    /// The training run's phases: data loading, steps, validation (with its LPIPS),
    /// checkpoints.
    pub training: PhaseTimes,
    /// The evaluation's phases: the evaluation, and the LPIPS inside it.
    pub evaluation: PhaseTimes,
    /// Wall-clock seconds of the training and the evaluation together.
    pub wall_seconds: f64,
}

impl ModelPhases {
    /// The rows of the phase table: `(JSON key, label, seconds)`. The LPIPS rows are parts of
    /// the row above them; `other` is the wall time no phase covers (building the model,
    /// loading LPIPS and the validation views, the metrics log).
    pub fn rows(&self) -> Vec<(&'static str, &'static str, f64)> {
        let (t, e) = (&self.training, &self.evaluation);
        let covered = t.top_level_seconds() + e.top_level_seconds();
        vec![
            (
                "data_wait",
                "data loading (step waits for the prefetcher)",
                t.get(Phase::DataWait),
            ),
            ("steps", "training steps", t.get(Phase::Steps)),
            ("validation", "validation", t.get(Phase::Validation)),
            ("validation_lpips", "- of which LPIPS", t.get(Phase::Lpips)),
            ("checkpoints", "checkpoints", t.get(Phase::Checkpoints)),
            ("evaluation", "evaluation", e.get(Phase::Evaluation)),
            ("evaluation_lpips", "- of which LPIPS", e.get(Phase::Lpips)),
            ("other", "setup and the rest", self.wall_seconds - covered),
        ]
    }
}

/// What a quickstart did.
#[derive(Clone, Debug)]
pub struct QuickstartReport {
    /// The dataset trained and evaluated on.
    pub data_dir: PathBuf,
    /// The teacher.
    pub teacher: QuickstartModel,
    /// The student.
    pub student: QuickstartModel,
    /// Wall-clock seconds of the whole quickstart.
    pub wall_seconds: f64,
    /// The share of the machine's CPU time the hypervisor ran something else during it
    /// ([`prism_core::steal`]; `None` where not counted): a wall time measured with a high one
    /// is longer than the code's.
    pub cpu_steal: Option<f64>,
}

/// Runs the quickstart on `options.data`: teacher, student (through `student_job`), both
/// evaluations.
/// A run a killed quickstart left in `options.out` continues from its last checkpoint and a
/// finished one is kept, so that a long one (the budget curve's 16x) is never trained twice;
/// the student starts over when its teacher trained in this call. `prism quickstart` clears
/// its run folders first (a rerun there trains again) unless given `--resume`.
///
/// # Errors
/// Any error of the dataset, training or evaluation.
pub fn quickstart(
    plan: &QuickstartPlan,
    options: &PipelineOptions,
    student_job: StudentJob<'_>,
) -> Result<QuickstartReport> {
    let (start, steal) = (Instant::now(), StealProbe::start());
    let data_dir = options.data.clone();
    let eval = EvaluateOptions {
        views: plan.eval_views,
        progress: options.progress,
        ..EvaluateOptions::default()
    };
    // Evaluates the model trained in `run` since `t0` (this thread's phase totals `before`).
    let evaluate_run = |run: &Path, steps: usize, t0: Instant, before: PhaseTimes| -> Result<_> {
        let train_seconds = t0.elapsed().as_secs_f64();
        let training = phase_totals().since(&before);
        let (evaluation, files) = timed(Phase::Evaluation, || {
            evaluate_checkpoint(
                run,
                &data_dir,
                &run.join("evaluation"),
                options.backend,
                options.lpips_weights.as_deref(),
                &eval,
            )
        })?;
        let phases = ModelPhases {
            training,
            evaluation: phase_totals().since(&before).since(&training),
            wall_seconds: t0.elapsed().as_secs_f64(),
        };
        Ok(QuickstartModel {
            run: run.to_path_buf(),
            steps,
            train_seconds,
            phases,
            evaluation,
            files,
        })
    };

    let teacher_dir = options.out.join(TEACHER_RUN);
    let (t0, before) = (Instant::now(), phase_totals());
    let teacher_run = continue_run(&teacher_dir, plan.teacher_steps, &plan.config, options)?;
    let teacher_trained = teacher_run.is_some();
    if let Some(run) = teacher_run {
        let task = TeacherTask {
            lpips_weights: options.lpips_weights.clone(),
        };
        train(&plan.config, &task, &run)?;
    }
    let teacher = evaluate_run(&teacher_dir, plan.teacher_steps, t0, before)?;

    let student_dir = options.out.join(STUDENT_RUN);
    if teacher_trained {
        // Whatever student is there was distilled from another teacher.
        remove_run(&student_dir)?;
    }
    let mut job_config = plan.config.clone();
    compress_schedule(&mut job_config, plan.student_steps);
    let (t0, before) = (Instant::now(), phase_totals());
    let stored = student_config(&job_config);
    if let Some(run) = continue_run(&student_dir, plan.student_steps, &stored, options)? {
        student_job(&job_config, &teacher_dir, &run)?;
    }
    let student = evaluate_run(&student_dir, plan.student_steps, t0, before)?;
    Ok(QuickstartReport {
        data_dir,
        teacher,
        student,
        wall_seconds: start.elapsed().as_secs_f64(),
        cpu_steal: steal.share(),
    })
}

/// The quickstart's result table (Markdown) and where the reports, sample images and training
/// curves are. Beside the teacher and the student (their NVS decoders' `I_t`), the renders
/// `I_gs` of their 3DGS heads (when they have one) and the "copy the source view" baseline on
/// the same views (the teacher's evaluation's; the student's is on the same views).
pub fn quickstart_table(report: &QuickstartReport) -> String {
    let mut table = ScoreTable::new("model")
        .before(["steps", "train (s)"])
        .after(["FPS"]);
    let models = [("teacher", &report.teacher), ("student", &report.student)];
    for (name, m) in models {
        let e = &m.evaluation;
        let before = [m.steps.to_string(), format!("{:.0}", m.train_seconds)];
        table.row(name, &before, &e.mean(), &[format!("{:.2}", e.fps)]);
    }
    let none = || [NO_VALUE.to_string(), NO_VALUE.to_string()];
    for (name, m) in models {
        if let Some(gs) = &m.evaluation.gs {
            let row = format!("{name} I_gs (3DGS head)");
            table.row(row, &none(), &gs.mean(), &[NO_VALUE.into()]);
        }
    }
    let copy = report.teacher.evaluation.copy_source.mean();
    table.row("copy source (view 0)", &none(), &copy, &[NO_VALUE.into()]);
    let mut out = table.to_markdown();
    let _ = writeln!(out);
    for (name, m) in models {
        let _ = writeln!(out, "{name} report: {}", m.files.report.display());
        if let Some(grid) = m.files.grids.first() {
            let _ = writeln!(out, "{name} sample images: {}", grid.display());
        }
        if let Some(plot) = &m.files.training_curves {
            let _ = writeln!(out, "{name} training curves: {}", plot.display());
        }
    }
    let _ = writeln!(
        out,
        "dataset {}, wall time {:.1} min, CPU steal {}",
        report.data_dir.display(),
        report.wall_seconds / 60.0,
        percent(report.cpu_steal)
    );
    out
}

/// The quick start's phase table (Markdown): seconds per phase for the teacher, the student
/// and both, after the `dataset_seconds` the caller spent synthesising or finding the dataset;
/// the last row is the wall time (the whole quick start's, the dataset's included, in the last
/// column). The rows other than the LPIPS ones add up to the wall time.
pub fn phase_table(report: &QuickstartReport, dataset_seconds: f64) -> String {
    let seconds = |s: f64| format!("{s:.1}");
    let mut out = String::from("| phase | teacher (s) | student (s) | total (s) |\n");
    out.push_str("|---|---:|---:|---:|\n");
    let _ = writeln!(
        out,
        "| dataset (synthesis or cache) | - | - | {} |",
        seconds(dataset_seconds)
    );
    let (teacher, student) = (report.teacher.phases, report.student.phases);
    for ((_, label, t), (_, _, s)) in teacher.rows().into_iter().zip(student.rows()) {
        let _ = writeln!(
            out,
            "| {label} | {} | {} | {} |",
            seconds(t),
            seconds(s),
            seconds(t + s)
        );
    }
    let _ = writeln!(
        out,
        "| wall time | {} | {} | {} |",
        seconds(teacher.wall_seconds),
        seconds(student.wall_seconds),
        seconds(dataset_seconds + report.wall_seconds)
    );
    out
}

/// The phase table as JSON: `dataset_seconds`, `wall_seconds` (the whole quick start's),
/// `cpu_steal` (its [`QuickstartReport::cpu_steal`], null where not counted) and per
/// model (`teacher`, `student`) the seconds of each row of [`ModelPhases::rows`] and its
/// `wall_seconds`.
pub fn phases_json(report: &QuickstartReport, dataset_seconds: f64) -> Value {
    let model = |phases: &ModelPhases| {
        let mut fields: Map<String, Value> = phases
            .rows()
            .into_iter()
            .map(|(key, _, s)| (key.to_string(), json!(s)))
            .collect();
        fields.insert("wall_seconds".into(), json!(phases.wall_seconds));
        Value::Object(fields)
    };
    json!({
        "dataset_seconds": dataset_seconds,
        "wall_seconds": dataset_seconds + report.wall_seconds,
        "cpu_steal": report.cpu_steal,
        "teacher": model(&report.teacher.phases),
        "student": model(&report.student.phases),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shipped_plans_parse_and_compress_the_schedule() {
        let mut plan = QuickstartPlan::fast().unwrap();
        assert_eq!(plan.config.model.resolution, 64);
        // The fast plan trains on more people than the tiny config's 6 (which it memorises).
        assert_eq!(plan.config.data.subjects, FAST_SUBJECTS);
        let split = prism_synth::synth::split(FAST_SUBJECTS, plan.config.data.test_fraction);
        assert_eq!((split.train.len(), split.test.len()), (27, 3));
        compress_schedule(&mut plan.config, 30);
        // group_size 3: switches at 7, 14, 21; the last 9 steps fully linear.
        assert_eq!(
            (plan.config.distill.start, plan.config.distill.interval),
            (7, 7)
        );
        let standard = QuickstartPlan::standard().unwrap();
        assert_eq!(standard.config.model.resolution, 128);
    }
}
