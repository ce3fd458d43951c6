//! Evaluation on the held-out subjects (`prism evaluate --checkpoint`), following the paper's
//! protocol: for each test subject the frontal view 0 is the source and views 1..=100 the
//! targets; PSNR, SSIM and LPIPS are averaged over a subject's views, then over the subjects.
//! Also a breakdown by view angle, the frame rate of the forward pass, a Markdown report and a
//! PNG grid per subject.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use burn::tensor::{Device, Tensor};
use image::RgbImage;
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use prism_data::dataset::{
    DatasetReader, PrismBatcher, Sample, SampleDataset, SplitKind, TargetSelection,
};
use prism_losses::{LPIPS_MIN_SIDE, Lpips, psnr, ssim};
use prism_model::Prism;
use serde::Serialize;

use crate::error::{Result, TrainError};
use crate::images::{HostImages, error_map, save_png, save_text, tile};
use crate::predict::{Pairs, nvs_model, synthesise};
use crate::validate::validation_views;

/// Width of the view-angle bins of [`PerAngle`], degrees.
pub const ANGLE_BIN_DEG: f32 = 10.0;
/// (source, target) pairs per forward pass during evaluation.
pub const EVAL_BATCH: usize = 10;
/// The file the evaluation's JSON is written to in the output folder.
pub const EVALUATION_JSON: &str = "evaluation.json";
/// The Markdown report in the output folder.
pub const REPORT_MD: &str = "report.md";
/// The folder of per-subject grids in the output folder.
pub const GRIDS_DIR: &str = "grids";

/// How to evaluate.
#[derive(Clone, Debug)]
pub struct EvaluateOptions {
    /// Target views per subject, evenly spread over 1..=100 (100: the paper's protocol).
    pub views_per_subject: usize,
    /// Views per subject drawn in its PNG grid.
    pub grid_views: usize,
    /// Timed forward passes for the frame rate (after two warm-up passes); at least this many,
    /// and more until one second has passed.
    pub fps_runs: usize,
    /// Draw a progress bar on stderr.
    pub progress: bool,
}

impl Default for EvaluateOptions {
    fn default() -> Self {
        Self {
            views_per_subject: 100,
            grid_views: 4,
            fps_runs: 5,
            progress: false,
        }
    }
}

/// One subject's scores: the means over its target views.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SubjectScores {
    /// PSNR in dB.
    pub psnr: f64,
    /// SSIM.
    pub ssim: f64,
    /// LPIPS (NaN, `null` in JSON, below LPIPS's 31 px minimum).
    pub lpips: f64,
    /// Target views scored.
    pub views: usize,
    /// The subject's PNG grid, relative to the output folder (when written).
    pub grid: Option<String>,
}

/// The means over the (subject, view) pairs whose |angle| falls in `[from_deg, to_deg)` (the
/// last bin includes its upper end).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct AngleBin {
    /// Lower end of the bin, degrees.
    pub from_deg: f32,
    /// Upper end of the bin, degrees.
    pub to_deg: f32,
    /// Pairs in the bin.
    pub views: usize,
    /// Mean PSNR in dB (NaN for an empty bin).
    pub psnr: f64,
    /// Mean SSIM.
    pub ssim: f64,
    /// Mean LPIPS.
    pub lpips: f64,
}

/// The scores by view angle: [`ANGLE_BIN_DEG`]-wide bins of |yaw| and of |pitch|.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct PerAngle {
    /// Bins of the target's |yaw|.
    pub yaw: Vec<AngleBin>,
    /// Bins of the target's |pitch|.
    pub pitch: Vec<AngleBin>,
}

/// The result of [`evaluate`]: what `evaluation.json` holds.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Evaluation {
    /// PSNR in dB: per subject over its views, then over the subjects.
    pub psnr: f64,
    /// SSIM, averaged the same way.
    pub ssim: f64,
    /// LPIPS (v0.1 AlexNet), averaged the same way.
    pub lpips: f64,
    /// Frames per second of the model's forward pass for one (source, target) pair (see
    /// [`measure_fps`]).
    pub fps: f64,
    /// Each test subject's scores, by folder name.
    pub subjects: BTreeMap<String, SubjectScores>,
    /// The scores by view angle.
    pub per_angle: PerAngle,
    /// Image side the model ran at, pixels.
    pub resolution: u32,
    /// Target views scored per subject.
    pub views_per_subject: usize,
}

