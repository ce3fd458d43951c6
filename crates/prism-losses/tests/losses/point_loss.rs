//! `L_pts` against a direct host implementation of its documented definition, and its
//! behaviour under a constant shift of the prediction.

use crate::common;

use common::{ndarray, tensor, uniform};
use prism_losses::point_loss;

/// The documented definition, with loops in f64: each image's terms, averaged over the batch.
#[allow(clippy::too_many_arguments)]
fn reference(
    x: &[f32],
    gt: &[f32],
    conf: &[f32],
    mask: &[f32],
    b: usize,
    h: usize,
    w: usize,
    alpha: f64,
) -> (f64, f64, f64) {
    let (points, pixels) = (3 * h * w, h * w);
    let mut sum = (0.0, 0.0, 0.0);
    for i in 0..b {
        let image = |v: &[f32], len: usize| v[i * len..(i + 1) * len].to_vec();
        let (g, p, c) = image_reference(
            &image(x, points),
            &image(gt, points),
            &image(conf, pixels),
            &image(mask, pixels),
            h,
            w,
            alpha,
        );
        sum = (sum.0 + g, sum.1 + p, sum.2 + c);
    }
    let n = b as f64;
    (sum.0 / n, sum.1 / n, sum.2 / n)
}

/// One image's terms, with loops in f64: values indexed `[c][y][x]` flattened.
fn image_reference(
    x: &[f32],
    gt: &[f32],
    conf: &[f32],
    mask: &[f32],
    h: usize,
    w: usize,
    alpha: f64,
) -> (f64, f64, f64) {
    let b = 1;
    let p = |b_: usize, c: usize, y: usize, xx: usize| ((b_ * 3 + c) * h + y) * w + xx;
    let s = |b_: usize, y: usize, xx: usize| (b_ * h + y) * w + xx;
    let fg = |b_, y, xx| mask[s(b_, y, xx)] > 0.5;
    let r = |b_, c, y, xx| f64::from(x[p(b_, c, y, xx)]) - f64::from(gt[p(b_, c, y, xx)]);
    let cf = |b_, y, xx| f64::from(conf[s(b_, y, xx)]);

    let (mut n, mut point, mut log_c) = (0.0, 0.0, 0.0);
    for b_ in 0..b {
        for y in 0..h {
            for xx in 0..w {
                if fg(b_, y, xx) {
                    n += 1.0;
                    point += cf(b_, y, xx) * (0..3).map(|c| r(b_, c, y, xx).abs()).sum::<f64>();
                    log_c += cf(b_, y, xx).ln();
                }
            }
        }
    }
    let n = f64::max(n, 1.0);
    let mut gradient = 0.0;
    for k in 0..4 {
        let step = 1 << k;
        let ys: Vec<usize> = (0..h).step_by(step).collect();
        let xs: Vec<usize> = (0..w).step_by(step).collect();
        let (mut sum, mut nk) = (0.0, 0.0);
        for b_ in 0..b {
            for (iy, &y) in ys.iter().enumerate() {
                for (ix, &xx) in xs.iter().enumerate() {
                    if fg(b_, y, xx) {
                        nk += 1.0;
                    }
                    // Differences to the next subsampled pixel along x and along y.
                    let neighbours = [
                        xs.get(ix + 1).map(|&x2| (y, x2)),
                        ys.get(iy + 1).map(|&y2| (y2, xx)),
                    ];
                    for (y2, x2) in neighbours.into_iter().flatten() {
                        if fg(b_, y, xx) && fg(b_, y2, x2) {
                            let c_d = 0.5 * (cf(b_, y, xx) + cf(b_, y2, x2));
                            let l1: f64 = (0..3)
                                .map(|c| (r(b_, c, y2, x2) - r(b_, c, y, xx)).abs())
                                .sum();
                            sum += c_d * l1;
                        }
                    }
                }
            }
        }
        gradient += sum / f64::max(nk, 1.0) / step as f64;
    }
    (gradient, point / n, -alpha * log_c / n)
}

#[test]
fn point_loss_matches_its_definition() {
    let device = ndarray();
    for (b, h, w, seed) in [(2, 13, 11, 1), (1, 9, 16, 2)] {
        let n = b * h * w;
        let x = uniform(seed, 3 * n, -1.0, 1.0);
        let gt = uniform(seed + 10, 3 * n, -1.0, 1.0);
        let conf: Vec<f32> = uniform(seed + 20, n, 1.0, 3.0);
        let mask: Vec<f32> = uniform(seed + 30, n, 0.0, 1.0);
        let loss = point_loss(
            tensor(x.clone(), [b, 3, h, w], &device),
            tensor(gt.clone(), [b, 3, h, w], &device),
            tensor(conf.clone(), [b, 1, h, w], &device),
            tensor(mask.clone(), [b, 1, h, w], &device),
            0.2,
        );
        let (g, p, c) = reference(&x, &gt, &conf, &mask, b, h, w, 0.2);
        let got = |t: burn::tensor::Tensor<1>| f64::from(t.into_scalar::<f32>());
        let close = |a: f64, e: f64| (a - e).abs() <= 1e-5 * e.abs().max(1.0);
        assert!(
            close(got(loss.gradient.clone()), g),
            "gradient term {:?} vs {g}",
            loss.gradient
        );
        assert!(close(got(loss.point.clone()), p), "point term vs {p}");
        assert!(
            close(got(loss.confidence.clone()), c),
            "confidence term vs {c}"
        );
        assert!(close(got(loss.total()), g + p + c));
    }
}

