//! The fused kernels as a Burn backend extension: [`FusedOps`] is implemented by the CPU
//! backends (flex, ndarray) with the host kernels, and by `Autodiff<B, C>` with one graph
//! node per call whose backward step runs the matching backward kernel.

// burn-ndarray is deprecated upstream, but the project's tests run on it.
#![allow(deprecated)]

use burn::backend::autodiff::checkpoint::{base::Checkpointer, strategy::CheckpointStrategy};
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind, unary};
use burn::backend::tensor::FloatTensor;
use burn::backend::{
    Autodiff, AutodiffBackend, Backend, Flex, NdArray, TensorMetadata, backend_extension,
};
use burn::tensor::Shape;

use crate::adamw::{self, AdamWStep};
use crate::attention::{self, Dims};
use crate::bf16::{self, Bf16Kernel};
use crate::conv::{self, ConvDims, Wanted};
use crate::elementwise;
use crate::heads::{self, Heads, Mixing};
use crate::host::HostTensors;
use crate::matrix::{self, View};
use crate::norm::{self, NormKind};
use crate::packed;
use crate::pool::{self, PoolDims};

/// Fused operations of the backbone. Every method takes and returns f32 tensors.
#[backend_extension(Autodiff, Flex, NdArray)]
pub trait FusedOps: Backend {
    /// `GELU(x)` element-wise.
    fn fused_gelu(x: FloatTensor<Self>) -> FloatTensor<Self>;
    /// LayerNorm without bias over the last dimension: `(x - mean) / sqrt(var + eps) * gamma`.
    fn fused_layer_norm(
        x: FloatTensor<Self>,
        gamma: FloatTensor<Self>,
        eps: f64,
    ) -> FloatTensor<Self>;
    /// RMSNorm over the last dimension: `x / sqrt(mean(x^2) + eps) * gamma`.
    fn fused_rms_norm(
        x: FloatTensor<Self>,
        gamma: FloatTensor<Self>,
        eps: f64,
    ) -> FloatTensor<Self>;
    /// `softmax(q k^T / sqrt(d_h)) v` on `[B, H, T, d_h]` tensors. With `bf16`, the two
    /// products take bf16 operands where the CPU's bf16 kernel is a hardware one (AMX's tiles
    /// or `vdpbf16ps`; see [`Bf16Kernel`]) and no gradient is needed; under a gradient, the f32
    /// kernels run forward and backward, so the gradient is the exact one of the output
    /// computed.
    fn fused_attention(
        q: FloatTensor<Self>,
        k: FloatTensor<Self>,
        v: FloatTensor<Self>,
        bf16: bool,
    ) -> FloatTensor<Self>;
    /// Multi-head self-attention with QK-norm from the joint projection `qkv` `[B, T, 3 H d_h]`
    /// (queries, keys, values; head by head within each), to the heads' outputs `[B, T, H d_h]`:
    /// the queries and keys RMS-normalised over `d_h` and scaled by `q_gain` and `k_gain`
    /// (`[d_h]`), then `mixing` in each head (its bf16 products without a gradient only).
    fn fused_self_attention(
        qkv: FloatTensor<Self>,
        q_gain: FloatTensor<Self>,
        k_gain: FloatTensor<Self>,
        heads: usize,
        eps: f64,
        mixing: Mixing,
    ) -> FloatTensor<Self>;
    /// `a b` for `a` of `[.., m, k]` and `b` of `[k, n]`, the leading dimensions of `a` taken
    /// as rows of one product. With `bf16`, both operands are rounded to bf16 and the products
    /// summed in f32 (see [`Bf16Kernel`]), forward and backward.
    fn fused_matmul(a: FloatTensor<Self>, b: FloatTensor<Self>, bf16: bool) -> FloatTensor<Self>;
    /// A 2D convolution with groups 1 and dilation 1 as matrix products over an im2col buffer
    /// (see [`conv`]): `x` `[B, C, H, W]`, `weight` `[O, C, k_h, k_w]`, `bias` `[O]`, `padding`
    /// zeros on both sides of each axis.
    fn fused_conv2d(
        x: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        bias: FloatTensor<Self>,
        stride: [usize; 2],
        padding: [usize; 2],
    ) -> FloatTensor<Self>;
    /// 2D max pooling of `x` `[B, C, H, W]` with a `kernel` window at `stride`, no padding,
    /// dilation 1 (see [`pool`]).
    fn fused_max_pool2d(
        x: FloatTensor<Self>,
        kernel: [usize; 2],
        stride: [usize; 2],
    ) -> FloatTensor<Self>;
    /// One AdamW step of a parameter: `(param, moment_1, moment_2)` after `grad` (see
    /// [`adamw::step`]; the moments are ignored at `step.time == 1`). Untracked: an optimizer
    /// works on the parameters' values.
    fn fused_adamw(
        param: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        moment_1: FloatTensor<Self>,
        moment_2: FloatTensor<Self>,
        step: AdamWStep,
    ) -> (FloatTensor<Self>, FloatTensor<Self>, FloatTensor<Self>);
}

