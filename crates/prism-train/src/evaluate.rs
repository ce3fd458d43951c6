//! `prism evaluate`: the paper's evaluation protocol on the test subjects of a dataset.
//!
//! For every test subject the frontal view 0 is the source and views 1..=100 the targets; PSNR,
//! SSIM and LPIPS are averaged over each subject's views, then over the subjects. The same
//! scores are also pooled by view angle (10-degree bins of |yaw| and of |pitch|), and the
//! model's forward pass is timed on one (source, target) pair.
//!
//! Every score comes with the same scores, on the same views, of the "copy the source view"
//! baseline (view 0 taken as the prediction of every target view), and, for a model with a 3DGS
//! head, of its render `I_gs`.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::fs;
use std::path::{Path, PathBuf};
use std::time::Instant;

use burn::tensor::{Device, Tensor};
use image::RgbImage;
use indicatif::ProgressBar;
use prism_core::BackendKind;
use prism_core::protocol::EVAL_TARGETS;
use prism_data::{DatasetReader, PrismBatcher, Sample, SampleDataset, SplitKind, TargetSelection};
use prism_losses::{LPIPS_MIN_SIDE, Lpips, psnr, ssim};
use prism_model::Prism;
use serde::Serialize;

use crate::checkpoint::{CHECKPOINTS_DIR, load_model};
use crate::error::{Result, TrainError};
use crate::images::{HostImages, error_map, save_png, save_text, tile};
use crate::log::METRICS_FILE;
use crate::plot::{PLOT_FILE, plot_metrics};
use crate::predict::{Pairs, forward_pairs, inference_model, synthesise};
use crate::validate::validation_views;

/// Width of the view-angle bins of the breakdown, degrees.
pub const ANGLE_BIN_DEG: f32 = 10.0;
/// File name of the JSON scores in an evaluation folder.
pub const EVALUATION_JSON: &str = "evaluation.json";
/// File name of the Markdown report in an evaluation folder.
pub const REPORT_MD: &str = "report.md";
/// Folder of the per-subject PNG grids in an evaluation folder.
pub const GRIDS_DIR: &str = "grids";
/// File name, in an evaluation folder, of the training curves of the checkpoint's run.
pub const TRAINING_CURVES_PNG: &str = "training-curves.png";

/// How an evaluation runs.
#[derive(Clone, Debug)]
pub struct EvaluateOptions {
    /// Target views per subject, evenly spread over views 1..=100 (100: every view, the
    /// paper's protocol; fewer for a quick look).
    pub views: usize,
    /// (source, target) pairs per forward pass.
    pub batch: usize,
    /// Rows (views) of each subject's PNG grid.
    pub grid_views: usize,
    /// Timed forward passes of one pair for the FPS (after two warm-up passes).
    pub fps_runs: usize,
    /// Draw a progress bar on stderr.
    pub progress: bool,
    /// Write every predicted target view as `DIR/SUBJECT/NNN.png` (`NNN` the view index, 3
    /// digits), for scoring against other methods with `evaluate --pred/--gt`.
    pub save_predictions: Option<PathBuf>,
}

impl Default for EvaluateOptions {
    fn default() -> Self {
        Self {
            views: EVAL_TARGETS.count(),
            batch: 8,
            grid_views: 4,
            fps_runs: 10,
            progress: false,
            save_predictions: None,
        }
    }
}

/// PSNR (dB), SSIM and LPIPS averaged over some views, with their number.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct MeanScores {
    /// PSNR in dB.
    pub psnr: f64,
    /// SSIM.
    pub ssim: f64,
    /// LPIPS (NaN, `null` in JSON, below LPIPS's 31 px minimum).
    pub lpips: f64,
    /// Number of views averaged.
    pub views: usize,
}

impl MeanScores {
    fn of(rows: &[[f64; 3]]) -> Self {
        let n = rows.len() as f64;
        let mean = |k: usize| rows.iter().map(|r| r[k]).sum::<f64>() / n;
        Self {
            psnr: mean(0),
            ssim: mean(1),
            lpips: mean(2),
            views: rows.len(),
        }
    }
}

