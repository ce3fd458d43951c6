//! LPIPS v0.1 with the AlexNet backbone (Zhang et al. 2018), as a differentiable training loss
//! and as a metric.
//!
//! `LPIPS(x, y) = sum_l mean_{h,w} w_l . (f_l(x)_hw / |f_l(x)_hw| - f_l(y)_hw / |f_l(y)_hw|)^2`
//! where `f_l` are the five ReLU taps of AlexNet on the scaled input `(2x - 1 - shift) / scale`
//! and `w_l` the learned non-negative 1x1 "linear" layers.
//!
//! Written here rather than taken from `burn-train`'s vision metrics because (1) that feature
//! links a downloader (the crate must have no code path that downloads) and (2) its channel
//! normalisation `x / max(|x|, eps)` has a NaN gradient wherever a feature vector is all zero
//! (`0 * d sqrt(0)`), which a ReLU tap can produce; here `x / sqrt(|x|^2 + eps^2)` keeps the
//! gradient finite and changes no value measurably (eps = 1e-10).

use std::path::Path;

use burn::module::Module;
use burn::nn::PaddingConfig2d;
use burn::nn::conv::{Conv2d, Conv2dConfig};
use burn::store::{ModuleSnapshot, SafetensorsStore};
use burn::tensor::activation::relu;
use burn::tensor::{Device, Tensor};
use prism_core::phases::{Phase, timed};
use prism_kernels::{conv2d, max_pool2d};

use crate::LossError;

/// The smallest image side AlexNet's five taps are defined for (conv1 stride 4 and two 3x3
/// stride-2 max-pools leave one pixel at side 31).
pub const LPIPS_MIN_SIDE: usize = 31;

/// Channel shift of LPIPS's scaling layer (applied to inputs in [-1, 1]).
const SHIFT: [f32; 3] = [-0.030, -0.088, -0.188];
/// Channel scale of LPIPS's scaling layer.
const SCALE: [f32; 3] = [0.458, 0.448, 0.450];
/// Epsilon of the channel-wise unit normalisation.
const NORM_EPS: f32 = 1e-10;
/// Number of weight tensors in the file: 5 convolutions (weight, bias) and 5 linear layers.
const WEIGHT_TENSORS: usize = 15;

/// LPIPS v0.1, AlexNet backbone: five AlexNet convolutions and five learned 1x1 layers.
///
/// Build it with [`Lpips::load`] (the real weights); its parameters do not require gradients,
/// so on an autodiff device it passes gradients to its inputs only.
#[derive(Module, Debug)]
pub struct Lpips {
    /// 3 -> 64, kernel 11, stride 4, padding 2.
    conv1: Conv2d,
    /// 64 -> 192, kernel 5, padding 2 (after a 3x3 stride-2 max-pool).
    conv2: Conv2d,
    /// 192 -> 384, kernel 3, padding 1 (after a 3x3 stride-2 max-pool).
    conv3: Conv2d,
    /// 384 -> 256, kernel 3, padding 1.
    conv4: Conv2d,
    /// 256 -> 256, kernel 3, padding 1.
    conv5: Conv2d,
    /// 1x1 weights of tap 1 (64 channels), no bias.
    lin0: Conv2d,
    /// 1x1 weights of tap 2 (192 channels).
    lin1: Conv2d,
    /// 1x1 weights of tap 3 (384 channels).
    lin2: Conv2d,
    /// 1x1 weights of tap 4 (256 channels).
    lin3: Conv2d,
    /// 1x1 weights of tap 5 (256 channels).
    lin4: Conv2d,
}