/// GELU through the host kernel: in place where the input is not kept, else into a new
/// buffer in one pass.
fn gelu<B: HostTensors>(x: FloatTensor<B>) -> FloatTensor<B> {
    B::map(x, elementwise::gelu, elementwise::gelu_of)
}

/// `(GELU(x), GELU'(x))` through the host kernel, in one pass: the value in place of `x` where
/// no other tensor holds it (else in a copy), the derivative in a new buffer.
fn gelu_with_derivative<B: HostTensors>(x: FloatTensor<B>) -> (FloatTensor<B>, FloatTensor<B>) {
    let (shape, device) = (x.shape(), x.device());
    let derivative = std::cell::OnceCell::new();
    let keep = |x: &mut [f32]| {
        let kept = derivative.set(elementwise::gelu_keeping_derivative(x));
        assert!(kept.is_ok(), "one derivative per call");
    };
    let y = B::map(x, keep, |x| {
        let mut y = x.to_vec();
        keep(&mut y);
        y
    });
    let derivative = derivative.into_inner().expect("map runs one of its paths");
    (y, B::tensor(derivative, shape, &device))
}

/// GELU's reverse pass from the derivative its forward pass kept: `grad * GELU'(x)`, in place
/// of `grad` where no other tensor holds it.
fn gelu_backward<B: HostTensors>(
    derivative: FloatTensor<B>,
    grad: FloatTensor<B>,
) -> FloatTensor<B> {
    let derivative = B::values(derivative);
    B::map(
        grad,
        |grad| elementwise::scale_in_place(grad, &derivative),
        |grad| elementwise::scaled(grad, &derivative),
    )
}

/// A normalisation through the host kernel.
fn norm_forward<B: HostTensors>(
    kind: NormKind,
    x: FloatTensor<B>,
    gamma: FloatTensor<B>,
    eps: f64,
) -> FloatTensor<B> {
    let (shape, device) = (x.shape(), x.device());
    let y = norm::forward(kind, &B::values(x), &B::values(gamma), eps as f32);
    B::tensor(y, shape, &device)
}

/// The gradients `(dx, dgamma)` of a normalisation through the host kernel.
fn norm_backward<B: HostTensors>(
    kind: NormKind,
    x: FloatTensor<B>,
    gamma: FloatTensor<B>,
    grad: FloatTensor<B>,
    eps: f64,
) -> (FloatTensor<B>, FloatTensor<B>) {
    let (shape, gamma_shape, device) = (x.shape(), gamma.shape(), x.device());
    let (dx, dgamma) = norm::backward(
        kind,
        &B::values(x),
        &B::values(gamma),
        &B::values(grad),
        eps as f32,
    );
    (
        B::tensor(dx, shape, &device),
        B::tensor(dgamma, gamma_shape, &device),
    )
}

/// The sizes of an attention call on `[B, H, T, d_h]` and its scale `1 / sqrt(d_h)`.
fn attention_dims(q: &Shape, k: &Shape, v: &Shape) -> (Dims, f32) {
    assert!(
        q.num_dims() == 4 && q == k && q == v,
        "fused attention takes q, k, v of one [B, H, T, d_h] shape, got {q:?}, {k:?}, {v:?}"
    );
    let dims = Dims {
        heads: q[0] * q[1],
        tokens: q[2],
        head_dim: q[3],
    };
    (dims, 1.0 / (dims.head_dim as f32).sqrt())
}

