//! What the CubeCL kernels' launchers share: inputs made contiguous `f32`, element-wise launch
//! sizes, and the check that the device can add floats atomically.

use burn::tensor::DType;
use burn_cubecl::kernel::{cast, into_contiguous};
use burn_cubecl::tensor::CubeTensor;
use cubecl::ir::features::AtomicUsage;
use cubecl::ir::{ElemType, FloatKind, Type};
use cubecl::prelude::*;

/// A contiguous `f32` copy of `tensor` (the kernels index flat `f32` buffers).
pub(crate) fn prepared(tensor: CubeTensor) -> CubeTensor {
    let tensor = if tensor.dtype == DType::F32 {
        tensor
    } else {
        cast(tensor, DType::F32)
    };
    into_contiguous(tensor)
}

/// A 1D launch of `units` units, 256 per cube.
pub(crate) fn elementwise(tensor: &CubeTensor, units: usize) -> (CubeCount, CubeDim) {
    let dim = CubeDim::new_1d(256);
    (
        cubecl::calculate_cube_count_elemwise(&tensor.client, units, dim),
        dim,
    )
}

/// Stops with one clear line when the device cannot add `f32` atomically: the reverse passes
/// need it, and prism never falls back to the host silently.
///
/// # Panics
/// On such a device, naming what is missing and what to do.
pub(crate) fn require_float_atomics(tensor: &CubeTensor) {
    let usage = tensor
        .client
        .properties()
        .atomic_type_usage(Type::atomic(ElemType::Float(FloatKind::F32)));
    assert!(
        usage.contains(AtomicUsage::Add),
        "prism: this GPU adapter has no atomic f32 add, which the geometry operations' \
         backward kernels need; train on a device that has it (Vulkan, CUDA, Metal), or with \
         --backend flex"
    );
}
