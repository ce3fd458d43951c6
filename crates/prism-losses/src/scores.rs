//! The one scoring pipeline of prism: PSNR, SSIM and LPIPS of each image of a batch of
//! predictions against their ground truth, and their means. Validation during training,
//! `prism evaluate` (checkpoint and `--pred/--gt`), `prism metrics` and the quick start all
//! score through [`score_images`] (`prism evaluate` through
//! [`crate::score_whole_and_region`], which adds the disoccluded region's scores to the same
//! computation), so their numbers agree.

use burn::tensor::Tensor;
use serde::{Deserialize, Deserializer, Serialize};

use crate::lpips::LpipsReference;
use crate::{LPIPS_MIN_SIDE, Lpips, psnr, ssim};

/// PSNR (dB), SSIM and LPIPS of one image against its ground truth, or their means over
/// several images. Read back from JSON, a `null` score is NaN.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ImageScores {
    /// PSNR in dB (`+inf` for identical images, written `null` in JSON).
    #[serde(deserialize_with = "number_or_nan")]
    pub psnr: f64,
    /// SSIM (scikit-image's Gaussian variant).
    #[serde(deserialize_with = "number_or_nan")]
    pub ssim: f64,
    /// LPIPS v0.1 AlexNet (NaN, `null` in JSON, when not measured: no LPIPS network, or images
    /// smaller than its [`LPIPS_MIN_SIDE`]).
    #[serde(deserialize_with = "number_or_nan")]
    pub lpips: f64,
}

/// A JSON number, or NaN for the `null` that JSON writes for a non-finite score.
fn number_or_nan<'de, D: Deserializer<'de>>(deserializer: D) -> Result<f64, D::Error> {
    Ok(Option::<f64>::deserialize(deserializer)?.unwrap_or(f64::NAN))
}

impl ImageScores {
    /// The mean of each metric over `scores` (NaN for an empty list).
    pub fn mean(scores: &[ImageScores]) -> ImageScores {
        let n = scores.len() as f64;
        let sum = |f: fn(&ImageScores) -> f64| scores.iter().map(f).sum::<f64>() / n;
        ImageScores {
            psnr: sum(|s| s.psnr),
            ssim: sum(|s| s.ssim),
            lpips: sum(|s| s.lpips),
        }
    }
}

/// A batch of ground-truth images, `[B, 3, H, W]` in [0, 1], ready to score predictions
/// against: the images, and their LPIPS features when there is a network and the images are
/// at least [`LPIPS_MIN_SIDE`] on a side. The features are computed once, however many
/// predictions (methods, regions) are scored against the same images.
pub struct GroundTruth<'a> {
    /// The images.
    pub image: Tensor<4>,
    /// Their LPIPS features (`None`: LPIPS is not measured, its scores are NaN).
    lpips: Option<LpipsReference<'a>>,
}

impl<'a> GroundTruth<'a> {
    /// `image` with its LPIPS features from `lpips` (none without a network or below
    /// [`LPIPS_MIN_SIDE`]).
    pub fn new(image: Tensor<4>, lpips: Option<&'a Lpips>) -> Self {
        let [_, _, height, width] = image.dims();
        let lpips = lpips
            .filter(|_| height.min(width) >= LPIPS_MIN_SIDE)
            .map(|net| net.reference(image.clone()));
        Self { image, lpips }
    }

    /// Per-image LPIPS of `pred` to these images (NaN for each when not measured).
    pub fn lpips(&self, pred: Tensor<4>) -> Vec<f64> {
        match &self.lpips {
            Some(reference) => reference.distance(pred),
            None => vec![f64::NAN; pred.dims()[0]],
        }
    }
}

/// PSNR, SSIM and LPIPS of each image of a batch, `pred` `[B, 3, H, W]` in [0, 1] against
/// `gt` (H, W >= [`crate::SSIM_WINDOW`]). LPIPS is NaN where `gt` has no LPIPS features.
pub fn score_images(pred: Tensor<4>, gt: &GroundTruth<'_>) -> Vec<ImageScores> {
    let s = ssim(pred.clone(), gt.image.clone());
    scores_beside_ssim(pred, gt, s)
}

/// [`score_images`] for a batch whose per-image SSIM `s` the caller has already computed.
pub(crate) fn scores_beside_ssim(
    pred: Tensor<4>,
    gt: &GroundTruth<'_>,
    s: Vec<f64>,
) -> Vec<ImageScores> {
    let p = psnr(pred.clone(), gt.image.clone());
    let l = gt.lpips(pred);
    p.into_iter()
        .zip(s)
        .zip(l)
        .map(|((psnr, ssim), lpips)| ImageScores { psnr, ssim, lpips })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use prism_core::BackendKind;

    #[test]
    fn small_images_or_no_network_score_without_lpips() {
        let device = BackendKind::Ndarray.device().unwrap();
        let gt = Tensor::<4>::full([2, 3, 16, 16], 0.5, &device);
        let pred = gt.clone().add_scalar(0.1);
        let scores = score_images(pred, &GroundTruth::new(gt, None));
        assert_eq!(scores.len(), 2);
        assert!((scores[0].psnr - 20.0).abs() < 1e-3, "{scores:?}");
        assert!(scores.iter().all(|s| s.lpips.is_nan()));
        let mean = ImageScores::mean(&scores);
        assert!((mean.psnr - scores[0].psnr).abs() < 1e-9);
    }
}