/// `(o, lse)` through the host kernel, its products in f32 or (`bf16`) through the chosen
/// bf16 kernel.
fn attention_forward<B: HostTensors>(
    q: FloatTensor<B>,
    k: FloatTensor<B>,
    v: FloatTensor<B>,
    bf16: bool,
) -> (FloatTensor<B>, FloatTensor<B>) {
    let (shape, device) = (q.shape(), q.device());
    let (dims, scale) = attention_dims(&shape, &k.shape(), &v.shape());
    let (q, k, v) = (B::values(q), B::values(k), B::values(v));
    let (o, lse) = if bf16 {
        attention::forward_bf16(Bf16Kernel::chosen(), &q, &k, &v, dims, scale)
    } else {
        attention::forward(&q, &k, &v, dims, scale)
    };
    let lse_shape = Shape::new([shape[0], shape[1], shape[2]]);
    (
        B::tensor(o, shape, &device),
        B::tensor(lse, lse_shape, &device),
    )
}

/// What the attention's backward step keeps: the inputs, the output and its log-sum-exp.
#[derive(Clone, Debug)]
struct AttentionState<B: Backend> {
    q: FloatTensor<B>,
    k: FloatTensor<B>,
    v: FloatTensor<B>,
    o: FloatTensor<B>,
    lse: FloatTensor<B>,
}

/// `(dq, dk, dv)` through the host kernel.
fn attention_backward<B: HostTensors>(
    state: AttentionState<B>,
    grad: FloatTensor<B>,
) -> [FloatTensor<B>; 3] {
    let (shape, device) = (state.q.shape(), state.q.device());
    let (dims, scale) = attention_dims(&shape, &state.k.shape(), &state.v.shape());
    let (dq, dk, dv) = attention::backward(
        &B::values(state.q),
        &B::values(state.k),
        &B::values(state.v),
        &B::values(state.o),
        &B::values(state.lse),
        &B::values(grad),
        dims,
        scale,
    );
    [dq, dk, dv].map(|g| B::tensor(g, shape.clone(), &device))
}

/// The sizes of a self-attention on `qkv` `[B, T, 3 H d_h]` with `heads` heads.
fn heads_of(qkv: &Shape, heads: usize) -> Heads {
    assert!(
        qkv.num_dims() == 3 && heads > 0 && qkv[2].is_multiple_of(3 * heads),
        "fused self-attention takes qkv of [B, T, 3 H d_h] with H = {heads}, got {qkv:?}"
    );
    Heads {
        batch: qkv[0],
        tokens: qkv[1],
        heads,
        head_dim: qkv[2] / (3 * heads),
    }
}

/// What the self-attention's backward step keeps: its inputs and the kernel's saved values.
#[derive(Clone, Debug)]
struct SelfAttentionState<B: Backend> {
    qkv: FloatTensor<B>,
    q_gain: FloatTensor<B>,
    k_gain: FloatTensor<B>,
    heads: usize,
    eps: f64,
    mixing: Mixing,
    saved: heads::Saved,
}

/// The heads' outputs through the host kernel, and what its backward step needs.
fn self_attention_forward<B: HostTensors>(
    qkv: FloatTensor<B>,
    q_gain: FloatTensor<B>,
    k_gain: FloatTensor<B>,
    heads: usize,
    eps: f64,
    mixing: Mixing,
) -> (FloatTensor<B>, SelfAttentionState<B>) {
    let (shape, device) = (qkv.shape(), qkv.device());
    let l = heads_of(&shape, heads);
    let (out, saved) = heads::forward(
        &B::values(qkv.clone()),
        &B::values(q_gain.clone()),
        &B::values(k_gain.clone()),
        eps as f32,
        l,
        mixing,
    );
    let out_shape = Shape::new([l.batch, l.tokens, l.heads * l.head_dim]);
    let state = SelfAttentionState {
        qkv,
        q_gain,
        k_gain,
        heads,
        eps,
        mixing,
        saved,
    };
    (B::tensor(out, out_shape, &device), state)
}

/// `(d qkv, d q_gain, d k_gain)` through the host kernel.
fn self_attention_backward<B: HostTensors>(
    state: SelfAttentionState<B>,
    grad: FloatTensor<B>,
) -> [FloatTensor<B>; 3] {
    let (shape, gain_shape, device) = (state.qkv.shape(), state.q_gain.shape(), state.qkv.device());
    let (dqkv, dq_gain, dk_gain) = heads::backward(
        &B::values(state.qkv),
        &B::values(state.q_gain),
        &B::values(state.k_gain),
        state.eps as f32,
        heads_of(&shape, state.heads),
        state.mixing,
        &state.saved,
        &B::values(grad),
    );
    [
        B::tensor(dqkv, shape, &device),
        B::tensor(dq_gain, gain_shape.clone(), &device),
        B::tensor(dk_gain, gain_shape, &device),
    ]
}

