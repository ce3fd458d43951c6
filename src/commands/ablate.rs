//! `prism ablate`: the paper's ablation rows trained at one budget and scored on the same
//! held-out views.

use std::path::PathBuf;

use anyhow::Context;
use clap::Args;

use super::args::{DataArgs, JobArgs};
use prism_train::{
    AblationPlan, AblationRow, PipelineOptions, TrainingConfig, ablate, ablation_markdown,
    config_name,
};

/// The ablation table: every row trained on the same dataset at one budget, scored on the same
/// held-out views (PSNR, SSIM, LPIPS, overall and in the disoccluded region), beside the row's
/// own 3DGS render I_gs and the copy-the-source baseline, with FPS and seconds per step.
///
/// Rows: teacher, progressive (the paper's student), all_at_once, fully_linear, no_smplx,
/// no_points, no_gs, no_distill, plain (the paper's direct NVS decoder and regressed 3DGS
/// colours). Teacher rows train from scratch for --steps; student rows are distilled from the
/// teacher row for --student-steps, the stitching schedule compressed into them.
///
/// Writes OUT/ablation.md, OUT/ablation.json and OUT/ablation.png after every row; each row's
/// run and evaluation are in OUT/ROW/. Run it again to continue: finished rows are kept, an
/// interrupted row resumes from its last checkpoint.
#[derive(Args, Debug)]
pub struct AblateArgs {
    /// The config every row starts from, e.g. configs/small.toml.
    #[arg(long, value_name = "FILE")]
    config: PathBuf,
    /// Training steps of the teacher rows [default: the config's train.steps].
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u64).range(1..))]
    steps: Option<u64>,
    /// Distillation steps of the student rows [default: half the teacher rows' steps, as in the
    /// quick start].
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u64).range(1..))]
    student_steps: Option<u64>,
    /// Target views per held-out person in the evaluations (100 is the paper's protocol).
    #[arg(long, default_value_t = 20, value_name = "N", value_parser = clap::value_parser!(u16).range(1..=100))]
    views: u16,
    /// The rows: all, or a comma list of their names (the teacher row is added when a student
    /// row needs it).
    #[arg(long, default_value = "all", value_name = "LIST")]
    rows: String,
    /// Folder of the rows and the table [default: runs/ablation-<config name>].
    #[arg(long, value_name = "DIR")]
    out: Option<PathBuf>,
    #[command(flatten)]
    data: DataArgs,
    #[command(flatten)]
    job: JobArgs,
}

impl AblateArgs {
    /// Trains and evaluates the rows not done yet, then prints the table.
    pub fn run(self) -> anyhow::Result<()> {
        let config = TrainingConfig::load(&self.config)?;
        let rows = AblationRow::parse_list(&self.rows).map_err(anyhow::Error::msg)?;
        let teacher_steps = self.steps.map_or(config.train.steps, |s| s as usize);
        let student_steps = self
            .student_steps
            .map_or((teacher_steps / 2).max(1), |s| s as usize);
        let name = config_name(&self.config);
        let out = self
            .out
            .unwrap_or_else(|| PathBuf::from("runs").join(format!("ablation-{name}")));
        let progress = !self.job.quiet;
        let options = PipelineOptions {
            data: self.data.resolve(&config.data, progress)?,
            out: out.clone(),
            backend: self.job.backend,
            lpips_weights: self.job.lpips_weights,
            progress,
        };
        let plan = AblationPlan {
            config_name: name,
            config,
            rows,
            teacher_steps,
            student_steps,
            views: usize::from(self.views),
        };
        let (ablation, files) =
            ablate(&plan, &options).with_context(|| format!("ablation in {}", out.display()))?;
        print!("{}", ablation_markdown(&ablation));
        println!(
            "table {}, values {}, chart {}",
            files.table.display(),
            files.json.display(),
            files.chart.display()
        );
        Ok(())
    }
}
