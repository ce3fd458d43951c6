//! `L_centres`: the 3DGS head's Gaussian centres against the dataset's points (not in the
//! paper).
//!
//! With `gs_depth = "points"` the Gaussians sit at the point branch's distances plus the
//! head's correction. `L_pts` supervises the point branch, but the correction is trained
//! only through the rendered images, which say little about depth. Yet the true depth is
//! worth the most of any property the oracle swaps give the renderer (BENCHMARKS, issue 42).
//! This term supervises the Gaussians' own centres directly. It is used in training only:
//! at inference the model still estimates its own depth.

use burn::tensor::Tensor;

/// Mean L1 distance between the Gaussian `centres` and the true points `points_gt`, both
/// `[B, N, 3]` (one row per source pixel, world coordinates), over the source foreground
/// `mask` `[B, N, 1]` (foreground where `> 0.5`), `[1]`:
///
/// `L_centres = mean_b [ sum_fg |mu - X_gt|_1 / max(N_fg, 1) ]`
///
/// Each image weighs the same (as in `L_pts`), and an image without foreground counts zero.
pub fn centres_loss(centres: Tensor<3>, points_gt: Tensor<3>, mask: Tensor<3>) -> Tensor<1> {
    let (residual, fg) = foreground_residual("L_centres", centres, points_gt, mask);
    mean_foreground_l1(residual, fg)
}

/// `L_spread`: like [`centres_loss`], but on each residual less its image's foreground mean,
/// `r - mean_fg(r)` with `r = mu - X_gt`, `[1]`. It penalises the spread of the centres' errors
/// and not their shared offset: a model whose Gaussians all sit the same distance behind the
/// surface pays nothing, one whose depth is noisy pays (BENCHMARKS, issue 42: the learnt bias
/// covers the spread).
pub fn spread_loss(centres: Tensor<3>, points_gt: Tensor<3>, mask: Tensor<3>) -> Tensor<1> {
    let (residual, fg) = foreground_residual("L_spread", centres, points_gt, mask);
    let count = fg.clone().sum_dim(1).clamp_min(1.0);
    let mean = residual.clone().mul(fg.clone()).sum_dim(1).div(count);
    mean_foreground_l1(residual.sub(mean), fg)
}

/// `mu - X_gt` and the foreground as 0 / 1, after checking the shapes (`loss` names the term
/// in the panic message).
fn foreground_residual(
    loss: &str,
    centres: Tensor<3>,
    points_gt: Tensor<3>,
    mask: Tensor<3>,
) -> (Tensor<3>, Tensor<3>) {
    assert_eq!(
        centres.dims(),
        points_gt.dims(),
        "{loss}: centres and points differ in shape"
    );
    let [batch, rows, _] = centres.dims();
    assert_eq!(
        mask.dims(),
        [batch, rows, 1],
        "{loss}: the mask must be [B, N, 1]"
    );
    (centres.sub(points_gt), mask.greater_elem(0.5).float())
}

/// `mean_b [ sum_fg |r|_1 / max(N_fg, 1) ]` of residuals `r` `[B, N, 3]` on the foreground
/// `fg` `[B, N, 1]` (0 / 1), `[1]`.
fn mean_foreground_l1(residual: Tensor<3>, fg: Tensor<3>) -> Tensor<1> {
    let [batch, ..] = residual.dims();
    let distance = residual.abs().sum_dim(2).mul(fg.clone());
    let per_image = |t: Tensor<3>| t.sum_dim(1).reshape([batch]);
    per_image(distance).div(per_image(fg).clamp_min(1.0)).mean()
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::TensorData;
    use prism_core::BackendKind;

    #[test]
    fn spread_ignores_a_shared_offset_and_sees_noise() {
        let device = BackendKind::Ndarray.device().unwrap();
        let points = Tensor::<3>::from_data(
            TensorData::new(
                (0..12).map(|v| v as f32 * 0.1).collect::<Vec<_>>(),
                [1, 4, 3],
            ),
            &device,
        );
        let mask = Tensor::<3>::from_data(
            TensorData::new(vec![1.0f32, 1.0, 1.0, 0.0], [1, 4, 1]),
            &device,
        );
        // All foreground centres 9 cm behind along z, the background one far off: no spread.
        let offset = Tensor::<3>::from_data(
            TensorData::new(
                vec![
                    0.0f32, 0.0, 0.09, 0.0, 0.0, 0.09, 0.0, 0.0, 0.09, 5.0, 5.0, 5.0,
                ],
                [1, 4, 3],
            ),
            &device,
        );
        let shifted = points.clone() + offset;
        let value = spread_loss(shifted.clone(), points.clone(), mask.clone()).into_scalar::<f64>();
        assert!(value.abs() < 1e-6, "{value}");
        assert!(centres_loss(shifted, points.clone(), mask.clone()).into_scalar::<f64>() > 0.08);
        // z errors of +0.1, -0.1, 0 (mean 0): spread (0.1 + 0.1 + 0) / 3.
        let noise = Tensor::<3>::from_data(
            TensorData::new(
                vec![
                    0.0f32, 0.0, 0.1, 0.0, 0.0, -0.1, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
                ],
                [1, 4, 3],
            ),
            &device,
        );
        let value = spread_loss(points.clone() + noise, points, mask).into_scalar::<f64>();
        assert!((value - 0.2 / 3.0).abs() < 1e-6, "{value}");
    }

    #[test]
    fn is_the_mean_foreground_distance_per_image_with_its_gradient() {
        let device = BackendKind::Ndarray.device().unwrap().autodiff();
        // Two images of three rows. Image 0: rows 0 and 2 foreground, off by (0.1, -0.2, 0)
        // and (0, 0, 0.5); row 1 is background and far off. Image 1: no foreground.
        let mu = [
            0.1f32, -0.2, 0.0, 9.0, 9.0, 9.0, 1.0, 1.0, 1.5, //
            3.0, 3.0, 3.0, 4.0, 4.0, 4.0, 5.0, 5.0, 5.0,
        ];
        let gt = [
            0.0f32, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 1.0, 1.0, //
            0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
        ];
        let m = [1.0f32, 0.0, 0.9, 0.2, 0.0, 0.4];
        let centres =
            Tensor::<3>::from_data(TensorData::new(mu.to_vec(), [2, 3, 3]), &device).require_grad();
        let points = Tensor::<3>::from_data(TensorData::new(gt.to_vec(), [2, 3, 3]), &device);
        let mask = Tensor::<3>::from_data(TensorData::new(m.to_vec(), [2, 3, 1]), &device);
        let loss = centres_loss(centres.clone(), points, mask);
        // Image 0: (0.3 + 0.5) / 2 = 0.4; image 1: 0; the mean of the two.
        let value = loss.clone().into_scalar::<f64>();
        assert!((value - 0.2).abs() < 1e-6, "{value}");
        // d/dmu = sign(mu - gt) / (2 N_fg) on the foreground, 0 elsewhere.
        let g = centres
            .grad(&loss.backward())
            .unwrap()
            .into_data()
            .try_into_vec_as::<f32>()
            .unwrap();
        let want = [
            0.25f32, -0.25, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.25, //
            0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
        ];
        for (i, (&g, &w)) in g.iter().zip(&want).enumerate() {
            // |x| at exactly 0 may take either subgradient; those entries are not checked.
            if mu[i] == gt[i] {
                continue;
            }
            assert!((g - w).abs() < 1e-6, "row {i}: {g} vs {w}");
        }
    }
}
