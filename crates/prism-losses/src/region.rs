//! The scores of a batch of predictions in a region of each image (the disoccluded region of
//! `prism evaluate`: the pixels the source view does not see).

use burn::tensor::Tensor;

use crate::scores::scores_beside_ssim;
use crate::ssim::image_means;
use crate::{GroundTruth, ImageScores, ssim_map};

/// Half the SSIM window: an SSIM map pixel `(y, x)` is the window centred at `(y + 5, x + 5)`.
const SSIM_RADIUS: usize = crate::SSIM_WINDOW / 2;

/// The scores of each image of a batch, `pred` `[B, 3, H, W]` in [0, 1] against `gt`: on the
/// whole image ([`crate::score_images`]'s, to the bit), and in `region` (`[B, 1, H, W]`, 1
/// inside, 0 outside). Both read one SSIM map, computed once. In the region:
/// - PSNR from the mean squared error over the region's pixels and channels;
/// - SSIM the mean of the SSIM map (as [`crate::ssim()`]) over the windows centred in the
///   region;
/// - LPIPS the distance to `gt` of `gt` with the prediction pasted in on the region: the
///   perceptual error of the region alone, measured on the whole image (NaN where `gt` has no
///   LPIPS features).
///
/// An image whose region is empty scores NaN (no pixel to score), as does SSIM when no
/// window is centred in the region.
pub fn score_whole_and_region(
    pred: Tensor<4>,
    gt: &GroundTruth<'_>,
    region: Tensor<4>,
) -> (Vec<ImageScores>, Vec<ImageScores>) {
    let [batch, channels, height, width] = pred.dims();
    let truth = gt.image.clone();
    let map = ssim_map(pred.clone(), truth.clone());
    let whole = scores_beside_ssim(pred.clone(), gt, image_means(map.clone()));
    let inside: Vec<bool> = host(region.clone()).iter().map(|&r| r > 0.5).collect();
    let plane = height * width;
    let diff = host(pred.clone().sub(truth.clone()));
    let [_, _, map_h, map_w] = map.dims();
    let map = host(map);
    let pasted = pred.mul(region.clone()) + truth.mul(region.neg().add_scalar(1.0));
    let lpips = gt.lpips(pasted);
    let in_region = (0..batch)
        .map(|b| {
            let inside = &inside[b * plane..(b + 1) * plane];
            let pixels = inside.iter().filter(|&&i| i).count();
            if pixels == 0 {
                return ImageScores {
                    psnr: f64::NAN,
                    ssim: f64::NAN,
                    lpips: f64::NAN,
                };
            }
            let mut sse = 0.0;
            for c in 0..channels {
                let values = &diff[(b * channels + c) * plane..][..plane];
                sse += values
                    .iter()
                    .zip(inside)
                    .filter(|(_, i)| **i)
                    .map(|(&d, _)| f64::from(d) * f64::from(d))
                    .sum::<f64>();
            }
            let psnr = -10.0 * (sse / (pixels * channels) as f64).log10();
            let (mut sum, mut count) = (0.0, 0usize);
            for c in 0..channels {
                let values = &map[(b * channels + c) * map_h * map_w..][..map_h * map_w];
                for y in 0..map_h {
                    for x in 0..map_w {
                        if inside[(y + SSIM_RADIUS) * width + x + SSIM_RADIUS] {
                            sum += f64::from(values[y * map_w + x]);
                            count += 1;
                        }
                    }
                }
            }
            let ssim = if count == 0 {
                f64::NAN
            } else {
                sum / count as f64
            };
            ImageScores {
                psnr,
                ssim,
                lpips: lpips[b],
            }
        })
        .collect();
    (whole, in_region)
}

/// PSNR of each image of a batch over all its pixels with the prediction replaced by `gt` in
/// `region` (`[B, 1, H, W]`, 1 inside): the score a prediction would reach if it were exact
/// where the source view shows nothing, so the most that any better guess there can add to
/// the overall PSNR. Infinite for an image exact outside the region.
pub fn psnr_region_filled(pred: Tensor<4>, gt: Tensor<4>, region: Tensor<4>) -> Vec<f64> {
    let [batch, channels, height, width] = pred.dims();
    let outside = host(region.neg().add_scalar(1.0));
    let diff = host(pred.sub(gt));
    let plane = height * width;
    (0..batch)
        .map(|b| {
            let outside = &outside[b * plane..(b + 1) * plane];
            let sse: f64 = (0..channels)
                .map(|c| {
                    diff[(b * channels + c) * plane..][..plane]
                        .iter()
                        .zip(outside)
                        .map(|(&d, &o)| f64::from(o) * f64::from(d) * f64::from(d))
                        .sum::<f64>()
                })
                .sum();
            -10.0 * (sse / (plane * channels) as f64).log10()
        })
        .collect()
}

