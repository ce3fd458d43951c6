//! `prism ablate`: the paper's ablation table (its Table 3) in miniature. Every row
//! ([`AblationRow`]) is trained at one budget on the same dataset and scored on the same
//! held-out views, beside the row's own 3DGS render `I_gs` and the copy-the-source baseline,
//! overall and in the disoccluded region.
//!
//! Each row lives in its own folder of the ablation's (`teacher/`, `progressive/`, ...): the run,
//! its `evaluation/` and, once both are done, [`ROW_FILE`]. A row with that file is not trained
//! again if the file's [`Provenance`] (config, dataset, plan) is the row's, and refused if not;
//! a row interrupted during training resumes from its last checkpoint. The table
//! ([`TABLE_FILE`]), its JSON ([`JSON_FILE`]) and bar chart ([`CHART_FILE`]) are rewritten after
//! every row.

mod chart;
mod rows;
mod table;

use std::path::{Path, PathBuf};

use prism_core::files::write_json;
use prism_losses::ImageScores;
use serde::{Deserialize, Serialize};
use serde_json::Value;

pub use chart::draw_ablation_chart;
pub use rows::AblationRow;
pub use table::ablation_markdown;

use crate::config::TrainingConfig;
use crate::error::{Result, TrainError};
use crate::evaluate::{EvaluateOptions, Evaluation, evaluate_checkpoint};
use crate::images::save_png;
use crate::log::{METRICS_FILE, read_metrics};
use crate::provenance::{Provenance, dataset_digest_of};
use crate::quickstart::{PipelineOptions, compress_schedule, continue_run};
use crate::student::{distill_student, student_config};
use crate::teacher::TeacherTask;
use crate::trainer::train;

/// A finished row's result, in its folder.
pub const ROW_FILE: &str = "row.json";
/// The table (Markdown), in the ablation's folder.
pub const TABLE_FILE: &str = "ablation.md";
/// The table's values (JSON), in the ablation's folder.
pub const JSON_FILE: &str = "ablation.json";
/// The bar chart (PNG), in the ablation's folder.
pub const CHART_FILE: &str = "ablation.png";

/// What an ablation trains: the config the rows change, the rows and the budget.
#[derive(Clone, Debug)]
pub struct AblationPlan {
    /// Name of the config (its file's stem), in the table's title.
    pub config_name: String,
    /// The config every row starts from.
    pub config: TrainingConfig,
    /// The rows, in the table's order, the teacher before the students distilled from it.
    pub rows: Vec<AblationRow>,
    /// Training steps of the teacher rows.
    pub teacher_steps: usize,
    /// Distillation steps of the student rows (the schedule compressed into them, as in the
    /// quick start).
    pub student_steps: usize,
    /// Target views per held-out person in the evaluations.
    pub views: usize,
}

impl AblationPlan {
    /// The budget of a row: the teacher's or the students' steps.
    pub fn steps(&self, row: AblationRow) -> usize {
        if row.is_student() {
            self.student_steps
        } else {
            self.teacher_steps
        }
    }
}

/// One row's result: its budget, speed and scores.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RowResult {
    /// The row's name ([`AblationRow::name`]).
    pub row: String,
    /// The row's label in the table.
    pub label: String,
    /// Training steps.
    pub steps: usize,
    /// Target views per held-out person of the evaluation.
    pub views: usize,
    /// Mean wall-clock seconds of a training step (from the run's `metrics.jsonl`).
    pub seconds_per_step: f64,
    /// Frames per second of the model's forward pass (see [`Evaluation::fps`]).
    pub fps: f64,
    /// The model's (NVS decoder's) scores.
    pub model: ImageScores,
    /// The model's scores in the disoccluded region.
    pub model_disoccluded: Option<ImageScores>,
    /// The scores of the row's 3DGS render `I_gs` (none without a 3DGS head).
    pub gs: Option<ImageScores>,
    /// `I_gs`'s scores in the disoccluded region.
    pub gs_disoccluded: Option<ImageScores>,
    /// The copy-the-source baseline on the same views.
    pub copy_source: ImageScores,
    /// The baseline in the disoccluded region.
    pub copy_source_disoccluded: Option<ImageScores>,
    /// What the row was made from; a finished row is kept only for the same.
    #[serde(default)]
    pub provenance: Provenance,
}

impl RowResult {
    /// The result of `row` from its evaluation.
    pub(crate) fn of(
        row: AblationRow,
        steps: usize,
        seconds_per_step: f64,
        e: &Evaluation,
        provenance: Provenance,
    ) -> Self {
        Self {
            row: row.name().into(),
            label: row.label().into(),
            steps,
            views: e.views_per_subject,
            seconds_per_step,
            fps: e.fps,
            model: e.mean(),
            model_disoccluded: e.disoccluded.map(|d| d.scores()),
            gs: e.gs.as_ref().map(|g| g.mean()),
            gs_disoccluded: e
                .gs
                .as_ref()
                .and_then(|g| g.disoccluded)
                .map(|d| d.scores()),
            copy_source: e.copy_source.mean(),
            copy_source_disoccluded: e.copy_source.disoccluded.map(|d| d.scores()),
            provenance,
        }
    }
}

/// The ablation's table: its budget and the finished rows.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Ablation {
    /// Name of the config.
    pub config: String,
    /// Training steps of the teacher rows.
    pub teacher_steps: usize,
    /// Distillation steps of the student rows.
    pub student_steps: usize,
    /// Target views per held-out person.
    pub views: usize,
    /// The rows, in the table's order.
    pub rows: Vec<RowResult>,
}

