//! `prism quickstart`: the main job. Dataset, teacher, student, evaluation of both, a table.

use std::path::PathBuf;

use anyhow::Context;
use clap::Args;
use prism_core::BackendKind;
use prism_core::files::write_json;
use prism_core::phases::{Phase, phase_totals, timed};
use prism_synth::ensure_synthetic_dataset;
use prism_train::{
    PHASES_FILE, PipelineOptions, QuickstartPlan, STUDENT_RUN, TEACHER_RUN, distill_student,
    phase_table, phases_json, quickstart, quickstart_table, remove_run,
};

/// Run the whole pipeline on the small config: synthesise the default dataset, train the
/// teacher, distil the student, evaluate both on the held-out people and print PSNR, SSIM,
/// LPIPS and FPS (with rows for their 3DGS heads' renders I_gs and for the copy-the-source
/// baseline) and the paths of the reports, sample images and training curves; then the wall time
/// of each phase (dataset, data loading, training steps, validation, checkpoints, evaluation
/// and the LPIPS inside validation and evaluation) for both models, also written to
/// OUT/phases.json.
///
/// The step counts are scaled down from the config's so the job takes minutes on a 2-core CPU
/// (flex; 4.6 to 5.3 measured on an AMD EPYC Zen 4): 300 teacher and 150 student steps, the
/// protocol's 100 target views per test subject. --fast uses the tiny config (64 px) on 30
/// synthetic people (960 and 720 steps, the student distilled at lr 3e-4, 10 views; 3.0 to
/// 3.3 minutes measured there), where both models beat copy-source with a lower LPIPS.
#[derive(Args, Debug)]
pub struct QuickstartArgs {
    /// The tiny config (64 px) on 30 people, 960 + 720 steps, 10 views per test subject.
    #[arg(long)]
    fast: bool,
    /// Folder of the two runs and their evaluations [default: runs/quickstart or
    /// runs/quickstart-fast]; replaced if it holds a previous quickstart (see --resume).
    #[arg(long, value_name = "DIR")]
    out: Option<PathBuf>,
    /// Continue the quick start an interruption left in --out instead of training again: each
    /// run goes on from its last checkpoint and a finished one is kept (a run made with another
    /// config or plan is refused); both are evaluated again. Train seconds count this call.
    #[arg(long)]
    resume: bool,
    /// Teacher training steps instead of the plan's.
    #[arg(long, value_name = "N")]
    teacher_steps: Option<usize>,
    /// Student distillation steps instead of the plan's.
    #[arg(long, value_name = "N")]
    student_steps: Option<usize>,
    /// Target views per test subject in the evaluations (1..=100; 100 is the paper's protocol).
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u16).range(1..=100))]
    eval_views: Option<u16>,
    /// Backend: ndarray, flex or wgpu.
    #[arg(long, default_value = "flex")]
    backend: BackendKind,
    /// LPIPS weight file [default: $PRISM_LPIPS_WEIGHTS, then data/lpips_alex.safetensors].
    #[arg(long, value_name = "FILE")]
    lpips_weights: Option<PathBuf>,
    /// No progress bars.
    #[arg(long)]
    quiet: bool,
}

impl QuickstartArgs {
    /// Runs the quickstart and prints the table.
    pub fn run(self) -> anyhow::Result<()> {
        let mut plan = if self.fast {
            QuickstartPlan::fast()?
        } else {
            QuickstartPlan::standard()?
        };
        for (value, field) in [
            (self.teacher_steps, &mut plan.teacher_steps),
            (self.student_steps, &mut plan.student_steps),
        ] {
            if let Some(v) = value {
                anyhow::ensure!(v > 0, "step counts must be at least 1");
                *field = v;
            }
        }
        if let Some(v) = self.eval_views {
            plan.eval_views = usize::from(v);
        }
        let out = self.out.clone().unwrap_or_else(|| {
            PathBuf::from(if self.fast {
                "runs/quickstart-fast"
            } else {
                "runs/quickstart"
            })
        });
        let before = phase_totals();
        let data = timed(Phase::Dataset, || {
            ensure_synthetic_dataset(&plan.config.data, !self.quiet)
        })?;
        let dataset_seconds = phase_totals().since(&before).get(Phase::Dataset);
        eprintln!(
            "quickstart: dataset {} ready in {dataset_seconds:.0} s",
            data.display()
        );
        let options = PipelineOptions {
            out: out.clone(),
            data,
            backend: self.backend,
            lpips_weights: self.lpips_weights.clone(),
            progress: !self.quiet,
        };
        eprintln!(
            "quickstart: {} config, {} teacher + {} student steps, {} views per test subject, \
             into {}",
            plan.name,
            plan.teacher_steps,
            plan.student_steps,
            plan.eval_views,
            out.display()
        );
        // A rerun trains again unless asked to resume (the library's quickstart continues what
        // it finds).
        if !self.resume {
            for run in [TEACHER_RUN, STUDENT_RUN] {
                remove_run(&out.join(run))?;
            }
        }
        let report = quickstart(&plan, &options, &distill_student)
            .with_context(|| format!("quickstart into {}", out.display()))?;
        print!("{}", quickstart_table(&report));
        println!();
        print!("{}", phase_table(&report, dataset_seconds));
        let phases = out.join(PHASES_FILE);
        write_json(&phases, &phases_json(&report, dataset_seconds))
            .with_context(|| format!("cannot write {}", phases.display()))?;
        println!("phase timings: {}", phases.display());
        Ok(())
    }
}
