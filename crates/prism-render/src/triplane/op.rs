//! Triplane sampling as a Burn backend extension with a hand-written backward pass (the same
//! mechanism as the Gaussian rasterizer, see [`crate::splat::op`]): the CPU backends sample on
//! the host (`host.rs`), the GPU backends in CubeCL kernels (`device.rs`), and `Autodiff<B, C>`
//! registers a [`Backward`] step that returns the gradients of the planes and of the
//! coordinates.

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
#[backend_extension(
    Autodiff,
    Flex,
    NdArray,
    Remote,
    Cube: cfg(any(feature = "wgpu", feature = "cuda"))
)]
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

/// How a backend samples under autodiff: the forward pass with the tape its reverse pass
/// reads, and that reverse pass (host memory on the CPU backends, device tensors on the GPU).
pub trait TriplaneTaped: TriplaneBackend {
    /// What the reverse pass needs from the forward pass.
    type Tape: Clone + Send + Sync + std::fmt::Debug + 'static;

    /// The samples and the tape.
    fn forward_taped(
        planes: FloatTensor<Self>,
        coords: FloatTensor<Self>,
    ) -> (FloatTensor<Self>, Self::Tape);

    /// The gradients of the planes and of the coordinates from `dL/d(samples)`.
    fn backward_taped(
        tape: Self::Tape,
        grad: FloatTensor<Self>,
    ) -> (FloatTensor<Self>, FloatTensor<Self>);
}

/// The host tape: the inputs in host memory and the device the gradients go back to.
#[derive(Debug)]
pub struct HostTape<B: Backend> {
    inputs: HostInputs,
    device: B::Device,
}

/// The CPU backends: sample on the host, keep the tape there.
macro_rules! host_triplane {
    ($backend:ty) => {
        impl TriplaneBackend for $backend {
            fn triplane_sample(
                planes: FloatTensor<Self>,
                coords: FloatTensor<Self>,
            ) -> FloatTensor<Self> {
                forward_on_host::<Self>(planes, coords).0
            }
        }

        impl TriplaneTaped for $backend {
            type Tape = Arc<HostTape<Self>>;

            fn forward_taped(
                planes: FloatTensor<Self>,
                coords: FloatTensor<Self>,
            ) -> (FloatTensor<Self>, Self::Tape) {
                let device = coords.device();
                let (output, inputs) = forward_on_host::<Self>(planes, coords);
                (output, Arc::new(HostTape { inputs, device }))
            }

            fn backward_taped(
                tape: Self::Tape,
                grad: FloatTensor<Self>,
            ) -> (FloatTensor<Self>, FloatTensor<Self>) {
                let grad_out = to_host::<Self>(grad);
                let inputs = &tape.inputs;
                let (grad_planes, grad_coords) =
                    host::backward(&inputs.planes_last, &inputs.coords, &grad_out, inputs.dims);
                (
                    to_device::<Self>(grad_planes, inputs.plane_shape.clone(), &tape.device),
                    to_device::<Self>(grad_coords, inputs.coord_shape.clone(), &tape.device),
                )
            }
        }
    };
}

host_triplane!(Flex);
host_triplane!(NdArray);

/// The GPU backends: the CubeCL kernels of `device.rs`, tape on the device.
#[cfg(any(feature = "wgpu", feature = "cuda"))]
mod on_device {
    use super::*;
    use crate::triplane::device::TriplaneDeviceOps;
    use burn::backend::Cube;

    impl TriplaneBackend for Cube {
        fn triplane_sample(
            planes: FloatTensor<Self>,
            coords: FloatTensor<Self>,
        ) -> FloatTensor<Self> {
            Self::triplane_device_forward(planes, coords)
        }
    }

    impl TriplaneTaped for Cube {
        type Tape = (FloatTensor<Self>, FloatTensor<Self>);

        fn forward_taped(
            planes: FloatTensor<Self>,
            coords: FloatTensor<Self>,
        ) -> (FloatTensor<Self>, Self::Tape) {
            let output = Self::triplane_device_forward(planes.clone(), coords.clone());
            (output, (planes, coords))
        }

        fn backward_taped(
            (planes, coords): Self::Tape,
            grad: FloatTensor<Self>,
        ) -> (FloatTensor<Self>, FloatTensor<Self>) {
            Self::triplane_device_backward(planes, coords, grad)
        }
    }
}

/// The backward step: the backend's [`TriplaneTaped::backward_taped`].
#[derive(Debug)]
struct TriplaneBackward;

impl<B: TriplaneTaped> Backward<B, 2> for TriplaneBackward {
    type State = B::Tape;

    fn backward(
        self,
        ops: Ops<Self::State, 2>,
        grads: &mut Gradients,
        _checkpointer: &mut Checkpointer,
    ) {
        let grad_out = grads.consume::<B>(&ops.node);
        let (grad_planes, grad_coords) = B::backward_taped(ops.state, grad_out);
        let [planes, coords] = ops.parents;
        if let Some(node) = planes {
            grads.register::<B>(node.id, grad_planes);
        }
        if let Some(node) = coords {
            grads.register::<B>(node.id, grad_coords);
        }
    }
}

impl<B: TriplaneTaped, C: CheckpointStrategy> TriplaneBackend for Autodiff<B, C> {
    fn triplane_sample(planes: FloatTensor<Self>, coords: FloatTensor<Self>) -> FloatTensor<Self> {
        let nodes = [planes.node(), coords.node()];
        let (planes, coords) = (planes.into_primitive(), coords.into_primitive());
        match TriplaneBackward
            .prepare::<C>(nodes)
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => {
                let (output, tape) = B::forward_taped(planes, coords);
                prep.finish(tape, output)
            }
            OpsKind::UnTracked(prep) => prep.finish(B::triplane_sample(planes, coords)),
        }
    }
}
