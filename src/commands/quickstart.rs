//! `prism quickstart`: the whole pipeline on a fresh machine, in one command.

use std::path::PathBuf;

use anyhow::Context;
use clap::Args;
use prism_data::BackendKind;
use prism_train::quickstart::default_out;
use prism_train::{QuickstartOptions, quickstart};

/// The quick start: synthesise the default dataset (cached), train the small teacher, distil the
/// student, evaluate both on the held-out people (100 views each) and print a table of PSNR,
/// SSIM, LPIPS and FPS with the paths of the reports and sample images. About 30 minutes on a
/// 2-core CPU; --fast (the tiny config) a few minutes. A rerun reuses the finished stages and
/// resumes an interrupted one.
#[derive(Args, Debug)]
pub struct QuickstartArgs {
    /// The tiny config (64 px, 150 teacher + 48 student steps) instead of the small one.
    #[arg(long)]
    fast: bool,
    /// Output folder [default: runs/quickstart, or runs/quickstart-fast with --fast].
    #[arg(long, value_name = "DIR")]
    out: Option<PathBuf>,
    /// Backend: ndarray, flex, wgpu or cuda.
    #[arg(long, default_value = "flex")]
    backend: BackendKind,
    /// The LPIPS weight file [default: $PRISM_LPIPS_WEIGHTS, then data/lpips_alex.safetensors].
    #[arg(long, value_name = "FILE")]
    lpips_weights: Option<PathBuf>,
    /// No progress bars.
    #[arg(long)]
    quiet: bool,
}

impl QuickstartArgs {
    /// Runs the quick start and prints the comparison table.
    pub fn run(self) -> anyhow::Result<()> {
        let out = self.out.unwrap_or_else(|| default_out(self.fast));
        let options = QuickstartOptions {
            fast: self.fast,
            out: out.clone(),
            backend: self.backend,
            progress: !self.quiet,
            lpips_weights: self.lpips_weights,
        };
        let summary =
            quickstart(&options).with_context(|| format!("quick start in {}", out.display()))?;
        print!("{}", summary.to_table());
        println!("dataset: {}", summary.data_dir.display());
        println!(
            "runs: {} and {} ({:.0} s in all)",
            summary.teacher_run.display(),
            summary.student_run.display(),
            summary.seconds
        );
        Ok(())
    }
}
