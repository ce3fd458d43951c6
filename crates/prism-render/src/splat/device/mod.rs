//! The rasterizer on the GPU: CubeCL kernels ([`kernels`]) launched on Burn's cube backend, so
//! that a training step on wgpu or CUDA never reads the Gaussians back to the host.
//!
//! [`SplatDeviceOps`] is a backend extension with two operations, the forward pass (returning
//! the image and the tape its reverse pass reads: the projected Gaussians, their per-camera
//! depth order, each pixel's final transmittance and contributor count) and the reverse pass.
//! Both are implemented for `CubeBackend`; the `Fusion` selector makes `#[backend_extension]`
//! generate the lazy `Fusion<CubeBackend>` version (the type Burn's wgpu device uses), with the
//! output shapes from [`forward_meta`] and [`backward_meta`].
//!
//! The pipeline of a forward pass: `project_kernel` (one unit per Gaussian: 2D mean, conic,
//! opacity, pixel rect, depth key), a bitonic sort of `(depth, index)` per camera (on the
//! device; the passes over nearby pairs in shared memory), and `rasterize_kernel` (one cube per 16x16
//! tile: it walks the camera's depth order in chunks of 256 staged in shared memory, skipping
//! the Gaussians whose rect misses the tile). The reverse pass walks the same chunks back to
//! front and accumulates the projected gradients with float atomics, then
//! `project_backward_kernel` applies the chain rule per Gaussian.

mod kernels;

use burn::backend::fusion::custom::TensorSpec;
use burn::backend::tensor::{FloatTensor, IntTensor};
use burn::backend::{Backend, ExtensionType, backend_extension};
use burn::tensor::{DType, Shape};
use burn_cubecl::ops::numeric::{empty_device_dtype, zeros_client};
use burn_cubecl::tensor::CubeTensor;
use burn_cubecl::{CubeBackend, CubeDevice};
use cubecl::prelude::*;

use crate::launch::{cameras_tensor, elementwise, prepared, require_float_atomics};

use self::kernels::{BLOCK, GRAD_HEAD, PROJECTED};
use super::host::{TILE_SIZE, view::View};
use super::op::{SplatCameras, SplatInputs, SplatInputsMetadata};
use prism_core::Camera;

/// What the reverse pass reads from the forward pass, as device tensors.
#[derive(ExtensionType, Clone, Debug)]
#[extension_type(fusion)]
pub struct DeviceTape<B: Backend> {
    /// `[B, C + 2, H, W]`: features, alpha and accumulated depth (the output).
    pub image: FloatTensor<B>,
    /// `[B, N, 12]` projected Gaussians (layout in [`kernels`]).
    pub projected: FloatTensor<B>,
    /// `[B, n_pad]` (`u32`): per camera, the Gaussians' indices sorted by depth, padding last.
    pub order: IntTensor<B>,
    /// `[B, H, W]` final transmittance per pixel.
    pub transmittance: FloatTensor<B>,
    /// `[B, H, W]` (`u32`): `1 +` the depth rank of the last Gaussian composited per pixel.
    pub contributors: IntTensor<B>,
}

/// The rasterizer's device operations (see the module docs).
#[backend_extension(Fusion, Cube)]
pub trait SplatDeviceOps: Backend {
    /// Renders `inputs` into `cameras`; the tape's `image` is the result.
    #[fusion(meta = forward_meta)]
    fn splat_device_forward(
        #[extension_type] inputs: SplatInputs<Self>,
        cameras: SplatCameras,
    ) -> DeviceTape<Self>;

    /// The gradients of every input from `dL/d(image)`, returned in the inputs' layout.
    #[fusion(meta = backward_meta)]
    fn splat_device_backward(
        #[extension_type] inputs: SplatInputs<Self>,
        #[extension_type] tape: DeviceTape<Self>,
        grad: FloatTensor<Self>,
        cameras: SplatCameras,
    ) -> SplatInputs<Self>;
}

/// The padded length of one camera's depth-order array: a power of two, at least one chunk.
fn padded(count: usize) -> usize {
    count.next_power_of_two().max(BLOCK)
}

/// `(B, N, C, H, W)` of a call.
fn sizes(features: &Shape, cameras: &SplatCameras) -> (usize, usize, usize, usize, usize) {
    let k = cameras.0[0].intrinsics;
    (
        features[0],
        features[1],
        features[2],
        k.height as usize,
        k.width as usize,
    )
}

