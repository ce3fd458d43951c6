//! Validation during training: PSNR, SSIM and LPIPS of the model on held-out subjects, the
//! "copy the source view" baseline, and a PNG grid of sample predictions.

use std::collections::BTreeMap;

use burn::module::Module;
use burn::tensor::{Device, Tensor};
use image::{Rgb, RgbImage};
use prism_data::{
    DatasetReader, PrismBatch, PrismBatcher, Sample, SampleDataset, SplitKind, TargetSelection,
};
use prism_losses::{LPIPS_MIN_SIDE, Lpips, psnr, ssim};
use prism_model::Prism;
use serde::Serialize;

use crate::error::Result;

/// Pairs per forward pass during validation.
const VALIDATION_BATCH: usize = 8;
/// Rows (target views of the first held-out subject) in the sample grid.
const GRID_ROWS: usize = 4;

/// Mean metrics over the held-out subjects (each subject's views averaged first, then the
/// subjects, as in the paper's evaluation protocol).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct ValidationScores {
    /// PSNR in dB.
    pub psnr: f64,
    /// SSIM.
    pub ssim: f64,
    /// LPIPS (NaN when the images are smaller than LPIPS's 31 px minimum).
    pub lpips: f64,
}

/// The held-out views a run validates on, loaded once.
pub struct Validator {
    samples: Vec<Sample>,
    subjects: Vec<usize>,
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
        let mut subjects = Vec::new();
        for subject in 0..dataset.subjects().len() {
            for &view in &views {
                // With one target per item, item `s * 100 + v - 1` is view `v` of subject `s`.
                samples.push(dataset.load(subject * 100 + view - 1)?);
                subjects.push(subject);
            }
        }
        let usable = resolution as usize >= LPIPS_MIN_SIDE;
        Ok(Self {
            samples,
            subjects,
            lpips: lpips.filter(|_| usable).map(|l| l.to_device(device)),
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
    pub fn validate(&self, model: &Prism) -> (ValidationScores, RgbImage) {
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
    pub fn copy_source_baseline(&self) -> ValidationScores {
        self.score(|batch| batch.source_image.clone(), None)
    }

    fn score(
        &self,
        predict: impl Fn(&PrismBatch) -> Tensor<4>,
        mut grid_rows: Option<&mut Vec<[Tensor<4>; 3]>>,
    ) -> ValidationScores {
        let mut per_subject: BTreeMap<usize, Vec<[f64; 3]>> = BTreeMap::new();
        let mut index = 0;
        for chunk in self.samples.chunks(VALIDATION_BATCH) {
            let batch = PrismBatcher.batch_samples(chunk, &self.device);
            let pred = predict(&batch).clamp(0.0, 1.0);
            let gt = batch.target_image.clone();
            let p = psnr(pred.clone(), gt.clone());
            let s = ssim(pred.clone(), gt.clone());
            let l = match &self.lpips {
                Some(lpips) => lpips.distance(pred.clone(), gt.clone()),
                None => vec![f64::NAN; p.len()],
            };
            if let Some(rows) = grid_rows.as_deref_mut() {
                let [n, c, h, w] = pred.dims();
                for i in 0..n {
                    if rows.len() < GRID_ROWS && self.subjects[index + i] == self.subjects[0] {
                        let row = |t: &Tensor<4>| t.clone().slice([i..i + 1, 0..c, 0..h, 0..w]);
                        rows.push([row(&batch.source_image), row(&pred), row(&gt)]);
                    }
                }
            }
            for i in 0..p.len() {
                per_subject
                    .entry(self.subjects[index + i])
                    .or_default()
                    .push([p[i], s[i], l[i]]);
            }
            index += p.len();
        }
        let means: Vec<[f64; 3]> = per_subject.values().map(|v| mean_rows(v)).collect();
        let [psnr, ssim, lpips] = mean_rows(&means);
        ValidationScores { psnr, ssim, lpips }
    }
}

fn mean_rows(rows: &[[f64; 3]]) -> [f64; 3] {
    let n = rows.len().max(1) as f64;
    let mut out = [0.0; 3];
    for r in rows {
        for (o, v) in out.iter_mut().zip(r) {
            *o += v / n;
        }
    }
    out
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
