//! The quick start (`prism quickstart`): on a fresh machine, synthesise the default dataset,
//! train the teacher, distil the student, evaluate both and compare them; every stage is
//! resumable (a rerun continues an interrupted stage and reuses finished ones).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use prism_data::BackendKind;
use prism_data::dataset::DatasetReader;
use prism_losses::Lpips;

use crate::checkpoint::{Checkpoint, latest_checkpoint, load_model};
use crate::config::TrainingConfig;
use crate::error::Result;
use crate::evaluate::{EvaluateOptions, Evaluation, REPORT_MD, evaluate};
use crate::student::{StudentTask, student_config};
use crate::teacher::TeacherTask;
use crate::trainer::{RunOptions, RunSummary, Task, train};

/// configs/small.toml, built in so that the quick start runs from any folder.
const SMALL_TOML: &str = include_str!("../../../configs/small.toml");
/// configs/tiny.toml, built in likewise.
const TINY_TOML: &str = include_str!("../../../configs/tiny.toml");

/// Teacher steps of the quick start on the small config: scaled from the config's 600 so that
/// the whole quick start (synthesis, both trainings, both evaluations) takes under 30 minutes on
/// a 2-core CPU (see README).
pub const SMALL_TEACHER_STEPS: usize = 300;
/// Student steps of the quick start on the small config (the config's 2400-step `[distill]`
/// schedule scaled to them).
pub const SMALL_STUDENT_STEPS: usize = 120;

/// Teacher steps of `--fast` (tiny config; its own 40 steps leave the teacher at the
/// initial model's level).
pub const FAST_TEACHER_STEPS: usize = 150;
/// Student steps of `--fast` (the tiny config's 24-step schedule scaled to them).
pub const FAST_STUDENT_STEPS: usize = 48;

/// How to run the quick start.
#[derive(Clone, Debug)]
pub struct QuickstartOptions {
    /// The tiny config (64 px, 6 subjects, [`FAST_TEACHER_STEPS`] + [`FAST_STUDENT_STEPS`]
    /// steps): about a minute instead of half an hour.
    pub fast: bool,
    /// The folder of the two runs and their evaluations.
    pub out: PathBuf,
    /// The backend.
    pub backend: BackendKind,
    /// Progress bars on stderr.
    pub progress: bool,
    /// LPIPS weight file (default: the project's search order).
    pub lpips_weights: Option<PathBuf>,
}

/// What the quick start did.
#[derive(Clone, Debug)]
pub struct QuickstartSummary {
    /// The teacher's run folder.
    pub teacher_run: PathBuf,
    /// The student's run folder.
    pub student_run: PathBuf,
    /// The dataset trained and evaluated on.
    pub data_dir: PathBuf,
    /// The teacher's evaluation.
    pub teacher: Evaluation,
    /// The student's evaluation.
    pub student: Evaluation,
    /// The teacher's evaluation folder (report.md, evaluation.json, grids/).
    pub teacher_eval: PathBuf,
    /// The student's evaluation folder.
    pub student_eval: PathBuf,
    /// Wall-clock seconds of the whole quick start.
    pub seconds: f64,
}

impl QuickstartSummary {
    /// The comparison table (Markdown) with the paths of the reports and sample images.
    pub fn to_table(&self) -> String {
        let mut t = String::new();
        let _ = writeln!(t, "| model | PSNR (dB) | SSIM | LPIPS | FPS |");
        let _ = writeln!(t, "|---|---:|---:|---:|---:|");
        for (name, e) in [("teacher", &self.teacher), ("student", &self.student)] {
            let _ = writeln!(
                t,
                "| {name} | {:.3} | {:.4} | {:.4} | {:.1} |",
                e.psnr, e.ssim, e.lpips, e.fps
            );
        }
        let _ = writeln!(t);
        for (name, dir, e) in [
            ("teacher", &self.teacher_eval, &self.teacher),
            ("student", &self.student_eval, &self.student),
        ] {
            let _ = writeln!(t, "{name} report: {}", dir.join(REPORT_MD).display());
            if let Some(grid) = e.subjects.values().find_map(|s| s.grid.as_ref()) {
                let _ = writeln!(t, "{name} samples: {}", dir.join(grid).display());
            }
        }
        t
    }
}

/// The config the quick start trains: the small config with [`SMALL_TEACHER_STEPS`] and
/// [`SMALL_STUDENT_STEPS`], or with `fast` the tiny config with [`FAST_TEACHER_STEPS`] and
/// [`FAST_STUDENT_STEPS`]; warm-up and distillation schedule scaled along. Validation and
/// checkpoints only at the end of each run.
pub fn quickstart_config(fast: bool) -> TrainingConfig {
    let (text, name) = if fast {
        (TINY_TOML, "configs/tiny.toml")
    } else {
        (SMALL_TOML, "configs/small.toml")
    };
    let mut config =
        TrainingConfig::parse(text, Path::new(name)).expect("the shipped configs parse");
    let (teacher_steps, student_steps) = if fast {
        (FAST_TEACHER_STEPS, FAST_STUDENT_STEPS)
    } else {
        (SMALL_TEACHER_STEPS, SMALL_STUDENT_STEPS)
    };
    let t = &mut config.train;
    t.warmup_steps = t.warmup_steps * teacher_steps / t.steps;
    t.steps = teacher_steps;
    let d = &mut config.distill;
    let scale = |v: usize| (v * student_steps / d.steps).max(1);
    d.start = scale(d.start);
    d.interval = scale(d.interval);
    d.steps = student_steps;
    let t = &mut config.train;
    t.checkpoint_every = t.steps.max(config.distill.steps);
    t.validate_every = t.checkpoint_every;
    t.keep_checkpoints = 1;
    config
}

