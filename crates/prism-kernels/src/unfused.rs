//! The same operations composed from Burn's tensor ops: what every backend without a fused
//! kernel runs (GPU backends, half precision), and the reference the fused kernels are tested
//! against.

use burn::tensor::activation::softmax;
use burn::tensor::{DType, Tensor};

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

/// `x w` with both operands rounded to bf16 and an f32 result, as Burn's matmul of the
/// operands cast to bf16 and back to f32 (`x` of `[.., m, k]`, `w` of `[k, n]`).
pub fn matmul_bf16<const D: usize>(x: Tensor<D>, w: Tensor<2>) -> Tensor<D> {
    let round = |t: Tensor<D>| t.cast(DType::BF16).cast(DType::F32);
    round(x).matmul(round(w.unsqueeze()))
}
