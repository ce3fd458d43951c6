//! prism's geometry operations on a served device (Burn's remote backend, `prism serve`).
//!
//! On a served device each operation is a custom operation of the remote backend: the trainer
//! sends its inputs' handles (the tensors stay on the server) and the server runs the
//! operation on its own backend, with the same implementations as a local run (host code on
//! the CPU backends, CubeCL kernels on a GPU). The reverse passes of the splatting and of the
//! triplane sampling are operations too: the server recomputes the forward pass's tape from
//! the inputs and runs the backward pass, so no tape crosses the network. `Autodiff<Remote>`
//! needs nothing else: the generic autodiff implementations of the operations take
//! [`Remote`]'s `forward_taped` / `backward_taped` below like any other backend's.
//!
//! The cameras and the mesh's faces, which are not tensors, travel as small `f32` tensors.

// burn-ndarray is deprecated upstream, but the project's tests run on it.
#![allow(deprecated)]

use std::sync::Arc;

use burn::backend::ir::{BackendIr, CustomOpIr, HandleContainer};
use burn::backend::tensor::FloatTensor;
use burn::backend::{Remote, TensorMetadata};
use burn::server::RemoteServer;
use burn::tensor::{Device, Shape};
use glam::Mat4;
use prism_core::served::{Call, ServerTensor, input_values};
use prism_core::{Camera, Intrinsics, for_served_backend};

use crate::mesh::op::{FragmentTensors, MeshBackend, MeshCameras, MeshFaces};
use crate::splat::op::{SplatBackend, SplatCameras, SplatInputs, SplatTaped};
use crate::triplane::op::{TriplaneBackend, TriplaneTaped};

/// Triplane sampling: planes, coordinates -> samples.
const TRIPLANE_FORWARD: &str = "prism.triplane.forward.v1";
/// Its reverse pass: planes, coordinates, `dL/d(samples)` -> gradients of both inputs.
const TRIPLANE_BACKWARD: &str = "prism.triplane.backward.v1";
/// Gaussian splatting: the five Gaussian tensors, cameras -> image.
const SPLAT_FORWARD: &str = "prism.splat.forward.v1";
/// Its reverse pass: the five tensors, cameras, `dL/d(image)` -> the five gradients.
const SPLAT_BACKWARD: &str = "prism.splat.backward.v1";
/// Mesh rasterization: vertices, faces, cameras -> faces, barycentrics and depth per pixel.
const MESH_RASTERIZE: &str = "prism.mesh.rasterize.v1";

/// `f32` values per camera: `fx fy cx cy width height` and the 16 entries of `c2w`.
const CAMERA_VALUES: usize = 22;

/// `server` running prism's geometry operations on the backend of `device`.
///
/// # Errors
/// A device of a backend that cannot be served (a remote device).
pub fn register(server: RemoteServer, device: &Device) -> Result<RemoteServer, String> {
    for_served_backend!(device, B => server
        .with_custom_op::<B, _>(TRIPLANE_FORWARD, triplane_forward::<B>)
        .with_custom_op::<B, _>(TRIPLANE_BACKWARD, triplane_backward::<B>)
        .with_custom_op::<B, _>(SPLAT_FORWARD, splat_forward::<B>)
        .with_custom_op::<B, _>(SPLAT_BACKWARD, splat_backward::<B>)
        .with_custom_op::<B, _>(MESH_RASTERIZE, mesh_rasterize::<B>))
}

/// A call on the server that holds `tensor`.
fn call_beside(tensor: &ServerTensor) -> Call {
    Call::new(&Device::from(tensor.device())).expect("a remote tensor is on a served device")
}

/// `cameras` as `f32` values ([`CAMERA_VALUES`] each).
fn encode_cameras(cameras: &[Camera]) -> Vec<f32> {
    cameras
        .iter()
        .flat_map(|c| {
            let k = c.intrinsics;
            [k.fx, k.fy, k.cx, k.cy, k.width as f32, k.height as f32]
                .into_iter()
                .chain(c.c2w.to_cols_array())
        })
        .collect()
}

/// The cameras of [`encode_cameras`]'s values.
fn decode_cameras(values: &[f32]) -> Vec<Camera> {
    values
        .chunks_exact(CAMERA_VALUES)
        .map(|v| {
            let intrinsics = Intrinsics {
                fx: v[0],
                fy: v[1],
                cx: v[2],
                cy: v[3],
                width: v[4] as u32,
                height: v[5] as u32,
            };
            let c2w = Mat4::from_cols_slice(&v[6..CAMERA_VALUES]);
            Camera::new(intrinsics, c2w)
        })
        .collect()
}

/// The image size `(height, width)` all `cameras` share.
fn image_size(cameras: &[Camera]) -> (usize, usize) {
    let k = cameras.first().expect("at least one camera").intrinsics;
    (k.height as usize, k.width as usize)
}

