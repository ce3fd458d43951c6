//! `prism evaluate`: the paper's evaluation protocol on the test subjects of a dataset.
//!
//! For every test subject the frontal view 0 is the source and views 1..=100 the targets; PSNR,
//! SSIM and LPIPS are averaged over each subject's views, then over the subjects. The same
//! scores are also pooled by view angle (10-degree bins of |yaw| and of |pitch|), and the
//! model's forward pass is timed on one (source, target) pair.
//!
//! Every score comes with the same scores, on the same views, of the "copy the source view"
//! baseline (view 0 taken as the prediction of every target view), and, for a model with a 3DGS
//! head, of its render `I_gs`. Each method is also scored in the disoccluded region of every
//! view (the target's foreground that the source does not see, where a warp has nothing to
//! copy; `prism_data::Sample::disoccluded_region`).
//!
//! Every method also gets a speckle score ([`prism_losses::speckle`]): its mean absolute
//! Laplacian over the truth's where the truth is smooth, on the target's foreground. The
//! true-depth warp's footprint is chosen on training subjects ([`pick_warp_footprint`]), never
//! on the views it is scored on, except in a test-only dataset (scans from another domain),
//! where it is chosen on the test subjects and the report says so. With
//! [`EvaluateOptions::oracle`], the 3DGS head's Gaussians are also drawn with one property at
//! a time taken from the truth ([`crate::oracle`]).

use std::collections::BTreeMap;
use std::fs;
use std::path::{Path, PathBuf};
use std::time::Instant;

use burn::tensor::{Device, Tensor};
use image::RgbImage;
use indicatif::ProgressBar;
use prism_core::BackendKind;
use prism_core::protocol::EVAL_TARGETS;
use prism_data::{
    DatasetReader, PrismBatcher, RegionMethod, Sample, SampleDataset, SplitKind, TargetSelection,
};
use prism_losses::{ImageScores, Lpips, SpeckleSums, psnr};
use prism_model::{Precision, Prism};
use serde::Serialize;