/// The output shapes of [`SplatDeviceOps::splat_device_forward`].
fn forward_meta(inputs: &SplatInputsMetadata, cameras: &SplatCameras) -> DeviceTapeMetadata {
    let (b, n, c, h, w) = sizes(&inputs.features.shape, cameras);
    let float = |shape: Vec<usize>| TensorSpec::new(Shape::from(shape), DType::F32);
    let int = |shape: Vec<usize>| TensorSpec::new(Shape::from(shape), DType::U32);
    DeviceTapeMetadata {
        image: float(vec![b, c + 2, h, w]),
        projected: float(vec![b, n, PROJECTED]),
        order: int(vec![b, padded(n)]),
        transmittance: float(vec![b, h, w]),
        contributors: int(vec![b, h, w]),
    }
}

/// The output shapes of [`SplatDeviceOps::splat_device_backward`]: those of the inputs.
fn backward_meta(
    inputs: &SplatInputsMetadata,
    _tape: &DeviceTapeMetadata,
    _grad: &TensorSpec,
    _cameras: &SplatCameras,
) -> SplatInputsMetadata {
    let f32_like = |spec: &TensorSpec| TensorSpec::new(spec.shape.clone(), DType::F32);
    SplatInputsMetadata {
        means: f32_like(&inputs.means),
        log_scales: f32_like(&inputs.log_scales),
        rotations: f32_like(&inputs.rotations),
        opacity_logits: f32_like(&inputs.opacity_logits),
        features: f32_like(&inputs.features),
    }
}

/// The inputs as contiguous `f32` tensors.
fn prepared_inputs(inputs: SplatInputs<CubeBackend>) -> SplatInputs<CubeBackend> {
    SplatInputs {
        means: prepared(inputs.means),
        log_scales: prepared(inputs.log_scales),
        rotations: prepared(inputs.rotations),
        opacity_logits: prepared(inputs.opacity_logits),
        features: prepared(inputs.features),
    }
}

/// The cameras as a `[B, VIEW]` device tensor: the pinhole, then the `x/z` and `y/z` limits of
/// the projection Jacobian (`View::ratio_limits`).
fn views_tensor(cameras: &SplatCameras, device: &CubeDevice) -> CubeTensor {
    let limits = |camera: &Camera| {
        let lim = View::new(camera).ratio_limits();
        vec![lim[0][0], lim[0][1], lim[1][0], lim[1][1]]
    };
    cameras_tensor(&cameras.0, limits, device)
}

/// The tile grid launch: one cube of 16x16 units per tile and camera.
fn tiled(b: usize, h: usize, w: usize) -> (CubeCount, CubeDim) {
    (
        CubeCount::Static(
            w.div_ceil(TILE_SIZE) as u32,
            h.div_ceil(TILE_SIZE) as u32,
            b as u32,
        ),
        CubeDim::new_2d(TILE_SIZE as u32, TILE_SIZE as u32),
    )
}

/// Sorts each `n_pad` segment of `(keys, values)` ascending, on the device: a bitonic network
/// whose passes over pairs closer than [`BLOCK`] run in shared memory, one launch for all of
/// them between two global passes (28 launches for 16k Gaussians instead of 105).
fn sort_segments(keys: &CubeTensor, values: &CubeTensor, n_pad: usize) {
    let total = keys.meta.shape().num_elements();
    let (count, dim) = elementwise(keys, total);
    let local = |k_first: usize, k_last: usize, j_first: usize| {
        kernels::bitonic_local_kernel::launch(
            &keys.client,
            CubeCount::Static((total / BLOCK) as u32, 1, 1),
            CubeDim::new_1d(BLOCK as u32),
            keys.clone().into_tensor_arg(),
            values.clone().into_tensor_arg(),
            k_first as u32,
            k_last as u32,
            j_first as u32,
            n_pad as u32,
        );
    };
    local(2, BLOCK.min(n_pad), 1);
    let mut k = 2 * BLOCK;
    while k <= n_pad {
        let mut j = k / 2;
        while j >= BLOCK {
            kernels::bitonic_step_kernel::launch(
                &keys.client,
                count.clone(),
                dim,
                keys.clone().into_tensor_arg(),
                values.clone().into_tensor_arg(),
                j as u32,
                k as u32,
                n_pad as u32,
            );
            j /= 2;
        }
        local(k, k, BLOCK / 2);
        k *= 2;
    }
}

