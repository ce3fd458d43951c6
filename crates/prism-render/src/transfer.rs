//! Moving backend primitives to host memory and back, for the geometry operations that compute
//! on the host (on the CPU backends), and the count of those reads.
//!
//! Every read a geometry operation makes goes through [`to_host`], which counts it
//! ([`prism_core::reads`]): on a GPU a read is a synchronisation that empties the device's
//! queue, so `prism bench` reports the count per training step and per frame, and a test
//! asserts that a step on a GPU backend makes none.

use burn::backend::Backend;
use burn::backend::tensor::FloatTensor;
use burn::tensor::{TensorData, read_sync};

use prism_core::reads::count_geometry_read;

/// Reads a primitive to host memory as `f32`, counting the read.
///
/// # Panics
/// If the device cannot be read (a broken device, not bad input).
pub(crate) fn to_host<B: Backend>(tensor: FloatTensor<B>) -> Vec<f32> {
    count_geometry_read();
    // On ndarray, Burn's read copies a tensor that autodiff also holds one element at a time.
    let tensor = match prism_kernels::ndarray_f32_values::<B>(tensor) {
        Ok(values) => return values,
        Err(tensor) => tensor,
    };
    read_sync(B::float_into_data(tensor))
        .expect("reading a tensor to host memory failed")
        .convert::<f32>()
        .try_into_vec::<f32>()
        .expect("tensor data is not f32 after conversion")
}

/// Uploads host data as a primitive of `shape` on `device`.
pub(crate) fn to_device<B: Backend>(
    data: Vec<f32>,
    shape: Vec<usize>,
    device: &B::Device,
) -> FloatTensor<B> {
    B::float_from_data(TensorData::new(data, shape), device)
}
