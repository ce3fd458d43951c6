//! Structural similarity (Wang et al. 2004), as scikit-image computes it with
//! `gaussian_weights=True, sigma=1.5, use_sample_covariance=False, data_range=1`.

use burn::tensor::module::conv2d;
use burn::tensor::ops::ConvOptions;
use burn::tensor::{Device, Tensor};

use crate::psnr::per_image_sums;

/// Taps of the Gaussian window (sigma 1.5 truncated at 3.5 sigma: radius 5).
pub const SSIM_WINDOW: usize = 11;
/// Standard deviation of the Gaussian window, in pixels.
const SIGMA: f64 = 1.5;
/// `C1 = (K1 L)^2` with `K1 = 0.01`, data range `L = 1`.
const C1: f32 = 0.01 * 0.01;
/// `C2 = (K2 L)^2` with `K2 = 0.03`.
const C2: f32 = 0.03 * 0.03;

/// Per-image SSIM of `pred` against `gt`, both `[B, C, H, W]` in [0, 1] (H, W >= 11).
///
/// With `mu`, `sigma^2`, `sigma_xy` the Gaussian-weighted local means, population variances
/// and covariance (normalised 11-tap window, sigma 1.5):
/// `SSIM = (2 mu_x mu_y + C1)(2 sigma_xy + C2) / ((mu_x^2 + mu_y^2 + C1)(sigma_x^2 + sigma_y^2 + C2))`,
/// averaged over the valid region (no padding: the `(H - 10) x (W - 10)` window centres that
/// fit inside the image) and over the channels. The local statistics are separable
/// convolutions on the device; the second moments are taken about 0.5 to keep f32 precise; the
/// final mean is accumulated on the host in f64.
///
/// # Panics
/// When the shapes differ or a side is below 11.
pub fn ssim(pred: Tensor<4>, gt: Tensor<4>) -> Vec<f64> {
    image_means(ssim_map(pred, gt))
}

/// Per image, the mean of an SSIM map `[B, C, h, w]` over its channels and windows: the
/// [`ssim`] of the images it was made from.
pub fn image_means(map: Tensor<4>) -> Vec<f64> {
    let [batch, channels, h, w] = map.dims();
    let count = (channels * h * w) as f64;
    per_image_sums(map.sum_dim(3), batch)
        .into_iter()
        .map(|sum| sum / count)
        .collect()
}

/// The SSIM map over the valid region, `[B, C, H - 10, W - 10]`: each window's SSIM, of which
/// [`ssim`] is the mean.
///
/// # Panics
/// As [`ssim`].
pub fn ssim_map(pred: Tensor<4>, gt: Tensor<4>) -> Tensor<4> {
    assert_eq!(
        pred.dims(),
        gt.dims(),
        "SSIM: prediction and target shapes differ"
    );
    let [batch, channels, height, width] = pred.dims();
    assert!(
        height >= SSIM_WINDOW && width >= SSIM_WINDOW,
        "SSIM: images must be at least {SSIM_WINDOW}x{SSIM_WINDOW}, got {height}x{width}"
    );
    let n = batch * channels;
    let x = pred.reshape([n, 1, height, width]).sub_scalar(0.5);
    let y = gt.reshape([n, 1, height, width]).sub_scalar(0.5);
    // The five local statistics in one batch: E[x], E[y], E[x^2], E[y^2], E[xy] (about 0.5).
    let stack = Tensor::cat(
        vec![
            x.clone(),
            y.clone(),
            x.clone().mul(x.clone()),
            y.clone().mul(y.clone()),
            x.mul(y),
        ],
        0,
    );
    let filtered = gaussian_filter_valid(stack);
    let [_, _, h, w] = filtered.dims();
    let part = |i: usize| {
        filtered
            .clone()
            .slice([i * n..(i + 1) * n, 0..1, 0..h, 0..w])
    };
    let (ex, ey, exx, eyy, exy) = (part(0), part(1), part(2), part(3), part(4));
    let var_x = exx.sub(ex.clone().mul(ex.clone()));
    let var_y = eyy.sub(ey.clone().mul(ey.clone()));
    let cov = exy.sub(ex.clone().mul(ey.clone()));
    let mu_x = ex.add_scalar(0.5);
    let mu_y = ey.add_scalar(0.5);
    let numerator = mu_x
        .clone()
        .mul(mu_y.clone())
        .mul_scalar(2.0)
        .add_scalar(C1)
        .mul(cov.mul_scalar(2.0).add_scalar(C2));
    let denominator = mu_x
        .clone()
        .mul(mu_x)
        .add(mu_y.clone().mul(mu_y))
        .add_scalar(C1)
        .mul(var_x.add(var_y).add_scalar(C2));
    numerator.div(denominator).reshape([batch, channels, h, w])
}

/// Valid (unpadded) separable Gaussian filtering of `[N, 1, H, W]`.
fn gaussian_filter_valid(x: Tensor<4>) -> Tensor<4> {
    let device = x.device();
    let taps = gaussian_taps(&device);
    let options = || ConvOptions::new([1, 1], [0, 0], [1, 1], 1);
    let rows = conv2d(
        x,
        taps.clone().reshape([1, 1, 1, SSIM_WINDOW]),
        None,
        options(),
    );
    conv2d(rows, taps.reshape([1, 1, SSIM_WINDOW, 1]), None, options())
}

/// The normalised Gaussian window, `exp(-i^2 / (2 sigma^2))` for `i = -5..=5`, summing to 1.
fn gaussian_taps(device: &Device) -> Tensor<1> {
    let radius = (SSIM_WINDOW / 2) as f64;
    let raw: Vec<f64> = (0..SSIM_WINDOW)
        .map(|i| {
            let d = i as f64 - radius;
            (-d * d / (2.0 * SIGMA * SIGMA)).exp()
        })
        .collect();
    let total: f64 = raw.iter().sum();
    let taps: Vec<f32> = raw.iter().map(|v| (v / total) as f32).collect();
    Tensor::from_floats(taps.as_slice(), device)
}