/// The sizes `(m, k, n)` of a product of `[.., m, k]` by `[k, n]`, `m` taking in the leading
/// dimensions.
fn product_dims(a: &Shape, b: &Shape) -> (usize, usize, usize) {
    let k = a[a.num_dims() - 1];
    assert!(
        b.num_dims() == 2 && b[0] == k,
        "fused matmul takes [.., m, k] by [k, n], got {a:?} by {b:?}"
    );
    (a.num_elements() / k.max(1), k, b[1])
}

/// The row-major `a b`, in f32 products or (`bf16`) through the chosen bf16 kernel (zeros when
/// the inner size is 0).
fn product(a: View<'_>, b: View<'_>, bf16: bool) -> Vec<f32> {
    if a.rows == 0 || b.cols == 0 || a.cols == 0 {
        return vec![0.0; a.rows * b.cols];
    }
    if bf16 {
        bf16::matmul(Bf16Kernel::chosen(), a, b)
    } else {
        matrix::product(a, b)
    }
}

/// `a b` through the host kernel. When `b` is a constant of the graph (`b_constant`: no
/// gradient will be taken through this product) and its buffer is shared, the bf16 kernels
/// read it packed once and kept ([`packed`]): a layer's weight in inference.
fn matmul_forward<B: HostTensors>(
    a: FloatTensor<B>,
    b: FloatTensor<B>,
    bf16: bool,
    b_constant: bool,
) -> FloatTensor<B> {
    let (a_shape, device) = (a.shape(), a.device());
    let (m, k, n) = product_dims(&a_shape, &b.shape());
    let buffer = (bf16 && b_constant && m * k * n > 0)
        .then(|| B::shared_buffer(&b))
        .flatten();
    let (a, b) = (B::values(a), B::values(b));
    let (a, b) = (View::rows(&a, m, k), View::rows(&b, k, n));
    let c = match buffer {
        Some(buffer) => bf16::product(a, &packed::packed(buffer, b)),
        None => product(a, b, bf16),
    };
    let mut shape = a_shape;
    let last = shape.num_dims() - 1;
    shape[last] = n;
    B::tensor(c, shape, &device)
}

/// `(da, db) = (g b^T, a^T g)` through the host kernel, `a` of all leading dimensions taken
/// as rows.
fn matmul_backward<B: HostTensors>(
    (a, b, bf16): (FloatTensor<B>, FloatTensor<B>, bool),
    grad: FloatTensor<B>,
) -> [FloatTensor<B>; 2] {
    let (a_shape, b_shape, device) = (a.shape(), b.shape(), a.device());
    let (m, k, n) = product_dims(&a_shape, &b_shape);
    let (a, b, g) = (B::values(a), B::values(b), B::values(grad));
    let da = product(View::rows(&g, m, n), View::transposed(&b, n, k), bf16);
    let db = product(View::transposed(&a, k, m), View::rows(&g, m, n), bf16);
    [
        B::tensor(da, a_shape, &device),
        B::tensor(db, b_shape, &device),
    ]
}

/// The sizes of a convolution of `x` `[B, C, H, W]` by `weight` `[O, C, k_h, k_w]`.
fn conv_dims(x: &Shape, weight: &Shape, stride: [usize; 2], padding: [usize; 2]) -> ConvDims {
    assert!(
        x.num_dims() == 4 && weight.num_dims() == 4 && x[1] == weight[1],
        "fused conv2d takes x [B, C, H, W] and weight [O, C, kh, kw], got {x:?}, {weight:?}"
    );
    ConvDims {
        batch: x[0],
        channels: x[1],
        outputs: weight[0],
        size: [x[2], x[3]],
        kernel: [weight[2], weight[3]],
        stride,
        padding,
    }
}