impl Lpips {
    /// The network with random weights: only the structure, for [`Lpips::load`] to fill.
    fn untrained(device: &Device) -> Self {
        let conv = |channels: [usize; 2], kernel: usize, stride: usize, pad: usize| {
            Conv2dConfig::new(channels, [kernel, kernel])
                .with_stride([stride, stride])
                .with_padding(PaddingConfig2d::Explicit(pad, pad, pad, pad))
                .init(device)
        };
        let lin = |channels: usize| {
            Conv2dConfig::new([channels, 1], [1, 1])
                .with_bias(false)
                .init(device)
        };
        Self {
            conv1: conv([3, 64], 11, 4, 2),
            conv2: conv([64, 192], 5, 1, 2),
            conv3: conv([192, 384], 3, 1, 1),
            conv4: conv([384, 256], 3, 1, 1),
            conv5: conv([256, 256], 3, 1, 1),
            lin0: lin(64),
            lin1: lin(192),
            lin2: lin(384),
            lin3: lin(256),
            lin4: lin(256),
        }
    }

    /// Loads the weights from a safetensors file in the official PyTorch LPIPS layout
    /// (`net.sliceN.K.{weight,bias}`, `linN.model.1.weight`; see `data/LPIPS_PROVENANCE.md`)
    /// onto `device`, frozen (no parameter requires a gradient). Use
    /// [`crate::find_lpips_weights`] to locate the file.
    ///
    /// # Errors
    /// [`LossError::WeightsInvalid`] when the file cannot be read or does not fill all 15
    /// tensors with the right shapes.
    pub fn load(path: &Path, device: &Device) -> Result<Self, LossError> {
        let invalid = |reason: String| LossError::WeightsInvalid {
            path: path.to_path_buf(),
            reason,
        };
        if !path.is_file() {
            return Err(invalid("no such file".into()));
        }
        let mut store = SafetensorsStore::from_file(path)
            .with_key_remapping(r"^net\.slice([1-5])\.[0-9]+\.", "conv$1.")
            .with_key_remapping(r"^lin([0-4])\.model\.1\.", "lin$1.");
        let mut lpips = Self::untrained(device);
        let result = lpips
            .load_from(&mut store)
            .map_err(|e| invalid(e.to_string()))?;
        if !result.errors.is_empty() || !result.missing.is_empty() {
            return Err(invalid(format!(
                "{} errors ({:?}), missing tensors {:?}",
                result.errors.len(),
                result.errors.first(),
                result.missing.iter().map(|(p, _)| p).collect::<Vec<_>>()
            )));
        }
        if result.applied.len() != WEIGHT_TENSORS {
            return Err(invalid(format!(
                "expected {WEIGHT_TENSORS} tensors, applied {}",
                result.applied.len()
            )));
        }
        Ok(lpips.no_grad())
    }

    /// Loads the weights found by [`crate::find_lpips_weights`] (`explicit` path, then
    /// `PRISM_LPIPS_WEIGHTS`, then the workspace's `data/`).
    ///
    /// # Errors
    /// When no file is found or it does not hold the LPIPS weights.
    pub fn load_default(explicit: Option<&Path>, device: &Device) -> Result<Self, LossError> {
        Self::load(&crate::find_lpips_weights(explicit)?, device)
    }

    /// Per-image LPIPS distance between `pred` and `gt`, both `[B, 3, H, W]` in [0, 1]
    /// (H, W >= 31); returns `[B]`. Differentiable with respect to `pred`: the ground truth's
    /// pass is not tracked (a target and frozen weights), so the backward pass only runs
    /// through the prediction's half. The same as [`Lpips::reference`] of `gt`, then
    /// [`LpipsReference::forward`].
    ///
    /// # Panics
    /// When the shapes differ, there are not 3 channels, or a side is below 31.
    pub fn forward(&self, pred: Tensor<4>, gt: Tensor<4>) -> Tensor<1> {
        self.loss_reference(gt).forward(pred)
    }

