//! Multi-head self-attention with two interchangeable kinds sharing one set of weights: full
//! softmax attention (the teacher) and SANA-style linear attention (paper Sec. 3.4).

use burn::config::Config;
use burn::module::Module;
use burn::nn::{Initializer, Linear, LinearConfig, RmsNorm, RmsNormConfig};
use burn::tensor::{Device, Tensor};
pub use prism_kernels::FeatureMap;
use prism_kernels::Mixing;
use serde::{Deserialize, Serialize};

use super::linear;

/// The attention a transformer block computes. Both kinds use the same parameters, so a block
/// switches kind without new weights (the paper's linear-attention stitching).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum AttentionKind {
    /// `softmax(Q K^T / sqrt(d_h)) V`: quadratic in the number of tokens.
    #[default]
    Full,
    /// `phi(Q) (phi(K)^T V) / (phi(Q) sum_j phi(K_j) + eps)`: linear in the number of tokens.
    Linear,
}

impl AttentionKind {
    /// The one-letter name used in compact patterns (`F` / `L`).
    pub fn letter(self) -> char {
        match self {
            Self::Full => 'F',
            Self::Linear => 'L',
        }
    }

    /// The lower-case name (`full` / `linear`), as in config files.
    pub fn name(self) -> &'static str {
        match self {
            Self::Full => "full",
            Self::Linear => "linear",
        }
    }
}

/// Configuration of a [`SelfAttention`] layer.
#[derive(Config, Debug)]
pub(crate) struct SelfAttentionConfig {
    /// Token width `d`.
    pub width: usize,
    /// Number of heads; `width` must be a multiple of it.
    pub heads: usize,
    /// Standard deviation of the `qkv` projection's normal initialisation.
    #[config(default = 0.02)]
    pub init_std: f64,
    /// Standard deviation of the output projection's initialisation (the depth-scaled one).
    #[config(default = 0.02)]
    pub out_init_std: f64,
    /// The attention kind the layer starts with.
    #[config(default = "AttentionKind::Full")]
    pub kind: AttentionKind,
    /// Feature map of linear attention.
    #[config(default = "FeatureMap::Relu")]
    pub feature_map: FeatureMap,
    /// `eps` in the normaliser of linear attention.
    #[config(default = 1e-6)]
    pub linear_eps: f64,
    /// `eps` of the per-head RMSNorm on queries and keys.
    #[config(default = 1e-5)]
    pub norm_eps: f64,
}

impl SelfAttentionConfig {
    /// Builds the layer.
    ///
    /// # Panics
    /// If `width` is not a multiple of `heads` (configs are checked before, see
    /// [`crate::PrismConfig::validate`]).
    pub(crate) fn init(&self, device: &Device) -> SelfAttention {
        assert!(
            self.heads > 0 && self.width.is_multiple_of(self.heads),
            "width {} is not a multiple of heads {}",
            self.width,
            self.heads
        );
        let head_dim = self.width / self.heads;
        let linear = |d_in: usize, d_out: usize, std: f64| {
            LinearConfig::new(d_in, d_out)
                .with_bias(false)
                .with_initializer(Initializer::Normal { mean: 0.0, std })
                .init(device)
        };
        SelfAttention {
            qkv: linear(self.width, 3 * self.width, self.init_std),
            q_norm: RmsNormConfig::new(head_dim)
                .with_epsilon(self.norm_eps)
                .init(device),
            k_norm: RmsNormConfig::new(head_dim)
                .with_epsilon(self.norm_eps)
                .init(device),
            out: linear(self.width, self.width, self.out_init_std),
            heads: self.heads,
            linear_eps: self.linear_eps,
            kind: self.kind,
            feature_map: self.feature_map,
            bf16_products: false,
        }
    }
}

/// Multi-head self-attention without biases, with QK-norm (RMSNorm per head on queries and
/// keys, one gain vector shared by the heads). The attention kind is not a parameter: changing
/// it with [`SelfAttention::set_kind`] leaves every weight untouched.
#[derive(Module, Debug)]
pub struct SelfAttention {
    /// Joint projection to queries, keys and values, `[d, 3d]`.
    pub qkv: Linear,
    /// RMSNorm on each head's queries.
    pub q_norm: RmsNorm,
    /// RMSNorm on each head's keys.
    pub k_norm: RmsNorm,
    /// Output projection `[d, d]`.
    pub out: Linear,
    heads: usize,
    linear_eps: f64,
    #[module(skip)]
    kind: AttentionKind,
    #[module(skip)]
    feature_map: FeatureMap,
    /// The `qkv` and output products, and full attention's, with bf16 operands (the block's
    /// bf16 on the CPU backends).
    #[module(skip)]
    bf16_products: bool,
}

