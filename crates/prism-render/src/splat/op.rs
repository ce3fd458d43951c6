//! The rasterizer as a Burn backend extension, with its hand-written backward pass.
//!
//! Burn 0.22 has no backend generics in user code; a custom differentiable operation is a
//! `#[backend_extension]` trait implemented for each concrete backend (the forward) and for
//! `Autodiff<B, C>` (the forward plus a [`Backward`] step registered in the graph). The generated
//! `impl SplatBackend for Dispatch` routes a call to the backend of its input tensors.
//!
//! The CPU backends (flex, ndarray) are served by the host rasterizer (`host`), the GPU backends
//! by its CubeCL twin (`device`), which never reads the Gaussians back to the host. Both share
//! one set of constants and one tile size (`host`'s). The forward pass keeps its tape
//! (projections, depth order, final transmittances) in the autodiff graph, so the backward pass
//! does not recompute it.

// burn-ndarray is deprecated upstream, but the project's tests run on it.
#![allow(deprecated)]

use std::sync::Arc;

use burn::backend::autodiff::checkpoint::{base::Checkpointer, strategy::CheckpointStrategy};
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::tensor::FloatTensor;
use burn::backend::{
    Autodiff, Backend, ExtensionType, Flex, NdArray, TensorMetadata, backend_extension,
};
use prism_core::Camera;

use super::host::{self, CameraTape, HostGaussians};
use crate::transfer::{to_device, to_host};

/// The tensor inputs of [`SplatBackend::splat_rasterize`], as backend primitives.
#[derive(ExtensionType, Clone, Debug)]
#[extension_type(fusion: cfg(any(feature = "wgpu", feature = "cuda")))]
pub struct SplatInputs<B: Backend> {
    /// `[B, N, 3]` world-space centres.
    pub means: FloatTensor<B>,
    /// `[B, N, 3]` log of the axis scales.
    pub log_scales: FloatTensor<B>,
    /// `[B, N, 4]` quaternions `w x y z` (normalised inside).
    pub rotations: FloatTensor<B>,
    /// `[B, N, 1]` opacities before the sigmoid.
    pub opacity_logits: FloatTensor<B>,
    /// `[B, N, C]` features composited into the image.
    pub features: FloatTensor<B>,
}

/// One camera per batch element; all share one image size.
#[derive(Clone, Debug)]
pub struct SplatCameras(pub Arc<[Camera]>);

/// The Gaussian rasterizer as a backend operation.
#[backend_extension(
    Autodiff,
    Flex,
    NdArray,
    Remote,
    Cube: cfg(any(feature = "wgpu", feature = "cuda"))
)]
pub trait SplatBackend: Backend {
    /// Renders `B x N` Gaussians into `B` cameras: `[B, C + 2, H, W]` holding the composited
    /// features, the alpha `1 - T` and the accumulated depth `sum_i w_i z_i`.
    fn splat_rasterize(
        #[extension_type] inputs: SplatInputs<Self>,
        cameras: SplatCameras,
    ) -> FloatTensor<Self>;
}

/// How a backend runs the rasterizer under autodiff: the forward pass together with the tape
/// its reverse pass reads, and that reverse pass. The CPU backends keep the tape in host memory
/// (`host`); the cube backend keeps it in device tensors (`device`).
pub trait SplatTaped: SplatBackend {
    /// What the reverse pass needs from the forward pass.
    type Tape: Clone + Send + Sync + std::fmt::Debug + 'static;

    /// The forward pass: the `[B, C + 2, H, W]` image and the tape.
    fn forward_taped(
        inputs: SplatInputs<Self>,
        cameras: &SplatCameras,
    ) -> (FloatTensor<Self>, Self::Tape);

    /// The gradients of every input, in the inputs' shapes, from `dL/d(image)`.
    fn backward_taped(
        tape: Self::Tape,
        cameras: &SplatCameras,
        grad: FloatTensor<Self>,
    ) -> SplatInputs<Self>;
}