    /// The unit-normalised AlexNet features of a batch of ground-truth images `gt`
    /// (`[B, 3, H, W]` in [0, 1], H, W >= 31), computed once for any number of predictions of
    /// the same images: `prism evaluate` scores several methods, and each one's disoccluded
    /// region, against one ground truth. Its wall time counts as [`Phase::Lpips`].
    ///
    /// # Panics
    /// When there are not 3 channels or a side is below 31.
    pub fn reference(&self, gt: Tensor<4>) -> LpipsReference<'_> {
        timed(Phase::Lpips, || self.loss_reference(gt))
    }

    /// [`Lpips::reference`] without the timing: the training loss's path, whose time belongs
    /// to its step. The objective scores both of a step's images against one target's features.
    pub fn loss_reference(&self, gt: Tensor<4>) -> LpipsReference<'_> {
        let dims = gt.dims();
        let [_, channels, height, width] = dims;
        assert_eq!(channels, 3, "LPIPS: images must have 3 channels");
        assert!(
            height >= LPIPS_MIN_SIDE && width >= LPIPS_MIN_SIDE,
            "LPIPS: images must be at least {LPIPS_MIN_SIDE}x{LPIPS_MIN_SIDE}, got {height}x{width}"
        );
        LpipsReference {
            net: self,
            dims,
            taps: self.taps(normalise(gt)).map(unit_normalise),
        }
    }

    /// Per-image LPIPS as numbers (the metric): [`Lpips::forward`] read back to the host. Its
    /// wall time counts as [`Phase::Lpips`].
    pub fn distance(&self, pred: Tensor<4>, gt: Tensor<4>) -> Vec<f64> {
        self.reference(gt).distance(pred)
    }

    /// A digest of the weights: equal for networks loaded from the same file, so that scores
    /// kept from one evaluation are only reused by another with the same network.
    pub fn digest(&self) -> u64 {
        use std::hash::{Hash, Hasher};
        let mut hasher = std::collections::hash_map::DefaultHasher::new();
        let convs = [
            &self.conv1,
            &self.conv2,
            &self.conv3,
            &self.conv4,
            &self.conv5,
        ];
        let lins = [&self.lin0, &self.lin1, &self.lin2, &self.lin3, &self.lin4];
        for conv in convs.into_iter().chain(lins) {
            let weights = conv.weight.val().into_data();
            weights.as_bytes().hash(&mut hasher);
        }
        hasher.finish()
    }

    /// The five ReLU taps of AlexNet's feature extractor.
    fn taps(&self, x: Tensor<4>) -> [Tensor<4>; 5] {
        let pool = |x: Tensor<4>| max_pool2d(x, [3, 3], [2, 2]);
        let t1 = relu(conv2d(&self.conv1, x));
        let t2 = relu(conv2d(&self.conv2, pool(t1.clone())));
        let t3 = relu(conv2d(&self.conv3, pool(t2.clone())));
        let t4 = relu(conv2d(&self.conv4, t3.clone()));
        let t5 = relu(conv2d(&self.conv5, t4.clone()));
        [t1, t2, t3, t4, t5]
    }
}

/// A batch of ground-truth images as LPIPS sees them ([`Lpips::reference`]): the five taps'
/// unit-normalised features, compared with each prediction scored against these images.
pub struct LpipsReference<'a> {
    /// The network whose features these are.
    net: &'a Lpips,
    /// The ground truth's shape, `[B, 3, H, W]`; predictions must match it.
    dims: [usize; 4],
    /// Unit-normalised features of the five taps.
    taps: [Tensor<4>; 5],
}