/// The scores of the views whose |angle| falls in `[from_deg, to_deg)` (pooled over subjects).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct AngleBin {
    /// Lower bound of |angle|, degrees.
    pub from_deg: f32,
    /// Upper bound of |angle| (exclusive, except the last bin), degrees.
    pub to_deg: f32,
    /// The mean scores of the bin's views.
    #[serde(flatten)]
    pub scores: MeanScores,
}

/// The breakdown by view angle: bins of |yaw| and of |pitch|.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct PerAngle {
    /// Bins of |yaw|.
    pub yaw: Vec<AngleBin>,
    /// Bins of |pitch|.
    pub pitch: Vec<AngleBin>,
}

/// The scores of one way of predicting the target views (the 3DGS head's render, or the copy
/// of the source view) on the evaluation's views, in the structure of the model's scores.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct MethodScores {
    /// PSNR in dB: each subject's views averaged, then the subjects.
    pub psnr: f64,
    /// SSIM, averaged the same way.
    pub ssim: f64,
    /// LPIPS, averaged the same way.
    pub lpips: f64,
    /// Each test subject's mean scores.
    pub subjects: BTreeMap<String, MeanScores>,
    /// The scores by view angle.
    pub per_angle: PerAngle,
}

impl PerAngle {
    /// The bins of `"yaw"`, or else of pitch.
    pub fn axis(&self, axis: &str) -> &[AngleBin] {
        if axis == "yaw" {
            &self.yaw
        } else {
            &self.pitch
        }
    }
}

/// The result of an evaluation: what `evaluation.json` holds. The top-level scores are the
/// model's (its NVS decoder's `I_t`).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Evaluation {
    /// PSNR in dB: each subject's views averaged, then the subjects.
    pub psnr: f64,
    /// SSIM, averaged the same way.
    pub ssim: f64,
    /// LPIPS, averaged the same way.
    pub lpips: f64,
    /// (source, target) pairs per second of the model's forward pass on one pair (the 3DGS
    /// head skipped; warm-up and data loading excluded).
    pub fps: f64,
    /// Each test subject's mean scores.
    pub subjects: BTreeMap<String, MeanScores>,
    /// The scores by view angle.
    pub per_angle: PerAngle,
    /// Image side of the evaluation, pixels (the model's resolution).
    pub resolution: u32,
    /// Target views per subject.
    pub views_per_subject: usize,
    /// The "copy the source view" baseline on the same views: the source (view 0) taken as the
    /// prediction of every target view. A model that does not beat it has learnt nothing about
    /// other viewpoints.
    pub copy_source: MethodScores,
    /// The 3DGS head's render `I_gs` (over the background) on the same views, from a forward
    /// pass with the head; `None` (absent from the JSON) for a model without a 3DGS head.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub gs: Option<MethodScores>,
}

/// One subject's sample grid: per row source | prediction | ground truth | error map.
#[derive(Clone, Debug)]
pub struct SubjectGrid {
    /// The subject's folder name.
    pub subject: String,
    /// The grid.
    pub image: RgbImage,
}

/// One scored view: its angles and scores.
struct ViewScore {
    yaw: f32,
    pitch: f32,
    scores: [f64; 3],
}

/// The scores of one prediction method, view by view, grouped by subject.
#[derive(Default)]
struct Tally {
    subjects: BTreeMap<String, Vec<[f64; 3]>>,
    views: Vec<ViewScore>,
}

impl Tally {
    fn add(&mut self, subject: &str, yaw: f32, pitch: f32, scores: [f64; 3]) {
        self.subjects
            .entry(subject.to_string())
            .or_default()
            .push(scores);
        self.views.push(ViewScore { yaw, pitch, scores });
    }

