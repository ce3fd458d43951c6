//! `prism distill-student`: the linear-attention student distilled from a trained teacher
//! (paper Sec. 3.4), or one of the paper's ablations (`[distill] mode`).

use std::path::PathBuf;

use anyhow::Context;
use clap::Args;

use super::args::{RunArgs, print_summary};
use prism_model::DistillMode;
use prism_train::{TrainingConfig, config_name, distill_student, kinds_letters};

/// Arguments of `prism distill-student`.
#[derive(Args, Debug)]
pub struct DistillStudentArgs {
    /// The config file; its `[distill]` section sets the mode (progressive, all_at_once,
    /// fully_linear, teacher), the schedule (group_size, start, interval), the L_distill layers,
    /// steps, batch_size and the fixed learning rate lr; e.g. configs/small.toml.
    #[arg(long, value_name = "FILE")]
    config: PathBuf,
    /// The teacher: a run folder of `prism train-teacher` (its latest checkpoint) or a
    /// checkpoint folder. The student starts as its copy; it stays frozen.
    #[arg(long, value_name = "RUN_OR_CKPT")]
    teacher: PathBuf,
    /// Override `[distill] mode`: progressive, all_at_once, fully_linear or teacher.
    #[arg(long, value_name = "MODE")]
    mode: Option<DistillMode>,
    #[command(flatten)]
    run: RunArgs,
}

impl DistillStudentArgs {
    /// Whether the run trains on one device ([`RunArgs::single_device`]).
    pub fn single_device(&self) -> bool {
        self.run.single_device()
    }

    /// Distils, then prints the schedule, the final validation and where the results are.
    pub fn run(self) -> anyhow::Result<()> {
        let mut config = TrainingConfig::load(&self.config)?;
        if let Some(mode) = self.mode {
            config.distill.mode = mode;
        }
        let mode = config.distill.mode;
        let default_out =
            PathBuf::from("runs").join(format!("student-{}-{mode}", config_name(&self.config)));
        let options = self.run.options(default_out, &config.data)?;
        let blocks = config.model.num_blocks();
        // The schedule as this run follows it: --steps replaces `[distill] steps`.
        let mut schedule = config.distill.clone();
        schedule.steps = self.run.steps.unwrap_or(schedule.steps);
        println!(
            "distilling {} ({mode}): {} steps at lr {:.1e}, final attention {}",
            self.teacher.display(),
            schedule.steps,
            schedule.lr,
            kinds_letters(&schedule.final_kinds(blocks)),
        );
        let summary = distill_student(&config, &self.teacher, &options).with_context(|| {
            format!(
                "distilling {} into {}",
                self.teacher.display(),
                options.out.display()
            )
        })?;
        print_summary(
            &summary,
            ["copy-the-source baseline", "teacher (initial student)"],
        );
        Ok(())
    }
}
