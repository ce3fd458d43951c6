//! Fused kernels of prism's backbone, with hand-written backward passes.
//!
//! The backbone's training step, written with Burn's tensor ops, makes one graph node and one
//! pass over memory per elementary op: a LayerNorm is about eight, softmax attention
//! materialises the `T x T` scores three times, GELU calls libm's scalar `erf`. Here each of
//! GELU, LayerNorm (no bias), RMSNorm and softmax attention is one kernel forward and one
//! backward, vectorised for AVX-512 / AVX2 (chosen at run time: [`HostIsa`]) and split over
//! threads; attention runs block by block over the queries with `gemm` (FlashAttention's
//! scheme).
//!
//! The blocks' and heads' matrix products ([`linear`], [`matmul`], [`matmul_left`]) and the
//! heads' and LPIPS's convolutions ([`conv2d`], im2col and `gemm`) are one node each too, their
//! outputs written once by `gemm`. [`math`] holds the branch-free `exp` and `erf` they share
//! with the host rasteriser.
//!
//! `--precision bf16` on the CPU runs the blocks' matrix products through [`matmul_bf16`]:
//! operands rounded to bf16, products summed in f32, with AMX's tiles or AVX512-BF16's
//! `vdpbf16ps` where the CPU has them and they beat `gemm`'s f32 products of the rounded
//! operands ([`Bf16Kernel`], timed once per process), forward and backward. Where no gradient
//! is taken, a flex weight's packing for those kernels is kept while its buffer lives (module
//! `packed`), so inference packs each weight once.
//!
//! On the GPU backends (features `wgpu`, `cuda`) softmax attention can run flash-attention
//! kernels in CubeCL (module `device`): forward and backward without the `T x T` scores, in
//! f32, f16 or bf16, checked against the unfused attention on lavapipe
//! (`tests/cli/device/flash_attention.rs`, and the tiny model through them in
//! `tests/cli/device/backend.rs`); opt-in through [`GpuAttention`].
//!
//! The functions below pick the kernel when the tensor is f32 on a CPU backend (flex, ndarray;
//! tracked by autodiff or not), the flash kernels for attention on a GPU backend when chosen,
//! and the composition of Burn ops in [`unfused`] otherwise (GPU backends, half precision on
//! the CPU), so a model calls them on every backend.

mod adamw;
mod attention;
mod bf16;
mod buffer;
mod conv;
#[cfg(any(feature = "wgpu", feature = "cuda"))]
pub mod device;
mod elementwise;
mod extension;
mod gpu_attention;
mod heads;
mod host;
mod isa;
mod linear_attention;
pub mod math;
mod matrix;
mod norm;
mod packed;
mod pool;
#[cfg(test)]
mod test_util;
pub mod unfused;
mod warm;

use burn::backend::{Dispatch, DispatchDevice};
use burn::nn::conv::Conv2d;
use burn::nn::{Linear, PaddingConfig2d};
use burn::tensor::{DType, Device, Tensor};

pub use adamw::AdamWStep;
pub use bf16::Bf16Kernel;
pub use extension::FusedOps;
pub use gpu_attention::{AttentionKernel, ChoiceOrigin, GpuAttention, MeasuredChoice};
pub use heads::Mixing;
pub use host::ndarray_f32_values;
pub use isa::HostIsa;
pub use linear_attention::FeatureMap;
pub use warm::warm;

/// Whether `x` runs the fused kernels: f32 on flex or ndarray (with or without autodiff).
pub fn is_fused<const D: usize>(x: &Tensor<D>) -> bool {
    x.dtype() == DType::F32 && is_host(&x.device())
}