    /// Each subject's views averaged, then the subjects; the views pooled by angle.
    fn finish(self) -> MethodScores {
        let subjects: BTreeMap<String, MeanScores> = self
            .subjects
            .into_iter()
            .map(|(name, rows)| (name, MeanScores::of(&rows)))
            .collect();
        let means: Vec<[f64; 3]> = subjects
            .values()
            .map(|m| [m.psnr, m.ssim, m.lpips])
            .collect();
        let overall = MeanScores::of(&means);
        MethodScores {
            psnr: overall.psnr,
            ssim: overall.ssim,
            lpips: overall.lpips,
            subjects,
            per_angle: PerAngle {
                yaw: angle_bins(&self.views, |v| v.yaw),
                pitch: angle_bins(&self.views, |v| v.pitch),
            },
        }
    }
}

/// PSNR, SSIM and LPIPS (NaN without LPIPS) of each pair of `pred` and `gt`.
fn score(pred: Tensor<4>, gt: Tensor<4>, lpips: Option<&Lpips>) -> Vec<[f64; 3]> {
    let p = psnr(pred.clone(), gt.clone());
    let q = ssim(pred.clone(), gt.clone());
    let l = match lpips {
        Some(lpips) => lpips.distance(pred, gt),
        None => vec![f64::NAN; p.len()],
    };
    (0..p.len()).map(|i| [p[i], q[i], l[i]]).collect()
}

/// Evaluates a checkpoint (a checkpoint folder or a run folder's latest) on the dataset at
/// `data` on `backend`, and writes the JSON, the report and the grids into `out`.
///
/// # Errors
/// An unreadable checkpoint, dataset or LPIPS weight file, or I/O errors.
pub fn evaluate_checkpoint(
    checkpoint: &Path,
    data: &Path,
    out: &Path,
    backend: BackendKind,
    lpips_weights: Option<&Path>,
    options: &EvaluateOptions,
) -> Result<(Evaluation, EvaluationFiles)> {
    let device = backend.device()?;
    let (model, config) = load_model(checkpoint, &device)?;
    let data_dir = data.to_path_buf();
    let reader = DatasetReader::open(&data_dir)?;
    let lpips = Lpips::load_default(lpips_weights, &device)?;
    let resolution = config.model.resolution as u32;
    let (evaluation, grids) =
        evaluate(&model, &reader, resolution, Some(&lpips), &device, options)?;
    let title = format!(
        "{} on {} ({backend})",
        checkpoint.display(),
        data_dir.display()
    );
    let run = run_folder(checkpoint);
    let files = write_evaluation(out, &title, &evaluation, &grids, run.as_deref())?;
    Ok((evaluation, files))
}

/// The run folder of a checkpoint path, when it has a metrics log: the path itself (a run
/// folder), or `RUN` of `RUN/checkpoints/step-N`.
pub fn run_folder(checkpoint: &Path) -> Option<PathBuf> {
    if checkpoint.join(METRICS_FILE).is_file() {
        return Some(checkpoint.to_path_buf());
    }
    let parent = checkpoint.parent()?;
    let run = parent.parent()?;
    (parent.file_name()? == CHECKPOINTS_DIR && run.join(METRICS_FILE).is_file())
        .then(|| run.to_path_buf())
}

