//! The flash-attention kernels' launchers on Burn's cube backend. [`FlashDeviceOps`] is
//! implemented for `CubeBackend`; `#[backend_extension]` generates the lazy `Fusion` version,
//! so a call joins the stream of fused operations like any of Burn's.

use burn::backend::fusion::custom::TensorSpec;
use burn::backend::tensor::FloatTensor;
use burn::backend::{Backend, backend_extension};
use burn::tensor::{DType, Shape};
use burn_cubecl::CubeBackend;
use burn_cubecl::kernel::into_contiguous;
use burn_cubecl::ops::numeric::empty_device_dtype;
use burn_cubecl::tensor::CubeTensor;
use cubecl::ir::{ElemType, FloatKind};
use cubecl::prelude::*;

use super::kernels::{ROWS, forward_kernel, key_grad_kernel, query_grad_kernel, tile_rows};

/// The device operations of flash attention on `[B, H, T, D]` tensors of one shape and one
/// float type (`f32`, `f16` or `bf16`); the log-sum-exp is `[B, H, T]` in `f32`.
#[backend_extension(Fusion, Cube)]
pub trait FlashDeviceOps: Backend {
    /// `(softmax(q k^T / sqrt(D)) v, lse)`.
    #[fusion(meta = forward_meta)]
    fn flash_forward(
        q: FloatTensor<Self>,
        k: FloatTensor<Self>,
        v: FloatTensor<Self>,
    ) -> (FloatTensor<Self>, FloatTensor<Self>);

    /// `(dq, dk, dv)` from the forward pass's output `out`, its `lse` and `dL/d(out)`.
    #[fusion(meta = backward_meta)]
    fn flash_backward(
        q: FloatTensor<Self>,
        k: FloatTensor<Self>,
        v: FloatTensor<Self>,
        out: FloatTensor<Self>,
        lse: FloatTensor<Self>,
        grad: FloatTensor<Self>,
    ) -> (FloatTensor<Self>, FloatTensor<Self>, FloatTensor<Self>);
}

/// The shape of the log-sum-exp of `[B, H, T, D]` queries.
fn lse_shape(q: &Shape) -> Shape {
    Shape::new([q[0], q[1], q[2]])
}

fn forward_meta(q: &TensorSpec, _k: &TensorSpec, _v: &TensorSpec) -> (TensorSpec, TensorSpec) {
    (
        TensorSpec::new(q.shape.clone(), q.dtype),
        TensorSpec::new(lse_shape(&q.shape), DType::F32),
    )
}

fn backward_meta(
    q: &TensorSpec,
    k: &TensorSpec,
    v: &TensorSpec,
    _out: &TensorSpec,
    _lse: &TensorSpec,
    _grad: &TensorSpec,
) -> (TensorSpec, TensorSpec, TensorSpec) {
    (q.clone(), k.clone(), v.clone())
}

/// The kernels' element type for a tensor's dtype.
///
/// # Panics
/// For a dtype other than `f32`, `f16` and `bf16` ([`super::supported`] keeps others away).
fn elem_type(dtype: DType) -> ElemType {
    let kind = match dtype {
        DType::F32 => FloatKind::F32,
        DType::F16 => FloatKind::F16,
        DType::BF16 => FloatKind::BF16,
        other => panic!("flash attention does not take {other:?} tensors"),
    };
    ElemType::Float(kind)
}

/// The sizes of a call: `(B H, T, D)`.
fn sizes(q: &CubeTensor) -> (usize, usize, usize) {
    let s = q.meta.shape();
    (s[0] * s[1], s[2], s[3])
}

/// One cube per block of [`ROWS`] rows per head.
fn launch_grid(heads: usize, tokens: usize) -> (CubeCount, CubeDim) {
    let blocks = tokens.div_ceil(ROWS) as u32;
    (
        CubeCount::Static(blocks, heads as u32, 1),
        CubeDim::new_1d(ROWS as u32),
    )
}

