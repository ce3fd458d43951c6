//! The same operations composed from Burn's tensor ops: what every backend without a fused
//! kernel runs (GPU backends, half precision), and the reference the fused kernels are tested
//! against.

use burn::tensor::activation::softmax;
use burn::tensor::{DType, FloatDType, Tensor};

use crate::{FeatureMap, Mixing};

/// `GELU(x)` (Burn's).
pub fn gelu<const D: usize>(x: Tensor<D>) -> Tensor<D> {
    burn::tensor::activation::gelu(x)
}

/// LayerNorm without bias over the last dimension (Burn's `layer_norm`), its statistics taken
/// in f32 for f16 and bf16 inputs (Burn's `LayerNorm` module widens f16 only; bf16's 8-bit
/// mantissa would round the mean and variance of a row too).
pub fn layer_norm<const D: usize>(x: Tensor<D>, gamma: Tensor<1>, eps: f64) -> Tensor<D> {
    let dtype = x.dtype();
    if matches!(dtype, DType::F16 | DType::BF16) {
        burn::tensor::module::layer_norm(x.cast(DType::F32), gamma.cast(DType::F32), None, eps)
            .cast(dtype)
    } else {
        burn::tensor::module::layer_norm(x, gamma, None, eps)
    }
}

/// RMSNorm over the last dimension, `x / sqrt(mean(x^2) + eps) * gamma`, the mean of squares
/// taken in f32 (as Burn's `RmsNorm`).
pub fn rms_norm<const D: usize>(x: Tensor<D>, gamma: Tensor<1>, eps: f64) -> Tensor<D> {
    let dtype = x.dtype();
    let rms = (x.clone().cast(DType::F32).square().mean_dim(D - 1) + eps).sqrt();
    x / rms.cast(dtype) * gamma.unsqueeze()
}

/// `softmax(q k^T / sqrt(d_h)) v` on `[B, H, T, d_h]` tensors as matmul, softmax, matmul.
pub fn attention(q: Tensor<4>, k: Tensor<4>, v: Tensor<4>) -> Tensor<4> {
    let head_dim = q.dims()[3];
    let scores = q.matmul(k.swap_dims(2, 3)) * (1.0 / (head_dim as f64).sqrt());
    softmax(scores, 3).matmul(v)
}

/// `attend(q, k, v)` on the heads of the joint projection `qkv` `[B, T, 3 H d_h]`, each
/// `[B, H, T, d_h]`, and its output merged back to `[B, T, H d_h]`: one copy into head-major
/// order, after which `q`, `k` and `v` are slices of it, and one back. The reordering is made
/// of axis swaps, which every backend records correctly (served devices included; see
/// `prism_core::axes`).
pub fn heads_attention(
    qkv: Tensor<3>,
    heads: usize,
    attend: impl FnOnce(Tensor<4>, Tensor<4>, Tensor<4>) -> Tensor<4>,
) -> Tensor<3> {
    let [batch, tokens, joint] = qkv.dims();
    let (width, head_dim) = (joint / 3, joint / (3 * heads));
    let qkv = qkv
        .reshape([batch, tokens, 3, heads, head_dim])
        .swap_dims(1, 2)
        .swap_dims(0, 1)
        .swap_dims(2, 3)
        .reshape([3 * batch, heads, tokens, head_dim]);
    let part = |i: usize| qkv.clone().narrow(0, i * batch, batch);
    let out = attend(part(0), part(1), part(2));
    out.swap_dims(1, 2).reshape([batch, tokens, width])
}

/// Multi-head self-attention with QK-norm from the joint projection (see
/// `prism_kernels::self_attention`), composed from Burn's ops (softmax attention in f32 whatever
/// `mixing` asks).
pub fn self_attention(
    qkv: Tensor<3>,
    q_gain: Tensor<1>,
    k_gain: Tensor<1>,
    heads: usize,
    eps: f64,
    mixing: Mixing,
) -> Tensor<3> {
    heads_attention(qkv, heads, |q, k, v| {
        let (q, k) = (rms_norm(q, q_gain, eps), rms_norm(k, k_gain, eps));
        match mixing {
            Mixing::Softmax { .. } => attention(q, k, v),
            Mixing::Linear { feature_map, eps } => linear_attention(q, k, v, feature_map, eps),
        }
    })
}

/// Linear attention (SANA; paper Sec. 3.4) on `[B, H, T, d_h]` tensors:
///
/// `out_i = phi(q_i) (sum_j phi(k_j)^T v_j) / (phi(q_i) . sum_j phi(k_j) + eps)`
///
/// computed right to left, so the cost is `O(T d_h^2)` per head and no `T x T` matrix is ever
/// formed. The sums are accumulated in f32 whatever the input precision; the result is cast
/// back to the input's dtype.
pub fn linear_attention(
    q: Tensor<4>,
    k: Tensor<4>,
    v: Tensor<4>,
    feature_map: FeatureMap,
    eps: f64,
) -> Tensor<4> {
    let dtype = q.dtype();
    let to_f32 = |x: Tensor<4>| {
        if x.dtype() == DType::F32 {
            x
        } else {
            x.cast(FloatDType::F32)
        }
    };
    let phi_q = feature_map.apply(to_f32(q));
    let phi_k = feature_map.apply(to_f32(k));
    let v = to_f32(v);
    // [B, H, d_h, d_h]: sum_j phi(k_j)^T v_j.
    let kv = phi_k.clone().swap_dims(2, 3).matmul(v);
    // [B, H, 1, d_h]: sum_j phi(k_j).
    let k_sum = phi_k.sum_dim(2);
    let numerator = phi_q.clone().matmul(kv);
    // [B, H, T, 1]: phi(q_i) . sum_j phi(k_j).
    let normaliser = (phi_q * k_sum).sum_dim(3);
    let out = numerator / (normaliser + eps);
    if dtype == DType::F32 {
        out
    } else {
        out.cast(dtype)
    }
}

/// `x w` with both operands rounded to bf16 and an f32 result, as Burn's matmul of the
/// operands cast to bf16 and back to f32 (`x` of `[.., m, k]`, `w` of `[k, n]`).
pub fn matmul_bf16<const D: usize>(x: Tensor<D>, w: Tensor<2>) -> Tensor<D> {
    let round = |t: Tensor<D>| t.cast(DType::BF16).cast(DType::F32);
    round(x).matmul(round(w.unsqueeze()))
}
