//! A DPT-style dense head (Ranftl et al. 2021) on the source tokens of several transformer
//! blocks: reassemble each tap into a feature map at its own scale, fuse them coarse to fine,
//! upsample to full resolution and project to the output channels.
//!
//! With `K` taps (earliest first) on a grid of `h x w` patch tokens:
//!
//! - Reassemble tap `k`: `Linear(d, c f_k^2)` per token, then a pixel shuffle to a
//!   `[c, f_k h, f_k w]` map (a transposed convolution with kernel and stride `f_k`), with
//!   `f = 4, 2, 1, 1` for the taps from the earliest: early blocks give the fine maps.
//! - Fuse from the last tap: `x <- RCU(up(x) + map_k)`, `up` a bilinear upsampling to the finer
//!   map's size and `RCU(x) = x + Conv3x3(GELU(x))` a residual convolution unit.
//! - Head: `Conv3x3(c, c/2)`, GELU, bilinear upsampling to `H x W`, then per pixel
//!   `Linear(c/2, 32)`, GELU, `Linear(32, outputs)`.

use burn::config::Config;
use burn::module::Module;
use burn::nn::conv::{Conv2d, Conv2dConfig};
use burn::nn::{Initializer, Linear, LinearConfig, PaddingConfig2d};
use burn::tensor::{Device, Tensor, TensorData};
use prism_core::axes::permute;
use prism_kernels::{conv2d, gelu};

/// The upsampling factors of the reassembled maps, from the earliest tap (for patch sizes that
/// are multiples of 4; otherwise every map stays on the token grid, see [`reassemble_factors`]).
pub(crate) const REASSEMBLE_FACTORS: [usize; 4] = [4, 2, 1, 1];

/// The reassembly factors for patch size `p`: [`REASSEMBLE_FACTORS`] when `p` is a multiple of
/// 4 (so that the finest map, at `4 / p` of the image, upsamples to it by an integer factor),
/// else all 1.
pub(crate) fn reassemble_factors(patch_size: usize) -> [usize; 4] {
    if patch_size.is_multiple_of(4) {
        REASSEMBLE_FACTORS
    } else {
        [1; 4]
    }
}
/// Hidden channels of the per-pixel output MLP.
const HEAD_HIDDEN: usize = 32;

/// The stage-I blocks a DPT head reads for `m` stage-I blocks: up to four, evenly spaced,
/// the last one `m - 1` (e.g. 2, 5, 8, 11 for `m = 12`; 0, 1 for `m = 2`).
pub(crate) fn dpt_taps(m: usize) -> Vec<usize> {
    let k = m.min(REASSEMBLE_FACTORS.len());
    (0..k).map(|i| ((i + 1) * m).div_ceil(k) - 1).collect()
}

/// Configuration of a [`DptHead`].
#[derive(Config, Debug)]
pub(crate) struct DptHeadConfig {
    /// Token width `d`.
    pub width: usize,
    /// Number of taps `K` (1 to 4).
    pub taps: usize,
    /// Feature channels `c` of the maps.
    pub channels: usize,
    /// Output channels per pixel.
    pub outputs: usize,
    /// Patch size `p` of the token grid.
    pub patch_size: usize,
    /// Standard deviation of the linear layers' normal initialisation.
    #[config(default = 0.02)]
    pub init_std: f64,
}

impl DptHeadConfig {
    /// Builds the head.
    ///
    /// # Panics
    /// If `taps` is not 1 to 4 or `channels` is below 2.
    pub(crate) fn init(&self, device: &Device) -> DptHead {
        assert!(
            (1..=REASSEMBLE_FACTORS.len()).contains(&self.taps),
            "a DPT head reads 1 to 4 taps, not {}",
            self.taps
        );
        assert!(self.channels >= 2, "a DPT head needs at least 2 channels");
        let c = self.channels;
        let factors = reassemble_factors(self.patch_size);
        let normal = Initializer::Normal {
            mean: 0.0,
            std: self.init_std,
        };
        let linear = |i: usize, o: usize| {
            LinearConfig::new(i, o)
                .with_initializer(normal.clone())
                .init(device)
        };
        let conv = |i: usize, o: usize| {
            Conv2dConfig::new([i, o], [3, 3])
                .with_padding(PaddingConfig2d::Same)
                .init(device)
        };
        DptHead {
            reassemble: (0..self.taps)
                .map(|k| linear(self.width, c * factors[k].pow(2)))
                .collect(),
            refine: (0..self.taps.saturating_sub(1))
                .map(|_| conv(c, c))
                .collect(),
            head_conv: conv(c, c / 2),
            head_hidden: linear(c / 2, HEAD_HIDDEN),
            head_out: linear(HEAD_HIDDEN, self.outputs),
            channels: c,
            factors,
        }
    }
}