/// Input `index` of `op` on the server, as a tensor of `B`.
fn input<B: BackendIr>(
    handles: &mut HandleContainer<B::Handle>,
    op: &CustomOpIr,
    index: usize,
) -> FloatTensor<B> {
    handles.get_float_tensor::<B>(&op.inputs[index])
}

/// Registers `tensors` as the outputs of `op`, in order.
fn outputs<B: BackendIr>(
    handles: &mut HandleContainer<B::Handle>,
    op: &CustomOpIr,
    tensors: impl IntoIterator<Item = FloatTensor<B>>,
) {
    for (out, tensor) in op.outputs.iter().zip(tensors) {
        handles.register_float_tensor::<B>(&out.id, tensor);
    }
}

impl TriplaneBackend for Remote {
    fn triplane_sample(planes: FloatTensor<Self>, coords: FloatTensor<Self>) -> FloatTensor<Self> {
        let (planes_shape, coords_shape) = (planes.shape(), coords.shape());
        let output = [
            coords_shape[0],
            planes_shape[1],
            coords_shape[2],
            coords_shape[3],
        ];
        call_beside(&coords)
            .input_tensor(planes)
            .input_tensor(coords)
            .output(output)
            .send(TRIPLANE_FORWARD)
            .remove(0)
    }
}

impl TriplaneTaped for Remote {
    /// The inputs, still on the server.
    type Tape = (FloatTensor<Self>, FloatTensor<Self>);

    fn forward_taped(
        planes: FloatTensor<Self>,
        coords: FloatTensor<Self>,
    ) -> (FloatTensor<Self>, Self::Tape) {
        let output = Self::triplane_sample(planes.clone(), coords.clone());
        (output, (planes, coords))
    }

    fn backward_taped(
        (planes, coords): Self::Tape,
        grad: FloatTensor<Self>,
    ) -> (FloatTensor<Self>, FloatTensor<Self>) {
        let (planes_shape, coords_shape) = (planes.shape(), coords.shape());
        let mut grads = call_beside(&grad)
            .input_tensor(planes)
            .input_tensor(coords)
            .input_tensor(grad)
            .output(planes_shape)
            .output(coords_shape)
            .send(TRIPLANE_BACKWARD)
            .into_iter();
        let mut next = || grads.next().expect("two gradients");
        (next(), next())
    }
}

fn triplane_forward<B: BackendIr + TriplaneBackend>(
    handles: &mut HandleContainer<B::Handle>,
    op: &CustomOpIr,
    _device: &B::Device,
) {
    let (planes, coords) = (input::<B>(handles, op, 0), input::<B>(handles, op, 1));
    outputs::<B>(handles, op, [B::triplane_sample(planes, coords)]);
}

fn triplane_backward<B: BackendIr + TriplaneTaped>(
    handles: &mut HandleContainer<B::Handle>,
    op: &CustomOpIr,
    _device: &B::Device,
) {
    let (planes, coords) = (input::<B>(handles, op, 0), input::<B>(handles, op, 1));
    let grad = input::<B>(handles, op, 2);
    let (_, tape) = B::forward_taped(planes, coords);
    let (grad_planes, grad_coords) = B::backward_taped(tape, grad);
    outputs::<B>(handles, op, [grad_planes, grad_coords]);
}

/// The five tensors of `inputs` added to `call`, in their declared order.
fn with_gaussians(call: Call, inputs: SplatInputs<Remote>) -> Call {
    [
        inputs.means,
        inputs.log_scales,
        inputs.rotations,
        inputs.opacity_logits,
        inputs.features,
    ]
    .into_iter()
    .fold(call, Call::input_tensor)
}

/// The five Gaussian tensors at inputs `0..5` of `op`, and the cameras at input 5.
fn gaussians_and_cameras<B: BackendIr>(
    handles: &mut HandleContainer<B::Handle>,
    op: &CustomOpIr,
) -> (SplatInputs<B>, SplatCameras) {
    let inputs = SplatInputs {
        means: input::<B>(handles, op, 0),
        log_scales: input::<B>(handles, op, 1),
        rotations: input::<B>(handles, op, 2),
        opacity_logits: input::<B>(handles, op, 3),
        features: input::<B>(handles, op, 4),
    };
    let cameras = decode_cameras(&input_values::<B>(handles, op, 5));
    (inputs, SplatCameras(Arc::from(cameras)))
}

impl SplatBackend for Remote {
    fn splat_rasterize(inputs: SplatInputs<Self>, cameras: SplatCameras) -> FloatTensor<Self> {
        let (h, w) = image_size(&cameras.0);
        let [b, _, c] = inputs.features.shape().dims();
        let call = call_beside(&inputs.means);
        with_gaussians(call, inputs)
            .input(encode_cameras(&cameras.0))
            .output([b, c + 2, h, w])
            .send(SPLAT_FORWARD)
            .remove(0)
    }
}

