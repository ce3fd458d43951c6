//! `prism data ...`: build and validate datasets.

use std::path::PathBuf;

use anyhow::bail;
use clap::{Args, Subcommand};

use indicatif::{ProgressBar, ProgressStyle};
use prism_data::dataset::check_dataset;
use prism_data::protocol::NUM_VIEWS;
use prism_data::synth::{SynthOptions, synth_dataset};

/// Dataset commands.
#[derive(Subcommand, Debug)]
pub enum DataCommand {
    /// Synthesise a dataset of procedural people under the paper's viewing protocol
    /// (105 views per subject). A rerun into the same folder continues where it stopped.
    Synth(SynthArgs),
    /// Validate a dataset folder and report every problem with its file (exit status 1 when any).
    Check(CheckArgs),
}

/// Arguments of `prism data synth`.
#[derive(Args, Debug)]
pub struct SynthArgs {
    /// Output dataset folder.
    #[arg(long)]
    pub out: PathBuf,
    /// Number of subjects.
    #[arg(long, default_value_t = SynthOptions::default().subjects)]
    pub subjects: usize,
    /// Image width and height, pixels.
    #[arg(long, default_value_t = SynthOptions::default().resolution)]
    pub res: u32,
    /// Seed of the whole dataset.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Fraction of the subjects held out for testing (the last ones).
    #[arg(long, default_value_t = SynthOptions::default().test_fraction)]
    pub test_fraction: f32,
    /// Background colour R,G,B with components in [0, 1].
    #[arg(long, default_value = "1,1,1", value_parser = parse_rgb)]
    pub background: [f32; 3],
    /// Supersampling factor of the renderer (s x s samples per pixel).
    #[arg(long, default_value_t = SynthOptions::default().supersample)]
    pub supersample: u32,
}

/// Parses `R,G,B` with components in [0, 1].
pub fn parse_rgb(text: &str) -> Result<[f32; 3], String> {
    let parts: Vec<&str> = text.split(',').map(str::trim).collect();
    let values: Vec<f32> = parts
        .iter()
        .map(|p| {
            p.parse::<f32>()
                .map_err(|_| format!("`{p}` is not a number"))
        })
        .collect::<Result<_, _>>()?;
    match values[..] {
        [r, g, b] if values.iter().all(|v| (0.0..=1.0).contains(v)) => Ok([r, g, b]),
        [_, _, _] => Err(format!("components of `{text}` must be in [0, 1]")),
        _ => Err(format!("expected R,G,B, got `{text}`")),
    }
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
            Self::Synth(args) => synth(args),
            Self::Check(args) => check(args),
        }
    }
}

fn synth(args: SynthArgs) -> anyhow::Result<()> {
    let options = SynthOptions {
        subjects: args.subjects,
        resolution: args.res,
        seed: args.seed,
        test_fraction: args.test_fraction,
        background: args.background,
        supersample: args.supersample,
    };
    let bar = ProgressBar::new((options.subjects * NUM_VIEWS) as u64).with_style(
        ProgressStyle::with_template(
            "{spinner} synth [{bar:30}] {pos}/{len} views  {msg}  {elapsed} (ETA {eta})",
        )
        .expect("valid template")
        .progress_chars("=> "),
    );
    let start = std::time::Instant::now();
    let summary = synth_dataset(&args.out, &options, &|| bar.inc(1), &|name, skipped| {
        if skipped {
            bar.inc(NUM_VIEWS as u64);
        }
        bar.set_message(name.to_string());
    })?;
    bar.finish_and_clear();
    println!(
        "{}: {} subjects written, {} already there, {}x{} px, in {:.1} s",
        args.out.display(),
        summary.written,
        summary.skipped,
        options.resolution,
        options.resolution,
        start.elapsed().as_secs_f64()
    );
    Ok(())
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
