//! Validation during training: PSNR, SSIM and LPIPS of the model on held-out subjects, the
//! "copy the source view" baseline, and a PNG grid of sample predictions. The views are scored
//! and averaged as `prism evaluate` does ([`score_images`], [`Tally`]).

use burn::module::Module;
use burn::tensor::{Device, Tensor};
use image::{Rgb, RgbImage};
use prism_data::{
    DatasetReader, PrismBatch, PrismBatcher, Sample, SampleDataset, SplitKind, TargetSelection,
};
use prism_losses::{GroundTruth, ImageScores, Lpips, score_images};
use prism_model::Prism;

use crate::chunk_scores::{all_at_once, chunks_at_once};
use crate::error::Result;
use crate::tally::Tally;

/// Pairs per forward pass during validation.
const VALIDATION_BATCH: usize = 8;
/// Rows (target views of the first held-out subject) in the sample grid.
const GRID_ROWS: usize = 4;

/// The held-out views a run validates on, loaded once. Its scores are means over the held-out
/// subjects (each subject's views averaged first, then the subjects, as in the paper's
/// evaluation protocol); LPIPS is NaN below LPIPS's 31 px minimum.
pub struct Validator {
    samples: Vec<Sample>,
    lpips: Option<Lpips>,
    background: [f32; 3],
    device: Device,
}

/// The evaluation views a validation uses: `count` views evenly spread over 1..=100.
pub fn validation_views(count: usize) -> Vec<usize> {
    let count = count.clamp(1, 100);
    (0..count).map(|k| 1 + k * 100 / count).collect()
}

impl Validator {
    /// Loads `views_per_subject` target views (see [`validation_views`]) of every held-out
    /// subject of the dataset at `resolution`, for validation on `device` (an inference
    /// device). `lpips` is moved to that device.
    ///
    /// # Errors
    /// A dataset without held-out subjects, or unreadable files.
    pub fn new(
        reader: &DatasetReader,
        resolution: u32,
        views_per_subject: usize,
        lpips: Option<Lpips>,
        device: &Device,
    ) -> Result<Self> {
        let dataset = SampleDataset::new(
            reader.clone(),
            SplitKind::Test,
            TargetSelection::Evaluation { per_sample: 1 },
            Some((resolution, resolution)),
            0,
        )?;
        let views = validation_views(views_per_subject);
        let mut samples = Vec::new();
        for subject in 0..dataset.subjects().len() {
            for &view in &views {
                // With one target per item, item `s * 100 + v - 1` is view `v` of subject `s`.
                samples.push(dataset.load(subject * 100 + view - 1)?);
            }
        }
        Ok(Self {
            samples,
            lpips: lpips.map(|l| l.to_device(device)),
            background: reader.meta().background,
            device: device.clone(),
        })
    }

    /// Number of (source, target) pairs validated.
    pub fn len(&self) -> usize {
        self.samples.len()
    }

    /// Whether there is nothing to validate.
    pub fn is_empty(&self) -> bool {
        self.samples.is_empty()
    }

    /// Scores `model` (an inference model on the validator's device) on every held-out view;
    /// also returns the sample grid (source, prediction, ground truth per row).
    pub fn validate(&self, model: &Prism) -> (ImageScores, RgbImage) {
        // The validated image is the NVS decoder's.
        let model = model.clone().without_training_heads();
        let mut grid_rows = Vec::new();
        let scores = self.score(
            |batch| model.forward_batch(batch, self.background, &[]).image,
            Some(&mut grid_rows),
        );
        (scores, grid(&grid_rows))
    }

    /// The "copy the source view" baseline: the source image taken as the prediction of every
    /// target view.
    pub fn copy_source_baseline(&self) -> ImageScores {
        self.score(|batch| batch.source_image.clone(), None)
    }

    /// The scores of `predict`'s images of every held-out view; with `grid_rows`, the first
    /// [`GRID_ROWS`] views of the first subject as (source, prediction, ground truth). Batches
    /// are predicted and scored [`chunks_at_once`] at a time, as `prism evaluate` does, and
    /// tallied in their order.
    fn score(
        &self,
        predict: impl Fn(&PrismBatch) -> Tensor<4> + Sync,
        mut grid_rows: Option<&mut Vec<[Tensor<4>; 3]>>,
    ) -> ImageScores {
        let mut tally = Tally::default();
        let chunks: Vec<&[Sample]> = self.samples.chunks(VALIDATION_BATCH).collect();
        for group in chunks.chunks(chunks_at_once(&self.device)) {
            let scored = all_at_once(group, |chunk| {
                let batch = PrismBatcher.batch_samples(chunk, &self.device);
                let pred = predict(&batch).clamp(0.0, 1.0);
                let truth = GroundTruth::new(batch.target_image.clone(), self.lpips.as_ref());
                let scores = score_images(pred.clone(), &truth);
                (batch, pred, scores)
            });
            for (chunk, (batch, pred, scores)) in group.iter().zip(scored) {
                if let Some(rows) = grid_rows.as_deref_mut() {
                    self.add_grid_rows(rows, chunk, &batch, &pred);
                }
                tally.add_batch(chunk, &scores);
            }
        }
        tally.finish().mean()
    }

    /// Adds the views of `chunk` (batched as `batch`, predicted as `pred`) that belong to the
    /// first subject to `rows` as (source, prediction, ground truth), up to [`GRID_ROWS`].
    fn add_grid_rows(
        &self,
        rows: &mut Vec<[Tensor<4>; 3]>,
        chunk: &[Sample],
        batch: &PrismBatch,
        pred: &Tensor<4>,
    ) {
        let [_, c, h, w] = pred.dims();
        for (i, sample) in chunk.iter().enumerate() {
            if rows.len() < GRID_ROWS && sample.subject == self.samples[0].subject {
                let row = |t: &Tensor<4>| t.clone().slice([i..i + 1, 0..c, 0..h, 0..w]);
                rows.push([
                    row(&batch.source_image),
                    row(pred),
                    row(&batch.target_image),
                ]);
            }
        }
    }
}

/// The sample grid: one row per pair, columns source | prediction | ground truth, 8-bit RGB.
fn grid(rows: &[[Tensor<4>; 3]]) -> RgbImage {
    let Some(first) = rows.first() else {
        return RgbImage::new(1, 1);
    };
    let [_, _, h, w] = first[0].dims();
    let mut out = RgbImage::new((3 * w) as u32, (rows.len() * h) as u32);
    for (r, row) in rows.iter().enumerate() {
        for (c, tensor) in row.iter().enumerate() {
            let data: Vec<f32> = tensor
                .clone()
                .into_data()
                .convert::<f32>()
                .try_into_vec()
                .expect("float image");
            let plane = h * w;
            for y in 0..h {
                for x in 0..w {
                    let px = |ch: usize| {
                        (data[ch * plane + y * w + x].clamp(0.0, 1.0) * 255.0).round() as u8
                    };
                    out.put_pixel(
                        (c * w + x) as u32,
                        (r * h + y) as u32,
                        Rgb([px(0), px(1), px(2)]),
                    );
                }
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn validation_views_are_spread_over_the_evaluation_views() {
        assert_eq!(validation_views(1), vec![1]);
        assert_eq!(validation_views(4), vec![1, 26, 51, 76]);
        assert_eq!(validation_views(100), (1..=100).collect::<Vec<_>>());
    }
}