#[test]
fn constant_shift_is_invisible_to_the_gradient_term_only() {
    let device = ndarray();
    let (b, h, w) = (2, 16, 12);
    let n = b * h * w;
    let gt = uniform(5, 3 * n, -1.0, 1.0);
    let shift = [0.25f32, -0.5, 0.125];
    let x: Vec<f32> = gt
        .iter()
        .enumerate()
        .map(|(i, &v)| v + shift[(i / (h * w)) % 3])
        .collect();
    let conf = uniform(6, n, 1.0, 2.0);
    let mask: Vec<f32> = (0..n)
        .map(|i| if (i % w) > 2 { 1.0 } else { 0.0 })
        .collect();
    let loss = point_loss(
        tensor(x, [b, 3, h, w], &device),
        tensor(gt, [b, 3, h, w], &device),
        tensor(conf.clone(), [b, 1, h, w], &device),
        tensor(mask.clone(), [b, 1, h, w], &device),
        0.2,
    );
    let gradient = loss.gradient.into_scalar::<f32>();
    let point = loss.point.into_scalar::<f32>();
    assert!(
        gradient.abs() < 1e-5,
        "gradient term of a shifted prediction: {gradient}"
    );
    // Point term: mean over foreground of C * (0.25 + 0.5 + 0.125).
    let (sum_c, count) = conf
        .iter()
        .zip(&mask)
        .filter(|&(_, &m)| m > 0.5)
        .fold((0.0f64, 0.0f64), |(s, k), (&c, _)| {
            (s + f64::from(c), k + 1.0)
        });
    let expected = sum_c / count * 0.875;
    assert!(point > 0.0);
    assert!(
        (f64::from(point) - expected).abs() < 1e-5,
        "point term {point} vs {expected}"
    );
}

#[test]
fn empty_mask_gives_zero_and_background_is_ignored() {
    let device = ndarray();
    let (b, h, w) = (1, 8, 8);
    let n = b * h * w;
    let x = uniform(7, 3 * n, -1.0, 1.0);
    let gt = uniform(8, 3 * n, -1.0, 1.0);
    let value = |x: &[f32], mask: &[f32]| {
        point_loss(
            tensor(x.to_vec(), [b, 3, h, w], &device),
            tensor(gt.clone(), [b, 3, h, w], &device),
            tensor(vec![2.0; n], [b, 1, h, w], &device),
            tensor(mask.to_vec(), [b, 1, h, w], &device),
            0.2,
        )
        .total()
        .into_scalar::<f32>()
    };
    assert_eq!(value(&x, &vec![0.0; n]), 0.0);
    // Foreground: the left half of each row; changing the right half changes nothing.
    let mask: Vec<f32> = (0..n)
        .map(|i| if i % w < w / 2 { 1.0 } else { 0.0 })
        .collect();
    let mut moved = x.clone();
    for (i, v) in moved.iter_mut().enumerate() {
        if i % w >= w / 2 {
            *v += 10.0;
        }
    }
    assert_eq!(value(&x, &mask), value(&moved, &mask));
    assert!(value(&x, &mask) > 0.0);
}

#[test]
fn zero_confidence_on_the_background_stays_finite() {
    let ad = ndarray().autodiff();
    let (b, h, w) = (1, 8, 8);
    let n = b * h * w;
    let mask: Vec<f32> = (0..n).map(|i| if i % w < 4 { 1.0 } else { 0.0 }).collect();
    let conf: Vec<f32> = mask
        .iter()
        .map(|&m| if m > 0.5 { 1.5 } else { 0.0 })
        .collect();
    let c = tensor(conf, [b, 1, h, w], &ad).require_grad();
    let loss = point_loss(
        tensor(uniform(9, 3 * n, -1.0, 1.0), [b, 3, h, w], &ad),
        tensor(uniform(10, 3 * n, -1.0, 1.0), [b, 3, h, w], &ad),
        c.clone(),
        tensor(mask, [b, 1, h, w], &ad),
        0.2,
    )
    .total();
    assert!(loss.clone().into_scalar::<f32>().is_finite());
    let grads = loss.backward();
    let g = common::host(c.grad(&grads).unwrap());
    assert!(g.iter().all(|v| v.is_finite()), "{g:?}");
}
