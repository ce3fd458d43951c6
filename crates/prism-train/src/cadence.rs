//! What a run does around its steps, and when: the one place of its cadence. Every step is
//! logged to `metrics.jsonl` and the progress bar; every `train.validate_every` steps (and at
//! the end) the model is validated, its sample grid saved and the training curves drawn; every
//! `train.checkpoint_every` steps (and at the end) a checkpoint is saved. A fresh run first logs
//! the copy-the-source baseline and validates the initial model.

use std::fs;
use std::path::{Path, PathBuf};

use burn::module::Module;
use indicatif::ProgressBar;
use prism_core::phases::{Phase, timed};
use prism_data::DatasetReader;
use prism_losses::{ImageScores, Lpips};
use prism_model::Prism;
use serde_json::{Value, json};

use crate::checkpoint::Checkpoint;
use crate::config::TrainingConfig;
use crate::error::{Result, TrainError};
use crate::images::save_png;
use crate::log::MetricsLog;
use crate::plot::plot_run;
use crate::step::StepValues;
use crate::trainer::{RunOptions, RunSummary, Task};
use crate::training_step::{StepReport, TrainingStep};
use crate::validate::Validator;

/// The run folder's folder of validation sample grids.
pub const SAMPLES_DIR: &str = "samples";

/// The logging, validation and checkpoint cadence of a run, and what it has done so far.
pub struct Cadence<'a> {
    config: &'a TrainingConfig,
    options: &'a RunOptions,
    log: MetricsLog,
    bar: ProgressBar,
    validator: Validator,
    samples_dir: PathBuf,
    summary: RunSummary,
    step_seconds: f64,
    steps_timed: usize,
}

impl<'a> Cadence<'a> {
    /// The cadence of `task`'s run with `config` and `options`, on the dataset of `reader`:
    /// loads the validation views and LPIPS onto `step`'s main device (without autodiff) and
    /// opens the log. A resumed run (from `resumed`) continues its `metrics.jsonl`; a fresh one
    /// begins with the copy-the-source baseline and the validation of the initial model.
    ///
    /// # Errors
    /// Unreadable LPIPS weights or validation views; I/O errors of the run folder.
    pub fn start(
        config: &'a TrainingConfig,
        options: &'a RunOptions,
        task: &dyn Task,
        reader: &DatasetReader,
        step: &TrainingStep<'_>,
        resumed: Option<&Checkpoint>,
    ) -> Result<Self> {
        let start = resumed.map_or(0, |c| c.state.step);
        let run = options.out.as_path();
        let inference = step.main_device().clone().inner();
        let lpips = Lpips::load_default(options.lpips_weights.as_deref(), &inference)?;
        let validator = Validator::new(
            reader,
            config.model.resolution as u32,
            config.train.validation_views,
            Some(lpips),
            &inference,
        )?;
        let log = MetricsLog::open(run, resumed.map(|c| c.state.step))?;
        let samples_dir = run.join(SAMPLES_DIR);
        fs::create_dir_all(&samples_dir).map_err(|e| TrainError::io(&samples_dir, e))?;
        let mut cadence = Self {
            config,
            options,
            log,
            bar: progress_bar(options.progress, start, config.train.steps, task.name()),
            validator,
            samples_dir,
            summary: RunSummary {
                run_dir: run.to_path_buf(),
                data_dir: options.data.clone(),
                start_step: start,
                steps: start,
                baseline: None,
                initial: None,
                last: None,
                last_samples: None,
                last_checkpoint: None,
                plot: None,
                skipped_steps: step.skipped_steps(),
                seconds_per_step: f64::NAN,
                first_loss: None,
                last_loss: None,
            },
            step_seconds: 0.0,
            steps_timed: 0,
        };
        if resumed.is_none() {
            cadence.begin(step)?;
        }
        Ok(cadence)
    }

    /// The start of a fresh run: logs the copy-the-source baseline and validates the initial
    /// model (step 0).
    fn begin(&mut self, step: &TrainingStep<'_>) -> Result<()> {
        let baseline = timed(Phase::Validation, || self.validator.copy_source_baseline());
        self.log.write(&json!({
            "step": 0,
            "copy_source_psnr": baseline.psnr,
            "copy_source_ssim": baseline.ssim,
            "copy_source_lpips": baseline.lpips,
        }))?;
        self.bar.println(format!(
            "copy-the-source baseline: PSNR {:.2} dB, SSIM {:.4}, LPIPS {:.4}",
            baseline.psnr, baseline.ssim, baseline.lpips
        ));
        self.summary.baseline = Some(baseline);
        self.summary.initial = Some(self.validate(step.model(), 0)?);
        Ok(())
    }

    /// Logs and prints what the task reported when it prepared the model for step `step`
    /// (0-based; see [`Task::before_step`]).
    ///
    /// # Errors
    /// I/O errors of the log.
    pub fn prepared(&mut self, step: usize, event: Option<Value>) -> Result<()> {
        let Some(event) = event else {
            return Ok(());
        };
        let mut line = json!({ "step": step });
        if let (Some(line), Value::Object(fields)) = (line.as_object_mut(), &event) {
            line.extend(fields.clone());
        }
        self.bar
            .println(format!("before step {}: {event}", step + 1));
        self.log.write(&line)
    }