impl SelfAttention {
    /// Whether the `qkv` and output products take bf16 operands (f32 inputs only; see
    /// [`prism_kernels::linear_bf16`]), and full attention's too where the CPU's bf16 kernel has
    /// an attention path ([`prism_kernels::attention_bf16`]).
    pub(crate) fn set_bf16_products(&mut self, bf16: bool) {
        self.bf16_products = bf16;
    }

    /// The attention kind this layer computes.
    pub fn kind(&self) -> AttentionKind {
        self.kind
    }

    /// Switches the attention kind in place; the weights are not touched.
    pub fn set_kind(&mut self, kind: AttentionKind) {
        self.kind = kind;
    }

    /// The feature map used when the kind is [`AttentionKind::Linear`].
    pub fn feature_map(&self) -> FeatureMap {
        self.feature_map
    }

    /// Number of heads.
    pub fn heads(&self) -> usize {
        self.heads
    }

    /// Self-attention of `x` (`[B, T, d]`) with this layer's kind: `q = RMSNorm(x W_q)`,
    /// `k = RMSNorm(x W_k)`, `v = x W_v` per head, attended and projected out. The attention
    /// with its QK-norms runs as one fused kernel on the CPU backends
    /// ([`prism_kernels::self_attention`]) and as Burn's ops elsewhere.
    pub fn forward(&self, x: Tensor<3>) -> Tensor<3> {
        let qkv = linear(&self.qkv, x, self.bf16_products);
        let mixing = match self.kind {
            AttentionKind::Full => Mixing::Softmax {
                bf16: self.bf16_products,
            },
            AttentionKind::Linear => Mixing::Linear {
                feature_map: self.feature_map,
                eps: self.linear_eps,
            },
        };
        // Both norms are built with the config's `norm_eps`.
        let heads_out = prism_kernels::self_attention(
            qkv,
            self.q_norm.gamma.val(),
            self.k_norm.gamma.val(),
            self.heads,
            self.q_norm.epsilon,
            mixing,
        );
        linear(&self.out, heads_out, self.bf16_products)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_util::{max_abs_diff, ndarray, values};
    use burn::tensor::{Distribution, TensorData};

    const SHAPE: [usize; 4] = [2, 3, 7, 4];

    fn random(seed: u64, device: &Device) -> Tensor<4> {
        device.seed(seed);
        Tensor::random(SHAPE, Distribution::Normal(0.0, 1.0), device)
    }

    /// Per (batch, head): row-major `[T, d_h]` slices.
    fn rows<'a>(x: &'a [f32], bh: usize) -> impl Fn(usize) -> &'a [f32] + 'a {
        let [_, _, t, dh] = SHAPE;
        move |i| &x[(bh * t + i) * dh..(bh * t + i + 1) * dh]
    }

    fn dot(a: &[f32], b: &[f32]) -> f64 {
        a.iter().zip(b).map(|(x, y)| *x as f64 * *y as f64).sum()
    }

    /// The explicit quadratic form `phi(Q) phi(K)^T V / (phi(Q) phi(K)^T 1 + eps)`, on the host.
    fn linear_reference(
        q: &[f32],
        k: &[f32],
        v: &[f32],
        phi: fn(f32) -> f32,
        eps: f64,
    ) -> Vec<f32> {
        let [b, h, t, dh] = SHAPE;
        let (pq, pk): (Vec<f32>, Vec<f32>) = (
            q.iter().map(|&x| phi(x)).collect(),
            k.iter().map(|&x| phi(x)).collect(),
        );
        let mut out = vec![0.0; q.len()];
        for bh in 0..b * h {
            let (qr, kr, vr) = (rows(&pq, bh), rows(&pk, bh), rows(v, bh));
            for i in 0..t {
                let weights: Vec<f64> = (0..t).map(|j| dot(qr(i), kr(j))).collect();
                let norm: f64 = weights.iter().sum::<f64>() + eps;
                for c in 0..dh {
                    let num: f64 = (0..t).map(|j| weights[j] * vr(j)[c] as f64).sum();
                    out[(bh * t + i) * dh + c] = (num / norm) as f32;
                }
            }
        }
        out
    }

