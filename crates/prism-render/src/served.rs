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
pub const TRIPLANE_FORWARD: &str = "prism.triplane.forward.v1";
/// Its reverse pass: planes, coordinates, `dL/d(samples)` -> gradients of both inputs.
pub const TRIPLANE_BACKWARD: &str = "prism.triplane.backward.v1";
/// Gaussian splatting: the five Gaussian tensors, cameras -> image.
pub const SPLAT_FORWARD: &str = "prism.splat.forward.v1";
/// Its reverse pass: the five tensors, cameras, `dL/d(image)` -> the five gradients.
pub const SPLAT_BACKWARD: &str = "prism.splat.backward.v1";
/// Mesh rasterization: vertices, faces, cameras -> faces, barycentrics and depth per pixel.
pub const MESH_RASTERIZE: &str = "prism.mesh.rasterize.v1";

/// `f32` values per camera: `fx fy cx cy width height` and the 16 entries of `c2w`.
pub const CAMERA_VALUES: usize = 22;

/// The most values a served geometry operation writes (all its outputs): 4 GiB of `f32`.
pub const MAX_OUTPUT_VALUES: usize = 1 << 30;

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

/// `cameras` as `f32` values ([`CAMERA_VALUES`] each): how they travel to a server.
pub fn encode_cameras(cameras: &[Camera]) -> Vec<f32> {
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

/// Checks a call's cameras, decoded on the server, before anything is allocated for it: one
/// per batch element, one size within [`crate::image_size::MAX_IMAGE_SIDE`], and at most
/// [`MAX_OUTPUT_VALUES`] values written for `channels` values per pixel.
fn check_cameras(cameras: &[Camera], batch: usize, channels: usize) -> Result<(), String> {
    let (w, h) = crate::image_size::image_size(cameras).map_err(|e| e.to_string())?;
    if cameras.len() != batch {
        return Err(format!("{} cameras for a batch of {batch}", cameras.len()));
    }
    check_output(&[batch, channels, h as usize, w as usize])
}

/// Checks that an output of `shape` stays within [`MAX_OUTPUT_VALUES`].
fn check_output(shape: &[usize]) -> Result<(), String> {
    match shape.iter().try_fold(1usize, |n, &d| n.checked_mul(d)) {
        Some(n) if n <= MAX_OUTPUT_VALUES => Ok(()),
        _ => Err(format!(
            "an output of {shape:?} exceeds the limit of {MAX_OUTPUT_VALUES} values"
        )),
    }
}

/// Checks that every face indexes one of `vertices` vertices.
fn check_faces(faces: &[[u32; 3]], vertices: usize) -> Result<(), String> {
    crate::mesh::check_faces(faces, vertices).map_err(|e| e.to_string())
}

/// Refuses a call whose inputs fail a check: the server says why and drops the session that
/// sent it (Burn's server catches the panic of one session's operation), and keeps serving.
/// A trainer never sends such a call: the same checks fail on its side first, with the same
/// message ([`crate::splat::render`], [`crate::mesh::rasterize_maps`]).
fn refuse_unless(op: &CustomOpIr, check: Result<(), String>) {
    if let Err(why) = check {
        eprintln!("prism serve: refused a call of {}: {why}", op.id);
        panic!("refused a call of {}: {why}", op.id);
    }
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
    let (p, c) = (planes.shape(), coords.shape());
    refuse_unless(op, check_output(&[c[0], p[1], c[2], c[3]]));
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

/// The five Gaussian tensors at inputs `0..5` of `op`, and the cameras at input 5, checked
/// against the server's limits (a call past them is refused, see [`refuse_unless`]).
fn gaussians_and_cameras<B: BackendIr>(
    handles: &mut HandleContainer<B::Handle>,
    op: &CustomOpIr,
) -> (SplatInputs<B>, SplatCameras) {
    let inputs: SplatInputs<B> = SplatInputs {
        means: input::<B>(handles, op, 0),
        log_scales: input::<B>(handles, op, 1),
        rotations: input::<B>(handles, op, 2),
        opacity_logits: input::<B>(handles, op, 3),
        features: input::<B>(handles, op, 4),
    };
    let cameras = decode_cameras(&input_values::<B>(handles, op, 5));
    // The image the forward pass renders (the backward pass's tape too): features, alpha, depth.
    let [b, _, c] = inputs.features.shape().dims();
    refuse_unless(op, check_cameras(&cameras, b, c + 2));
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
    let [b, v, _] = vertices.shape().dims();
    // Faces, barycentrics (3) and depth: five values per pixel.
    refuse_unless(op, check_cameras(&cameras, b, 5));
    refuse_unless(op, check_faces(&faces, v));
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

    /// What a server refuses before allocating: huge or mismatched cameras, outputs past the
    /// limit, faces past the vertices. Each message names the limit or the index.
    #[test]
    fn calls_past_the_limits_are_refused_with_the_limit_named() {
        let camera = |w, h| {
            Camera::look_at(
                Vec3::Z,
                Vec3::ZERO,
                Vec3::Y,
                Intrinsics::protocol_default(w, h),
            )
        };
        assert!(check_cameras(&[camera(64, 48)], 1, 5).is_ok());
        let huge = check_cameras(&[camera(100_000, 100_000)], 1, 5).unwrap_err();
        assert!(huge.contains("limit of 4096"), "{huge}");
        let count = check_cameras(&[camera(64, 48)], 3, 5).unwrap_err();
        assert!(count.contains("1 cameras for a batch of 3"), "{count}");
        let big = check_cameras(&[camera(4096, 4096); 16], 16, 5).unwrap_err();
        assert!(big.contains(&MAX_OUTPUT_VALUES.to_string()), "{big}");
        assert!(check_output(&[usize::MAX, 2]).is_err());
        assert!(check_faces(&[[0, 1, 2]], 3).is_ok());
        let face = check_faces(&[[0, 1, 2], [2, 3, 1]], 3).unwrap_err();
        assert!(
            face.contains("[2, 3, 1]") && face.contains("3 vertices"),
            "{face}"
        );
    }
}
