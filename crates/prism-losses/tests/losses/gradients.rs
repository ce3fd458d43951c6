//! Gradients of `L_pts` and of LPIPS with respect to their inputs agree with finite
//! differences (f32 on ndarray: central differences along whole-tensor directions, relative
//! tolerances).

use crate::common;

use burn::tensor::Tensor;
use common::{check_directional, host, ndarray, tensor, uniform};
use prism_losses::{Lpips, point_loss};

const B: usize = 2;
const H: usize = 12;
const W: usize = 10;

struct PointCase {
    x: Vec<f32>,
    x_gt: Vec<f32>,
    conf_logit: Vec<f32>,
    mask: Vec<f32>,
}

/// Points whose residual `X - X_gt` is a tilted plane plus small noise, with a sign per
/// channel: every residual and every finite difference of it (at all four scales) stays away
/// from zero, so no `|.|` kink lies within a finite-difference step.
fn point_case() -> PointCase {
    let n = B * H * W;
    let x_gt = uniform(2, 3 * n, -1.0, 1.0);
    let noise = uniform(1, 3 * n, -0.005, 0.005);
    let x = (0..3 * n)
        .map(|idx| {
            let (b, c, y, xx) = (
                idx / (3 * H * W),
                (idx / (H * W)) % 3,
                (idx / W) % H,
                idx % W,
            );
            let sign = if c == 1 { -1.0 } else { 1.0 };
            let slope = 0.05 + 0.01 * (b + c) as f32;
            x_gt[idx] + sign * (0.2 + slope * y as f32 + 0.03 * xx as f32 + noise[idx])
        })
        .collect();
    PointCase {
        x,
        x_gt,
        conf_logit: uniform(3, n, -1.0, 1.0),
        mask: uniform(4, n, 0.0, 1.0)
            .into_iter()
            .map(|u| if u < 0.75 { 1.0 } else { 0.0 })
            .collect(),
    }
}

/// `L_pts` with `C = 1 + exp(logit)` as the point branch produces it.
fn point_total(
    case: &PointCase,
    x: &[f32],
    logit: &[f32],
    device: &burn::tensor::Device,
) -> Tensor<1> {
    let conf = tensor(logit.to_vec(), [B, 1, H, W], device)
        .exp()
        .add_scalar(1.0);
    point_loss(
        tensor(x.to_vec(), [B, 3, H, W], device),
        tensor(case.x_gt.clone(), [B, 3, H, W], device),
        conf,
        tensor(case.mask.clone(), [B, 1, H, W], device),
        0.2,
    )
    .total()
}

#[test]
fn point_loss_gradients_match_finite_differences() {
    let device = ndarray();
    let ad = device.clone().autodiff();
    let case = point_case();

    let x = tensor(case.x.clone(), [B, 3, H, W], &ad).require_grad();
    let logit = tensor(case.conf_logit.clone(), [B, 1, H, W], &ad).require_grad();
    let conf = logit.clone().exp().add_scalar(1.0);
    let loss = point_loss(
        x.clone(),
        tensor(case.x_gt.clone(), [B, 3, H, W], &ad),
        conf,
        tensor(case.mask.clone(), [B, 1, H, W], &ad),
        0.2,
    )
    .total();
    let grads = loss.backward();
    let gx = host(x.grad(&grads).unwrap());
    let gc = host(logit.grad(&grads).unwrap());
    assert!(gx.iter().chain(&gc).all(|g| g.is_finite()));
    // Background pixels get no gradient at all.
    for (i, &m) in case.mask.iter().enumerate() {
        if m == 0.0 {
            assert_eq!(gc[i], 0.0, "confidence gradient on a background pixel");
        }
    }

    let f_x = |v: &[f32]| {
        f64::from(point_total(&case, v, &case.conf_logit, &device).into_scalar::<f32>())
    };
    let f_c = |v: &[f32]| f64::from(point_total(&case, &case.x, v, &device).into_scalar::<f32>());
    for seed in [10, 11] {
        let dir = uniform(seed, gx.len(), -1.0, 1.0);
        check_directional(&f_x, &case.x, &gx, &dir, 1e-3, 5e-4, "dL_pts/dX");
        let dir = uniform(seed + 100, gc.len(), -1.0, 1.0);
        check_directional(
            &f_c,
            &case.conf_logit,
            &gc,
            &dir,
            1e-2,
            2e-4,
            "dL_pts/dlogit C",
        );
    }
    // The coordinate with the largest gradient, alone.
    let largest = (0..gx.len())
        .max_by(|&a, &b| gx[a].abs().total_cmp(&gx[b].abs()))
        .unwrap();
    let mut one_hot = vec![0.0; gx.len()];
    one_hot[largest] = 1.0;
    check_directional(
        &f_x,
        &case.x,
        &gx,
        &one_hot,
        1e-3,
        1e-2,
        "dL_pts/dX one coordinate",
    );
}

#[test]
fn lpips_gradient_matches_finite_differences() {
    let device = ndarray();
    let ad = device.clone().autodiff();
    let lpips = Lpips::load_default(None, &device).unwrap();
    let lpips_ad = Lpips::load_default(None, &ad).unwrap();
    let shape = [1, 3, 32, 32];
    let n = 3 * 32 * 32;
    // Smooth-ish images (a ramp plus noise) so that the value is well away from 0.
    let pred: Vec<f32> = uniform(20, n, 0.2, 0.8);
    let gt: Vec<f32> = (0..n)
        .map(|i| ((i % 32) as f32 / 31.0) * 0.8 + 0.1)
        .collect();

    let x = tensor(pred.clone(), shape, &ad).require_grad();
    let value = lpips.forward(
        tensor(pred.clone(), shape, &device),
        tensor(gt.clone(), shape, &device),
    );
    let value_ad = lpips_ad.forward(x.clone(), tensor(gt.clone(), shape, &ad));
    let v0 = f64::from(value.into_scalar::<f32>());
    assert!((f64::from(value_ad.clone().into_scalar::<f32>()) - v0).abs() < 1e-6);
    assert!(v0 > 0.01, "LPIPS of different images is {v0}");
    let grads = value_ad.sum().backward();
    let g = host(x.grad(&grads).unwrap());
    assert!(g.iter().all(|v| v.is_finite()));

    let f = |v: &[f32]| {
        f64::from(
            lpips
                .forward(
                    tensor(v.to_vec(), shape, &device),
                    tensor(gt.clone(), shape, &device),
                )
                .into_scalar::<f32>(),
        )
    };
    // Small steps: along whole-image directions ReLU and max-pool switches make the value
    // piecewise smooth, and the central difference converges to <grad, v> as h -> 0.
    let sign: Vec<f32> = g.iter().map(|v| v.signum()).collect();
    check_directional(
        &f,
        &pred,
        &g,
        &sign,
        3e-5,
        2e-3,
        "dLPIPS/dx along sign(grad)",
    );
    let weighted: Vec<f32> = sign
        .iter()
        .zip(uniform(22, n, 0.0, 1.0))
        .map(|(s, u)| s * u)
        .collect();
    check_directional(
        &f,
        &pred,
        &g,
        &weighted,
        3e-5,
        5e-3,
        "dLPIPS/dx along u * sign(grad)",
    );
    let random = uniform(21, n, -1.0, 1.0);
    check_directional(
        &f,
        &pred,
        &g,
        &random,
        1e-4,
        1e-3,
        "dLPIPS/dx along a random direction",
    );
}