/// Evaluates `model` (an inference model on `device`) on the test subjects of the dataset
/// opened by `reader`, at `resolution`; returns the scores and each subject's grid.
///
/// The views are scored from one forward pass of the whole model (with its 3DGS head, when it
/// has one, for `I_gs`: the NVS decoder's `I_t` does not depend on that head); the FPS is
/// measured without the 3DGS head, as inference serves.
///
/// # Errors
/// A dataset without test subjects, or unreadable files.
pub fn evaluate(
    model: &Prism,
    reader: &DatasetReader,
    resolution: u32,
    lpips: Option<&Lpips>,
    device: &Device,
    options: &EvaluateOptions,
) -> Result<(Evaluation, Vec<SubjectGrid>)> {
    let fast = inference_model(model);
    let has_gs = model.gs_head.is_some();
    let dataset = SampleDataset::new(
        reader.clone(),
        SplitKind::Test,
        TargetSelection::Evaluation { per_sample: 1 },
        Some((resolution, resolution)),
        0,
    )?;
    let background = reader.meta().background;
    let lpips = lpips.filter(|_| resolution as usize >= LPIPS_MIN_SIDE);
    let views = validation_views(options.views);
    let grid_views: Vec<usize> = validation_views(options.grid_views.min(views.len()))
        .into_iter()
        .map(|v| views[(v - 1) * views.len() / 100])
        .collect();
    let subjects = dataset.subjects().to_vec();
    let bar = progress_bar(options.progress, (subjects.len() * views.len()) as u64);
    let (mut nvs, mut copy, mut gs) = (Tally::default(), Tally::default(), Tally::default());
    let mut grids = Vec::new();
    let mut fps_pair = None;
    for (s, subject) in subjects.iter().enumerate() {
        bar.set_message(subject.clone());
        let mut grid_rows = Vec::new();
        let predictions_dir = options.save_predictions.as_ref().map(|d| d.join(subject));
        if let Some(dir) = &predictions_dir {
            fs::create_dir_all(dir).map_err(|e| TrainError::io(dir, e))?;
        }
        for chunk in views.chunks(options.batch.max(1)) {
            let samples = chunk
                .iter()
                .map(|&v| dataset.load(s * 100 + v - 1))
                .collect::<std::result::Result<Vec<Sample>, _>>()?;
            let batch = PrismBatcher.batch_samples(&samples, device);
            let pairs = Pairs::of_batch(&batch, background);
            if fps_pair.is_none() {
                fps_pair = Some(pairs.slice(0, 1));
            }
            let out = forward_pairs(if has_gs { model } else { &fast }, &pairs);
            let pred = out.image.clamp(0.0, 1.0);
            let gt = batch.target_image.clone();
            let nvs_scores = score(pred.clone(), gt.clone(), lpips);
            let copy_scores = score(batch.source_image.clone(), gt.clone(), lpips);
            let gs_scores = out
                .gaussians
                .map(|g| score(g.image.clamp(0.0, 1.0), gt.clone(), lpips));
            let pred_host = HostImages::from_tensor(pred);
            let gt_host = HostImages::from_tensor(gt);
            let src_host = HostImages::from_tensor(batch.source_image.clone());
            for (i, sample) in samples.iter().enumerate() {
                let target = &sample.targets[0];
                let (yaw, pitch) = (target.yaw_deg, target.pitch_deg);
                nvs.add(subject, yaw, pitch, nvs_scores[i]);
                copy.add(subject, yaw, pitch, copy_scores[i]);
                if let Some(g) = &gs_scores {
                    gs.add(subject, yaw, pitch, g[i]);
                }
                if let Some(dir) = &predictions_dir {
                    let path = dir.join(format!("{:03}.png", target.index));
                    save_png(&path, &pred_host.rgb8(i))?;
                }
                if grid_views.contains(&target.index) {
                    let (w, h) = (pred_host.width, pred_host.height);
                    grid_rows.push(vec![
                        src_host.rgb8(i),
                        pred_host.rgb8(i),
                        gt_host.rgb8(i),
                        error_map(&pred_host.images[i], &gt_host.images[i], w, h),
                    ]);
                }
            }
            bar.inc(chunk.len() as u64);
        }
        grids.push(SubjectGrid {
            subject: subject.clone(),
            image: tile(&grid_rows),
        });
    }
    bar.finish_and_clear();
    let fps = match fps_pair {
        Some(pair) => forward_fps(&fast, &pair, options.fps_runs.max(1)),
        None => f64::NAN,
    };
    let nvs = nvs.finish();
    Ok((
        Evaluation {
            psnr: nvs.psnr,
            ssim: nvs.ssim,
            lpips: nvs.lpips,
            fps,
            subjects: nvs.subjects,
            per_angle: nvs.per_angle,
            resolution,
            views_per_subject: views.len(),
            copy_source: copy.finish(),
            gs: has_gs.then(|| gs.finish()),
        },
        grids,
    ))
}

