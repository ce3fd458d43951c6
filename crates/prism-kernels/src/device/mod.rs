//! Flash attention on the GPU backends (wgpu, cuda): softmax attention whose `T x T` scores
//! never reach device memory, forward and backward, as CubeCL kernels (`kernels.rs`) registered
//! as a Burn backend extension with its own autodiff step.
//!
//! Under autodiff the forward pass keeps `q, k, v`, the output and its log-sum-exp (all linear
//! in the tokens) and the backward pass recomputes the scores from them (FlashAttention-2), so
//! a training step's attention memory grows linearly in the tokens where matmul-softmax-matmul
//! keeps every head's `T x T` probabilities for the backward pass.

mod kernels;
mod ops;

use burn::backend::autodiff::checkpoint::{base::Checkpointer, strategy::CheckpointStrategy};
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::tensor::FloatTensor;
use burn::backend::{Autodiff, Backend, Cube, DispatchDevice, backend_extension};
use burn::tensor::{DType, Tensor};

pub use ops::FlashDeviceOps;

use crate::extension::backward_each;

/// The widest head the kernels take (their rows live in registers).
pub const MAX_HEAD_DIM: usize = 128;

/// Softmax attention that never writes the scores, on the cube backends and under autodiff.
#[backend_extension(Autodiff, Cube)]
pub trait FlashAttention: Backend {
    /// `softmax(q k^T / sqrt(D)) v` on `[B, H, T, D]` tensors of one shape and float type.
    fn flash_attention(
        q: FloatTensor<Self>,
        k: FloatTensor<Self>,
        v: FloatTensor<Self>,
    ) -> FloatTensor<Self>;
}

impl FlashAttention for Cube {
    fn flash_attention(
        q: FloatTensor<Self>,
        k: FloatTensor<Self>,
        v: FloatTensor<Self>,
    ) -> FloatTensor<Self> {
        Self::flash_forward(q, k, v).0
    }
}

/// What the backward step keeps: the inputs, the output and its log-sum-exp.
#[derive(Clone, Debug)]
struct FlashState<B: Backend> {
    q: FloatTensor<B>,
    k: FloatTensor<B>,
    v: FloatTensor<B>,
    out: FloatTensor<B>,
    lse: FloatTensor<B>,
}

/// Backward step of [`FlashAttention::flash_attention`]: the device's reverse kernels.
#[derive(Debug)]
struct FlashBackward;

impl<B: FlashDeviceOps> Backward<B, 3> for FlashBackward {
    type State = FlashState<B>;

    fn backward(self, ops: Ops<Self::State, 3>, grads: &mut Gradients, _: &mut Checkpointer) {
        backward_each::<B, _, 3>(ops, grads, |state, grad| {
            let (dq, dk, dv) =
                B::flash_backward(state.q, state.k, state.v, state.out, state.lse, grad);
            [dq, dk, dv]
        });
    }
}

impl<B: FlashDeviceOps, C: CheckpointStrategy> FlashAttention for Autodiff<B, C> {
    fn flash_attention(
        q: FloatTensor<Self>,
        k: FloatTensor<Self>,
        v: FloatTensor<Self>,
    ) -> FloatTensor<Self> {
        let nodes = [q.node(), k.node(), v.node()];
        let (q, k, v) = (q.into_primitive(), k.into_primitive(), v.into_primitive());
        match FlashBackward.prepare::<C>(nodes).compute_bound().stateful() {
            OpsKind::Tracked(prep) => {
                let (out, lse) = B::flash_forward(q.clone(), k.clone(), v.clone());
                let state = FlashState {
                    q,
                    k,
                    v,
                    out: out.clone(),
                    lse,
                };
                prep.finish(state, out)
            }
            OpsKind::UnTracked(prep) => prep.finish(B::flash_forward(q, k, v).0),
        }
    }
}

/// Whether `q, k, v` can run [`flash`]: one `[B, H, T, D]` shape with `D <= MAX_HEAD_DIM`, one
/// float type of `f32`, `f16`, `bf16`, on a cube backend (tracked by autodiff or not).
pub fn supported(q: &Tensor<4>, k: &Tensor<4>, v: &Tensor<4>) -> bool {
    let dims = q.dims();
    matches!(q.device().inner().as_dispatch(), DispatchDevice::Cube(_))
        && dims == k.dims()
        && dims == v.dims()
        && (1..=MAX_HEAD_DIM).contains(&dims[3])
        && matches!(q.dtype(), DType::F32 | DType::F16 | DType::BF16)
        && k.dtype() == q.dtype()
        && v.dtype() == q.dtype()
}

/// `softmax(q k^T / sqrt(D)) v` through the flash kernels; see [`supported`] for what it takes.
pub fn flash(q: Tensor<4>, k: Tensor<4>, v: Tensor<4>) -> Tensor<4> {
    use burn::backend::Dispatch;
    Tensor::from_dispatch(<Dispatch as FlashAttention>::flash_attention(
        q.into_dispatch(),
        k.into_dispatch(),
        v.into_dispatch(),
    ))
}