impl LpipsReference<'_> {
    /// Per-image LPIPS distance of `pred` (`[B, 3, H, W]` in [0, 1], the reference's shape)
    /// to the reference images; returns `[B]`, differentiable with respect to `pred`.
    ///
    /// # Panics
    /// When `pred`'s shape is not the reference's.
    pub fn forward(&self, pred: Tensor<4>) -> Tensor<1> {
        assert_eq!(
            pred.dims(),
            self.dims,
            "LPIPS: prediction and target shapes differ"
        );
        let batch = self.dims[0];
        let net = self.net;
        let lins = [&net.lin0, &net.lin1, &net.lin2, &net.lin3, &net.lin4];
        net.taps(normalise(pred))
            .into_iter()
            .zip(&self.taps)
            .zip(lins)
            .map(|((a, b), lin)| {
                let diff = unit_normalise(a).sub(b.clone());
                let [_, _, h, w] = diff.dims();
                conv2d(lin, diff.clone().mul(diff))
                    .reshape([batch, h * w])
                    .mean_dim(1)
                    .reshape([batch])
            })
            .reduce(|acc, d| acc.add(d))
            .expect("five taps")
    }

    /// Per-image LPIPS of `pred` to the reference images as numbers (the metric). Its wall
    /// time counts as [`Phase::Lpips`].
    pub fn distance(&self, pred: Tensor<4>) -> Vec<f64> {
        timed(Phase::Lpips, || {
            self.forward(pred)
                .into_data()
                .try_into_vec_as::<f32>()
                .expect("float tensor data")
                .into_iter()
                .map(f64::from)
                .collect()
        })
    }
}

/// LPIPS's input scaling of images in [0, 1]: `(2x - 1 - shift) / scale` per channel.
fn normalise(x: Tensor<4>) -> Tensor<4> {
    let device = x.device();
    let shift = Tensor::<1>::from_floats(SHIFT, &device).reshape([1, 3, 1, 1]);
    let scale = Tensor::<1>::from_floats(SCALE, &device).reshape([1, 3, 1, 1]);
    x.mul_scalar(2.0).sub_scalar(1.0).sub(shift).div(scale)
}

/// Unit length along channels: `x / sqrt(sum_c x^2 + eps^2)` (finite gradient at `x = 0`).
fn unit_normalise(x: Tensor<4>) -> Tensor<4> {
    let norm = x
        .clone()
        .mul(x.clone())
        .sum_dim(1)
        .add_scalar(NORM_EPS * NORM_EPS)
        .sqrt();
    x.div(norm)
}

#[cfg(test)]
mod tests {
    use super::*;
    use prism_core::BackendKind;

    #[test]
    fn unit_normalisation_has_a_finite_gradient_at_zero_features() {
        let device = BackendKind::Ndarray.device().unwrap().autodiff();
        // Channel vectors: (3, 4) at pixel 0 and (0, 0) at pixel 1.
        let x = Tensor::<1>::from_floats([3.0, 0.0, 4.0, 0.0], &device)
            .reshape([1, 2, 1, 2])
            .require_grad();
        let unit = unit_normalise(x.clone());
        let values = unit.clone().into_data().try_into_vec_as::<f32>().unwrap();
        assert!((values[0] - 0.6).abs() < 1e-6 && (values[2] - 0.8).abs() < 1e-6);
        assert_eq!((values[1], values[3]), (0.0, 0.0));
        let weights = Tensor::<1>::from_floats([1.0, 2.0, 3.0, 4.0], &device).reshape([1, 2, 1, 2]);
        let grads = unit.mul(weights).sum().backward();
        let g = x
            .grad(&grads)
            .unwrap()
            .into_data()
            .try_into_vec_as::<f32>()
            .unwrap();
        assert!(g.iter().all(|v| v.is_finite()), "gradient {g:?}");
        // d/dx (x / |x|) . w at (3, 4) with w = (1, 3): (w - u (u . w)) / |x|.
        let (u, w) = ([0.6f32, 0.8], [1.0f32, 3.0]);
        let dot = u[0] * w[0] + u[1] * w[1];
        assert!((g[0] - (w[0] - u[0] * dot) / 5.0).abs() < 1e-5);
        assert!((g[2] - (w[1] - u[1] * dot) / 5.0).abs() < 1e-5);
    }

    /// Two networks' digests differ when their weights do, and a copy's is the same.
    #[test]
    fn the_digest_tells_networks_apart() {
        let device = BackendKind::Ndarray.device().unwrap();
        let (a, b) = (Lpips::untrained(&device), Lpips::untrained(&device));
        assert_eq!(a.digest(), a.clone().digest());
        assert_ne!(a.digest(), b.digest());
    }
}