/// A convolution through the host kernel.
fn conv_forward<B: HostTensors>(
    x: FloatTensor<B>,
    weight: FloatTensor<B>,
    bias: FloatTensor<B>,
    stride: [usize; 2],
    padding: [usize; 2],
) -> FloatTensor<B> {
    let device = x.device();
    let d = conv_dims(&x.shape(), &weight.shape(), stride, padding);
    let [h, w] = d
        .output_size()
        .expect("fused conv2d: the kernel fits the padded input");
    let y = conv::forward(&B::values(x), &B::values(weight), &B::values(bias), d);
    B::tensor(y, Shape::from(vec![d.batch, d.outputs, h, w]), &device)
}

/// The sizes of a max pooling of `x` `[B, C, H, W]`.
fn pool_dims(x: &Shape, kernel: [usize; 2], stride: [usize; 2]) -> PoolDims {
    assert!(
        x.num_dims() == 4,
        "fused max_pool2d takes x [B, C, H, W], got {x:?}"
    );
    PoolDims {
        planes: x[0] * x[1],
        size: [x[2], x[3]],
        kernel,
        stride,
    }
}

/// A max pooling through the host kernel.
fn max_pool_forward<B: HostTensors>(
    x: FloatTensor<B>,
    kernel: [usize; 2],
    stride: [usize; 2],
) -> FloatTensor<B> {
    let (shape, device) = (x.shape(), x.device());
    let d = pool_dims(&shape, kernel, stride);
    let [h, w] = d
        .output_size()
        .expect("fused max_pool2d: the window fits the input");
    let y = pool::forward(&B::values(x), d);
    B::tensor(y, Shape::from(vec![shape[0], shape[1], h, w]), &device)
}

/// The input's gradient of a max pooling through the host kernel.
fn max_pool_backward<B: HostTensors>(
    (x, kernel, stride): (FloatTensor<B>, [usize; 2], [usize; 2]),
    grad: FloatTensor<B>,
) -> [FloatTensor<B>; 1] {
    let (shape, device) = (x.shape(), x.device());
    let d = pool_dims(&shape, kernel, stride);
    let dx = pool::backward(&B::values(x), &B::values(grad), d);
    [B::tensor(dx, shape, &device)]
}

/// One AdamW step through the host kernel, in place where the backend lends the parameter's and
/// moments' values mutably (see [`HostTensors::update`]).
fn adamw_step<B: HostTensors>(
    param: FloatTensor<B>,
    grad: FloatTensor<B>,
    moment_1: FloatTensor<B>,
    moment_2: FloatTensor<B>,
    step: AdamWStep,
) -> (FloatTensor<B>, FloatTensor<B>, FloatTensor<B>) {
    let grad = B::values(grad);
    let (mut m_out, mut v_out) = (None, None);
    let param = B::update(param, |p| {
        m_out = Some(B::update(moment_1, |m| {
            v_out = Some(B::update(moment_2, |v| adamw::step(p, m, v, &grad, step)));
        }));
    });
    let both = "the update closures ran";
    (param, m_out.expect(both), v_out.expect(both))
}

/// The concrete CPU backends: the host kernels directly.
macro_rules! host_fused_ops {
    ($backend:ty) => {
        impl FusedOps for $backend {
            fn fused_gelu(x: FloatTensor<Self>) -> FloatTensor<Self> {
                gelu::<Self>(x)
            }

            fn fused_layer_norm(
                x: FloatTensor<Self>,
                gamma: FloatTensor<Self>,
                eps: f64,
            ) -> FloatTensor<Self> {
                norm_forward::<Self>(NormKind::Layer, x, gamma, eps)
            }

            fn fused_rms_norm(
                x: FloatTensor<Self>,
                gamma: FloatTensor<Self>,
                eps: f64,
            ) -> FloatTensor<Self> {
                norm_forward::<Self>(NormKind::Rms, x, gamma, eps)
            }

            fn fused_attention(
                q: FloatTensor<Self>,
                k: FloatTensor<Self>,
                v: FloatTensor<Self>,
                bf16: bool,
            ) -> FloatTensor<Self> {
                attention_forward::<Self>(q, k, v, bf16).0
            }

            fn fused_self_attention(
                qkv: FloatTensor<Self>,
                q_gain: FloatTensor<Self>,
                k_gain: FloatTensor<Self>,
                heads: usize,
                eps: f64,
                mixing: Mixing,
            ) -> FloatTensor<Self> {
                self_attention_forward::<Self>(qkv, q_gain, k_gain, heads, eps, mixing).0
            }

            fn fused_matmul(
                a: FloatTensor<Self>,
                b: FloatTensor<Self>,
                bf16: bool,
            ) -> FloatTensor<Self> {
                matmul_forward::<Self>(a, b, bf16, true)
            }

            fn fused_conv2d(
                x: FloatTensor<Self>,
                weight: FloatTensor<Self>,
                bias: FloatTensor<Self>,
                stride: [usize; 2],
                padding: [usize; 2],
            ) -> FloatTensor<Self> {
                conv_forward::<Self>(x, weight, bias, stride, padding)
            }

            fn fused_max_pool2d(
                x: FloatTensor<Self>,
                kernel: [usize; 2],
                stride: [usize; 2],
            ) -> FloatTensor<Self> {
                max_pool_forward::<Self>(x, kernel, stride)
            }

            fn fused_adamw(
                param: FloatTensor<Self>,
                grad: FloatTensor<Self>,
                moment_1: FloatTensor<Self>,
                moment_2: FloatTensor<Self>,
                step: AdamWStep,
            ) -> (FloatTensor<Self>, FloatTensor<Self>, FloatTensor<Self>) {
                adamw_step::<Self>(param, grad, moment_1, moment_2, step)
            }
        }
    };
}