/// The host inputs and the shapes of the original primitives.
#[derive(Debug)]
struct Inputs {
    gaussians: HostGaussians,
    shapes: [Vec<usize>; 5],
}

fn inputs_to_host<B: Backend>(inputs: SplatInputs<B>) -> Inputs {
    let shapes = [
        inputs.means.shape().to_vec(),
        inputs.log_scales.shape().to_vec(),
        inputs.rotations.shape().to_vec(),
        inputs.opacity_logits.shape().to_vec(),
        inputs.features.shape().to_vec(),
    ];
    let (batch, count, channels) = (shapes[0][0], shapes[0][1], shapes[4][2]);
    Inputs {
        gaussians: HostGaussians {
            batch,
            count,
            channels,
            means: to_host::<B>(inputs.means),
            log_scales: to_host::<B>(inputs.log_scales),
            rotations: to_host::<B>(inputs.rotations),
            opacity_logits: to_host::<B>(inputs.opacity_logits),
            features: to_host::<B>(inputs.features),
        },
        shapes,
    }
}

/// The output shape `[B, C + 2, H, W]`.
fn output_shape(gaussians: &HostGaussians, cameras: &[Camera]) -> Vec<usize> {
    let k = cameras
        .first()
        .map(|c| c.intrinsics)
        .expect("splat: no camera");
    vec![
        gaussians.batch,
        gaussians.channels + 2,
        k.height as usize,
        k.width as usize,
    ]
}

/// The host rasterizer's tape: its inputs, per camera what `host::backward` reads, and the
/// device the gradients go back to.
#[derive(Debug)]
pub struct HostTape<B: Backend> {
    inputs: Inputs,
    tapes: Vec<CameraTape>,
    device: B::Device,
}

/// The forward pass on the host for any backend: the output primitive and the tape.
fn host_forward<B: Backend>(
    inputs: SplatInputs<B>,
    cameras: &SplatCameras,
) -> (FloatTensor<B>, HostTape<B>) {
    let device = inputs.means.device();
    let host = inputs_to_host::<B>(inputs);
    let (image, tapes) = host::forward(&host.gaussians, &cameras.0);
    let shape = output_shape(&host.gaussians, &cameras.0);
    let output = to_device::<B>(image, shape, &device);
    let tape = HostTape {
        inputs: host,
        tapes,
        device,
    };
    (output, tape)
}

/// The reverse pass on the host: reverse compositing and the chain rule through the projection
/// (`host::backward`).
fn host_backward<B: Backend>(
    tape: &HostTape<B>,
    cameras: &SplatCameras,
    grad: FloatTensor<B>,
) -> SplatInputs<B> {
    let grad_out = to_host::<B>(grad);
    let g = host::backward(&tape.inputs.gaussians, &cameras.0, &tape.tapes, &grad_out);
    let [means, log_scales, rotations, opacity_logits, features] = [
        g.means,
        g.log_scales,
        g.rotations,
        g.opacity_logits,
        g.features,
    ]
    .into_iter()
    .zip(&tape.inputs.shapes)
    .map(|(value, shape)| to_device::<B>(value, shape.clone(), &tape.device))
    .collect::<Vec<_>>()
    .try_into()
    .expect("five gradients");
    SplatInputs {
        means,
        log_scales,
        rotations,
        opacity_logits,
        features,
    }
}

/// The CPU backends: rasterize on the host, keep the tape there.
macro_rules! host_splat {
    ($backend:ty) => {
        impl SplatBackend for $backend {
            fn splat_rasterize(
                inputs: SplatInputs<Self>,
                cameras: SplatCameras,
            ) -> FloatTensor<Self> {
                host_forward::<Self>(inputs, &cameras).0
            }
        }

        impl SplatTaped for $backend {
            type Tape = Arc<HostTape<Self>>;

            fn forward_taped(
                inputs: SplatInputs<Self>,
                cameras: &SplatCameras,
            ) -> (FloatTensor<Self>, Self::Tape) {
                let (output, tape) = host_forward::<Self>(inputs, cameras);
                (output, Arc::new(tape))
            }

            fn backward_taped(
                tape: Self::Tape,
                cameras: &SplatCameras,
                grad: FloatTensor<Self>,
            ) -> SplatInputs<Self> {
                host_backward::<Self>(&tape, cameras, grad)
            }
        }
    };
}