/// A new tensor on `like`'s device.
fn empty_like(like: &CubeTensor, shape: Shape, dtype: DType) -> CubeTensor {
    empty_device_dtype(like.client.clone(), like.device.clone(), shape, dtype)
}

impl FlashDeviceOps for CubeBackend {
    fn flash_forward(q: CubeTensor, k: CubeTensor, v: CubeTensor) -> (CubeTensor, CubeTensor) {
        let (q, k, v) = (into_contiguous(q), into_contiguous(k), into_contiguous(v));
        let (heads, tokens, head_dim) = sizes(&q);
        let shape = q.meta.shape().clone();
        let out = empty_like(&q, shape.clone(), q.dtype);
        let lse = empty_like(&q, lse_shape(&shape), DType::F32);
        let (count, dim) = launch_grid(heads, tokens);
        let dtype = elem_type(q.dtype);
        // SAFETY: every index the kernel reads or writes is guarded by the sizes passed here,
        // which are those of the contiguous tensors bound.
        unsafe {
            forward_kernel::launch_unchecked(
                &q.client,
                count,
                dim,
                q.clone().into_tensor_arg(),
                k.into_tensor_arg(),
                v.into_tensor_arg(),
                out.clone().into_tensor_arg(),
                lse.clone().into_tensor_arg(),
                tokens as u32,
                1.0 / (head_dim as f32).sqrt(),
                head_dim,
                tile_rows(head_dim),
                dtype,
            );
        }
        (out, lse)
    }

    fn flash_backward(
        q: CubeTensor,
        k: CubeTensor,
        v: CubeTensor,
        out: CubeTensor,
        lse: CubeTensor,
        grad: CubeTensor,
    ) -> (CubeTensor, CubeTensor, CubeTensor) {
        let [q, k, v, out, lse] = [q, k, v, out, lse].map(into_contiguous);
        // The upstream gradient in the inputs' type (a sum of branches may have promoted it).
        let grad = if grad.dtype == q.dtype {
            into_contiguous(grad)
        } else {
            into_contiguous(burn_cubecl::kernel::cast(grad, q.dtype))
        };
        let (heads, tokens, head_dim) = sizes(&q);
        let shape = q.meta.shape().clone();
        let delta = empty_like(&q, lse_shape(&shape), DType::F32);
        let [grad_q, grad_k, grad_v] = [(); 3].map(|_| empty_like(&q, shape.clone(), q.dtype));
        let (count, dim) = launch_grid(heads, tokens);
        let dtype = elem_type(q.dtype);
        let scale = 1.0 / (head_dim as f32).sqrt();
        let tile = tile_rows(head_dim);
        // SAFETY: as in the forward pass; `delta` is written by the first kernel and read by
        // the second, which the stream runs in order.
        unsafe {
            query_grad_kernel::launch_unchecked(
                &q.client,
                count.clone(),
                dim,
                q.clone().into_tensor_arg(),
                k.clone().into_tensor_arg(),
                v.clone().into_tensor_arg(),
                out.into_tensor_arg(),
                grad.clone().into_tensor_arg(),
                lse.clone().into_tensor_arg(),
                delta.clone().into_tensor_arg(),
                grad_q.clone().into_tensor_arg(),
                tokens as u32,
                scale,
                head_dim,
                tile,
                dtype,
            );
            key_grad_kernel::launch_unchecked(
                &q.client,
                count,
                dim,
                q.clone().into_tensor_arg(),
                k.into_tensor_arg(),
                v.into_tensor_arg(),
                grad.into_tensor_arg(),
                lse.into_tensor_arg(),
                delta.into_tensor_arg(),
                grad_k.clone().into_tensor_arg(),
                grad_v.clone().into_tensor_arg(),
                tokens as u32,
                scale,
                head_dim,
                tile,
                dtype,
            );
        }
        (grad_q, grad_k, grad_v)
    }
}