/// The DPT-style head (see the module docs).
#[derive(Module, Debug)]
pub struct DptHead {
    /// Per tap: `Linear(d, c f_k^2)` before the pixel shuffle.
    pub reassemble: Vec<Linear>,
    /// The residual convolution units of the fusion, one per fusion step.
    pub refine: Vec<Conv2d>,
    /// `Conv3x3(c, c/2)` of the head.
    pub head_conv: Conv2d,
    /// `Linear(c/2, 32)` per pixel.
    pub head_hidden: Linear,
    /// `Linear(32, outputs)` per pixel.
    pub head_out: Linear,
    channels: usize,
    factors: [usize; 4],
}

/// `[B, h w, c f^2]` token features to a `[B, c, f h, f w]` map (pixel shuffle).
pub(crate) fn shuffle(x: Tensor<3>, c: usize, f: usize, h: usize, w: usize) -> Tensor<4> {
    let [b, _, _] = x.dims();
    permute(x.reshape([b, h, w, f, f, c]), [0, 5, 1, 3, 2, 4]).reshape([b, c, h * f, w * f])
}

/// The `[n, f n]` matrix of bilinear upsampling by the integer factor `f` along one axis,
/// with half-pixel centres and edge clamping (`align_corners = false`, as Burn's and PyTorch's
/// bilinear `interpolate`): output `f i + r` reads the input at `i + d_r`,
/// `d_r = (2 r + 1 - f) / 2f`, i.e. `(1 - |d_r|) x_i + |d_r| x_{i +- 1}`.
fn upsampling_matrix(n: usize, f: usize, device: &Device) -> Tensor<2> {
    let mut m = vec![0.0f32; n * n * f];
    for i in 0..n {
        for r in 0..f {
            let d = (2.0 * r as f32 + 1.0 - f as f32) / (2.0 * f as f32);
            let neighbour = if d < 0.0 {
                i.saturating_sub(1)
            } else {
                (i + 1).min(n - 1)
            };
            let column = f * i + r;
            m[i * n * f + column] += 1.0 - d.abs();
            m[neighbour * n * f + column] += d.abs();
        }
    }
    Tensor::from_data(TensorData::new(m, [n, n * f]), device)
}

/// Bilinear upsampling of `x` to `height x width`, integer multiples of its size: one matrix
/// product per axis with [`upsampling_matrix`], whose backward pass is two products on every
/// backend (ndarray has no bilinear `interpolate` backward).
///
/// # Panics
/// If `height` or `width` is not a multiple of the input's size.
pub(crate) fn resize(x: Tensor<4>, height: usize, width: usize) -> Tensor<4> {
    let [b, c, h, w] = x.dims();
    assert!(
        height.is_multiple_of(h) && width.is_multiple_of(w),
        "DPT upsampling from {h}x{w} to {height}x{width} is not by an integer factor"
    );
    let device = x.device();
    let x = if width == w {
        x
    } else {
        prism_kernels::matmul(
            x.reshape([b * c * h, w]),
            upsampling_matrix(w, width / w, &device),
        )
        .reshape([b, c, h, width])
    };
    if height == h {
        return x;
    }
    prism_kernels::matmul_left(
        upsampling_matrix(h, height / h, &device).transpose(),
        x.reshape([b * c, h, width]),
        None,
    )
    .reshape([b, c, height, width])
}

/// A per-pixel linear layer on `[B, C, H, W]`: `W^T x` over the channels of every pixel,
/// one matrix product on the channel-first layout (no permutation copies at full resolution).
fn per_pixel(linear: &Linear, x: Tensor<4>) -> Tensor<4> {
    let [b, c, h, w] = x.dims();
    let weight = linear.weight.val().transpose();
    let out = weight.dims()[0];
    let bias = linear.bias.as_ref().map(|bias| bias.val());
    prism_kernels::matmul_left(weight, x.reshape([b, c, h * w]), bias).reshape([b, out, h, w])
}