use crate::baselines::{BaselineCache, BaselineKey, Baselines};
use crate::checkpoint::{CHECKPOINTS_DIR, load_inference_model};
use crate::chunk_scores::{ChunkScorer, MethodBatch, all_at_once, chunks_at_once};
use crate::error::{Result, TrainError};
use crate::images::{error_map, save_png, tile};
use crate::log::METRICS_FILE;
use crate::oracle::{DepthError, Swap};
use crate::predict::{Pairs, inference_model, synthesise};
use crate::report::{EvaluationFiles, write_evaluation};
use crate::tally::{DisoccludedScores, MeanScores, MethodScores, PerAngle, Tally};
use crate::validate::validation_views;
use crate::warp::{WARP_FOOTPRINTS, true_depth_warp};
use prism_model::GsColour;

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
    /// The precision of the transformer blocks (their weights stored in it, see
    /// [`Prism::with_block_precision`]); the rest of the model computes in f32.
    pub precision: Precision,
    /// Also score the oracle swaps of [`crate::oracle`] (a diagnostic; needs a 3DGS head with
    /// colour Gaussians and a dataset with point maps).
    pub oracle: bool,
    /// The baselines' scores of the last evaluation with these options (or a clone of them),
    /// reused by the next one on the same views: they do not depend on the model.
    pub baselines: BaselineCache,
    /// Batches of views predicted and scored at once (`None`: two on a CPU device, where one
    /// fills the other's single-threaded stretches, one on a GPU). The scores are the same
    /// whatever it is.
    pub at_once: Option<usize>,
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
            precision: Precision::F32,
            oracle: false,
            baselines: BaselineCache::default(),
            at_once: None,
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
    /// The model's scores in the disoccluded region (`psnr_disoccluded`, `ssim_disoccluded`,
    /// `lpips_disoccluded` in the JSON), and `psnr_region_filled`: its overall PSNR with the
    /// region taken from the ground truth.
    #[serde(flatten)]
    pub disoccluded: Option<DisoccludedScores>,
    /// How the disoccluded regions were found (`disoccluded_by` in the JSON): by the depth
    /// test, or estimated for a dataset without depth maps (when any view lacked one).
    pub disoccluded_by: RegionMethod,
    /// Image side of the evaluation, pixels (the model's resolution).
    pub resolution: u32,
    /// Target views per subject.
    pub views_per_subject: usize,
    /// The "copy the source view" baseline on the same views: the source (view 0) taken as the
    /// prediction of every target view. A model that does not beat it has learnt nothing about
    /// other viewpoints.
    pub copy_source: MethodScores,
    /// The true-depth warp baseline on the same views (`true_depth_warp` in the JSON): the
    /// source's pixels as Gaussians at the dataset's own 3D points ([`crate::warp`]), at the
    /// footprint of [`WARP_FOOTPRINTS`] with the best mean PSNR on training subjects.
    pub true_depth_warp: MethodScores,
    /// The footprint (source pixels) of the reported true-depth warp.
    pub true_depth_warp_footprint: f32,
    /// Every footprint the warp was rendered at on the subjects that chose it
    /// ([`pick_warp_footprint`]), with its mean PSNR (dB) there.
    pub true_depth_warp_sweep: Vec<FootprintPsnr>,
    /// The split those subjects came from: `train`, or `test` in a dataset without training
    /// subjects (the baseline then tuned on the views it is scored on, so at its best).
    pub true_depth_warp_chosen_on: SplitKind,
    /// The speckle score of each method ([`prism_losses::speckle`]).
    pub speckle: SpeckleScores,
    /// The oracle swaps' scores, when asked for ([`EvaluateOptions::oracle`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub oracle: Option<Vec<OracleScores>>,
    /// With the oracle swaps: the 3DGS head's depth error over the source foreground, the
    /// error the depth swap removes ([`OracleBatch::depth_errors`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub depth_error: Option<DepthError>,
    /// The 3DGS head's render `I_gs` (over the background) on the same views, from a forward
    /// pass with the head; `None` (absent from the JSON) for a model without a 3DGS head.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub gs: Option<MethodScores>,
}

impl Evaluation {
    /// The model's means over the subjects.
    pub fn mean(&self) -> ImageScores {
        ImageScores {
            psnr: self.psnr,
            ssim: self.ssim,
            lpips: self.lpips,
        }
    }
}

/// Each method's speckle score: its mean absolute Laplacian over the truth's, on the pixels
/// where the truth is smooth (inside the target's foreground); 1 is as smooth as the truth.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct SpeckleScores {
    /// The truth's own mean absolute Laplacian on those pixels (the score's denominator).
    pub truth_laplacian: f64,
    /// The model's NVS decoder `I_t`.
    pub model: f64,
    /// The 3DGS head's render `I_gs` (`None` without the head).
    pub gs: Option<f64>,
    /// The copy of the source view.
    pub copy_source: f64,
    /// The true-depth warp.
    pub true_depth_warp: f64,
}

/// One oracle swap's scores: its render `I_gs` and the `I_t` the NVS decoder makes of it.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct OracleScores {
    /// What was swapped.
    pub swap: Swap,
    /// The swapped render.
    pub gs: MethodScores,
    /// The NVS decoder's output on the swapped render.
    pub nvs: MethodScores,
    /// Speckle scores of `gs` and `nvs`.
    pub gs_speckle: f64,
    /// See `gs_speckle`.
    pub nvs_speckle: f64,
}

/// A method's tallies: its scores and its speckle sums.
#[derive(Clone, Default)]
pub(crate) struct MethodTally {
    scores: Tally,
    speckle: SpeckleSums,
}