host_splat!(Flex);
host_splat!(NdArray);

/// The GPU backends: the CubeCL kernels of [`crate::splat::device`], tape on the device.
#[cfg(any(feature = "wgpu", feature = "cuda"))]
mod on_device {
    use super::*;
    use crate::splat::device::{DeviceTape, SplatDeviceOps};
    use burn::backend::Cube;

    impl SplatBackend for Cube {
        fn splat_rasterize(inputs: SplatInputs<Self>, cameras: SplatCameras) -> FloatTensor<Self> {
            Self::splat_device_forward(inputs, cameras).image
        }
    }

    impl SplatTaped for Cube {
        type Tape = (SplatInputs<Self>, DeviceTape<Self>);

        fn forward_taped(
            inputs: SplatInputs<Self>,
            cameras: &SplatCameras,
        ) -> (FloatTensor<Self>, Self::Tape) {
            let tape = Self::splat_device_forward(inputs.clone(), cameras.clone());
            (tape.image.clone(), (inputs, tape))
        }

        fn backward_taped(
            (inputs, tape): Self::Tape,
            cameras: &SplatCameras,
            grad: FloatTensor<Self>,
        ) -> SplatInputs<Self> {
            Self::splat_device_backward(inputs, tape, grad, cameras.clone())
        }
    }
}

/// The backward step of [`SplatBackend::splat_rasterize`] under autodiff: the backend's
/// [`SplatTaped::backward_taped`], registered for the inputs that are tracked.
#[derive(Debug)]
struct SplatBackward;

impl<B: SplatTaped> Backward<B, 5> for SplatBackward {
    type State = (B::Tape, SplatCameras);

    fn backward(
        self,
        ops: Ops<Self::State, 5>,
        grads: &mut Gradients,
        _checkpointer: &mut Checkpointer,
    ) {
        let grad_out = grads.consume::<B>(&ops.node);
        let (tape, cameras) = ops.state;
        let g = B::backward_taped(tape, &cameras, grad_out);
        let values = [
            g.means,
            g.log_scales,
            g.rotations,
            g.opacity_logits,
            g.features,
        ];
        for (parent, value) in ops.parents.into_iter().zip(values) {
            if let Some(node) = parent {
                grads.register::<B>(node.id, value);
            }
        }
    }
}

impl<B: SplatTaped, C: CheckpointStrategy> SplatBackend for Autodiff<B, C> {
    fn splat_rasterize(inputs: SplatInputs<Self>, cameras: SplatCameras) -> FloatTensor<Self> {
        let nodes = [
            inputs.means.node(),
            inputs.log_scales.node(),
            inputs.rotations.node(),
            inputs.opacity_logits.node(),
            inputs.features.node(),
        ];
        let inner = SplatInputs::<B> {
            means: inputs.means.into_primitive(),
            log_scales: inputs.log_scales.into_primitive(),
            rotations: inputs.rotations.into_primitive(),
            opacity_logits: inputs.opacity_logits.into_primitive(),
            features: inputs.features.into_primitive(),
        };
        match SplatBackward.prepare::<C>(nodes).compute_bound().stateful() {
            OpsKind::Tracked(prep) => {
                let (output, tape) = B::forward_taped(inner, &cameras);
                prep.finish((tape, cameras), output)
            }
            OpsKind::UnTracked(prep) => prep.finish(B::splat_rasterize(inner, cameras)),
        }
    }
}