host_fused_ops!(Flex);
host_fused_ops!(NdArray);

/// Backward step of [`FusedOps::fused_gelu`]; its state is the derivative at the input.
#[derive(Debug)]
struct GeluBackward;

impl<B: HostTensors> Backward<B, 1> for GeluBackward {
    type State = FloatTensor<B>;

    fn backward(self, ops: Ops<Self::State, 1>, grads: &mut Gradients, _: &mut Checkpointer) {
        let Ops {
            parents,
            node,
            state,
        } = ops;
        unary::<B, _>(parents, node, grads, |grad| gelu_backward::<B>(state, grad));
    }
}

/// Backward step of the normalisations.
#[derive(Debug)]
struct NormBackward(NormKind);

impl<B: HostTensors> Backward<B, 2> for NormBackward {
    type State = (FloatTensor<B>, FloatTensor<B>, f64);

    fn backward(self, ops: Ops<Self::State, 2>, grads: &mut Gradients, _: &mut Checkpointer) {
        let kind = self.0;
        backward_each::<B, _, 2>(ops, grads, |(x, gamma, eps), grad| {
            let (dx, dgamma) = norm_backward::<B>(kind, x, gamma, grad, eps);
            [dx, dgamma]
        });
    }
}

/// Backward step of [`FusedOps::fused_attention`].
#[derive(Debug)]
struct AttentionBackward;

impl<B: HostTensors> Backward<B, 3> for AttentionBackward {
    type State = AttentionState<B>;

    fn backward(self, ops: Ops<Self::State, 3>, grads: &mut Gradients, _: &mut Checkpointer) {
        backward_each::<B, _, 3>(ops, grads, attention_backward::<B>);
    }
}

/// Backward step of [`FusedOps::fused_self_attention`].
#[derive(Debug)]
struct SelfAttentionBackward;

impl<B: HostTensors> Backward<B, 3> for SelfAttentionBackward {
    type State = SelfAttentionState<B>;

    fn backward(self, ops: Ops<Self::State, 3>, grads: &mut Gradients, _: &mut Checkpointer) {
        backward_each::<B, _, 3>(ops, grads, self_attention_backward::<B>);
    }
}

/// Backward step of [`FusedOps::fused_matmul`].
#[derive(Debug)]
struct MatmulBackward;

impl<B: HostTensors> Backward<B, 2> for MatmulBackward {
    type State = (FloatTensor<B>, FloatTensor<B>, bool);

    fn backward(self, ops: Ops<Self::State, 2>, grads: &mut Gradients, _: &mut Checkpointer) {
        backward_each::<B, _, 2>(ops, grads, matmul_backward::<B>);
    }
}

/// Backward step of [`FusedOps::fused_conv2d`]: the input's gradient and the weight's and
/// bias's, each computed only when its input is tracked.
#[derive(Debug)]
struct ConvBackward;

impl<B: HostTensors> Backward<B, 3> for ConvBackward {
    type State = (FloatTensor<B>, FloatTensor<B>, [usize; 2], [usize; 2]);