impl SplatTaped for Remote {
    /// The inputs, still on the server.
    type Tape = SplatInputs<Self>;

    fn forward_taped(
        inputs: SplatInputs<Self>,
        cameras: &SplatCameras,
    ) -> (FloatTensor<Self>, Self::Tape) {
        let output = Self::splat_rasterize(inputs.clone(), cameras.clone());
        (output, inputs)
    }

    fn backward_taped(
        inputs: Self::Tape,
        cameras: &SplatCameras,
        grad: FloatTensor<Self>,
    ) -> SplatInputs<Self> {
        let shapes: Vec<Shape> = [
            &inputs.means,
            &inputs.log_scales,
            &inputs.rotations,
            &inputs.opacity_logits,
            &inputs.features,
        ]
        .iter()
        .map(|t| t.shape())
        .collect();
        let call = call_beside(&grad);
        let call = with_gaussians(call, inputs)
            .input(encode_cameras(&cameras.0))
            .input_tensor(grad);
        let mut grads = shapes
            .into_iter()
            .fold(call, Call::output)
            .send(SPLAT_BACKWARD)
            .into_iter();
        let mut next = || grads.next().expect("five gradients");
        SplatInputs {
            means: next(),
            log_scales: next(),
            rotations: next(),
            opacity_logits: next(),
            features: next(),
        }
    }
}

fn splat_forward<B: BackendIr + SplatBackend>(
    handles: &mut HandleContainer<B::Handle>,
    op: &CustomOpIr,
    _device: &B::Device,
) {
    let (inputs, cameras) = gaussians_and_cameras::<B>(handles, op);
    outputs::<B>(handles, op, [B::splat_rasterize(inputs, cameras)]);
}

fn splat_backward<B: BackendIr + SplatTaped>(
    handles: &mut HandleContainer<B::Handle>,
    op: &CustomOpIr,
    _device: &B::Device,
) {
    let (inputs, cameras) = gaussians_and_cameras::<B>(handles, op);
    let grad = input::<B>(handles, op, 6);
    let (_, tape) = B::forward_taped(inputs, &cameras);
    let g = B::backward_taped(tape, &cameras, grad);
    outputs::<B>(
        handles,
        op,
        [
            g.means,
            g.log_scales,
            g.rotations,
            g.opacity_logits,
            g.features,
        ],
    );
}

impl MeshBackend for Remote {
    fn mesh_rasterize(
        vertices: FloatTensor<Self>,
        faces: MeshFaces,
        cameras: MeshCameras,
    ) -> FragmentTensors<Self> {
        let (h, w) = image_size(&cameras.0);
        let b = vertices.shape()[0];
        let faces: Vec<f32> = faces.0.iter().flatten().map(|&i| i as f32).collect();
        let mut maps = call_beside(&vertices)
            .input_tensor(vertices)
            .input(faces)
            .input(encode_cameras(&cameras.0))
            .output([b, h, w])
            .output([b, h, w, 3])
            .output([b, h, w])
            .send(MESH_RASTERIZE)
            .into_iter();
        let mut next = || maps.next().expect("three maps");
        FragmentTensors {
            faces: next(),
            barycentrics: next(),
            depth: next(),
        }
    }
}

fn mesh_rasterize<B: BackendIr + MeshBackend>(
    handles: &mut HandleContainer<B::Handle>,
    op: &CustomOpIr,
    _device: &B::Device,
) {
    let vertices = input::<B>(handles, op, 0);
    let faces: Vec<[u32; 3]> = input_values::<B>(handles, op, 1)
        .chunks_exact(3)
        .map(|f| [f[0] as u32, f[1] as u32, f[2] as u32])
        .collect();
    let cameras = decode_cameras(&input_values::<B>(handles, op, 2));
    let maps = B::mesh_rasterize(
        vertices,
        MeshFaces(Arc::from(faces)),
        MeshCameras(Arc::from(cameras)),
    );
    outputs::<B>(handles, op, [maps.faces, maps.barycentrics, maps.depth]);
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    #[test]
    fn cameras_travel_exactly() {
        let k = Intrinsics::protocol_default(48, 32);
        let cameras = [
            Camera::look_at(Vec3::new(0.3, 1.2, 2.5), Vec3::Y, Vec3::Y, k),
            Camera::look_at(Vec3::new(-1.0, 0.8, 2.0), Vec3::ZERO, Vec3::Y, k),
        ];
        let values = encode_cameras(&cameras);
        assert_eq!(values.len(), 2 * CAMERA_VALUES);
        assert_eq!(decode_cameras(&values), cameras);
    }
}
