//! What the CubeCL kernels' launchers share: inputs made contiguous `f32`, cameras uploaded in
//! the kernels' layout, element-wise launch sizes, and the check that the device can add floats
//! atomically.

use burn::tensor::{DType, TensorData};
use burn_cubecl::kernel::{cast, into_contiguous};
use burn_cubecl::tensor::CubeTensor;
use burn_cubecl::{CubeBackend, CubeDevice};
use cubecl::ir::features::AtomicUsage;
use cubecl::ir::{ElemType, FloatKind, Type};
use cubecl::prelude::*;
use prism_core::Camera;

/// A contiguous `f32` copy of `tensor` (the kernels index flat `f32` buffers).
pub(crate) fn prepared(tensor: CubeTensor) -> CubeTensor {
    let tensor = if tensor.dtype == DType::F32 {
        tensor
    } else {
        cast(tensor, DType::F32)
    };
    into_contiguous(tensor)
}

/// Floats of one camera in the kernels' layout: the world-to-camera rotation (row-major), the
/// translation, `fx fy cx cy`.
pub(crate) const PINHOLE: usize = 16;

/// `cameras` as a `[B, PINHOLE + extra]` device tensor (an upload, never a read): each row the
/// camera's [`PINHOLE`] floats followed by what `extra` adds for it.
pub(crate) fn cameras_tensor(
    cameras: &[Camera],
    extra: impl Fn(&Camera) -> Vec<f32>,
    device: &CubeDevice,
) -> CubeTensor {
    let mut data = Vec::new();
    for camera in cameras {
        let w2c = camera.w2c();
        for row in 0..3 {
            data.extend([w2c.x_axis[row], w2c.y_axis[row], w2c.z_axis[row]]);
        }
        data.extend(w2c.w_axis.truncate().to_array());
        let k = camera.intrinsics;
        data.extend([k.fx, k.fy, k.cx, k.cy]);
        data.extend(extra(camera));
    }
    let width = data.len() / cameras.len().max(1);
    <CubeBackend as burn::backend::ops::FloatTensorOps<CubeBackend>>::float_from_data(
        TensorData::new(data, [cameras.len(), width]),
        device,
    )
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
