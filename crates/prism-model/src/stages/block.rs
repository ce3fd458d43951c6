//! The transformer block of the cascade: pre-norm attention and MLP, no biases.

use burn::config::Config;
use burn::module::Module;
use burn::nn::{Initializer, LayerNorm, LayerNormConfig, Linear, LinearConfig};
use burn::tensor::{DType, Device, FloatDType, Tensor};

use super::attention::{AttentionKind, FeatureMap, SelfAttention, SelfAttentionConfig};
use super::{cast, linear};
use crate::precision::{CastParams, Precision};

/// Configuration of a [`PrismBlock`].
#[derive(Config, Debug)]
pub(crate) struct PrismBlockConfig {
    /// Token width `d`.
    pub width: usize,
    /// Number of attention heads.
    pub heads: usize,
    /// Hidden width of the MLP as a multiple of `width`.
    #[config(default = 4)]
    pub mlp_ratio: usize,
    /// Standard deviation of the normal initialisation of the input projections.
    #[config(default = 0.02)]
    pub init_std: f64,
    /// Number of blocks of the whole network; output projections are initialised with
    /// `init_std / sqrt(2 * num_blocks)` so that the residual stream's variance does not grow
    /// with depth.
    #[config(default = 1)]
    pub num_blocks: usize,
    /// The attention kind the block starts with.
    #[config(default = "AttentionKind::Full")]
    pub attention: AttentionKind,
    /// Feature map of linear attention.
    #[config(default = "FeatureMap::Relu")]
    pub feature_map: FeatureMap,
    /// `eps` in the normaliser of linear attention.
    #[config(default = 1e-6)]
    pub linear_eps: f64,
    /// `eps` of the LayerNorms and of the QK RMSNorms.
    #[config(default = 1e-5)]
    pub norm_eps: f64,
}

impl PrismBlockConfig {
    /// The standard deviation of the output projections: `init_std / sqrt(2 * num_blocks)`.
    pub(crate) fn out_init_std(&self) -> f64 {
        self.init_std / (2.0 * self.num_blocks.max(1) as f64).sqrt()
    }

    /// Builds the block.
    pub(crate) fn init(&self, device: &Device) -> PrismBlock {
        let norm = || {
            LayerNormConfig::new(self.width)
                .with_bias(false)
                .with_epsilon(self.norm_eps)
                .init(device)
        };
        let attention = SelfAttentionConfig::new(self.width, self.heads)
            .with_init_std(self.init_std)
            .with_out_init_std(self.out_init_std())
            .with_kind(self.attention)
            .with_feature_map(self.feature_map)
            .with_linear_eps(self.linear_eps)
            .with_norm_eps(self.norm_eps)
            .init(device);
        let hidden = self.width * self.mlp_ratio;
        let layer = |d_in: usize, d_out: usize, std: f64| {
            LinearConfig::new(d_in, d_out)
                .with_bias(false)
                .with_initializer(Initializer::Normal { mean: 0.0, std })
                .init(device)
        };
        PrismBlock {
            attention_norm: norm(),
            attention,
            mlp_norm: norm(),
            mlp: Mlp {
                fc_in: layer(self.width, hidden, self.init_std),
                fc_out: layer(hidden, self.width, self.out_init_std()),
                bf16_products: false,
            },
            norm_eps: self.norm_eps,
            compute: Precision::F32,
        }
    }
}

/// The block's feed-forward part: `Linear(d, r d) -> GELU -> Linear(r d, d)`, no biases.
#[derive(Module, Debug)]
pub struct Mlp {
    /// Expansion `[d, r d]`.
    pub fc_in: Linear,
    /// Output projection `[r d, d]` (depth-scaled initialisation).
    pub fc_out: Linear,
    /// Both products with bf16 operands (the block's bf16 on the CPU backends).
    #[module(skip)]
    bf16_products: bool,
}

impl Mlp {
    /// `fc_out(GELU(fc_in(x)))` (GELU fused on the CPU backends, see [`prism_kernels`]).
    pub fn forward(&self, x: Tensor<3>) -> Tensor<3> {
        let hidden = linear(&self.fc_in, x, self.bf16_products);
        linear(
            &self.fc_out,
            prism_kernels::gelu(hidden),
            self.bf16_products,
        )
    }
}