/// Where the ablation's table is.
#[derive(Clone, Debug)]
pub struct AblationFiles {
    /// [`TABLE_FILE`].
    pub table: PathBuf,
    /// [`JSON_FILE`].
    pub json: PathBuf,
    /// [`CHART_FILE`].
    pub chart: PathBuf,
}

impl AblationFiles {
    /// The files of an ablation in the folder `out`.
    pub fn in_folder(out: &Path) -> Self {
        Self {
            table: out.join(TABLE_FILE),
            json: out.join(JSON_FILE),
            chart: out.join(CHART_FILE),
        }
    }
}

/// Trains and evaluates every row of `plan` not finished in `options.out`, and writes the
/// table, its JSON and its chart there.
///
/// # Errors
/// A row folder finished from another config, dataset or plan, any error of training or evaluation (naming the
/// row's folder), or a file that cannot be written.
pub fn ablate(plan: &AblationPlan, options: &PipelineOptions) -> Result<(Ablation, AblationFiles)> {
    std::fs::create_dir_all(&options.out).map_err(|e| TrainError::io(&options.out, e))?;
    let mut ablation = Ablation {
        config: plan.config_name.clone(),
        teacher_steps: plan.teacher_steps,
        student_steps: plan.student_steps,
        views: plan.views,
        rows: Vec::new(),
    };
    let files = AblationFiles::in_folder(&options.out);
    let teacher = options.out.join(AblationRow::Teacher.name());
    let dataset = dataset_digest_of(&options.data)?;
    // One set of options for every row: their baselines are scored once.
    let eval = EvaluateOptions {
        views: plan.views,
        progress: options.progress,
        ..EvaluateOptions::default()
    };
    for (i, &row) in plan.rows.iter().enumerate() {
        if options.progress {
            eprintln!(
                "ablate: row {}/{} {} ({} steps)",
                i + 1,
                plan.rows.len(),
                row.label(),
                plan.steps(row)
            );
        }
        ablation
            .rows
            .push(run_row(row, plan, options, &eval, &teacher, &dataset)?);
        write_table(&ablation, &files)?;
    }
    Ok((ablation, files))
}

/// One row: kept if finished from the same config, dataset and plan, else trained (or
/// resumed) and evaluated.
fn run_row(
    row: AblationRow,
    plan: &AblationPlan,
    options: &PipelineOptions,
    eval: &EvaluateOptions,
    teacher: &Path,
    dataset: &str,
) -> Result<RowResult> {
    let dir = options.out.join(row.name());
    let file = dir.join(ROW_FILE);
    let steps = plan.steps(row);
    let mut config = row.config(&plan.config);
    if row.is_student() {
        compress_schedule(&mut config, steps);
    }
    let row_plan = serde_json::json!({"row": row.name(), "steps": steps, "views": plan.views});
    let provenance = Provenance::new(&config, dataset, &row_plan);
    if file.is_file() {
        let done = read_row(&file)?;
        provenance.check(&done.provenance, &file)?;
        if options.progress {
            eprintln!("ablate: {} is done ({}), kept", row.name(), file.display());
        }
        return Ok(done);
    }
    let stored = if row.is_student() {
        student_config(&config)
    } else {
        config.clone()
    };
    if let Some(run) = continue_run(&dir, steps, &stored, options)? {
        if row.is_student() {
            distill_student(&config, teacher, &run)?;
        } else {
            let task = TeacherTask {
                lpips_weights: options.lpips_weights.clone(),
            };
            train(&config, &task, &run)?;
        }
    }
    let (evaluation, _) = evaluate_checkpoint(
        &dir,
        &options.data,
        &dir.join("evaluation"),
        options.backend,
        options.lpips_weights.as_deref(),
        eval,
    )?;
    let seconds = mean_step_seconds(&dir)?;
    let result = RowResult::of(row, steps, seconds, &evaluation, provenance);
    write_json(&file, &result).map_err(|e| TrainError::io(&file, e))?;
    Ok(result)
}

/// A finished row's [`ROW_FILE`].
fn read_row(file: &Path) -> Result<RowResult> {
    read_finished(file, "a row of an ablation")
}

/// The JSON result of a finished part of a long job (an ablation's row, a budget point),
/// `what` naming it in the error that says to remove its folder to run it again.
pub(crate) fn read_finished<T: serde::de::DeserializeOwned>(file: &Path, what: &str) -> Result<T> {
    let text = std::fs::read_to_string(file).map_err(|e| TrainError::io(file, e))?;
    serde_json::from_str(&text).map_err(|e| TrainError::RunFolder {
        path: file.to_path_buf(),
        message: format!("not {what} ({e}); remove its folder to run it again"),
    })
}

/// The mean `seconds` of the training steps of the run folder `run`'s `metrics.jsonl`.
pub(crate) fn mean_step_seconds(run: &Path) -> Result<f64> {
    let seconds: Vec<f64> = read_metrics(&run.join(METRICS_FILE))?
        .iter()
        .filter_map(|line| line.get("seconds").and_then(Value::as_f64))
        .collect();
    Ok(seconds.iter().sum::<f64>() / seconds.len().max(1) as f64)
}

/// Writes the table, its JSON and its chart into `files`.
fn write_table(ablation: &Ablation, files: &AblationFiles) -> Result<()> {
    prism_core::files::write_bytes(&files.table, ablation_markdown(ablation).as_bytes())
        .map_err(|e| TrainError::io(&files.table, e))?;
    write_json(&files.json, ablation).map_err(|e| TrainError::io(&files.json, e))?;
    let chart = draw_ablation_chart(ablation).map_err(|message| TrainError::Plot {
        path: files.chart.clone(),
        message,
    })?;
    save_png(&files.chart, &chart)
}