fn host(t: Tensor<4>) -> Vec<f32> {
    t.into_data()
        .try_into_vec_as::<f32>()
        .expect("float tensor data")
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::TensorData;
    use prism_core::BackendKind;

    const S: usize = 32;

    fn image(values: Vec<f32>) -> Tensor<4> {
        let device = BackendKind::Ndarray.device().unwrap();
        Tensor::from_data(TensorData::new(values, [1, 3, S, S]), &device)
    }

    /// `values` as a ground truth without LPIPS.
    fn truth(values: Vec<f32>) -> GroundTruth<'static> {
        GroundTruth::new(image(values), None)
    }

    /// A region of the right half of the image.
    fn right_half() -> Tensor<4> {
        let device = BackendKind::Ndarray.device().unwrap();
        let values = (0..S * S)
            .map(|i| if i % S >= S / 2 { 1.0 } else { 0.0 })
            .collect();
        Tensor::from_data(TensorData::new(values, [1, 1, S, S]), &device)
    }

    #[test]
    fn errors_outside_the_region_do_not_count_and_inside_they_are_scored_alone() {
        let gt: Vec<f32> = (0..3 * S * S)
            .map(|i| (i % 7) as f32 / 8.0 + 0.05)
            .collect();
        // The left half off by 0.3, the right half off by 0.1: in the region the MSE is 0.01.
        let pred: Vec<f32> = gt
            .iter()
            .enumerate()
            .map(|(i, v)| if i % S < S / 2 { v + 0.3 } else { v + 0.1 })
            .collect();
        let (whole, scores) =
            score_whole_and_region(image(pred.clone()), &truth(gt.clone()), right_half());
        assert!((scores[0].psnr - 20.0).abs() < 1e-4, "{scores:?}");
        // The whole images' scores are score_images', to the bit.
        let alone = crate::score_images(image(pred.clone()), &truth(gt.clone()));
        assert_eq!(
            (whole[0].psnr.to_bits(), whole[0].ssim.to_bits()),
            (alone[0].psnr.to_bits(), alone[0].ssim.to_bits())
        );
        assert!(scores[0].lpips.is_nan());

        // Exact in the region: PSNR infinite whatever happens outside, and SSIM above the
        // whole image's (only the windows reaching across the border see the outside).
        let exact: Vec<f32> = gt
            .iter()
            .enumerate()
            .map(|(i, v)| if i % S < S / 2 { 1.0 - v } else { *v })
            .collect();
        let whole = crate::ssim(image(exact.clone()), image(gt.clone()))[0];
        let (_, scores) = score_whole_and_region(image(exact), &truth(gt.clone()), right_half());
        assert!(scores[0].psnr.is_infinite(), "{scores:?}");
        assert!(
            scores[0].ssim > whole && scores[0].ssim <= 1.0,
            "{scores:?} vs {whole}"
        );

        // An empty region has nothing to score.
        let device = BackendKind::Ndarray.device().unwrap();
        let none = Tensor::<4>::zeros([1, 1, S, S], &device);
        let (_, scores) = score_whole_and_region(image(pred), &truth(gt), none);
        assert!(scores[0].psnr.is_nan() && scores[0].ssim.is_nan());
    }

    #[test]
    fn filling_the_region_from_the_truth_leaves_only_the_errors_outside() {
        let gt: Vec<f32> = (0..3 * S * S).map(|i| (i % 5) as f32 / 8.0 + 0.1).collect();
        // The left half off by 0.2, the right half (the region) off by 0.4: filled, the MSE is
        // the left half's 0.04 over half of the pixels, 0.02 (16.99 dB); unfilled 0.1 (10 dB).
        let pred: Vec<f32> = gt
            .iter()
            .enumerate()
            .map(|(i, v)| if i % S < S / 2 { v + 0.2 } else { v - 0.4 })
            .collect();
        let filled = psnr_region_filled(image(pred.clone()), image(gt.clone()), right_half());
        let expected = -10.0 * 0.02f64.log10();
        assert!(
            (filled[0] - expected).abs() < 1e-4,
            "{filled:?} vs {expected}"
        );
        // With no region it is the overall PSNR.
        let device = BackendKind::Ndarray.device().unwrap();
        let none = Tensor::<4>::zeros([1, 1, S, S], &device);
        let overall = psnr_region_filled(image(pred), image(gt), none);
        assert!((overall[0] - 10.0).abs() < 1e-4, "{overall:?}");
    }
}
