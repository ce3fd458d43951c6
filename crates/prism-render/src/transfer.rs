//! Moving backend primitives to host memory and back, for the operations that compute on the
//! host for every backend (the Gaussian rasterizer, triplane sampling).

use burn::backend::Backend;
use burn::backend::tensor::FloatTensor;
use burn::tensor::{TensorData, read_sync};

/// Reads a primitive to host memory as `f32`.
///
/// # Panics
/// If the device cannot be read (a broken device, not bad input).
pub(crate) fn to_host<B: Backend>(tensor: FloatTensor<B>) -> Vec<f32> {
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
