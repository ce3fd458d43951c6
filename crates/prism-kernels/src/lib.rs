//! Fused CPU kernels of prism's backbone, with hand-written backward passes.
//!
//! The backbone's training step, written with Burn's tensor ops, makes one graph node and one
//! pass over memory per elementary op: a LayerNorm is about eight, softmax attention
//! materialises the `T x T` scores three times, GELU calls libm's scalar `erf`. Here each of
//! GELU, LayerNorm (no bias), RMSNorm and softmax attention is one kernel forward and one
//! backward, vectorised for AVX-512 / AVX2 (chosen at run time) and split over threads;
//! attention runs block by block over the queries with `gemm` (FlashAttention's scheme).
//!
//! The functions below pick the kernel when the tensor is f32 on a CPU backend (flex, ndarray;
//! tracked by autodiff or not) and the composition of Burn ops in [`unfused`] otherwise (GPU
//! backends, half precision), so a model calls them on every backend.

mod attention;
mod elementwise;
mod extension;
mod host;
mod math;
mod norm;
pub mod unfused;

use burn::backend::{Dispatch, DispatchDevice};
use burn::tensor::{DType, Tensor};

pub use extension::FusedOps;

/// Whether `x` runs the fused kernels: f32 on flex or ndarray (with or without autodiff).
pub fn is_fused<const D: usize>(x: &Tensor<D>) -> bool {
    x.dtype() == DType::F32
        && matches!(
            x.device().inner().as_dispatch(),
            DispatchDevice::Flex(_) | DispatchDevice::NdArray(_)
        )
}

/// `GELU(x) = x Phi(x)` element-wise (the exact, erf-based GELU).
pub fn gelu<const D: usize>(x: Tensor<D>) -> Tensor<D> {
    if !is_fused(&x) {
        return unfused::gelu(x);
    }
    Tensor::from_dispatch(<Dispatch as FusedOps>::fused_gelu(x.into_dispatch()))
}

/// LayerNorm without bias over the last dimension: `(x - mean) / sqrt(var + eps) * gamma`
/// (biased variance), `gamma` of the last dimension's size.
pub fn layer_norm<const D: usize>(x: Tensor<D>, gamma: Tensor<1>, eps: f64) -> Tensor<D> {
    if !is_fused(&x) || gamma.dtype() != DType::F32 {
        return unfused::layer_norm(x, gamma, eps);
    }
    Tensor::from_dispatch(<Dispatch as FusedOps>::fused_layer_norm(
        x.into_dispatch(),
        gamma.into_dispatch(),
        eps,
    ))
}

/// RMSNorm over the last dimension: `x / sqrt(mean(x^2) + eps) * gamma`.
pub fn rms_norm<const D: usize>(x: Tensor<D>, gamma: Tensor<1>, eps: f64) -> Tensor<D> {
    if !is_fused(&x) || gamma.dtype() != DType::F32 {
        return unfused::rms_norm(x, gamma, eps);
    }
    Tensor::from_dispatch(<Dispatch as FusedOps>::fused_rms_norm(
        x.into_dispatch(),
        gamma.into_dispatch(),
        eps,
    ))
}

/// Softmax attention `softmax(q k^T / sqrt(d_h)) v` on `[B, H, T, d_h]` tensors of one shape.
///
/// Without a fused kernel: Burn's attention op when no gradient is needed (fused on the
/// backends that have one), else matmul, softmax, matmul.
pub fn attention(q: Tensor<4>, k: Tensor<4>, v: Tensor<4>) -> Tensor<4> {
    if is_fused(&q) && q.dims() == k.dims() && q.dims() == v.dims() {
        return Tensor::from_dispatch(<Dispatch as FusedOps>::fused_attention(
            q.into_dispatch(),
            k.into_dispatch(),
            v.into_dispatch(),
        ));
    }
    if q.is_tracked() || k.is_tracked() || v.is_tracked() {
        return unfused::attention(q, k, v);
    }
    burn::tensor::module::attention(
        q,
        k,
        v,
        None,
        None,
        burn::tensor::ops::AttentionModuleOptions {
            scale: None,
            softcap: None,
            is_causal: false,
        },
    )
}
