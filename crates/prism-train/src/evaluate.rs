//! `prism evaluate`: the paper's evaluation protocol on the test subjects of a dataset.
//!
//! For every test subject the frontal view 0 is the source and views 1..=100 the targets; PSNR,
//! SSIM and LPIPS are averaged over each subject's views, then over the subjects. The same
//! scores are also pooled by view angle (10-degree bins of |yaw| and of |pitch|), and the
//! model's forward pass is timed on one (source, target) pair.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use burn::tensor::{Device, Tensor};
use image::RgbImage;
use indicatif::ProgressBar;
use prism_data::BackendKind;
use prism_data::dataset::{
    DatasetReader, PrismBatcher, Sample, SampleDataset, SplitKind, TargetSelection,
};
use prism_data::protocol::EVAL_TARGETS;
use prism_losses::{LPIPS_MIN_SIDE, Lpips, psnr, ssim};
use prism_model::Prism;
use serde::Serialize;

use crate::cache::ensure_synthetic_dataset;
use crate::checkpoint::load_model;
use crate::error::{Result, TrainError};
use crate::images::{HostImages, error_map, save_png, save_text, tile};
use crate::predict::{Pairs, inference_model, synthesise};
use crate::validate::validation_views;

/// Width of the view-angle bins of the breakdown, degrees.
pub const ANGLE_BIN_DEG: f32 = 10.0;
/// File name of the JSON scores in an evaluation folder.
pub const EVALUATION_JSON: &str = "evaluation.json";
/// File name of the Markdown report in an evaluation folder.
pub const REPORT_MD: &str = "report.md";
/// Folder of the per-subject PNG grids in an evaluation folder.
pub const GRIDS_DIR: &str = "grids";

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
}

