//! Patchify and unpatchify: images to token rows and back.
//!
//! Layout (shared by the whole project): `[B, C, H, W] -> [B, (H/p)(W/p), p*p*C]`, patches in
//! row-major order over the `(H/p, W/p)` grid, and inside a patch the feature index is
//! `(y * p + x) * C + c` (channel fastest). [`unpatchify`] is the exact inverse.

use burn::tensor::Tensor;
use prism_core::axes::permute;

/// Splits `[B, C, H, W]` into non-overlapping `p x p` patches: `[B, (H/p)(W/p), p*p*C]`.
///
/// # Panics
/// If `H` or `W` is not a multiple of `p`.
pub(crate) fn patchify(x: Tensor<4>, p: usize) -> Tensor<3> {
    let [batch, channels, height, width] = x.dims();
    assert!(
        p > 0 && height.is_multiple_of(p) && width.is_multiple_of(p),
        "image size {height}x{width} is not a multiple of the patch size {p}"
    );
    let (rows, cols) = (height / p, width / p);
    // [B, rows, cols, y, x, C]
    permute(
        x.reshape([batch, channels, rows, p, cols, p]),
        [0, 2, 4, 3, 5, 1],
    )
    .reshape([batch, rows * cols, p * p * channels])
}

/// Reassembles patches `[B, (H/p)(W/p), p*p*C]` into `[B, C, H, W]`: the inverse of
/// [`patchify`].
///
/// # Panics
/// If the token count or feature size does not match `height`, `width`, `channels` and `p`.
pub(crate) fn unpatchify(
    tokens: Tensor<3>,
    channels: usize,
    height: usize,
    width: usize,
    p: usize,
) -> Tensor<4> {
    let [batch, count, features] = tokens.dims();
    assert!(
        p > 0 && height.is_multiple_of(p) && width.is_multiple_of(p),
        "image size {height}x{width} is not a multiple of the patch size {p}"
    );
    let (rows, cols) = (height / p, width / p);
    assert_eq!(
        (count, features),
        (rows * cols, p * p * channels),
        "tokens [{batch}, {count}, {features}] do not form a {channels}x{height}x{width} image \
         with patch {p}"
    );
    // [B, C, rows, y, cols, x]
    permute(
        tokens.reshape([batch, rows, cols, p, p, channels]),
        [0, 5, 1, 3, 2, 4],
    )
    .reshape([batch, channels, height, width])
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_util::{ndarray, values};
    use burn::tensor::TensorData;

    fn ramp(shape: [usize; 4]) -> Tensor<4> {
        let n: usize = shape.iter().product();
        let data: Vec<f32> = (0..n).map(|i| i as f32).collect();
        Tensor::from_data(TensorData::new(data, shape), &ndarray())
    }

    #[test]
    fn patchify_layout_is_row_major_patches_channel_fastest() {
        let (b, c, h, w, p) = (2, 3, 4, 6, 2);
        let x = ramp([b, c, h, w]);
        let tokens = patchify(x, p);
        assert_eq!(tokens.dims(), [b, (h / p) * (w / p), p * p * c]);
        let got = values(&tokens);
        let cols = w / p;
        for bi in 0..b {
            for row in 0..h / p {
                for col in 0..cols {
                    for y in 0..p {
                        for xx in 0..p {
                            for ci in 0..c {
                                let token = row * cols + col;
                                let feature = (y * p + xx) * c + ci;
                                let index = (bi * (h / p) * cols + token) * p * p * c + feature;
                                let pixel = ((bi * c + ci) * h + row * p + y) * w + col * p + xx;
                                assert_eq!(got[index], pixel as f32);
                            }
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn unpatchify_inverts_patchify_exactly() {
        let x = ramp([2, 9, 16, 24]);
        let back = unpatchify(patchify(x.clone(), 8), 9, 16, 24, 8);
        assert_eq!(values(&back), values(&x));
        let tokens = patchify(ramp([1, 6, 8, 8]), 4);
        let again = patchify(unpatchify(tokens.clone(), 6, 8, 8, 4), 4);
        assert_eq!(values(&again), values(&tokens));
    }
}