impl Evaluation {
    /// The evaluation as pretty JSON (NaN and infinities as `null`).
    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).expect("an evaluation serialises")
    }

    /// A Markdown report: the means, the subjects, the angle bins and the grids. `title`
    /// names what was evaluated.
    pub fn to_markdown(&self, title: &str) -> String {
        let mut md = String::new();
        let _ = writeln!(md, "# Evaluation of {title}\n");
        let _ = writeln!(
            md,
            "{} test subjects, source view 0, {} target views each, at {} x {} px. Means per \
             subject, then over the subjects.\n",
            self.subjects.len(),
            self.views_per_subject,
            self.resolution,
            self.resolution
        );
        let _ = writeln!(md, "| PSNR (dB) | SSIM | LPIPS | FPS |");
        let _ = writeln!(md, "|---:|---:|---:|---:|");
        let _ = writeln!(
            md,
            "| {:.3} | {:.4} | {:.4} | {:.1} |\n",
            self.psnr, self.ssim, self.lpips, self.fps
        );
        let _ = writeln!(md, "## Subjects\n");
        let _ = writeln!(md, "| subject | views | PSNR (dB) | SSIM | LPIPS |");
        let _ = writeln!(md, "|---|---:|---:|---:|---:|");
        for (name, s) in &self.subjects {
            let _ = writeln!(
                md,
                "| {name} | {} | {:.3} | {:.4} | {:.4} |",
                s.views, s.psnr, s.ssim, s.lpips
            );
        }
        for (axis, bins) in [
            ("yaw", &self.per_angle.yaw),
            ("pitch", &self.per_angle.pitch),
        ] {
            let _ = writeln!(md, "\n## By |{axis}|\n");
            let _ = writeln!(md, "| abs({axis}) | views | PSNR (dB) | SSIM | LPIPS |");
            let _ = writeln!(md, "|---|---:|---:|---:|---:|");
            for b in bins {
                let _ = writeln!(
                    md,
                    "| {:.0}-{:.0} deg | {} | {:.3} | {:.4} | {:.4} |",
                    b.from_deg, b.to_deg, b.views, b.psnr, b.ssim, b.lpips
                );
            }
        }
        let grids: Vec<_> = self
            .subjects
            .iter()
            .filter_map(|(n, s)| s.grid.as_ref().map(|g| (n, g)))
            .collect();
        if !grids.is_empty() {
            let _ = writeln!(
                md,
                "\n## Samples\n\nColumns: source, prediction, ground truth, error map (mean \
                 absolute error, black 0, white {} and above).\n",
                crate::images::ERROR_MAP_FULL_SCALE
            );
            for (name, grid) in grids {
                let _ = writeln!(md, "### {name}\n\n![{name}]({grid})\n");
            }
        }
        md
    }
}

/// One scored (source, target) pair.
#[derive(Clone, Copy, Debug)]
struct PairScore {
    subject: usize,
    yaw_deg: f32,
    pitch_deg: f32,
    scores: [f64; 3],
}