/// One transformer block of the cascade (pre-norm, no positional embedding: the Plücker rays
/// in the tokens are the position signal):
///
/// `x = x + Attn(LN(x))`, then `x = x + MLP(LN(x))`.
#[derive(Module, Debug)]
pub struct PrismBlock {
    /// LayerNorm (no bias) before attention.
    pub attention_norm: LayerNorm,
    /// Multi-head self-attention, full or linear.
    pub attention: SelfAttention,
    /// LayerNorm (no bias) before the MLP.
    pub mlp_norm: LayerNorm,
    /// The 4x GELU MLP.
    pub mlp: Mlp,
    /// `eps` of the two LayerNorms (Burn's `LayerNorm` does not expose its own), for the fused
    /// kernel.
    #[module(skip)]
    norm_eps: f64,
    /// The precision the block computes in (see [`crate::Precision`]): a setting, not a
    /// parameter, so checkpoints do not hold it.
    #[module(skip)]
    compute: Precision,
}

impl PrismBlock {
    /// The block on `x` (`[B, T, d]`), computed in the block's compute precision: `x` and the
    /// weights are cast to its dtype ([`PrismBlock::working_dtype`]; no op for those already
    /// in it; on tracked weights the cast is differentiable, so their gradients come back in
    /// their own dtype). The output is in that dtype.
    pub fn forward(&self, x: Tensor<3>) -> Tensor<3> {
        let dtype = self.working_dtype(&x.device());
        let x = cast(x, dtype);
        if self.dtype() == DType::from(dtype) {
            self.forward_as_stored(x)
        } else {
            self.clone()
                .map(&mut CastParams(dtype))
                .forward_as_stored(x)
        }
    }

    /// The block on `x` with its weights as they are stored (`x` in their dtype).
    fn forward_as_stored(&self, x: Tensor<3>) -> Tensor<3> {
        let x = x.clone() + self.attention.forward(self.norm(&self.attention_norm, x));
        x.clone() + self.mlp.forward(self.norm(&self.mlp_norm, x))
    }

    /// One of the block's LayerNorms on `x` through [`prism_kernels::layer_norm`] (fused on
    /// the CPU backends, Burn's op elsewhere); one with a bias, from foreign weights, takes
    /// Burn's module.
    fn norm(&self, norm: &LayerNorm, x: Tensor<3>) -> Tensor<3> {
        match norm.beta {
            None => prism_kernels::layer_norm(x, norm.gamma.val(), self.norm_eps),
            Some(_) => norm.forward(x),
        }
    }

    /// The dtype of the block's stored weights (`f32` unless cast for half-precision
    /// inference, see [`crate::Prism::with_block_precision`]).
    pub fn dtype(&self) -> DType {
        self.attention.qkv.weight.val().dtype()
    }

    /// The precision the block computes in.
    pub fn compute_precision(&self) -> Precision {
        self.compute
    }

    /// Sets the precision the block computes in; the stored weights are not touched.
    pub fn set_compute_precision(&mut self, precision: Precision) {
        self.compute = precision;
        let bf16 = precision == Precision::Bf16;
        self.mlp.bf16_products = bf16;
        self.attention.set_bf16_products(bf16);
    }

    /// The dtype the block's activations and weights take on `device`: the compute
    /// precision's, except bf16 on the CPU backends, where they stay f32 and the matrix
    /// products of the attention and MLP layers take bf16 operands
    /// ([`prism_kernels::matmul_bf16`]: AMX or AVX512-BF16 where the CPU has them), as do full
    /// attention's own two products where the CPU has AMX and no gradient is needed
    /// ([`prism_kernels::attention_bf16`]); the norms, GELU and attention's softmax then run
    /// the fused f32 kernels, as f32 does.
    pub fn working_dtype(&self, device: &Device) -> FloatDType {
        match self.compute {
            Precision::Bf16 if prism_kernels::is_host(device) => FloatDType::F32,
            precision => precision.dtype(),
        }
    }

    /// The block's attention kind.
    pub fn attention_kind(&self) -> AttentionKind {
        self.attention.kind()
    }

    /// Switches the block's attention kind in place, keeping every weight.
    pub fn set_attention(&mut self, kind: AttentionKind) {
        self.attention.set_kind(kind);
    }
}
