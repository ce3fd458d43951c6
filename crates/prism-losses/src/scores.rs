//! The one scoring pipeline of prism: PSNR, SSIM and LPIPS of each image of a batch of
//! predictions against their ground truth, and their means. Validation during training,
//! `prism evaluate` (checkpoint and `--pred/--gt`), `prism metrics` and the quick start all
//! score through [`score_images`], so their numbers agree.

use burn::tensor::Tensor;
use serde::{Deserialize, Deserializer, Serialize};

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

/// PSNR, SSIM and LPIPS of each image of a batch, `pred` and `gt` `[B, 3, H, W]` in [0, 1]
/// (H, W >= [`crate::SSIM_WINDOW`]). LPIPS is NaN without a network (`lpips` `None`) or when
/// the images are smaller than [`LPIPS_MIN_SIDE`].
pub fn score_images(pred: Tensor<4>, gt: Tensor<4>, lpips: Option<&Lpips>) -> Vec<ImageScores> {
    let [_, _, height, width] = pred.dims();
    let p = psnr(pred.clone(), gt.clone());
    let s = ssim(pred.clone(), gt.clone());
    let l = match lpips.filter(|_| height.min(width) >= LPIPS_MIN_SIDE) {
        Some(lpips) => lpips.distance(pred, gt),
        None => vec![f64::NAN; p.len()],
    };
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
        let scores = score_images(pred, gt, None);
        assert_eq!(scores.len(), 2);
        assert!((scores[0].psnr - 20.0).abs() < 1e-3, "{scores:?}");
        assert!(scores.iter().all(|s| s.lpips.is_nan()));
        let mean = ImageScores::mean(&scores);
        assert!((mean.psnr - scores[0].psnr).abs() < 1e-9);
    }
}
