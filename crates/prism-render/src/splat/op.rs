//! The rasterizer as a Burn backend extension, with its hand-written backward pass.
//!
//! Burn 0.22 has no backend generics in user code; a custom differentiable operation is a
//! `#[backend_extension]` trait implemented for each concrete backend (the forward) and for
//! `Autodiff<B, C>` (the forward plus a [`Backward`] step registered in the graph). The generated
//! `impl SplatBackend for Dispatch` routes a call to the backend of its input tensors.
//!
//! Every backend is served by the host rasterizer (`host`): the inputs are read to host memory,
//! rendered there and the result is uploaded to the inputs' device. The forward pass keeps its
//! tape (projections, tile lists, final transmittances) in the autodiff graph, so the backward
//! pass does not recompute it.

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
use prism_data::Camera;

use super::host::{self, CameraTape, HostGaussians};
use crate::transfer::{to_device, to_host};

/// The tensor inputs of [`SplatBackend::splat_rasterize`], as backend primitives.
#[derive(ExtensionType)]
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
#[backend_extension(Autodiff, Flex, NdArray, Cube: cfg(any(feature = "wgpu", feature = "cuda")))]
pub trait SplatBackend: Backend {
    /// Renders `B x N` Gaussians into `B` cameras: `[B, C + 2, H, W]` holding the composited
    /// features, the alpha `1 - T` and the accumulated depth `sum_i w_i z_i`.
    fn splat_rasterize(
        #[extension_type] inputs: SplatInputs<Self>,
        cameras: SplatCameras,
    ) -> FloatTensor<Self>;
}

/// The host inputs and the shapes of the original primitives.
#[derive(Debug)]
struct Inputs {
    gaussians: HostGaussians,
    shapes: [Vec<usize>; 5],
}

fn inputs_to_host<B: Backend>(
    means: FloatTensor<B>,
    log_scales: FloatTensor<B>,
    rotations: FloatTensor<B>,
    opacity_logits: FloatTensor<B>,
    features: FloatTensor<B>,
) -> Inputs {
    let shapes = [
        means.shape().to_vec(),
        log_scales.shape().to_vec(),
        rotations.shape().to_vec(),
        opacity_logits.shape().to_vec(),
        features.shape().to_vec(),
    ];
    let (batch, count, channels) = (shapes[0][0], shapes[0][1], shapes[4][2]);
    Inputs {
        gaussians: HostGaussians {
            batch,
            count,
            channels,
            means: to_host::<B>(means),
            log_scales: to_host::<B>(log_scales),
            rotations: to_host::<B>(rotations),
            opacity_logits: to_host::<B>(opacity_logits),
            features: to_host::<B>(features),
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

/// The forward pass on the host for any backend: returns the output primitive, and the tape
/// when asked for.
fn forward_on_host<B: Backend>(
    inputs: SplatInputs<B>,
    cameras: &SplatCameras,
) -> (FloatTensor<B>, Inputs, Vec<CameraTape>) {
    let device = inputs.means.device();
    let host = inputs_to_host::<B>(
        inputs.means,
        inputs.log_scales,
        inputs.rotations,
        inputs.opacity_logits,
        inputs.features,
    );
    let (image, tapes) = host::forward(&host.gaussians, &cameras.0);
    let shape = output_shape(&host.gaussians, &cameras.0);
    (to_device::<B>(image, shape, &device), host, tapes)
}

impl SplatBackend for Flex {
    fn splat_rasterize(inputs: SplatInputs<Self>, cameras: SplatCameras) -> FloatTensor<Self> {
        forward_on_host::<Self>(inputs, &cameras).0
    }
}

impl SplatBackend for NdArray {
    fn splat_rasterize(inputs: SplatInputs<Self>, cameras: SplatCameras) -> FloatTensor<Self> {
        forward_on_host::<Self>(inputs, &cameras).0
    }
}

#[cfg(any(feature = "wgpu", feature = "cuda"))]
impl SplatBackend for burn::backend::Cube {
    fn splat_rasterize(inputs: SplatInputs<Self>, cameras: SplatCameras) -> FloatTensor<Self> {
        forward_on_host::<Self>(inputs, &cameras).0
    }
}

/// Everything the backward pass needs, shared (not copied) by the graph.
#[derive(Debug)]
struct Tape {
    inputs: Inputs,
    cameras: SplatCameras,
    tapes: Vec<CameraTape>,
}

/// The backward step of [`SplatBackend::splat_rasterize`]: reverse compositing and the chain
/// rule through the projection, on the host (see `host::backward`).
#[derive(Debug)]
struct SplatBackward;

impl<B: Backend> Backward<B, 5> for SplatBackward {
    type State = (Arc<Tape>, B::Device);

    fn backward(
        self,
        ops: Ops<Self::State, 5>,
        grads: &mut Gradients,
        _checkpointer: &mut Checkpointer,
    ) {
        let grad_out = to_host::<B>(grads.consume::<B>(&ops.node));
        let (tape, device) = ops.state;
        let g = host::backward(
            &tape.inputs.gaussians,
            &tape.cameras.0,
            &tape.tapes,
            &grad_out,
        );
        let values = [
            g.means,
            g.log_scales,
            g.rotations,
            g.opacity_logits,
            g.features,
        ];
        for ((parent, value), shape) in ops.parents.into_iter().zip(values).zip(&tape.inputs.shapes)
        {
            if let Some(node) = parent {
                grads.register::<B>(node.id, to_device::<B>(value, shape.clone(), &device));
            }
        }
    }
}

impl<B: Backend, C: CheckpointStrategy> SplatBackend for Autodiff<B, C> {
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
                let device = inner.means.device();
                let (output, inputs, tapes) = forward_on_host::<B>(inner, &cameras);
                let tape = Tape {
                    inputs,
                    cameras,
                    tapes,
                };
                prep.finish((Arc::new(tape), device), output)
            }
            OpsKind::UnTracked(prep) => prep.finish(forward_on_host::<B>(inner, &cameras).0),
        }
    }
}