/// Runs the quick start (see the module doc) into `options.out`: `teacher/` and `student/`
/// run folders, each with its `evaluation/`.
///
/// # Errors
/// Whatever a stage fails with (synthesis, training, evaluation), naming the file.
pub fn quickstart(options: &QuickstartOptions) -> Result<QuickstartSummary> {
    let started = Instant::now();
    let config = quickstart_config(options.fast);
    let data_dir = crate::cache::ensure_synthetic_dataset(&config.data, options.progress)?;
    let teacher_run = options.out.join("teacher");
    let student_run = options.out.join("student");
    let run_options = |out: &Path| RunOptions {
        data: Some(data_dir.clone()),
        progress: options.progress,
        lpips_weights: options.lpips_weights.clone(),
        ..RunOptions::new(out, options.backend)
    };

    say(options, "training the teacher");
    let teacher_task = TeacherTask {
        lpips_weights: options.lpips_weights.clone(),
    };
    run_stage(&config, &teacher_task, run_options(&teacher_run), options)?;

    say(options, "distilling the student");
    let student = student_config(&config);
    let student_task = StudentTask::new(&student, &teacher_run, options.lpips_weights.clone())?;
    let mut student_options = run_options(&student_run);
    student_options.init = Some(student_task.teacher.clone());
    run_stage(&student, &student_task, student_options, options)?;

    let device = options.backend.device()?;
    let lpips = Lpips::load_default(options.lpips_weights.as_deref(), &device)?;
    let reader = DatasetReader::open(&data_dir)?;
    let eval_options = EvaluateOptions {
        progress: options.progress,
        ..EvaluateOptions::default()
    };
    let evaluate_run = |name: &str, run: &Path| -> Result<(Evaluation, PathBuf)> {
        say(options, &format!("evaluating the {name}"));
        let (model, config) = load_model(run, &device)?;
        let out = run.join("evaluation");
        let e = evaluate(
            &model,
            &reader,
            config.model.resolution as u32,
            Some(&lpips),
            &device,
            &eval_options,
            Some(&out),
            &format!("the quick start's {name} ({})", run.display()),
        )?;
        Ok((e, out))
    };
    let (teacher, teacher_eval) = evaluate_run("teacher", &teacher_run)?;
    let (student, student_eval) = evaluate_run("student", &student_run)?;
    let summary = QuickstartSummary {
        teacher_run,
        student_run,
        data_dir,
        teacher,
        student,
        teacher_eval,
        student_eval,
        seconds: started.elapsed().as_secs_f64(),
    };
    let md = format!(
        "# prism quick start\n\n{}\n\nDataset: {}\n\nWall time: {:.0} s\n",
        summary.to_table(),
        summary.data_dir.display(),
        summary.seconds
    );
    crate::images::save_text(&options.out.join("quickstart.md"), &md)?;
    Ok(summary)
}

/// Trains one stage: fresh, resumed from an interrupted run, or skipped when its run folder
/// already holds the last checkpoint.
fn run_stage(
    config: &TrainingConfig,
    task: &dyn Task,
    mut run: RunOptions,
    options: &QuickstartOptions,
) -> Result<Option<RunSummary>> {
    if let Some(latest) = latest_checkpoint(&run.out)? {
        let done = Checkpoint::read(&latest)?.state.step;
        if done >= config.train.steps {
            say(
                options,
                &format!("  reusing {} (step {done})", latest.display()),
            );
            return Ok(None);
        }
        run.resume = true;
        run.init = None;
    }
    let summary = train(config, task, &run)?;
    if options.progress {
        eprintln!(
            "  {} steps in {} ({:.2} s per step)",
            summary.steps,
            summary.run_dir.display(),
            summary.seconds_per_step
        );
    }
    Ok(Some(summary))
}

/// A progress line on stderr.
fn say(options: &QuickstartOptions, what: &str) {
    if options.progress {
        eprintln!("quickstart: {what}");
    }
}

/// The default output folder: `runs/quickstart` (`runs/quickstart-fast` with `fast`).
pub fn default_out(fast: bool) -> PathBuf {
    PathBuf::from("runs").join(if fast {
        "quickstart-fast"
    } else {
        "quickstart"
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn small_quickstart_scales_the_schedules() {
        let c = quickstart_config(false);
        assert_eq!(c.train.steps, SMALL_TEACHER_STEPS);
        assert_eq!(c.train.warmup_steps, 15);
        assert_eq!(c.distill.steps, SMALL_STUDENT_STEPS);
        assert_eq!((c.distill.start, c.distill.interval), (15, 15));
        assert_eq!(c.model.resolution, 128);
        let fast = quickstart_config(true);
        assert_eq!(fast.model.resolution, 64);
        assert_eq!(fast.train.steps, FAST_TEACHER_STEPS);
        assert_eq!(fast.train.checkpoint_every, FAST_TEACHER_STEPS);
        assert_eq!((fast.distill.start, fast.distill.interval), (8, 8));
        // The student's last switch comes before its last step (it has steps to recover).
        let d = &c.distill;
        assert!(d.start + 4 * d.interval < d.steps);
    }
}