    /// After a step that took `seconds`: logs it, then validates and checkpoints when due.
    ///
    /// # Errors
    /// [`TrainError::NonFinite`] when the non-finite guard stops the run; I/O errors.
    pub fn after_step(
        &mut self,
        step: &TrainingStep<'_>,
        report: &StepReport,
        seconds: f64,
    ) -> Result<()> {
        self.record(report, seconds)?;
        let (done, train) = (report.done, &self.config.train);
        let last = done == train.steps;
        if last || (train.validate_every > 0 && done.is_multiple_of(train.validate_every)) {
            self.validate(step.model(), done)?;
        }
        if last || done.is_multiple_of(train.checkpoint_every) {
            let (out, backend) = (&self.options.out, self.options.backend);
            let path = timed(Phase::Checkpoints, || {
                step.save_checkpoint(out, self.config, backend, done)
            })?;
            self.summary.last_checkpoint = Some(path);
        }
        Ok(())
    }

    /// What the run did.
    pub fn finish(mut self, step: &TrainingStep<'_>) -> RunSummary {
        self.bar.finish_and_clear();
        self.summary.skipped_steps = step.skipped_steps();
        self.summary.seconds_per_step = self.step_seconds / self.steps_timed.max(1) as f64;
        self.summary
    }

    /// Logs a step (with `seconds` when it was applied, as skipped when not) and moves the
    /// progress bar.
    fn record(&mut self, report: &StepReport, seconds: f64) -> Result<()> {
        let done = report.done;
        let mut line = step_line(report);
        let loss = report.values.total();
        if let Some(skipped) = report.skipped {
            line["skipped"] = json!(true);
            line["reason"] = json!(skipped.reason);
            self.log.write(&line)?;
            self.bar.println(format!(
                "step {done}: {}, step skipped ({} in a row)",
                skipped.reason, skipped.in_row
            ));
            if skipped.fatal {
                self.bar.abandon();
                return Err(TrainError::NonFinite {
                    step: done,
                    count: skipped.in_row,
                    reason: skipped.reason.into(),
                });
            }
        } else {
            line["seconds"] = json!(seconds);
            self.log.write(&line)?;
            self.step_seconds += seconds;
            self.steps_timed += 1;
            self.summary.first_loss.get_or_insert(loss);
            self.summary.last_loss = Some(loss);
        }
        self.summary.steps = done;
        self.bar
            .set_message(progress_message(&report.values, report.lr_backbone));
        self.bar.inc(1);
        Ok(())
    }

    /// Validates `model` after `step` steps: the scores, the sample grid and the log line, then
    /// the training curves (timed as [`Phase::Validation`]).
    fn validate(&mut self, model: &Prism, step: usize) -> Result<ImageScores> {
        timed(Phase::Validation, || self.validate_untimed(model, step))
    }

    /// [`Cadence::validate`]'s work.
    fn validate_untimed(&mut self, model: &Prism, step: usize) -> Result<ImageScores> {
        let (scores, grid) = self.validator.validate(&model.valid());
        let name = format!("step-{step:08}.png");
        let path = self.samples_dir.join(&name);
        save_png(&path, &grid)?;
        self.log.write(&json!({
            "step": step,
            "val_psnr": scores.psnr,
            "val_ssim": scores.ssim,
            "val_lpips": scores.lpips,
            "samples": format!("{SAMPLES_DIR}/{name}"),
        }))?;
        self.bar.println(format!(
            "step {step}: validation PSNR {:.2} dB, SSIM {:.4}, LPIPS {:.4} ({} views)",
            scores.psnr,
            scores.ssim,
            scores.lpips,
            self.validator.len()
        ));
        self.summary.last = Some(scores);
        self.summary.last_samples = Some(path);
        self.summary.plot = refresh_plot(&self.options.out, &self.bar);
        Ok(scores)
    }
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

/// The log line of a step: `step`, `loss`, every term, learning rates, gradient norm and the
/// loss scale (when the run scales its loss).
fn step_line(report: &StepReport) -> Value {
    let values = &report.values;
    let mut line = json!({ "step": report.done, "loss": values.total() });
    for &(name, value) in values.terms.iter().filter(|(n, _)| *n != "total") {
        line[name] = json!(value);
    }
    line["lr"] = json!(report.lr_backbone);
    line["lr_heads"] = json!(report.lr_heads);
    line["grad_norm"] = json!(report.grad_norm);
    if let Some(scale) = report.loss_scale {
        line["loss_scale"] = json!(scale);
    }
    line
}

/// The progress bar of a run of `total` steps, `start` of them done, named `name`.
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

/// The progress bar's message after a step: its loss, terms and backbone learning rate.
fn progress_message(values: &StepValues, lr: f64) -> String {
    let mut msg = format!("loss {:.4}", values.total());
    for &(name, value) in values.terms.iter().filter(|(n, _)| *n != "total") {
        msg.push_str(&format!(" {name} {value:.4}"));
    }
    msg.push_str(&format!(" lr {lr:.2e}"));
    msg
}
