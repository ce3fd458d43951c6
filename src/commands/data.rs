//! `prism data ...`: build and validate datasets.

use std::path::PathBuf;

use anyhow::bail;
use clap::{Args, Subcommand};

use indicatif::ProgressBar;
use prism_core::progress::progress_bar;
use prism_core::protocol::NUM_VIEWS;
use prism_data::SynthOptions;
use prism_data::check_dataset;
use prism_synth::scan_dataset::{ScanDatasetOptions, ScanEvent, render_scans};
use prism_synth::synth::synth_dataset;
use prism_synth::{Facing, UpAxis};

/// Dataset commands.
#[derive(Subcommand, Debug)]
pub enum DataCommand {
    /// Synthesise a dataset of procedural people under the paper's viewing protocol
    /// (105 views per subject). A rerun into the same folder continues where it stopped.
    Synth(SynthArgs),
    /// Render a dataset from textured scans (one folder per subject with one .obj/.mtl or
    /// .gltf/.glb mesh, e.g. THuman's NNNN/NNNN.obj): each subject normalised by the viewing
    /// protocol and rendered unlit from 105 views; a body fit in the folder (body.json,
    /// smplx.json or smplx_param.json) is moved along into body.json. Subjects that cannot be
    /// rendered are reported and skipped (exit status 1 at the end); a rerun into the same
    /// folder renders only what is missing.
    Render(RenderArgs),
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

/// Arguments of `prism data render`.
#[derive(Args, Debug)]
pub struct RenderArgs {
    /// Folder of scans: one sub-folder per subject, each with one mesh.
    #[arg(long)]
    pub scans: PathBuf,
    /// Output dataset folder (not inside --scans).
    #[arg(long)]
    pub out: PathBuf,
    /// Image width and height, pixels.
    #[arg(long, default_value_t = ScanDatasetOptions::default().resolution)]
    pub res: u32,
    /// Seed of placements and views (each subject's is derived from it and the folder name).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Background colour R,G,B with components in [0, 1].
    #[arg(long, default_value = "1,1,1", value_parser = parse_rgb)]
    pub background: [f32; 3],
    /// The scans' up axis: y or z.
    #[arg(long, default_value = "y")]
    pub up: UpAxis,
    /// Where the scanned people face once the up axis is Y: +z, -z, +x or -x.
    #[arg(long, default_value = "+z", allow_hyphen_values = true)]
    pub facing: Facing,
    /// Fraction of the subject folders held out for testing (the last ones by name).
    #[arg(long, default_value_t = ScanDatasetOptions::default().test_fraction)]
    pub test_fraction: f32,
    /// Supersampling factor of the renderer (s x s samples per pixel).
    #[arg(long, default_value_t = ScanDatasetOptions::default().supersample)]
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
            Self::Render(args) => render(args),
            Self::Check(args) => check(args),
        }
    }
}

/// The bar of a dataset job (`job` names it) over `len` views: drawn in place on a terminal,
/// plain lines on a pipe or a log file, as the training and evaluation bars are.
fn views_bar(job: &str, len: u64) -> ProgressBar {
    progress_bar(
        true,
        len,
        &format!("{job} [{{bar:30}}] {{pos}}/{{len}} views {{msg}} {{elapsed}} (ETA {{eta}})"),
    )
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
    let bar = views_bar("synth", (options.subjects * NUM_VIEWS) as u64);
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

fn render(args: RenderArgs) -> anyhow::Result<()> {
    let options = ScanDatasetOptions {
        resolution: args.res,
        seed: args.seed,
        test_fraction: args.test_fraction,
        background: args.background,
        supersample: args.supersample,
        up: args.up,
        facing: args.facing,
    };
    let bar = views_bar("render", 0);
    let start = std::time::Instant::now();
    let summary =
        render_scans(
            &args.scans,
            &args.out,
            &options,
            &|| bar.inc(1),
            &|event| match event {
                ScanEvent::Planned { to_render, .. } => {
                    bar.set_length((to_render * NUM_VIEWS) as u64);
                }
                ScanEvent::Skipped(_) => {}
                ScanEvent::Rendered(name) => bar.set_message(name.to_string()),
                ScanEvent::Warning { subject, message } => {
                    bar.suspend(|| eprintln!("warning: {subject}: {message}"));
                }
                ScanEvent::Failed { subject, message } => {
                    bar.suspend(|| eprintln!("error: {subject}: {message} (skipped)"));
                }
            },
        )?;
    bar.finish_and_clear();
    for name in &summary.moved {
        eprintln!(
            "note: subject {name} changed split because the scan folders changed (see dataset.json)"
        );
    }
    for name in &summary.unlisted {
        eprintln!(
            "note: {} has no scan folder any more; it is not listed in dataset.json",
            args.out.join(name).display()
        );
    }
    let listed = summary.meta.as_ref().map_or(0, |m| m.subjects.len());
    println!(
        "{}: {} subjects rendered ({} with a body fit), {} already there, {} failed, {} warnings; \
         dataset.json lists {listed} subjects, {}x{} px, in {:.1} s",
        args.out.display(),
        summary.written,
        summary.with_fit,
        summary.skipped,
        summary.failed.len(),
        summary.warnings,
        options.resolution,
        options.resolution,
        start.elapsed().as_secs_f64()
    );
    if !summary.failed.is_empty() {
        let names: Vec<&str> = summary.failed.iter().map(|f| f.subject.as_str()).collect();
        bail!(
            "{} subject(s) could not be rendered: {} (the others are in {})",
            names.len(),
            names.join(", "),
            args.out.display()
        );
    }
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