/// Evaluates `model` on the test split of the dataset opened by `reader`, at the model's
/// `resolution`, on `device` (an inference device). With `out`, writes `evaluation.json`,
/// `report.md` (titled `title`) and `grids/SUBJECT.png` there.
///
/// `lpips` is `None` (LPIPS reported as NaN) below LPIPS's 31 px minimum.
///
/// # Errors
/// A dataset without test subjects, unreadable dataset files, or output that cannot be
/// written.
#[allow(clippy::too_many_arguments)]
pub fn evaluate(
    model: &Prism,
    reader: &DatasetReader,
    resolution: u32,
    lpips: Option<&Lpips>,
    device: &Device,
    options: &EvaluateOptions,
    out: Option<&Path>,
    title: &str,
) -> Result<Evaluation> {
    let model = nvs_model(model);
    let background = reader.meta().background;
    let dataset = SampleDataset::new(
        reader.clone(),
        SplitKind::Test,
        TargetSelection::Evaluation { per_sample: 1 },
        Some((resolution, resolution)),
        0,
    )?;
    let views = validation_views(options.views_per_subject);
    let lpips = lpips.filter(|_| resolution as usize >= LPIPS_MIN_SIDE);
    let subjects = dataset.subjects().to_vec();
    let bar = progress_bar(
        options.progress,
        (subjects.len() * views.len()) as u64,
        "evaluating",
    );
    if let Some(out) = out {
        std::fs::create_dir_all(out.join(GRIDS_DIR)).map_err(|e| TrainError::io(out, e))?;
    }
    let grid_views: Vec<usize> = validation_views(options.grid_views.min(views.len()))
        .into_iter()
        .filter(|_| options.grid_views > 0)
        .collect();
    let mut pairs: Vec<PairScore> = Vec::new();
    let mut grids: BTreeMap<String, String> = BTreeMap::new();
    let mut first_pair: Option<Pairs> = None;
    for (s, name) in subjects.iter().enumerate() {
        let mut grid_rows: Vec<Vec<RgbImage>> = Vec::new();
        for chunk in views.chunks(EVAL_BATCH) {
            // With one target per item, item `s * 100 + v - 1` is view `v` of subject `s`.
            let samples: Vec<Sample> = chunk
                .iter()
                .map(|&v| dataset.load(s * 100 + v - 1))
                .collect::<std::result::Result<_, _>>()?;
            let batch = PrismBatcher.batch_samples(&samples, device);
            let batch_pairs = Pairs::of_batch(&batch, background);
            if first_pair.is_none() {
                first_pair = Some(batch_pairs.slice(0, 1));
            }
            let pred = synthesise(&model, &batch_pairs);
            let gt = batch.target_image.clone();
            let scores = score(pred.clone(), gt.clone(), lpips);
            for (info, scores) in batch.pairs.iter().zip(scores) {
                pairs.push(PairScore {
                    subject: s,
                    yaw_deg: info.yaw_deg,
                    pitch_deg: info.pitch_deg,
                    scores,
                });
            }
            if out.is_some() {
                let wanted: Vec<usize> = chunk
                    .iter()
                    .enumerate()
                    .filter(|(_, v)| grid_views.contains(v))
                    .map(|(i, _)| i)
                    .collect();
                if !wanted.is_empty() {
                    let src = HostImages::from_tensor(batch.source_image.clone());
                    let p = HostImages::from_tensor(pred);
                    let g = HostImages::from_tensor(gt);
                    for i in wanted {
                        grid_rows.push(vec![
                            src.rgb8(i),
                            p.rgb8(i),
                            g.rgb8(i),
                            error_map(&p.images[i], &g.images[i], p.width, p.height),
                        ]);
                    }
                }
            }
            bar.inc(chunk.len() as u64);
        }
        if let Some(out) = out
            && !grid_rows.is_empty()
        {
            let relative = format!("{GRIDS_DIR}/{}.png", file_safe(name));
            save_png(&out.join(&relative), &tile(&grid_rows))?;
            grids.insert(name.clone(), relative);
        }
    }
    bar.finish_and_clear();
    let fps = match &first_pair {
        Some(pair) => measure_fps(&model, pair, options.fps_runs).0,
        None => f64::NAN,
    };
    let mut subject_scores = BTreeMap::new();
    for (s, name) in subjects.iter().enumerate() {
        let rows: Vec<[f64; 3]> = pairs
            .iter()
            .filter(|p| p.subject == s)
            .map(|p| p.scores)
            .collect();
        let [psnr, ssim, lpips] = mean_rows(&rows);
        subject_scores.insert(
            name.clone(),
            SubjectScores {
                psnr,
                ssim,
                lpips,
                views: rows.len(),
                grid: grids.get(name).cloned(),
            },
        );
    }
    let means: Vec<[f64; 3]> = subject_scores
        .values()
        .map(|s| [s.psnr, s.ssim, s.lpips])
        .collect();
    let [psnr, ssim, lpips] = mean_rows(&means);
    let evaluation = Evaluation {
        psnr,
        ssim,
        lpips,
        fps,
        subjects: subject_scores,
        per_angle: PerAngle {
            yaw: angle_bins(&pairs, |p| p.yaw_deg),
            pitch: angle_bins(&pairs, |p| p.pitch_deg),
        },
        resolution,
        views_per_subject: views.len(),
    };
    if let Some(out) = out {
        save_text(&out.join(EVALUATION_JSON), &evaluation.to_json())?;
        save_text(&out.join(REPORT_MD), &evaluation.to_markdown(title))?;
    }
    Ok(evaluation)
}

/// The frame rate of `model`'s forward pass on the first pair of `pairs` (batch 1): two
/// warm-up passes are not timed, then at least `runs` passes and until one second has passed;
/// each pass ends when its output image is back on the host. Returns (frames per second,
/// timed passes). Data loading is not included.
pub fn measure_fps(model: &Prism, pairs: &Pairs, runs: usize) -> (f64, usize) {
    let one = pairs.slice(0, 1);
    let pass = || {
        let image = synthesise(model, &one);
        let _host = image.into_data().convert::<f32>().try_into_vec::<f32>();
    };
    pass();
    pass();
    let start = Instant::now();
    let mut done = 0;
    while done < runs.max(1) || start.elapsed().as_secs_f64() < 1.0 {
        pass();
        done += 1;
    }
    (done as f64 / start.elapsed().as_secs_f64(), done)
}

/// PSNR, SSIM and LPIPS of each pair of a batch (LPIPS NaN without `lpips`).
fn score(pred: Tensor<4>, gt: Tensor<4>, lpips: Option<&Lpips>) -> Vec<[f64; 3]> {
    let p = psnr(pred.clone(), gt.clone());
    let s = ssim(pred.clone(), gt.clone());
    let l = match lpips {
        Some(lpips) => lpips.distance(pred, gt),
        None => vec![f64::NAN; p.len()],
    };
    (0..p.len()).map(|i| [p[i], s[i], l[i]]).collect()
}

