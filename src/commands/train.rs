//! `prism train-teacher`: teacher pretraining (paper Sec. 3.3 and the supplement's training
//! details).

use std::path::PathBuf;

use anyhow::Context;
use clap::Args;

use super::args::{RunArgs, print_summary};
use prism_train::{RunOptions, TeacherTask, TrainingConfig, config_name, train};

/// Arguments of `prism train-teacher`.
#[derive(Args, Debug)]
pub struct TrainTeacherArgs {
    /// The config file (`[model]`, `[distill]`, `[losses]`, `[train]`, `[data]`), e.g.
    /// configs/small.toml.
    #[arg(long, value_name = "FILE")]
    config: PathBuf,
    /// Start a new run from the weights of this checkpoint (a checkpoint folder or a run
    /// folder's latest), e.g. to fine-tune on another dataset.
    #[arg(long, value_name = "CKPT")]
    init: Option<PathBuf>,
    #[command(flatten)]
    run: RunArgs,
}

impl TrainTeacherArgs {
    /// Whether the run trains on one device ([`RunArgs::single_device`]).
    pub fn single_device(&self) -> bool {
        self.run.single_device()
    }

    /// Trains, then prints the final validation metrics and where the results are.
    pub fn run(self) -> anyhow::Result<()> {
        let config = TrainingConfig::load(&self.config)?;
        let default_out =
            PathBuf::from("runs").join(format!("teacher-{}", config_name(&self.config)));
        let options = RunOptions {
            init: self.init,
            ..self.run.options(default_out, &config.data)?
        };
        let task = TeacherTask {
            lpips_weights: options.lpips_weights.clone(),
        };
        let summary = train(&config, &task, &options)
            .with_context(|| format!("training into {}", options.out.display()))?;
        print_summary(&summary, ["copy-the-source baseline", "initial model"]);
        Ok(())
    }
}