/// Forward passes per second of `model` on `pair` (one pair): two warm-up passes, then `runs`
/// timed ones, each read back to the host so the time includes the whole computation.
pub fn forward_fps(model: &Prism, pair: &Pairs, runs: usize) -> f64 {
    let once = || {
        let image: Tensor<4> = synthesise(model, pair);
        let _ = image.into_data();
    };
    once();
    once();
    let start = Instant::now();
    for _ in 0..runs {
        once();
    }
    runs as f64 / start.elapsed().as_secs_f64()
}

/// Pools the views into bins of `ANGLE_BIN_DEG` degrees of |angle|, `[from, to)`; the last bin
/// also holds its upper bound (the protocol's +-30 degree corners); empty bins are left out.
fn angle_bins(views: &[ViewScore], angle: impl Fn(&ViewScore) -> f32) -> Vec<AngleBin> {
    let top = views.iter().map(|v| angle(v).abs()).fold(0.0f32, f32::max);
    let last = ((top / ANGLE_BIN_DEG).ceil() as usize).saturating_sub(1);
    let mut bins: BTreeMap<usize, Vec<[f64; 3]>> = BTreeMap::new();
    for v in views {
        let k = ((angle(v).abs() / ANGLE_BIN_DEG).floor() as usize).min(last);
        bins.entry(k).or_default().push(v.scores);
    }
    bins.into_iter()
        .map(|(k, rows)| AngleBin {
            from_deg: k as f32 * ANGLE_BIN_DEG,
            to_deg: (k + 1) as f32 * ANGLE_BIN_DEG,
            scores: MeanScores::of(&rows),
        })
        .collect()
}

fn progress_bar(show: bool, len: u64) -> ProgressBar {
    prism_core::progress::progress_bar(
        show,
        len,
        "evaluating [{bar:30}] {pos}/{len} views {msg} (ETA {eta})",
    )
}

/// The files an evaluation wrote.
#[derive(Clone, Debug)]
pub struct EvaluationFiles {
    /// `evaluation.json`.
    pub json: PathBuf,
    /// `report.md`.
    pub report: PathBuf,
    /// One PNG grid per subject.
    pub grids: Vec<PathBuf>,
    /// The training curves of the checkpoint's run ([`TRAINING_CURVES_PNG`]), when its run
    /// folder was known.
    pub training_curves: Option<PathBuf>,
}

/// Writes `evaluation.json`, `report.md` and `grids/SUBJECT.png` into `dir` (created), each
/// atomically. `title` heads the report (e.g. the checkpoint evaluated). With the checkpoint's
/// `run` folder, its training curves (its [`PLOT_FILE`], or, for a run without one, a plot of
/// its `metrics.jsonl`) are put beside the report as [`TRAINING_CURVES_PNG`] and shown in it.
///
/// # Errors
/// I/O errors, naming the file; a plot that cannot be drawn.
pub fn write_evaluation(
    dir: &Path,
    title: &str,
    evaluation: &Evaluation,
    grids: &[SubjectGrid],
    run: Option<&Path>,
) -> Result<EvaluationFiles> {
    let grid_dir = dir.join(GRIDS_DIR);
    fs::create_dir_all(&grid_dir).map_err(|e| TrainError::io(&grid_dir, e))?;
    let mut grid_paths = Vec::new();
    for grid in grids {
        let path = grid_dir.join(format!("{}.png", grid.subject));
        save_png(&path, &grid.image)?;
        grid_paths.push(path);
    }
    let training_curves = match run {
        Some(run) => training_curves(run, &dir.join(TRAINING_CURVES_PNG))?,
        None => None,
    };
    let json = dir.join(EVALUATION_JSON);
    save_text(&json, &evaluation_json(evaluation))?;
    let report = dir.join(REPORT_MD);
    save_text(
        &report,
        &markdown_report(
            title,
            evaluation,
            &grid_paths,
            training_curves.as_deref(),
            dir,
        ),
    )?;
    Ok(EvaluationFiles {
        json,
        report,
        grids: grid_paths,
        training_curves,
    })
}

