//! One chunk of an evaluation: a subject's views in one batch, predicted and scored by every
//! method, with nothing written anywhere, so that chunks can run at once and be tallied in
//! their order afterwards ([`crate::evaluate`]).
//!
//! On a CPU device two chunks run at once on rayon's pool: while one is in a stretch that a
//! single thread computes (Burn's element-wise ops, a small product, the host-side scores),
//! the other's kernels have the second core, as training's two shares do. Each chunk's values
//! do not depend on what runs beside it, so the evaluation gives the same scores either way.
//! Validation during training runs its batches the same way ([`crate::validate`]).

use std::time::Instant;

use burn::tensor::{Device, Tensor, TensorData};
use prism_core::images::HostImages;
use prism_core::phases::{PhaseTimes, credit, recorded};
use prism_data::{PrismBatcher, RegionMethod, Sample, SampleDataset};
use prism_losses::{
    GroundTruth, ImageScores, Lpips, SpeckleSums, psnr_region_filled, score_whole_and_region,
    speckle_sums,
};
use prism_model::Prism;
use rayon::prelude::*;

use crate::error::Result;
use crate::oracle::{OracleBatch, Swap, draw};
use crate::predict::{Pairs, forward_pairs};
use crate::warp::true_depth_warp;

/// Chunks an evaluation computes at once on `device`: two on a CPU backend's device, one on a
/// GPU (whose kernels are already queued one after another).
pub(crate) fn chunks_at_once(device: &Device) -> usize {
    if prism_core::backend::is_cpu_device(device) {
        2
    } else {
        1
    }
}

/// `work` on every item of `group` at once on rayon's pool; the results in `group`'s order.
///
/// The phase times each item's work recorded on whatever thread ran it (LPIPS) are credited to
/// the calling thread, scaled by the share of the group's wall time that item had: two items
/// that each ran through the whole group's time, side by side, count half of their own times.
/// So the phase timings stay shares of the wall time.
pub(crate) fn all_at_once<I: Sync, T: Send>(group: &[I], work: impl Fn(&I) -> T + Sync) -> Vec<T> {
    let start = Instant::now();
    let results: Vec<(T, PhaseTimes, f64)> = group
        .par_iter()
        .map(|item| {
            let began = Instant::now();
            let (out, times) = recorded(|| work(item));
            (out, times, began.elapsed().as_secs_f64())
        })
        .collect();
    let busy: f64 = results.iter().map(|r| r.2).sum();
    let share = if busy > 0.0 {
        (start.elapsed().as_secs_f64() / busy).min(1.0)
    } else {
        1.0
    };
    results
        .into_iter()
        .map(|(out, times, _)| {
            credit(&times.scaled(share));
            out
        })
        .collect()
}

/// One method's scores of a chunk's views, in the views' order.
pub(crate) struct MethodBatch {
    /// Over the whole image.
    pub full: Vec<ImageScores>,
    /// In each view's disoccluded region.
    pub region: Vec<ImageScores>,
    /// PSNR with the region taken from the truth.
    pub filled: Vec<f64>,
    /// Each view's speckle sums.
    pub speckle: Vec<SpeckleSums>,
}

/// What one chunk gives: its samples, each method's scores and the images the evaluation
/// writes.
pub(crate) struct ChunkScores {
    /// The chunk's samples (subject, view, target angles).
    pub samples: Vec<Sample>,
    /// The first pair, for timing the forward pass.
    pub first_pair: Pairs,
    /// `Some(RegionMethod::Estimate)` when a sample had no depth maps.
    pub disoccluded_by: Option<RegionMethod>,
    /// The model's `I_t`.
    pub nvs: MethodBatch,
    /// The 3DGS head's `I_gs`, for a model with one.
    pub gs: Option<MethodBatch>,
    /// The true-depth warp and the copy of the source, when asked for.
    pub baselines: Option<[MethodBatch; 2]>,
    /// Per oracle swap, its render and its `I_t` (empty unless asked for).
    pub oracle: Vec<[MethodBatch; 2]>,
    /// The 3DGS head's depth errors, with the oracle swaps.
    pub depth_errors: Vec<f32>,
    /// The predictions, sources and truths on the host.
    pub pred: HostImages,
    /// See `pred`.
    pub source: HostImages,
    /// See `pred`.
    pub truth: HostImages,
}

/// What every chunk of one evaluation shares.
pub(crate) struct ChunkScorer<'a> {
    /// The model that predicts (with its 3DGS head where it has one).
    pub model: &'a Prism,
    /// The test split, one evaluation target per sample.
    pub dataset: &'a SampleDataset,
    /// The dataset's background colour.
    pub background: [f32; 3],
    /// The true-depth warp's footprint.
    pub footprint: f32,
    /// Whether to score the baselines (not kept from an earlier evaluation).
    pub baselines: bool,
    /// Whether to score the oracle swaps.
    pub oracle: bool,
    /// The LPIPS network, when LPIPS is measured.
    pub lpips: Option<&'a Lpips>,
    /// The device everything computes on.
    pub device: &'a Device,
}