/// Whether `device` is one of the CPU backends the host kernels run on: flex or ndarray (with
/// or without autodiff).
pub fn is_host(device: &Device) -> bool {
    matches!(
        device.clone().inner().as_dispatch(),
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

/// `x w` for `x` of `[.., m, k]` and `w` of `[k, n]`. On f32 tensors of the CPU backends: one
/// `gemm` over all of `x`'s rows, forward and backward (one autodiff node), writing its
/// outputs straight into the result (Burn's flex matmul zeroes its output and then copies it
/// to an aligned buffer, and materialises the transposes of its backward pass). Elsewhere:
/// Burn's matmul.
pub fn matmul<const D: usize>(x: Tensor<D>, w: Tensor<2>) -> Tensor<D> {
    if !is_fused(&x) || w.dtype() != DType::F32 {
        return x.matmul(w.unsqueeze());
    }
    Tensor::from_dispatch(<Dispatch as FusedOps>::fused_matmul(
        x.into_dispatch(),
        w.into_dispatch(),
        false,
    ))
}

/// `x w` with both operands rounded to bf16 and the products summed in f32: the matrix
/// products of `--precision bf16` on the CPU, for `x` of `[.., m, k]` and `w` of `[k, n]`.
/// On f32 tensors of the CPU backends: the host kernel [`Bf16Kernel::chosen`] picks (one
/// autodiff node, its backward pass in bf16 products too). Elsewhere: Burn's matmul of the
/// operands cast to bf16 ([`unfused::matmul_bf16`]).
pub fn matmul_bf16<const D: usize>(x: Tensor<D>, w: Tensor<2>) -> Tensor<D> {
    if !is_fused(&x) || w.dtype() != DType::F32 {
        return unfused::matmul_bf16(x, w);
    }
    Tensor::from_dispatch(<Dispatch as FusedOps>::fused_matmul(
        x.into_dispatch(),
        w.into_dispatch(),
        true,
    ))
}

/// A `Linear` layer on `x` through [`matmul`] and the bias added: the layer's own values, its
/// product on the host kernel where [`matmul`] takes it.
pub fn linear<const D: usize>(layer: &Linear, x: Tensor<D>) -> Tensor<D> {
    with_bias(layer, matmul(x, layer.weight.val()))
}

/// A `Linear` layer on `x` with its product's operands in bf16: for f32 `x`, [`matmul_bf16`]
/// and the bias added in f32; for `x` in half precision, Burn's layer in that precision.
pub fn linear_bf16<const D: usize>(layer: &Linear, x: Tensor<D>) -> Tensor<D> {
    if x.dtype() != DType::F32 {
        return layer.forward(x);
    }
    with_bias(layer, matmul_bf16(x, layer.weight.val()))
}

/// `y` plus `layer`'s bias, if it has one.
fn with_bias<const D: usize>(layer: &Linear, y: Tensor<D>) -> Tensor<D> {
    match &layer.bias {
        Some(bias) => y + bias.val().unsqueeze(),
        None => y,
    }
}

/// `w x_b + bias` for every `x_b` of `x` `[B, C, N]`, with `w` `[O, C]` and `bias` `[O]`: a
/// linear map of each column's channels (a per-pixel linear layer on channel-first maps, or an
/// interpolation along one axis), giving `[B, O, N]`. On f32 tensors of the CPU backends: a
/// 1 x 1 convolution on the host kernel (one autodiff node whose forward and backward are
/// `gemm`s on the tensors as they lie, no transposed copies). Elsewhere: Burn's batched matmul.
pub fn matmul_left(w: Tensor<2>, x: Tensor<3>, bias: Option<Tensor<1>>) -> Tensor<3> {
    let ([b, c, n], [o, _]) = (x.dims(), w.dims());
    if !is_fused(&x) || w.dtype() != DType::F32 {
        let y = w.unsqueeze::<3>().matmul(x);
        return match bias {
            Some(bias) => y + bias.reshape([1, o, 1]),
            None => y,
        };
    }
    let bias = bias.unwrap_or_else(|| Tensor::zeros([o], &x.device()));
    let y: Tensor<4> = Tensor::from_dispatch(<Dispatch as FusedOps>::fused_conv2d(
        x.reshape([b, c, 1, n]).into_dispatch(),
        w.reshape([o, c, 1, 1]).into_dispatch(),
        bias.into_dispatch(),
        [1, 1],
        [0, 0],
    ));
    y.reshape([b, o, n])
}

/// A `Conv2d` layer on `x` `[B, C, H, W]`. On f32 tensors of the CPU backends, for groups 1,
/// dilation 1 and symmetric padding: the host kernel, one autodiff node whose products (im2col
/// and `gemm`, forward and backward) replace Burn's convolutions there, which are slow for the
/// weight gradient at the heads' few images and many pixels. Elsewhere: the layer itself.
pub fn conv2d(layer: &Conv2d, x: Tensor<4>) -> Tensor<4> {
    let weight = layer.weight.val();
    let Some(padding) = host_conv_padding(layer, &x, &weight) else {
        return layer.forward(x);
    };
    let bias = match &layer.bias {
        Some(bias) => bias.val(),
        None => Tensor::zeros([weight.dims()[0]], &x.device()),
    };
    Tensor::from_dispatch(<Dispatch as FusedOps>::fused_conv2d(
        x.into_dispatch(),
        weight.into_dispatch(),
        bias.into_dispatch(),
        layer.stride,
        padding,
    ))
}

/// 2D max pooling of `x` `[B, C, H, W]` with a `kernel` window at `stride` (no padding,
/// dilation 1). On f32 tensors of the CPU backends: the host kernel, one autodiff node (Burn's
/// CPU pooling works window by window, with indices even where none are wanted). Elsewhere, or
/// where the window is larger than the input: Burn's op.
pub fn max_pool2d(x: Tensor<4>, kernel: [usize; 2], stride: [usize; 2]) -> Tensor<4> {
    let [b, c, h, w] = x.dims();
    let dims = pool::PoolDims {
        planes: b * c,
        size: [h, w],
        kernel,
        stride,
    };
    if !is_fused(&x) || dims.output_size().is_none() {
        return burn::tensor::module::max_pool2d(
            x,
            burn::tensor::ops::MaxPoolOptions::new(kernel).with_stride(stride),
        );
    }
    Tensor::from_dispatch(<Dispatch as FusedOps>::fused_max_pool2d(
        x.into_dispatch(),
        kernel,
        stride,
    ))
}

/// Whether [`conv2d`] runs `layer` on `x` through the host kernel.
pub fn is_fused_conv2d(layer: &Conv2d, x: &Tensor<4>) -> bool {
    host_conv_padding(layer, x, &layer.weight.val()).is_some()
}

/// The padding on each side of each axis when the host kernel runs `layer` on `x`; `None`
/// when it does not (another backend or dtype, groups, dilation, asymmetric padding, or a
/// kernel larger than the padded input).
fn host_conv_padding(layer: &Conv2d, x: &Tensor<4>, weight: &Tensor<4>) -> Option<[usize; 2]> {
    let [batch, channels, height, width] = x.dims();
    let [outputs, weight_channels, kh, kw] = weight.dims();
    let plain = layer.groups == 1 && layer.dilation == [1, 1] && channels == weight_channels;
    if !is_fused(x) || weight.dtype() != DType::F32 || !plain {
        return None;
    }
    let padding = match layer.padding {
        PaddingConfig2d::Valid => [0, 0],
        PaddingConfig2d::Explicit(top, left, bottom, right) if top == bottom && left == right => {
            [top, left]
        }
        PaddingConfig2d::Same if layer.stride == [1, 1] && kh % 2 == 1 && kw % 2 == 1 => {
            [kh / 2, kw / 2]
        }
        _ => return None,
    };
    let dims = conv::ConvDims {
        batch,
        channels,
        outputs,
        size: [height, width],
        kernel: [kh, kw],
        stride: layer.stride,
        padding,
    };
    dims.output_size().map(|_| padding)
}

/// Softmax attention `softmax(q k^T / sqrt(d_h)) v` on `[B, H, T, d_h]` tensors of one shape.
///
/// On the CPU backends in f32: the fused host kernel. Elsewhere (GPU backends, half precision
/// on the CPU) the kernel [`GpuAttention::current`] names: prism's flash kernels (module
/// `device`, GPU backends only), prism's composition matmul, softmax, matmul ([`unfused`]), or
/// Burn's attention op, which is fused on the backends that have one (with cooperative matrices
/// where the adapter has them) but is only taken when no gradient is needed (under autodiff
/// Burn decomposes it as [`unfused`] does).
pub fn attention(q: Tensor<4>, k: Tensor<4>, v: Tensor<4>) -> Tensor<4> {
    attention_in(q, k, v, false)
}

/// [`attention`] for `--precision bf16`: on the CPU backends in f32, the fused host kernel with
/// its two products' operands in bf16 and their sums in f32 where the chosen [`Bf16Kernel`] is
/// a hardware one (AMX's tiles or `vdpbf16ps`) and no gradient is needed; under a gradient,
/// and with the rounded kernel, the f32 kernel. Elsewhere, as [`attention`].
pub fn attention_bf16(q: Tensor<4>, k: Tensor<4>, v: Tensor<4>) -> Tensor<4> {
    attention_in(q, k, v, true)
}

/// One AdamW step of a parameter's values on the host kernel: `(param, moment_1, moment_2)`
/// after `grad`, Burn's `AdamW` arithmetic in one pass over memory instead of about fifteen
/// (see [`AdamWStep`]). `moments` is `None` at a parameter's first step. For tensors that
/// [`is_fused`] takes (f32 on a CPU backend); the caller runs Burn's optimizer on others.
pub fn adamw_step<const D: usize>(
    param: Tensor<D>,
    grad: Tensor<D>,
    moments: Option<(Tensor<D>, Tensor<D>)>,
    step: AdamWStep,
) -> (Tensor<D>, Tensor<D>, Tensor<D>) {
    assert!(
        is_fused(&param) && is_fused(&grad),
        "adamw_step takes f32 tensors on a CPU backend"
    );
    // At the first step the kernel ignores the moments' values but checks their sizes.
    let (m, v) = moments.unwrap_or_else(|| (param.zeros_like(), param.zeros_like()));
    let (p, m, v) = <Dispatch as FusedOps>::fused_adamw(
        param.into_dispatch(),
        grad.into_dispatch(),
        m.into_dispatch(),
        v.into_dispatch(),
        step,
    );
    (
        Tensor::from_dispatch(p),
        Tensor::from_dispatch(m),
        Tensor::from_dispatch(v),
    )
}

/// Multi-head self-attention with QK-norm, from the joint projection `qkv` `[B, T, 3 H d_h]`
/// (queries, keys and values, head by head within each) to the heads' outputs `[B, T, H d_h]`,
/// as the output projection reads them: `mixing` per head on `RMSNorm(q) q_gain`,
/// `RMSNorm(k) k_gain` and `v`, the norms over `d_h` with `eps`. Softmax attention with `bf16`
/// as in [`attention_bf16`].
///
/// On the CPU backends in f32: one host kernel, forward and backward, that reads `qkv` and
/// writes its gradient in their own layout (the composition permutes, narrows and merges with
/// a copy or a zeroed gradient each, and linear attention is a dozen graph nodes). Elsewhere:
/// that composition ([`unfused::heads_attention`]) around [`rms_norm`], and [`attention`]'s
/// paths or [`unfused::linear_attention`].
pub fn self_attention(
    qkv: Tensor<3>,
    q_gain: Tensor<1>,
    k_gain: Tensor<1>,
    heads: usize,
    eps: f64,
    mixing: Mixing,
) -> Tensor<3> {
    if is_fused(&qkv) && q_gain.dtype() == DType::F32 && k_gain.dtype() == DType::F32 {
        return Tensor::from_dispatch(<Dispatch as FusedOps>::fused_self_attention(
            qkv.into_dispatch(),
            q_gain.into_dispatch(),
            k_gain.into_dispatch(),
            heads,
            eps,
            mixing,
        ));
    }
    unfused::heads_attention(qkv, heads, |q, k, v| {
        let (q, k) = (rms_norm(q, q_gain, eps), rms_norm(k, k_gain, eps));
        match mixing {
            Mixing::Softmax { bf16 } => attention_in(q, k, v, bf16),
            Mixing::Linear { feature_map, eps } => {
                unfused::linear_attention(q, k, v, feature_map, eps)
            }
        }
    })
}

/// [`attention`], its fused host kernel taking bf16 products when `bf16`.
fn attention_in(q: Tensor<4>, k: Tensor<4>, v: Tensor<4>, bf16: bool) -> Tensor<4> {
    if is_fused(&q) && q.dims() == k.dims() && q.dims() == v.dims() {
        return Tensor::from_dispatch(<Dispatch as FusedOps>::fused_attention(
            q.into_dispatch(),
            k.into_dispatch(),
            v.into_dispatch(),
            bf16,
        ));
    }
    let tracked = q.is_tracked() || k.is_tracked() || v.is_tracked();
    let kernel = GpuAttention::current(&q.device(), q.dtype()).kernel(tracked);
    #[cfg(any(feature = "wgpu", feature = "cuda"))]
    if kernel == AttentionKernel::Flash && device::supported(&q, &k, &v) {
        return device::flash(q, k, v);
    }
    if tracked || kernel == AttentionKernel::Unfused {
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