/// Puts the training curves of `run` at `out`: a copy of its [`PLOT_FILE`], or a plot of its
/// `metrics.jsonl` when it has no plot; `None` when it has neither.
fn training_curves(run: &Path, out: &Path) -> Result<Option<PathBuf>> {
    let plot = run.join(PLOT_FILE);
    let metrics = run.join(METRICS_FILE);
    if plot.is_file() {
        let bytes = fs::read(&plot).map_err(|e| TrainError::io(&plot, e))?;
        prism_core::files::write_bytes(out, &bytes).map_err(|e| TrainError::io(out, e))?;
    } else if metrics.is_file() {
        let name = run.file_name().unwrap_or(run.as_os_str()).to_string_lossy();
        plot_metrics(&metrics, out, &format!("training curves of {name}"))?;
    } else {
        return Ok(None);
    }
    Ok(Some(out.to_path_buf()))
}

/// The evaluation as pretty JSON (NaN written as `null`).
pub fn evaluation_json(evaluation: &Evaluation) -> String {
    serde_json::to_string_pretty(evaluation).expect("evaluation serialises") + "\n"
}

/// The rows of the report's tables after the model's: the 3DGS head's `I_gs` (when there is
/// one) and the copy of the source view, with their names.
fn other_rows(e: &Evaluation) -> Vec<(&'static str, &MethodScores)> {
    let mut rows = Vec::new();
    if let Some(gs) = &e.gs {
        rows.push(("I_gs", gs));
    }
    rows.push(("copy source", &e.copy_source));
    rows
}