    /// `softmax(Q K^T / sqrt(d_h)) V` with the `T x T` matrix written out, on the host.
    fn softmax_reference(q: &[f32], k: &[f32], v: &[f32]) -> Vec<f32> {
        let [b, h, t, dh] = SHAPE;
        let mut out = vec![0.0; q.len()];
        for bh in 0..b * h {
            let (qr, kr, vr) = (rows(q, bh), rows(k, bh), rows(v, bh));
            for i in 0..t {
                let scores: Vec<f64> = (0..t)
                    .map(|j| dot(qr(i), kr(j)) / (dh as f64).sqrt())
                    .collect();
                let top = scores.iter().cloned().fold(f64::MIN, f64::max);
                let exp: Vec<f64> = scores.iter().map(|s| (s - top).exp()).collect();
                let sum: f64 = exp.iter().sum();
                for c in 0..dh {
                    let acc: f64 = (0..t).map(|j| exp[j] / sum * vr(j)[c] as f64).sum();
                    out[(bh * t + i) * dh + c] = acc as f32;
                }
            }
        }
        out
    }

    fn inputs(device: &Device) -> (Tensor<4>, Tensor<4>, Tensor<4>) {
        (random(1, device), random(2, device), random(3, device))
    }

    #[test]
    fn linear_attention_equals_the_explicit_quadratic_form() {
        let device = ndarray();
        let (q, k, v) = inputs(&device);
        let (qv, kv, vv) = (values(&q), values(&k), values(&v));
        let relu: fn(f32) -> f32 = |x| x.max(0.0);
        let elu1: fn(f32) -> f32 = |x| if x > 0.0 { x + 1.0 } else { x.exp() };
        for (map, phi) in [(FeatureMap::Relu, relu), (FeatureMap::Elu1, elu1)] {
            let got = prism_kernels::unfused::linear_attention(
                q.clone(),
                k.clone(),
                v.clone(),
                map,
                1e-6,
            );
            assert_eq!(got.dims(), SHAPE);
            let want = linear_reference(&qv, &kv, &vv, phi, 1e-6);
            let err = max_abs_diff(&values(&got), &want);
            assert!(err < 1e-5, "{map:?}: max error {err}");
        }
    }

    #[test]
    fn full_attention_equals_explicit_softmax_attention_on_both_paths() {
        let device = ndarray();
        let (q, k, v) = inputs(&device);
        let want = softmax_reference(&values(&q), &values(&k), &values(&v));
        let fused = prism_kernels::attention(q.clone(), k.clone(), v.clone());
        let decomposed = prism_kernels::unfused::attention(q.clone(), k.clone(), v.clone());
        // The autodiff path: tracked inputs on an autodiff device.
        let ad = device.clone().autodiff();
        let track = |x: &Tensor<4>| Tensor::<4>::from_data(x.to_data(), &ad).require_grad();
        let tracked = prism_kernels::attention(track(&q), track(&k), track(&v));
        assert!(tracked.is_tracked());
        for (name, got) in [
            ("fused", fused),
            ("softmax", decomposed),
            ("autodiff", tracked),
        ] {
            let err = max_abs_diff(&values(&got), &want);
            assert!(err < 1e-5, "{name}: max error {err}");
        }
    }

    #[test]
    fn elu1_feature_map_values() {
        let device = ndarray();
        let x = Tensor::<1>::from_data(TensorData::from([-1.0f32, 0.0, 2.0]), &device);
        let got = values(&FeatureMap::Elu1.apply(x.clone()));
        let want = [(-1.0f32).exp(), 1.0, 3.0];
        assert!(max_abs_diff(&got, &want) < 1e-6, "{got:?}");
        assert_eq!(values(&FeatureMap::Relu.apply(x)), vec![0.0, 0.0, 2.0]);
    }

    #[test]
    fn self_attention_paths_agree_with_and_without_autodiff() {
        let ad = ndarray().autodiff();
        for kind in [AttentionKind::Full, AttentionKind::Linear] {
            ad.seed(7);
            let layer = SelfAttentionConfig::new(16, 4)
                .with_init_std(0.3)
                .with_out_init_std(0.3)
                .with_kind(kind)
                .init(&ad);
            let x = Tensor::<3>::random([2, 9, 16], Distribution::Normal(0.0, 1.0), &ad);
            let trained = layer.forward(x.clone());
            assert!(trained.is_tracked(), "{kind:?}: parameters must be tracked");
            let inference = layer.valid().forward(x.inner());
            assert!(!inference.is_tracked());
            let err = max_abs_diff(&values(&trained), &values(&inference));
            assert!(err < 1e-5, "{kind:?}: max error {err}");
        }
    }
}