impl SplatDeviceOps for CubeBackend {
    fn splat_device_forward(inputs: SplatInputs<Self>, cameras: SplatCameras) -> DeviceTape<Self> {
        let (b, n, c, h, w) = sizes(&inputs.features.meta.shape().clone(), &cameras);
        let client = inputs.means.client.clone();
        let device = inputs.means.device.clone();
        let n_pad = padded(n);
        let SplatInputs {
            means,
            log_scales,
            rotations,
            opacity_logits,
            features,
        } = prepared_inputs(inputs);
        let views = views_tensor(&cameras, &device);
        let empty = |shape: Vec<usize>, dtype| {
            empty_device_dtype(client.clone(), device.clone(), Shape::from(shape), dtype)
        };
        let projected = empty(vec![b, n, PROJECTED], DType::F32);
        let keys = empty(vec![b, n_pad], DType::U32);
        let order = empty(vec![b, n_pad], DType::U32);
        let (count, dim) = elementwise(&keys, b * n_pad);
        kernels::project_kernel::launch(
            &client,
            count,
            dim,
            means.into_tensor_arg(),
            log_scales.into_tensor_arg(),
            rotations.into_tensor_arg(),
            opacity_logits.into_tensor_arg(),
            views.into_tensor_arg(),
            projected.clone().into_tensor_arg(),
            keys.clone().into_tensor_arg(),
            order.clone().into_tensor_arg(),
            n as u32,
            n_pad as u32,
            w as u32,
            h as u32,
        );
        sort_segments(&keys, &order, n_pad);

        let image = zeros_client(
            client.clone(),
            device.clone(),
            Shape::from(vec![b, c + 2, h, w]),
            DType::F32,
        );
        let transmittance = empty(vec![b, h, w], DType::F32);
        let contributors = empty(vec![b, h, w], DType::U32);
        let (count, dim) = tiled(b, h, w);
        kernels::rasterize_kernel::launch(
            &client,
            count,
            dim,
            projected.clone().into_tensor_arg(),
            features.into_tensor_arg(),
            order.clone().into_tensor_arg(),
            image.clone().into_tensor_arg(),
            transmittance.clone().into_tensor_arg(),
            contributors.clone().into_tensor_arg(),
            n as u32,
            n_pad as u32,
            w as u32,
            h as u32,
            c as u32,
        );
        DeviceTape {
            image,
            projected,
            order,
            transmittance,
            contributors,
        }
    }

    fn splat_device_backward(
        inputs: SplatInputs<Self>,
        tape: DeviceTape<Self>,
        grad: FloatTensor<Self>,
        cameras: SplatCameras,
    ) -> SplatInputs<Self> {
        let (b, n, c, h, w) = sizes(&inputs.features.meta.shape().clone(), &cameras);
        let client = inputs.means.client.clone();
        let device = inputs.means.device.clone();
        require_float_atomics(&inputs.means);
        let n_pad = padded(n);
        let shapes = [
            inputs.means.meta.shape().clone(),
            inputs.log_scales.meta.shape().clone(),
            inputs.rotations.meta.shape().clone(),
            inputs.opacity_logits.meta.shape().clone(),
            inputs.features.meta.shape().clone(),
        ];
        let SplatInputs {
            means,
            log_scales,
            rotations,
            opacity_logits,
            features,
        } = prepared_inputs(inputs);
        let grad = prepared(grad);
        let views = views_tensor(&cameras, &device);
        let zeros = |shape: Vec<usize>| {
            zeros_client(
                client.clone(),
                device.clone(),
                Shape::from(shape),
                DType::F32,
            )
        };
        let behind = zeros(vec![b, c + 2, h, w]);
        let slots = zeros(vec![b * n, GRAD_HEAD + c]);
        let (count, dim) = tiled(b, h, w);
        kernels::rasterize_backward_kernel::launch(
            &client,
            count,
            dim,
            tape.projected.into_tensor_arg(),
            features.clone().into_tensor_arg(),
            tape.order.into_tensor_arg(),
            tape.transmittance.into_tensor_arg(),
            tape.contributors.into_tensor_arg(),
            grad.into_tensor_arg(),
            behind.into_tensor_arg(),
            slots.clone().into_tensor_arg(),
            n as u32,
            n_pad as u32,
            w as u32,
            h as u32,
            c as u32,
        );
        let empty = |shape: &Shape| {
            empty_device_dtype(client.clone(), device.clone(), shape.clone(), DType::F32)
        };
        let out: SplatInputs<Self> = SplatInputs {
            means: empty(&shapes[0]),
            log_scales: empty(&shapes[1]),
            rotations: empty(&shapes[2]),
            opacity_logits: empty(&shapes[3]),
            features: empty(&shapes[4]),
        };
        let (count, dim) = elementwise(&slots, b * n);
        kernels::project_backward_kernel::launch(
            &client,
            count,
            dim,
            means.into_tensor_arg(),
            log_scales.into_tensor_arg(),
            rotations.into_tensor_arg(),
            opacity_logits.into_tensor_arg(),
            views.into_tensor_arg(),
            slots.into_tensor_arg(),
            out.means.clone().into_tensor_arg(),
            out.log_scales.clone().into_tensor_arg(),
            out.rotations.clone().into_tensor_arg(),
            out.opacity_logits.clone().into_tensor_arg(),
            out.features.clone().into_tensor_arg(),
            n as u32,
            c as u32,
        );
        out
    }
}