/// The Markdown report: the means of the model, of its 3DGS head (if any) and of the copy of
/// the source view; per-subject and per-angle tables with the same three; the training curves
/// and links to the grids (relative to `dir`).
pub fn markdown_report(
    title: &str,
    evaluation: &Evaluation,
    grids: &[PathBuf],
    training_curves: Option<&Path>,
    dir: &Path,
) -> String {
    let e = evaluation;
    let mut out = String::new();
    let _ = writeln!(out, "# Evaluation of {title}\n");
    let _ = writeln!(
        out,
        "{} test subjects, source view 0, {} target views each, {} x {} px. Each subject's \
         views are averaged, then the subjects. \"copy source\" takes the source view as the \
         prediction of every target view: the baseline a model must beat.\n",
        e.subjects.len(),
        e.views_per_subject,
        e.resolution,
        e.resolution
    );
    let _ = writeln!(
        out,
        "| prediction | PSNR (dB) | SSIM | LPIPS | FPS (1 pair) |"
    );
    let _ = writeln!(out, "|---|---:|---:|---:|---:|");
    let _ = writeln!(
        out,
        "| model (NVS decoder I_t) | {:.3} | {:.4} | {:.4} | {:.2} |",
        e.psnr, e.ssim, e.lpips, e.fps
    );
    if let Some(gs) = &e.gs {
        let _ = writeln!(
            out,
            "| model's 3DGS head (I_gs) | {:.3} | {:.4} | {:.4} | - |",
            gs.psnr, gs.ssim, gs.lpips
        );
    }
    let c = &e.copy_source;
    let _ = writeln!(
        out,
        "| copy source (view 0) | {:.3} | {:.4} | {:.4} | - |",
        c.psnr, c.ssim, c.lpips
    );
    let _ = writeln!(
        out,
        "\nModel minus copy source: PSNR {:+.3} dB, SSIM {:+.4}, LPIPS {:+.4} (the model beats \
         the baseline where PSNR and SSIM are positive and LPIPS negative).\n",
        e.psnr - c.psnr,
        e.ssim - c.ssim,
        e.lpips - c.lpips
    );
    // The per-subject and per-angle tables: the model's three scores, then PSNR and LPIPS of
    // the others.
    let others = other_rows(e);
    let mut head = String::from("| views | PSNR (dB) | SSIM | LPIPS |");
    let mut rule = String::from("|---:|---:|---:|---:|");
    for (name, _) in &others {
        let _ = write!(head, " {name} PSNR | {name} LPIPS |");
        rule.push_str("---:|---:|");
    }
    let row = |m: &MeanScores, rest: Vec<Option<&MeanScores>>| {
        let mut line = format!(
            "| {} | {:.3} | {:.4} | {:.4} |",
            m.views, m.psnr, m.ssim, m.lpips
        );
        for o in rest {
            match o {
                Some(o) => {
                    let _ = write!(line, " {:.3} | {:.4} |", o.psnr, o.lpips);
                }
                None => line.push_str(" - | - |"),
            }
        }
        line
    };
    let _ = writeln!(out, "## Per subject\n");
    let _ = writeln!(out, "| subject {head}");
    let _ = writeln!(out, "|---{rule}");
    for (name, s) in &e.subjects {
        let rest = others.iter().map(|(_, o)| o.subjects.get(name)).collect();
        let _ = writeln!(out, "| {name} {}", row(s, rest));
    }
    for axis in ["yaw", "pitch"] {
        let _ = writeln!(out, "\n## By |{axis}|\n");
        let _ = writeln!(out, "| abs {axis} (deg) {head}");
        let _ = writeln!(out, "|---{rule}");
        for b in e.per_angle.axis(axis) {
            let rest = others
                .iter()
                .map(|(_, o)| {
                    o.per_angle
                        .axis(axis)
                        .iter()
                        .find(|ob| ob.from_deg == b.from_deg)
                        .map(|ob| &ob.scores)
                })
                .collect();
            let _ = writeln!(
                out,
                "| {:.0}-{:.0} {}",
                b.from_deg,
                b.to_deg,
                row(&b.scores, rest)
            );
        }
    }
    if let Some(path) = training_curves {
        let rel = path.strip_prefix(dir).unwrap_or(path);
        let _ = writeln!(
            out,
            "\n## Training curves\n\nThe run's loss terms, and its validation PSNR, SSIM and \
             LPIPS with the copy-source baseline (dashed), from its metrics.jsonl.\n\n![training \
             curves]({})",
            rel.display()
        );
    }
    if !grids.is_empty() {
        let _ = writeln!(
            out,
            "\n## Samples\n\nPer row: source | prediction | ground truth | error map (mean \
             absolute error, black 0, white {} and above).\n",
            crate::images::ERROR_MAP_FULL_SCALE
        );
        for path in grids {
            let rel = path.strip_prefix(dir).unwrap_or(path);
            let _ = writeln!(out, "![{}]({})\n", rel.display(), rel.display());
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn view(yaw: f32, pitch: f32, psnr: f64) -> ViewScore {
        ViewScore {
            yaw,
            pitch,
            scores: [psnr, 0.5, 0.1],
        }
    }

    #[test]
    fn angle_bins_pool_absolute_angles_in_ten_degree_steps() {
        let views = [
            view(-5.0, 25.0, 10.0),
            view(9.9, -30.0, 20.0),
            view(10.0, 0.0, 30.0),
            view(-30.0, 12.0, 40.0),
        ];
        let yaw = angle_bins(&views, |v| v.yaw);
        let bounds: Vec<_> = yaw.iter().map(|b| (b.from_deg, b.scores.views)).collect();
        assert_eq!(bounds, vec![(0.0, 2), (10.0, 1), (20.0, 1)]);
        assert_eq!(yaw[0].scores.psnr, 15.0);
        assert_eq!(yaw[2].scores.psnr, 40.0);
        let pitch = angle_bins(&views, |v| v.pitch);
        let bounds: Vec<_> = pitch.iter().map(|b| (b.from_deg, b.scores.views)).collect();
        assert_eq!(bounds, vec![(0.0, 1), (10.0, 1), (20.0, 2)]);
        assert_eq!(pitch[2].scores.psnr, 15.0);
    }

    #[test]
    fn means_average_each_metric() {
        let m = MeanScores::of(&[[10.0, 0.5, 0.2], [20.0, 0.7, 0.4]]);
        assert_eq!((m.psnr, m.ssim, m.views), (15.0, 0.6, 2));
        assert!((m.lpips - 0.3).abs() < 1e-12);
    }
}
