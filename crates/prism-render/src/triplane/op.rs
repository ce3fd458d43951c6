//! Triplane sampling as a Burn backend extension with a hand-written backward pass (the same
//! mechanism as the Gaussian rasterizer, see [`crate::splat::op`]): every backend samples on
//! the host (`host.rs`), and `Autodiff<B, C>` registers a [`Backward`] step that returns the
//! gradients of the planes and of the coordinates.

// burn-ndarray is deprecated upstream, but the project's tests run on it.
#![allow(deprecated)]

use std::sync::Arc;

use burn::backend::autodiff::checkpoint::{base::Checkpointer, strategy::CheckpointStrategy};
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::tensor::FloatTensor;
use burn::backend::{Autodiff, Backend, Flex, NdArray, TensorMetadata, backend_extension};

use super::host::{self, Dims};
use crate::transfer::{to_device, to_host};

/// Triplane sampling as a backend operation.
#[backend_extension(Autodiff, Flex, NdArray, Cube: cfg(any(feature = "wgpu", feature = "cuda")))]
pub trait TriplaneBackend: Backend {
    /// Samples `planes` `[3, C, R, R]` at `coords` `[B, 3, H, W]` (in `[-1, 1]`): `[B, C, H, W]`,
    /// the sum of the three planes' bilinear samples.
    fn triplane_sample(planes: FloatTensor<Self>, coords: FloatTensor<Self>) -> FloatTensor<Self>;
}

/// The inputs on the host and the sizes of the call.
#[derive(Debug)]
struct HostInputs {
    planes_last: Vec<f32>,
    coords: Vec<f32>,
    dims: Dims,
    coord_shape: Vec<usize>,
    plane_shape: Vec<usize>,
}

fn inputs_to_host<B: Backend>(planes: FloatTensor<B>, coords: FloatTensor<B>) -> HostInputs {
    let plane_shape = planes.shape().to_vec();
    let coord_shape = coords.shape().to_vec();
    assert!(
        plane_shape.len() == 4 && plane_shape[0] == 3 && plane_shape[2] == plane_shape[3],
        "triplane: planes must be [3, C, R, R], got {plane_shape:?}"
    );
    assert!(
        coord_shape.len() == 4 && coord_shape[1] == 3,
        "triplane: coordinates must be [B, 3, H, W], got {coord_shape:?}"
    );
    let dims = Dims {
        batch: coord_shape[0],
        points: coord_shape[2] * coord_shape[3],
        channels: plane_shape[1],
        resolution: plane_shape[2],
    };
    HostInputs {
        planes_last: host::to_channel_last(&to_host::<B>(planes), dims.channels, dims.resolution),
        coords: to_host::<B>(coords),
        dims,
        coord_shape,
        plane_shape,
    }
}

/// The forward pass on the host for any backend: the output primitive and the host inputs.
fn forward_on_host<B: Backend>(
    planes: FloatTensor<B>,
    coords: FloatTensor<B>,
) -> (FloatTensor<B>, HostInputs) {
    let device = coords.device();
    let inputs = inputs_to_host::<B>(planes, coords);
    let out = host::forward(&inputs.planes_last, &inputs.coords, inputs.dims);
    let s = &inputs.coord_shape;
    let shape = vec![s[0], inputs.dims.channels, s[2], s[3]];
    (to_device::<B>(out, shape, &device), inputs)
}

impl TriplaneBackend for Flex {
    fn triplane_sample(planes: FloatTensor<Self>, coords: FloatTensor<Self>) -> FloatTensor<Self> {
        forward_on_host::<Self>(planes, coords).0
    }
}

impl TriplaneBackend for NdArray {
    fn triplane_sample(planes: FloatTensor<Self>, coords: FloatTensor<Self>) -> FloatTensor<Self> {
        forward_on_host::<Self>(planes, coords).0
    }
}

#[cfg(any(feature = "wgpu", feature = "cuda"))]
impl TriplaneBackend for burn::backend::Cube {
    fn triplane_sample(planes: FloatTensor<Self>, coords: FloatTensor<Self>) -> FloatTensor<Self> {
        forward_on_host::<Self>(planes, coords).0
    }
}

/// The backward step: the host reverse pass (`host::backward`).
#[derive(Debug)]
struct TriplaneBackward;

impl<B: Backend> Backward<B, 2> for TriplaneBackward {
    type State = (Arc<HostInputs>, B::Device);

    fn backward(
        self,
        ops: Ops<Self::State, 2>,
        grads: &mut Gradients,
        _checkpointer: &mut Checkpointer,
    ) {
        let grad_out = to_host::<B>(grads.consume::<B>(&ops.node));
        let (inputs, device) = ops.state;
        let (grad_planes, grad_coords) =
            host::backward(&inputs.planes_last, &inputs.coords, &grad_out, inputs.dims);
        let [planes, coords] = ops.parents;
        if let Some(node) = planes {
            grads.register::<B>(
                node.id,
                to_device::<B>(grad_planes, inputs.plane_shape.clone(), &device),
            );
        }
        if let Some(node) = coords {
            grads.register::<B>(
                node.id,
                to_device::<B>(grad_coords, inputs.coord_shape.clone(), &device),
            );
        }
    }
}

impl<B: Backend, C: CheckpointStrategy> TriplaneBackend for Autodiff<B, C> {
    fn triplane_sample(planes: FloatTensor<Self>, coords: FloatTensor<Self>) -> FloatTensor<Self> {
        let nodes = [planes.node(), coords.node()];
        let (planes, coords) = (planes.into_primitive(), coords.into_primitive());
        match TriplaneBackward
            .prepare::<C>(nodes)
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => {
                let device = coords.device();
                let (output, inputs) = forward_on_host::<B>(planes, coords);
                prep.finish((Arc::new(inputs), device), output)
            }
            OpsKind::UnTracked(prep) => prep.finish(forward_on_host::<B>(planes, coords).0),
        }
    }
}