impl MethodTally {
    /// Adds a chunk's scores of `samples`' views (chunks added in their order give the
    /// tallies of the views scored one chunk after another).
    fn add(&mut self, samples: &[Sample], batch: MethodBatch) {
        self.scores.add_batch(samples, &batch.full);
        self.scores
            .add_disoccluded(samples, &batch.region, &batch.filled);
        for sums in batch.speckle {
            self.speckle.add(sums);
        }
    }
}

/// The true-depth warp's mean PSNR at one footprint.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct FootprintPsnr {
    /// Size of the warp's Gaussians, in source pixels.
    pub footprint: f32,
    /// Mean PSNR in dB, averaged like the model's.
    pub psnr: f64,
}

/// One subject's sample grid: per row source | prediction | ground truth | error map.
#[derive(Clone, Debug)]
pub struct SubjectGrid {
    /// The subject's folder name.
    pub subject: String,
    /// The grid.
    pub image: RgbImage,
}

/// Evaluates a checkpoint (a checkpoint folder or a run folder's latest) on the dataset at
/// `data` on `backend`, its blocks in `options.precision`, and writes the JSON, the report and
/// the grids into `out`.
///
/// # Errors
/// An unreadable checkpoint, dataset or LPIPS weight file, a precision the backend cannot
/// compute in, or I/O errors.
pub fn evaluate_checkpoint(
    checkpoint: &Path,
    data: &Path,
    out: &Path,
    backend: BackendKind,
    lpips_weights: Option<&Path>,
    options: &EvaluateOptions,
) -> Result<(Evaluation, EvaluationFiles)> {
    let device = backend.device()?;
    let precision = options.precision;
    let (model, config) = load_inference_model(checkpoint, backend, &device, precision)?;
    let data_dir = data.to_path_buf();
    let reader = DatasetReader::open(&data_dir)?;
    let lpips = Lpips::load_default(lpips_weights, &device)?;
    let resolution = config.model.resolution as u32;
    let (evaluation, grids) =
        evaluate(&model, &reader, resolution, Some(&lpips), &device, options)?;
    let title = format!(
        "{} on {} ({backend}, blocks in {precision})",
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
/// A dataset without test or training subjects, unreadable files, or `options.oracle` for a
/// model without colour Gaussians.
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
    if options.oracle
        && model
            .gs_head
            .as_ref()
            .is_none_or(|head| head.colour() == GsColour::Flow)
    {
        return Err(TrainError::Input(
            "the oracle swaps need a model whose 3DGS head draws colour Gaussians (gs_head = \
             true, gs_colour \"regressed\" or \"source\")"
                .into(),
        ));
    }
    let dataset = SampleDataset::new(
        reader.clone(),
        SplitKind::Test,
        TargetSelection::Evaluation { per_sample: 1 },
        Some((resolution, resolution)),
        0,
    )?
    .with_depth();
    let mut disoccluded_by = RegionMethod::DepthTest;
    let background = reader.meta().background;
    let views = validation_views(options.views);
    let batch_size = options.batch.max(1);
    let key = BaselineKey::new(
        reader.root(),
        resolution,
        &views,
        batch_size,
        lpips.map(Lpips::digest),
    );
    let kept = options.baselines.get(&key);
    let (true_depth_warp_sweep, true_depth_warp_chosen_on) = match &kept {
        Some(baselines) => (baselines.sweep.clone(), baselines.chosen_on),
        None => pick_warp_footprint(reader, resolution, device)?,
    };
    let footprint = best_footprint(&true_depth_warp_sweep);
    let grid_views: Vec<usize> = validation_views(options.grid_views.min(views.len()))
        .into_iter()
        .map(|v| views[(v - 1) * views.len() / 100])
        .collect();
    let subjects = dataset.subjects().to_vec();
    let bar = progress_bar(options.progress, (subjects.len() * views.len()) as u64);
    let mut nvs = MethodTally::default();
    let mut copy = MethodTally::default();
    let mut gs = MethodTally::default();
    let mut warp = MethodTally::default();
    let mut oracle: Vec<[MethodTally; 2]> = if options.oracle {
        Swap::ALL.iter().map(|_| Default::default()).collect()
    } else {
        Vec::new()
    };
    let mut depth_errors: Vec<f32> = Vec::new();
    let mut grids = Vec::new();
    let mut grid_rows = Vec::new();
    let mut fps_pair = None;
    let chunks = ChunkScorer {
        model: if has_gs { model } else { &fast },
        dataset: &dataset,
        background,
        footprint,
        baselines: kept.is_none(),
        oracle: options.oracle,
        lpips,
        device,
    };
    // Each subject's views in chunks of `batch_size`, in order.
    let jobs: Vec<(usize, &[usize])> = (0..subjects.len())
        .flat_map(|s| views.chunks(batch_size).map(move |chunk| (s, chunk)))
        .collect();
    let at_once = options.at_once.unwrap_or_else(|| chunks_at_once(device));
    for group in jobs.chunks(at_once.max(1)) {
        bar.set_message(subjects[group[0].0].clone());
        let results = all_at_once(group, |&(s, chunk)| chunks.score(s, chunk));
        for (&(s, chunk), result) in group.iter().zip(results) {
            let result = result?;
            let samples = &result.samples;
            if let Some(method) = result.disoccluded_by {
                disoccluded_by = method;
            }
            fps_pair.get_or_insert(result.first_pair);
            nvs.add(samples, result.nvs);
            if let Some(batch) = result.gs {
                gs.add(samples, batch);
            }
            if let Some([warped, copied]) = result.baselines {
                warp.add(samples, warped);
                copy.add(samples, copied);
            }
            for (tallies, batches) in oracle.iter_mut().zip(result.oracle) {
                let [gs_tally, nvs_tally] = tallies;
                let [gs_batch, nvs_batch] = batches;
                gs_tally.add(samples, gs_batch);
                nvs_tally.add(samples, nvs_batch);
            }
            depth_errors.extend(result.depth_errors);
            let predictions_dir = options
                .save_predictions
                .as_ref()
                .map(|d| d.join(&subjects[s]));
            if let Some(dir) = &predictions_dir {
                fs::create_dir_all(dir).map_err(|e| TrainError::io(dir, e))?;
            }
            let (pred, src, gt) = (&result.pred, &result.source, &result.truth);
            for (i, sample) in samples.iter().enumerate() {
                let target = &sample.targets[0];
                if let Some(dir) = &predictions_dir {
                    let path = dir.join(format!("{:03}.png", target.index));
                    save_png(&path, &pred.rgb8(i))?;
                }
                if grid_views.contains(&target.index) {
                    let (w, h) = (pred.width, pred.height);
                    grid_rows.push(vec![
                        src.rgb8(i),
                        pred.rgb8(i),
                        gt.rgb8(i),
                        error_map(&pred.images[i], &gt.images[i], w, h),
                    ]);
                }
            }
            bar.inc(chunk.len() as u64);
            if chunk.last() == views.last() {
                grids.push(SubjectGrid {
                    subject: subjects[s].clone(),
                    image: tile(&std::mem::take(&mut grid_rows)),
                });
            }
        }
    }
    bar.finish_and_clear();
    let Baselines { copy, warp, .. } = match kept {
        Some(baselines) => baselines,
        None => {
            let baselines = Baselines {
                copy,
                warp,
                sweep: true_depth_warp_sweep.clone(),
                chosen_on: true_depth_warp_chosen_on,
            };
            options.baselines.put(key, baselines.clone());
            baselines
        }
    };
    let fps = match fps_pair {
        Some(pair) => forward_fps(&fast, &pair, options.fps_runs.max(1)),
        None => f64::NAN,
    };
    let speckle = SpeckleScores {
        truth_laplacian: nvs.speckle.truth_mean(),
        model: nvs.speckle.score(),
        gs: has_gs.then(|| gs.speckle.score()),
        copy_source: copy.speckle.score(),
        true_depth_warp: warp.speckle.score(),
    };
    let oracle = options.oracle.then(|| {
        oracle
            .into_iter()
            .zip(Swap::ALL)
            .map(|([gs, nvs], swap)| OracleScores {
                swap,
                gs_speckle: gs.speckle.score(),
                nvs_speckle: nvs.speckle.score(),
                gs: gs.scores.finish(),
                nvs: nvs.scores.finish(),
            })
            .collect()
    });
    let nvs = nvs.scores.finish();
    Ok((
        Evaluation {
            psnr: nvs.psnr,
            ssim: nvs.ssim,
            lpips: nvs.lpips,
            fps,
            subjects: nvs.subjects,
            per_angle: nvs.per_angle,
            disoccluded: nvs.disoccluded,
            disoccluded_by,
            resolution,
            views_per_subject: views.len(),
            copy_source: copy.scores.finish(),
            true_depth_warp: warp.scores.finish(),
            true_depth_warp_footprint: footprint,
            true_depth_warp_sweep,
            true_depth_warp_chosen_on,
            speckle,
            oracle,
            depth_error: DepthError::of(&depth_errors),
            gs: has_gs.then(|| gs.scores.finish()),
        },
        grids,
    ))
}

/// Training subjects the true-depth warp's footprint is chosen on.
pub const WARP_SELECTION_SUBJECTS: usize = 3;
/// Target views per training subject the footprint is chosen on.
pub const WARP_SELECTION_VIEWS: usize = 10;

/// The true-depth warp's mean PSNR at each of [`WARP_FOOTPRINTS`] on the first
/// [`WARP_SELECTION_SUBJECTS`] training subjects ([`WARP_SELECTION_VIEWS`] evaluation views
/// each): the warp is a baseline tuned like a model, on data it is not scored on. A dataset
/// with no training subjects (a test-only one) has it chosen on its test subjects instead;
/// the split used is returned with the sweep.
///
/// # Errors
/// A dataset without subjects, or unreadable files.
pub fn pick_warp_footprint(
    reader: &DatasetReader,
    resolution: u32,
    device: &Device,
) -> Result<(Vec<FootprintPsnr>, SplitKind)> {
    let split = if reader.meta().subjects_of(SplitKind::Train).is_empty() {
        SplitKind::Test
    } else {
        SplitKind::Train
    };
    let dataset = SampleDataset::new(
        reader.clone(),
        split,
        TargetSelection::Evaluation { per_sample: 1 },
        Some((resolution, resolution)),
        0,
    )?;
    let background = reader.meta().background;
    let subjects = dataset.subjects().len().min(WARP_SELECTION_SUBJECTS);
    let samples = (0..subjects)
        .flat_map(|s| {
            validation_views(WARP_SELECTION_VIEWS)
                .into_iter()
                .map(move |v| s * 100 + v - 1)
        })
        .map(|i| dataset.load(i))
        .collect::<std::result::Result<Vec<Sample>, _>>()?;
    let gt = PrismBatcher.batch_samples(&samples, device).target_image;
    let sweep = WARP_FOOTPRINTS
        .iter()
        .map(|&footprint| {
            let warp = true_depth_warp(&samples, background, footprint, device);
            let values = psnr(warp, gt.clone());
            FootprintPsnr {
                footprint,
                psnr: values.iter().sum::<f64>() / values.len() as f64,
            }
        })
        .collect();
    Ok((sweep, split))
}

/// The footprint of the sweep's best mean PSNR.
fn best_footprint(sweep: &[FootprintPsnr]) -> f32 {
    sweep
        .iter()
        .max_by(|a, b| a.psnr.total_cmp(&b.psnr))
        .expect("at least one footprint")
        .footprint
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

fn progress_bar(show: bool, len: u64) -> ProgressBar {
    prism_core::progress::progress_bar(
        show,
        len,
        "evaluating [{bar:30}] {pos}/{len} views {msg} (ETA {eta})",
    )
}
