//! `L_opacity`: the 3DGS head's per-pixel opacities against the source view's foreground mask.
//!
//! With colours taken from the source pixels (`gs_colour = "source"`), every source pixel
//! becomes a Gaussian, the background's included: a background pixel drawn in front of the
//! person spoils the render. The mask says which pixels are the person, so the opacity is
//! supervised with it directly (binary cross-entropy on the opacity logit), instead of being
//! left to the image loss, which learns it slowly and only where a wrong pixel shows.

use burn::tensor::Tensor;
use burn::tensor::activation::log_sigmoid;

/// Mean binary cross-entropy between `sigmoid(logits)` and `target`, both `[B, N, 1]` (targets
/// in [0, 1], e.g. a soft foreground mask), `[1]`:
/// `-mean(m log sigmoid(x) + (1 - m) log sigmoid(-x))`, through the stable `log_sigmoid`. (The
/// form `max(x, 0) - x m + log(1 + exp(-|x|))` has the right value but, through the kinks of
/// `max` and `|x|`, the gradient `-m` instead of `1/2 - m` at exactly `x = 0`, where
/// zero-initialised logits start.)
pub fn opacity_loss(logits: Tensor<3>, target: Tensor<3>) -> Tensor<1> {
    let inside = log_sigmoid(logits.clone()) * target.clone();
    let outside = log_sigmoid(logits.neg()) * target.neg().add_scalar(1.0);
    (inside + outside).mean().neg()
}

/// A per-pixel map `[B, C, H, W]` (a foreground mask, a point map) as one row per pixel,
/// `[B, H W, C]`: the order of the 3DGS head's Gaussians.
pub fn pixel_rows(map: Tensor<4>) -> Tensor<3> {
    let [b, c, h, w] = map.dims();
    map.reshape([b, c, h * w]).swap_dims(1, 2)
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::TensorData;
    use prism_core::BackendKind;

    #[test]
    fn matches_the_cross_entropy_formula_and_its_gradient() {
        let device = BackendKind::Ndarray.device().unwrap().autodiff();
        let x = [-30.0f32, -2.0, -0.3, 0.0, 0.0, 0.7, 3.0, 40.0];
        let m = [0.0f32, 1.0, 0.25, 1.0, 0.0, 0.0, 1.0, 0.0];
        let logits =
            Tensor::<3>::from_data(TensorData::new(x.to_vec(), [1, 8, 1]), &device).require_grad();
        let target = Tensor::<3>::from_data(TensorData::new(m.to_vec(), [1, 8, 1]), &device);
        let loss = opacity_loss(logits.clone(), target);
        let sig = |v: f64| 1.0 / (1.0 + (-v).exp());
        let expected: f64 = x
            .iter()
            .zip(&m)
            .map(|(&x, &m)| {
                let (x, m) = (x as f64, m as f64);
                // -m log s - (1 - m) log(1 - s), with log s = -log(1 + e^-x).
                m * (-x).exp().ln_1p() + (1.0 - m) * x.exp().ln_1p()
            })
            .sum::<f64>()
            / 8.0;
        let value = loss.clone().into_scalar::<f64>();
        assert!((value - expected).abs() < 1e-5, "{value} vs {expected}");
        // d/dx = (sigmoid(x) - m) / N.
        let grads = loss.backward();
        let g = logits
            .grad(&grads)
            .unwrap()
            .into_data()
            .try_into_vec_as::<f32>()
            .unwrap();
        for ((&g, &x), &m) in g.iter().zip(&x).zip(&m) {
            let want = (sig(x as f64) - m as f64) / 8.0;
            assert!((g as f64 - want).abs() < 1e-6, "{g} vs {want} at {x}");
        }
    }

    #[test]
    fn pixel_rows_follow_the_pixels_row_major() {
        let device = BackendKind::Ndarray.device().unwrap();
        let check = |values: Vec<f32>, shape: [usize; 4], dims: [usize; 3], want: Vec<f32>| {
            let rows = pixel_rows(Tensor::<4>::from_data(
                TensorData::new(values, shape),
                &device,
            ));
            assert_eq!(rows.dims(), dims);
            assert_eq!(rows.into_data().try_into_vec_as::<f32>().unwrap(), want);
        };
        // A mask of 2 x 3 pixels.
        let mask = (0..6).map(|v| v as f32).collect();
        check(
            mask,
            [1, 1, 2, 3],
            [1, 6, 1],
            vec![0.0, 1.0, 2.0, 3.0, 4.0, 5.0],
        );
        // Three channels of 1 x 2 pixels, channel c of pixel p being 10 c + p: a row holds one
        // pixel's channels.
        let points = vec![0.0, 1.0, 10.0, 11.0, 20.0, 21.0];
        check(
            points,
            [1, 3, 1, 2],
            [1, 2, 3],
            vec![0.0, 10.0, 20.0, 1.0, 11.0, 21.0],
        );
    }
}