impl Default for EvaluateOptions {
    fn default() -> Self {
        Self {
            views: EVAL_TARGETS.count(),
            batch: 8,
            grid_views: 4,
            fps_runs: 10,
            progress: false,
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

/// The result of an evaluation: what `evaluation.json` holds.
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

/// Evaluates a checkpoint (a checkpoint folder or a run folder's latest) on the dataset at
/// `data` (default: its config's synthetic dataset, synthesised into the cache if needed) on
/// `backend`, and writes the JSON, the report and the grids into `out`.
///
/// # Errors
/// An unreadable checkpoint, dataset or LPIPS weight file, or I/O errors.
pub fn evaluate_checkpoint(
    checkpoint: &Path,
    data: Option<&Path>,
    out: &Path,
    backend: BackendKind,
    lpips_weights: Option<&Path>,
    options: &EvaluateOptions,
) -> Result<(Evaluation, EvaluationFiles)> {
    let device = backend.device()?;
    let (model, config) = load_model(checkpoint, &device)?;
    let data_dir = match data {
        Some(dir) => dir.to_path_buf(),
        None => ensure_synthetic_dataset(&config.data, options.progress)?,
    };
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
    let files = write_evaluation(out, &title, &evaluation, &grids)?;
    Ok((evaluation, files))
}

/// Evaluates `model` (an inference model on `device`) on the test subjects of the dataset
/// opened by `reader`, at `resolution`; returns the scores and each subject's grid.
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
    let model = inference_model(model);
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
    let mut all = Vec::new();
    let mut per_subject = BTreeMap::new();
    let mut grids = Vec::new();
    let mut fps_pair = None;
    for (s, subject) in subjects.iter().enumerate() {
        bar.set_message(subject.clone());
        let mut rows = Vec::new();
        let mut grid_rows = Vec::new();
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
            let pred = synthesise(&model, &pairs);
            let gt = batch.target_image.clone();
            let p = psnr(pred.clone(), gt.clone());
            let q = ssim(pred.clone(), gt.clone());
            let l = match lpips {
                Some(lpips) => lpips.distance(pred.clone(), gt.clone()),
                None => vec![f64::NAN; p.len()],
            };
            let pred_host = HostImages::from_tensor(pred);
            let gt_host = HostImages::from_tensor(gt);
            let src_host = HostImages::from_tensor(batch.source_image.clone());
            for (i, sample) in samples.iter().enumerate() {
                let target = &sample.targets[0];
                rows.push([p[i], q[i], l[i]]);
                all.push(ViewScore {
                    yaw: target.yaw_deg,
                    pitch: target.pitch_deg,
                    scores: [p[i], q[i], l[i]],
                });
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
        per_subject.insert(subject.clone(), MeanScores::of(&rows));
        grids.push(SubjectGrid {
            subject: subject.clone(),
            image: tile(&grid_rows),
        });
    }
    bar.finish_and_clear();
    let means: Vec<[f64; 3]> = per_subject
        .values()
        .map(|m| [m.psnr, m.ssim, m.lpips])
        .collect();
    let overall = MeanScores::of(&means);
    let fps = match fps_pair {
        Some(pair) => forward_fps(&model, &pair, options.fps_runs.max(1)),
        None => f64::NAN,
    };
    Ok((
        Evaluation {
            psnr: overall.psnr,
            ssim: overall.ssim,
            lpips: overall.lpips,
            fps,
            subjects: per_subject,
            per_angle: PerAngle {
                yaw: angle_bins(&all, |v| v.yaw),
                pitch: angle_bins(&all, |v| v.pitch),
            },
            resolution,
            views_per_subject: views.len(),
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
    crate::progress::progress_bar(
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
}

/// Writes `evaluation.json`, `report.md` and `grids/SUBJECT.png` into `dir` (created), each
/// atomically. `title` heads the report (e.g. the checkpoint evaluated).
///
/// # Errors
/// I/O errors, naming the file.
pub fn write_evaluation(
    dir: &Path,
    title: &str,
    evaluation: &Evaluation,
    grids: &[SubjectGrid],
) -> Result<EvaluationFiles> {
    let grid_dir = dir.join(GRIDS_DIR);
    std::fs::create_dir_all(&grid_dir).map_err(|e| TrainError::io(&grid_dir, e))?;
    let mut grid_paths = Vec::new();
    for grid in grids {
        let path = grid_dir.join(format!("{}.png", grid.subject));
        save_png(&path, &grid.image)?;
        grid_paths.push(path);
    }
    let json = dir.join(EVALUATION_JSON);
    save_text(&json, &evaluation_json(evaluation))?;
    let report = dir.join(REPORT_MD);
    save_text(
        &report,
        &markdown_report(title, evaluation, &grid_paths, dir),
    )?;
    Ok(EvaluationFiles {
        json,
        report,
        grids: grid_paths,
    })
}

/// The evaluation as pretty JSON (NaN written as `null`).
pub fn evaluation_json(evaluation: &Evaluation) -> String {
    serde_json::to_string_pretty(evaluation).expect("evaluation serialises") + "\n"
}

/// The Markdown report: the means, the per-subject and per-angle tables, links to the grids
/// (relative to `dir`).
pub fn markdown_report(
    title: &str,
    evaluation: &Evaluation,
    grids: &[PathBuf],
    dir: &Path,
) -> String {
    let e = evaluation;
    let mut out = String::new();
    let _ = writeln!(out, "# Evaluation of {title}\n");
    let _ = writeln!(
        out,
        "{} test subjects, source view 0, {} target views each, {} x {} px. Each subject's \
         views are averaged, then the subjects.\n",
        e.subjects.len(),
        e.views_per_subject,
        e.resolution,
        e.resolution
    );
    let _ = writeln!(out, "| PSNR (dB) | SSIM | LPIPS | FPS (1 pair) |");
    let _ = writeln!(out, "|---:|---:|---:|---:|");
    let _ = writeln!(
        out,
        "| {:.3} | {:.4} | {:.4} | {:.2} |\n",
        e.psnr, e.ssim, e.lpips, e.fps
    );
    let _ = writeln!(out, "## Per subject\n");
    let _ = writeln!(out, "| subject | views | PSNR (dB) | SSIM | LPIPS |");
    let _ = writeln!(out, "|---|---:|---:|---:|---:|");
    for (name, s) in &e.subjects {
        let _ = writeln!(
            out,
            "| {name} | {} | {:.3} | {:.4} | {:.4} |",
            s.views, s.psnr, s.ssim, s.lpips
        );
    }
    for (axis, bins) in [("yaw", &e.per_angle.yaw), ("pitch", &e.per_angle.pitch)] {
        let _ = writeln!(out, "\n## By |{axis}|\n");
        let _ = writeln!(
            out,
            "| abs {axis} (deg) | views | PSNR (dB) | SSIM | LPIPS |"
        );
        let _ = writeln!(out, "|---|---:|---:|---:|---:|");
        for b in bins {
            let _ = writeln!(
                out,
                "| {:.0}-{:.0} | {} | {:.3} | {:.4} | {:.4} |",
                b.from_deg, b.to_deg, b.scores.views, b.scores.psnr, b.scores.ssim, b.scores.lpips
            );
        }
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