impl DptHead {
    /// The per-pixel outputs `[B, outputs, H, W]` from the source tokens of the taps
    /// (`[B, h w, d]` each, earliest first) on an `h x w` token grid.
    ///
    /// # Panics
    /// If the number of taps differs from the config's.
    pub fn forward(
        &self,
        taps: &[Tensor<3>],
        grid: (usize, usize),
        height: usize,
        width: usize,
    ) -> Tensor<4> {
        assert_eq!(taps.len(), self.reassemble.len(), "DPT taps");
        let (h, w) = grid;
        let c = self.channels;
        let maps: Vec<Tensor<4>> = taps
            .iter()
            .zip(&self.reassemble)
            .enumerate()
            .map(|(k, (tokens, linear))| {
                let f = self.factors[k];
                shuffle(prism_kernels::linear(linear, tokens.clone()), c, f, h, w)
            })
            .collect();
        let mut maps = maps.into_iter().rev();
        let mut x = maps.next().expect("at least one tap");
        for (map, conv) in maps.zip(self.refine.iter().rev()) {
            let [_, _, mh, mw] = map.dims();
            x = resize(x, mh, mw) + map;
            x = x.clone() + conv2d(conv, gelu(x));
        }
        let x = gelu(conv2d(&self.head_conv, x));
        let x = resize(x, height, width);
        per_pixel(&self.head_out, gelu(per_pixel(&self.head_hidden, x)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn per_pixel_is_the_linear_layer_on_every_pixel() {
        let device = crate::test_util::ndarray();
        device.seed(2);
        let linear = LinearConfig::new(5, 3).init(&device);
        let x = Tensor::<4>::random([2, 5, 4, 6], burn::tensor::Distribution::Default, &device);
        let want = permute(
            linear.forward(permute(x.clone(), [0, 2, 3, 1])),
            [0, 3, 1, 2],
        );
        let got = per_pixel(&linear, x);
        assert_eq!(got.dims(), [2, 3, 4, 6]);
        let err = crate::test_util::max_abs_diff(
            &crate::test_util::values(&got),
            &crate::test_util::values(&want),
        );
        assert!(err < 1e-6, "max error {err}");
    }

    #[test]
    fn taps_are_evenly_spaced_and_end_at_the_last_block() {
        assert_eq!(dpt_taps(12), vec![2, 5, 8, 11]);
        assert_eq!(dpt_taps(4), vec![0, 1, 2, 3]);
        assert_eq!(dpt_taps(2), vec![0, 1]);
        assert_eq!(dpt_taps(1), vec![0]);
        assert_eq!(dpt_taps(6), vec![1, 2, 4, 5]);
    }

    #[test]
    fn upsampling_matches_burns_bilinear_interpolate() {
        use burn::tensor::Distribution;
        use burn::tensor::module::interpolate;
        use burn::tensor::ops::{InterpolateMode, InterpolateOptions};
        let device = crate::test_util::ndarray();
        let x = Tensor::<4>::random([2, 3, 5, 4], Distribution::Normal(0.0, 1.0), &device);
        for (fh, fw) in [(2, 2), (4, 2), (3, 1), (1, 1)] {
            let ours = crate::test_util::values(&resize(x.clone(), 5 * fh, 4 * fw));
            let theirs = crate::test_util::values(&interpolate(
                x.clone(),
                InterpolateOptions::new(InterpolateMode::Bilinear)
                    .with_align_corners(false)
                    .with_output_size([5 * fh, 4 * fw]),
            ));
            let err = crate::test_util::max_abs_diff(&ours, &theirs);
            assert!(err < 1e-5, "x{fh} x{fw}: {err}");
        }
    }

    #[test]
    fn upsampling_gradients_match_finite_differences() {
        use burn::tensor::Distribution;
        let device = crate::test_util::ndarray();
        device.seed(3);
        let ad = device.clone().autodiff();
        let x = Tensor::<4>::random([1, 2, 3, 2], Distribution::Normal(0.0, 1.0), &device);
        let y = Tensor::<4>::random([1, 2, 6, 8], Distribution::Normal(0.0, 1.0), &device);
        // loss(x) = sum(resize(x) * y): linear in x, so central differences are exact but for
        // rounding.
        let loss = |x: Tensor<4>| -> f32 { (resize(x, 6, 8) * y.clone()).sum().into_scalar() };
        let tracked = Tensor::<4>::from_data(x.to_data(), &ad).require_grad();
        let grads = (resize(tracked.clone(), 6, 8) * Tensor::from_data(y.to_data(), &ad))
            .sum()
            .backward();
        let grad = crate::test_util::values(&tracked.grad(&grads).expect("x is tracked"));
        let base = crate::test_util::values(&x);
        let eps = 1e-2;
        for (i, &g) in grad.iter().enumerate() {
            let at = |delta: f32| {
                let mut v = base.clone();
                v[i] += delta;
                loss(Tensor::from_data(TensorData::new(v, [1, 2, 3, 2]), &device))
            };
            let fd = (at(eps) - at(-eps)) / (2.0 * eps);
            assert!((g - fd).abs() < 1e-3, "element {i}: {g} against {fd}");
        }
    }

    #[test]
    fn pixel_shuffle_places_each_token_on_its_patch() {
        let device = crate::test_util::ndarray();
        // One channel, factor 2, a 1 x 2 grid: token t's four values land in its 2x2 patch,
        // row-major inside the patch.
        let x = Tensor::<3>::from_data(
            TensorData::new(vec![1.0f32, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0], [1, 2, 4]),
            &device,
        );
        let map = crate::test_util::values(&shuffle(x, 1, 2, 1, 2));
        assert_eq!(map, vec![1.0, 2.0, 5.0, 6.0, 3.0, 4.0, 7.0, 8.0]);
    }
}