    fn backward(self, ops: Ops<Self::State, 3>, grads: &mut Gradients, _: &mut Checkpointer) {
        let Ops {
            parents,
            node,
            state: (x, weight, stride, padding),
        } = ops;
        let grad = grads.consume::<B>(&node);
        let (x_shape, w_shape, device) = (x.shape(), weight.shape(), x.device());
        let d = conv_dims(&x_shape, &w_shape, stride, padding);
        let [dx_node, dw_node, db_node] = parents;
        let wanted = Wanted {
            input: dx_node.is_some(),
            weight: dw_node.is_some() || db_node.is_some(),
        };
        let (dx, dw, db) = conv::backward(
            &B::values(x),
            &B::values(weight),
            &B::values(grad),
            d,
            wanted,
        );
        let gradients = [
            (dx_node, dx, x_shape),
            (dw_node, dw, w_shape),
            (db_node, db, Shape::from(vec![d.outputs])),
        ];
        for (node, values, shape) in gradients {
            if let Some(node) = node {
                grads.register::<B>(node.id, B::tensor(values, shape, &device));
            }
        }
    }
}

/// Backward step of [`FusedOps::fused_max_pool2d`].
#[derive(Debug)]
struct MaxPoolBackward;

impl<B: HostTensors> Backward<B, 1> for MaxPoolBackward {
    type State = (FloatTensor<B>, [usize; 2], [usize; 2]);

    fn backward(self, ops: Ops<Self::State, 1>, grads: &mut Gradients, _: &mut Checkpointer) {
        backward_each::<B, _, 1>(ops, grads, max_pool_backward::<B>);
    }
}

/// One backward step of an operation with `N` inputs: `step(state, dL/d(output))` gives the
/// gradient of each input, registered for those that are tracked.
pub(crate) fn backward_each<B: Backend, S, const N: usize>(
    ops: Ops<S, N>,
    grads: &mut Gradients,
    step: impl FnOnce(S, FloatTensor<B>) -> [FloatTensor<B>; N],
) {
    let Ops {
        parents,
        node,
        state,
    } = ops;
    let grad = grads.consume::<B>(&node);
    for (parent, gradient) in parents.into_iter().zip(step(state, grad)) {
        if let Some(node) = parent {
            grads.register::<B>(node.id, gradient);
        }
    }
}

impl<B: HostTensors, C: CheckpointStrategy> FusedOps for Autodiff<B, C> {
    fn fused_gelu(x: FloatTensor<Self>) -> FloatTensor<Self> {
        let nodes = [x.node()];
        let x = x.into_primitive();
        match GeluBackward.prepare::<C>(nodes).compute_bound().stateful() {
            OpsKind::Tracked(prep) => {
                let (y, derivative) = gelu_with_derivative::<B>(x);
                prep.finish(derivative, y)
            }
            OpsKind::UnTracked(prep) => prep.finish(gelu::<B>(x)),
        }
    }

    fn fused_layer_norm(
        x: FloatTensor<Self>,
        gamma: FloatTensor<Self>,
        eps: f64,
    ) -> FloatTensor<Self> {
        tracked_norm::<B, C>(NormKind::Layer, x, gamma, eps)
    }

    fn fused_rms_norm(
        x: FloatTensor<Self>,
        gamma: FloatTensor<Self>,
        eps: f64,
    ) -> FloatTensor<Self> {
        tracked_norm::<B, C>(NormKind::Rms, x, gamma, eps)
    }

