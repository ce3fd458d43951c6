//! Peak signal-to-noise ratio.

use burn::tensor::Tensor;

/// Per-image PSNR in dB of `pred` against `gt`, both `[B, C, H, W]` with data range 1:
/// `PSNR = 10 log10(1 / MSE)`, MSE over all pixels and channels of an image.
///
/// The differences are taken on the device; squaring and summing happen on the host in f64
/// (a device-side f32 reduction was off by up to 1e-6 dB at 256 x 256 on ndarray), so the
/// result is exact to ~1e-7 dB whatever the backend. Identical images give `+inf`.
///
/// # Panics
/// When the shapes differ.
pub fn psnr(pred: Tensor<4>, gt: Tensor<4>) -> Vec<f64> {
    assert_eq!(
        pred.dims(),
        gt.dims(),
        "PSNR: prediction and target shapes differ"
    );
    let [batch, ..] = pred.dims();
    let diff: Vec<f32> = pred
        .sub(gt)
        .into_data()
        .try_into_vec_as::<f32>()
        .expect("float tensor data");
    let per_image = diff.len() / batch.max(1);
    diff.chunks(per_image.max(1))
        .map(|chunk| {
            let sse: f64 = chunk.iter().map(|&d| f64::from(d) * f64::from(d)).sum();
            -10.0 * (sse / chunk.len() as f64).log10()
        })
        .collect()
}

/// Sums every image's values of a `[B, ...]` tensor in f64 on the host.
pub(crate) fn per_image_sums<const D: usize>(values: Tensor<D>, batch: usize) -> Vec<f64> {
    let data: Vec<f32> = values
        .into_data()
        .try_into_vec_as::<f32>()
        .expect("float tensor data");
    let per_image = data.len() / batch.max(1);
    data.chunks(per_image.max(1))
        .map(|chunk| chunk.iter().map(|&v| f64::from(v)).sum())
        .collect()
}
