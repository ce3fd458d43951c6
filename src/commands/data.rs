//! `prism data ...`: build and validate datasets.

use std::path::PathBuf;

use anyhow::bail;
use clap::{Args, Subcommand};

use prism_data::dataset::check_dataset;

/// Dataset commands.
#[derive(Subcommand, Debug)]
pub enum DataCommand {
    /// Validate a dataset folder and report every problem with its file (exit status 1 when any).
    Check(CheckArgs),
}

/// Arguments of `prism data check`.
#[derive(Args, Debug)]
pub struct CheckArgs {
    /// The dataset folder (holding dataset.json).
    pub dir: PathBuf,
}

impl DataCommand {
    /// Runs the subcommand.
    pub fn run(self) -> anyhow::Result<()> {
        match self {
            Self::Check(args) => check(args),
        }
    }
}

fn check(args: CheckArgs) -> anyhow::Result<()> {
    let report = check_dataset(&args.dir);
    for problem in &report.problems {
        println!("{problem}");
    }
    if report.problems.is_empty() {
        println!(
            "{}: ok ({} subjects, {} views)",
            args.dir.display(),
            report.subjects,
            report.views
        );
        Ok(())
    } else {
        bail!(
            "{}: {} problem(s) found",
            args.dir.display(),
            report.problems.len()
        )
    }
}