impl ChunkScorer<'_> {
    /// Predicts and scores `views` (1-based) of subject `subject`.
    pub fn score(&self, subject: usize, views: &[usize]) -> Result<ChunkScores> {
        let samples = views
            .iter()
            .map(|&v| self.dataset.load(subject * 100 + v - 1))
            .collect::<std::result::Result<Vec<Sample>, _>>()?;
        let batch = PrismBatcher.batch_samples(&samples, self.device);
        let pairs = Pairs::of_batch(&batch, self.background);
        let out = forward_pairs(self.model, &pairs);
        let gt = batch.target_image.clone();
        let (region, method) = disoccluded_regions(&samples, self.device);
        let truth = Truth {
            scores: GroundTruth::new(gt.clone(), self.lpips),
            host: HostImages::from_tensor(gt.clone()),
            masks: samples
                .iter()
                .map(|s| s.targets[0].mask.as_raw().as_slice())
                .collect(),
            region,
        };
        let (nvs, pred) = truth.score(out.image.clone().clamp(0.0, 1.0));
        let (baselines, source) = if self.baselines {
            let warped = true_depth_warp(&samples, self.background, self.footprint, self.device);
            let (warp, _) = truth.score(warped);
            let (copy, source) = truth.score(batch.source_image.clone());
            (Some([warp, copy]), source)
        } else {
            (None, HostImages::from_tensor(batch.source_image.clone()))
        };
        let mut gs = None;
        let mut oracle = Vec::new();
        let mut depth_errors = Vec::new();
        if let Some(g) = &out.gaussians {
            gs = Some(truth.score(g.image.clone().clamp(0.0, 1.0)).0);
            if self.oracle {
                let swaps = OracleBatch::new(&samples, &g.gaussians).with_surface(&g.surface);
                depth_errors = swaps.depth_errors();
                let [_, _, h, w] = gt.dims();
                for &swap in &Swap::ALL {
                    let swapped = swaps.swapped(swap, self.footprint, self.device);
                    let render = draw(&swapped, &samples, self.background, self.device);
                    let decoded =
                        self.model
                            .nvs_head
                            .forward(out.target_t_out(), h, w, Some(render.clone()));
                    oracle.push([
                        truth.score(render).0,
                        truth.score(decoded.clamp(0.0, 1.0)).0,
                    ]);
                }
            }
        }
        let disoccluded_by = (method == RegionMethod::Estimate).then_some(method);
        let first_pair = pairs.slice(0, 1);
        let truth = truth.host;
        Ok(ChunkScores {
            samples,
            first_pair,
            disoccluded_by,
            nvs,
            gs,
            baselines,
            oracle,
            depth_errors,
            pred,
            source,
            truth,
        })
    }
}

/// A chunk's truth, as each method is scored against it.
struct Truth<'a> {
    scores: GroundTruth<'a>,
    host: HostImages,
    /// Each target's foreground mask.
    masks: Vec<&'a [f32]>,
    /// The disoccluded regions, `[B, 1, H, W]`.
    region: Tensor<4>,
}

impl Truth<'_> {
    /// `image`'s scores, and `image` on the host.
    fn score(&self, image: Tensor<4>) -> (MethodBatch, HostImages) {
        let gt = self.scores.image.clone();
        let (full, region) =
            score_whole_and_region(image.clone(), &self.scores, self.region.clone());
        let filled = psnr_region_filled(image.clone(), gt, self.region.clone());
        let host = HostImages::from_tensor(image);
        let speckle = self
            .masks
            .iter()
            .enumerate()
            .map(|(i, mask)| {
                speckle_sums(
                    &host.images[i],
                    &self.host.images[i],
                    Some(mask),
                    host.width,
                    host.height,
                )
            })
            .collect();
        let batch = MethodBatch {
            full,
            region,
            filled,
            speckle,
        };
        (batch, host)
    }
}

/// The disoccluded region of each sample's (first) target view, `[B, 1, H, W]` on `device`,
/// and how it was found (the estimate when any sample lacked depth maps).
fn disoccluded_regions(samples: &[Sample], device: &Device) -> (Tensor<4>, RegionMethod) {
    let target = &samples[0].targets[0];
    let (w, h) = (target.mask.width() as usize, target.mask.height() as usize);
    let mut method = RegionMethod::DepthTest;
    let mut values = Vec::with_capacity(samples.len() * w * h);
    for sample in samples {
        let (region, by) = sample.disoccluded_region(0);
        if by == RegionMethod::Estimate {
            method = by;
        }
        values.extend(region.into_raw());
    }
    let region = Tensor::from_data(TensorData::new(values, [samples.len(), 1, h, w]), device);
    (region, method)
}

#[cfg(test)]
mod tests {
    use std::time::Duration;

    use prism_core::phases::{Phase, phase_totals, timed};

    use super::*;

    /// The results come in order, and the phase times credited never exceed the wall time,
    /// whether the items ran side by side or one after the other.
    #[test]
    fn items_run_at_once_credit_shares_of_the_wall_time() {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(2)
            .build()
            .unwrap();
        let (out, lpips, wall) = pool.install(|| {
            let before = phase_totals();
            let start = Instant::now();
            let out = all_at_once(&[3, 5], |&x| {
                timed(Phase::Lpips, || {
                    std::thread::sleep(Duration::from_millis(40));
                });
                x * 2
            });
            let wall = start.elapsed().as_secs_f64();
            (out, phase_totals().since(&before).get(Phase::Lpips), wall)
        });
        assert_eq!(out, [6, 10]);
        assert!(
            (0.04..=wall).contains(&lpips),
            "LPIPS {lpips} s in {wall} s"
        );
    }
}