/// The mean of each column (NaN for no rows).
fn mean_rows(rows: &[[f64; 3]]) -> [f64; 3] {
    let n = rows.len() as f64;
    let mut out = [0.0; 3];
    for r in rows {
        for (o, v) in out.iter_mut().zip(r) {
            *o += v / n;
        }
    }
    if rows.is_empty() { [f64::NAN; 3] } else { out }
}

/// [`ANGLE_BIN_DEG`]-wide bins of `|angle(p)|` from 0 up to the largest angle present (the
/// protocol's 30 degrees give 0-10, 10-20, 20-30); a value on a bin edge goes to the upper bin,
/// except the last edge.
fn angle_bins(pairs: &[PairScore], angle: impl Fn(&PairScore) -> f32) -> Vec<AngleBin> {
    let max = pairs.iter().map(|p| angle(p).abs()).fold(0.0f32, f32::max);
    let count = ((max / ANGLE_BIN_DEG).ceil() as usize).max(1);
    let mut rows: Vec<Vec<[f64; 3]>> = vec![Vec::new(); count];
    for p in pairs {
        let bin = ((angle(p).abs() / ANGLE_BIN_DEG) as usize).min(count - 1);
        rows[bin].push(p.scores);
    }
    rows.iter()
        .enumerate()
        .map(|(i, r)| {
            let [psnr, ssim, lpips] = mean_rows(r);
            AngleBin {
                from_deg: i as f32 * ANGLE_BIN_DEG,
                to_deg: (i + 1) as f32 * ANGLE_BIN_DEG,
                views: r.len(),
                psnr,
                ssim,
                lpips,
            }
        })
        .collect()
}

/// A progress bar on stderr (hidden without `show`).
pub fn progress_bar(show: bool, len: u64, what: &str) -> ProgressBar {
    let target = if show {
        ProgressDrawTarget::stderr()
    } else {
        ProgressDrawTarget::hidden()
    };
    ProgressBar::with_draw_target(Some(len), target).with_style(
        ProgressStyle::with_template(&format!(
            "{what} [{{bar:30}}] {{pos}}/{{len}} (ETA {{eta}})"
        ))
        .expect("valid template"),
    )
}

/// `name` with every character but letters, digits, `-`, `_` and `.` replaced by `_`.
fn file_safe(name: &str) -> String {
    name.chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || "-_.".contains(c) {
                c
            } else {
                '_'
            }
        })
        .collect()
}

/// The default output folder of an evaluation of `checkpoint` (a run or checkpoint folder):
/// `evaluation/` inside it.
pub fn default_out(checkpoint: &Path) -> PathBuf {
    checkpoint.join("evaluation")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pair(yaw: f32, pitch: f32, psnr: f64) -> PairScore {
        PairScore {
            subject: 0,
            yaw_deg: yaw,
            pitch_deg: pitch,
            scores: [psnr, 0.5, 0.1],
        }
    }

    #[test]
    fn angle_bins_split_abs_angles_in_ten_degree_bins() {
        let pairs = [
            pair(-5.0, 25.0, 10.0),
            pair(9.9, -12.0, 20.0),
            pair(-10.0, 0.0, 30.0),
            pair(30.0, -30.0, 40.0),
        ];
        let yaw = angle_bins(&pairs, |p| p.yaw_deg);
        assert_eq!(yaw.len(), 3);
        assert_eq!(
            yaw.iter().map(|b| b.views).collect::<Vec<_>>(),
            vec![2, 1, 1]
        );
        assert_eq!(yaw[0].psnr, 15.0);
        assert_eq!(yaw[1].psnr, 30.0);
        assert_eq!(yaw[2].psnr, 40.0);
        assert_eq!((yaw[2].from_deg, yaw[2].to_deg), (20.0, 30.0));
        let pitch = angle_bins(&pairs, |p| p.pitch_deg);
        assert_eq!(
            pitch.iter().map(|b| b.views).collect::<Vec<_>>(),
            vec![1, 1, 2]
        );
        assert!(angle_bins(&pairs[..1], |p| p.yaw_deg)[0].views == 1);
    }

    #[test]
    fn mean_rows_is_columnwise_and_nan_when_empty() {
        assert_eq!(
            mean_rows(&[[1.0, 2.0, 3.0], [3.0, 4.0, 5.0]]),
            [2.0, 3.0, 4.0]
        );
        assert!(mean_rows(&[]).iter().all(|v| v.is_nan()));
    }

    #[test]
    fn file_safe_keeps_plain_names() {
        assert_eq!(file_safe("subject-007_a.b"), "subject-007_a.b");
        assert_eq!(file_safe("a b/c"), "a_b_c");
    }
}