    fn fused_attention(
        q: FloatTensor<Self>,
        k: FloatTensor<Self>,
        v: FloatTensor<Self>,
        bf16: bool,
    ) -> FloatTensor<Self> {
        let nodes = [q.node(), k.node(), v.node()];
        let (q, k, v) = (q.into_primitive(), k.into_primitive(), v.into_primitive());
        match AttentionBackward
            .prepare::<C>(nodes)
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => {
                let (o, lse) = attention_forward::<B>(q.clone(), k.clone(), v.clone(), false);
                let state = AttentionState {
                    q,
                    k,
                    v,
                    o: o.clone(),
                    lse,
                };
                prep.finish(state, o)
            }
            OpsKind::UnTracked(prep) => prep.finish(attention_forward::<B>(q, k, v, bf16).0),
        }
    }

    fn fused_self_attention(
        qkv: FloatTensor<Self>,
        q_gain: FloatTensor<Self>,
        k_gain: FloatTensor<Self>,
        heads: usize,
        eps: f64,
        mixing: Mixing,
    ) -> FloatTensor<Self> {
        let nodes = [qkv.node(), q_gain.node(), k_gain.node()];
        let (qkv, q_gain, k_gain) = (
            qkv.into_primitive(),
            q_gain.into_primitive(),
            k_gain.into_primitive(),
        );
        match SelfAttentionBackward
            .prepare::<C>(nodes)
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => {
                // The f32 kernels under a gradient, as fused_attention.
                let mixing = mixing.in_f32();
                let (out, state) =
                    self_attention_forward::<B>(qkv, q_gain, k_gain, heads, eps, mixing);
                prep.finish(state, out)
            }
            OpsKind::UnTracked(prep) => {
                prep.finish(self_attention_forward::<B>(qkv, q_gain, k_gain, heads, eps, mixing).0)
            }
        }
    }

    fn fused_matmul(a: FloatTensor<Self>, b: FloatTensor<Self>, bf16: bool) -> FloatTensor<Self> {
        let nodes = [a.node(), b.node()];
        let (a, b) = (a.into_primitive(), b.into_primitive());
        match MatmulBackward
            .prepare::<C>(nodes)
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => {
                let c = matmul_forward::<B>(a.clone(), b.clone(), bf16, false);
                prep.finish((a, b, bf16), c)
            }
            OpsKind::UnTracked(prep) => prep.finish(matmul_forward::<B>(a, b, bf16, true)),
        }
    }

    fn fused_conv2d(
        x: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        bias: FloatTensor<Self>,
        stride: [usize; 2],
        padding: [usize; 2],
    ) -> FloatTensor<Self> {
        let nodes = [x.node(), weight.node(), bias.node()];
        let (x, weight, bias) = (
            x.into_primitive(),
            weight.into_primitive(),
            bias.into_primitive(),
        );
        match ConvBackward.prepare::<C>(nodes).compute_bound().stateful() {
            OpsKind::Tracked(prep) => {
                let y = conv_forward::<B>(x.clone(), weight.clone(), bias, stride, padding);
                prep.finish((x, weight, stride, padding), y)
            }
            OpsKind::UnTracked(prep) => {
                prep.finish(conv_forward::<B>(x, weight, bias, stride, padding))
            }
        }
    }

    fn fused_max_pool2d(
        x: FloatTensor<Self>,
        kernel: [usize; 2],
        stride: [usize; 2],
    ) -> FloatTensor<Self> {
        let nodes = [x.node()];
        let x = x.into_primitive();
        match MaxPoolBackward
            .prepare::<C>(nodes)
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => {
                let y = max_pool_forward::<B>(x.clone(), kernel, stride);
                prep.finish((x, kernel, stride), y)
            }
            OpsKind::UnTracked(prep) => prep.finish(max_pool_forward::<B>(x, kernel, stride)),
        }
    }

    fn fused_adamw(
        param: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        moment_1: FloatTensor<Self>,
        moment_2: FloatTensor<Self>,
        step: AdamWStep,
    ) -> (FloatTensor<Self>, FloatTensor<Self>, FloatTensor<Self>) {
        let (p, m, v) = adamw_step::<B>(
            param.into_primitive(),
            grad.into_primitive(),
            moment_1.into_primitive(),
            moment_2.into_primitive(),
            step,
        );
        (
            Self::from_inner(p),
            Self::from_inner(m),
            Self::from_inner(v),
        )
    }
}

/// A normalisation as one autodiff node.
fn tracked_norm<B: HostTensors, C: CheckpointStrategy>(
    kind: NormKind,
    x: FloatTensor<Autodiff<B, C>>,
    gamma: FloatTensor<Autodiff<B, C>>,
    eps: f64,
) -> FloatTensor<Autodiff<B, C>> {
    let nodes = [x.node(), gamma.node()];
    let (x, gamma) = (x.into_primitive(), gamma.into_primitive());
    match NormBackward(kind)
        .prepare::<C>(nodes)
        .compute_bound()
        .stateful()
    {
        OpsKind::Tracked(prep) => {
            let y = norm_forward::<B>(kind, x.clone(), gamma.clone(), eps);
            prep.finish((x, gamma, eps), y)
        }
        OpsKind::UnTracked(prep) => prep.finish(norm_forward::<B>(kind, x, gamma, eps)),
    }
}
