//! Triplane sampling on the GPU: the host's bilinear taps (`host.rs`, border padding, texel
//! centres at `i + 0.5`) as CubeCL kernels on Burn's cube backend, forward and reverse, so that
//! the SMPL-X branch never reads its triplane or coordinates back to the host.
//!
//! The forward pass runs one unit per output value `(b, channel, point)`; the reverse pass one
//! unit per point, adding its texel gradients with float atomics and writing its coordinate
//! gradient. [`TriplaneDeviceOps`] is implemented for `CubeBackend`; `#[backend_extension]`
//! generates the lazy `Fusion<CubeBackend>` version.

use burn::backend::fusion::custom::TensorSpec;
use burn::backend::tensor::FloatTensor;
use burn::backend::{Backend, backend_extension};
use burn::tensor::{DType, Shape};
use burn_cubecl::CubeBackend;
use burn_cubecl::ops::numeric::{empty_device_dtype, zeros_client};
use burn_cubecl::tensor::CubeTensor;
use cubecl::prelude::*;

use super::host::PLANE_AXES;
use crate::launch::{elementwise, prepared, require_float_atomics};

/// Triplane sampling's device operations.
#[backend_extension(Fusion, Cube)]
pub trait TriplaneDeviceOps: Backend {
    /// `[B, C, H, W]` samples of `planes` `[3, C, R, R]` at `coords` `[B, 3, H, W]`.
    #[fusion(meta = forward_meta)]
    fn triplane_device_forward(
        planes: FloatTensor<Self>,
        coords: FloatTensor<Self>,
    ) -> FloatTensor<Self>;

    /// The gradients of the planes and of the coordinates from `dL/d(samples)`.
    #[fusion(meta = backward_meta)]
    fn triplane_device_backward(
        planes: FloatTensor<Self>,
        coords: FloatTensor<Self>,
        grad: FloatTensor<Self>,
    ) -> (FloatTensor<Self>, FloatTensor<Self>);
}

fn forward_meta(planes: &TensorSpec, coords: &TensorSpec) -> TensorSpec {
    let (p, c) = (&planes.shape, &coords.shape);
    TensorSpec::new(Shape::from(vec![c[0], p[1], c[2], c[3]]), DType::F32)
}

fn backward_meta(
    planes: &TensorSpec,
    coords: &TensorSpec,
    _grad: &TensorSpec,
) -> (TensorSpec, TensorSpec) {
    (
        TensorSpec::new(planes.shape.clone(), DType::F32),
        TensorSpec::new(coords.shape.clone(), DType::F32),
    )
}

/// The axes of plane `p` (host `PLANE_AXES`), as `(column axis, row axis)`.
#[cube]
fn plane_axes(#[comptime] p: usize) -> (usize, usize) {
    let axes = comptime!(PLANE_AXES[p]);
    (comptime!(axes[0]), comptime!(axes[1]))
}

/// One bilinear tap along one axis (host `Tap::new`): lower texel, upper texel, weight of the
/// upper one and `d(texel coordinate) / d(coordinate)`.
#[derive(CubeType, Clone, Copy)]
struct Tap {
    i0: u32,
    i1: u32,
    frac: f32,
    slope: f32,
}

#[cube]
fn tap(c: f32, r: u32) -> Tap {
    let half = f32::cast_from(r) * 0.5;
    let t = (c + 1.0) * half - 0.5;
    let max = f32::cast_from(r - 1);
    let mut out = Tap {
        i0: 0,
        i1: 0,
        frac: 0.0,
        slope: 0.0,
    };
    if r == 1 || f32::is_nan(t) || t <= 0.0 || t >= max {
        if r > 1 && t >= max {
            out.i0 = r - 1;
            out.i1 = r - 1;
        }
    } else {
        let i0 = u32::cast_from(f32::floor(t));
        out.i0 = i0;
        out.i1 = i0 + 1;
        out.frac = t - f32::floor(t);
        out.slope = half;
    }
    out
}

/// `out[b, ch, s] = sum_p bilinear(planes[p, ch], coords[b, axes(p), s])`.
#[cube(launch)]
fn sample_kernel(
    planes: &Tensor<f32>,
    coords: &Tensor<f32>,
    out: &mut Tensor<f32>,
    points: u32,
    channels: u32,
    resolution: u32,
) {
    let pos = ABSOLUTE_POS;
    if pos >= out.len() {
        terminate!();
    }
    let n = points as usize;
    let s = pos % n;
    let ch = (pos / n) % channels as usize;
    let b = pos / (n * channels as usize);
    let r = resolution as usize;
    let mut value = 0.0f32;
    #[unroll]
    for p in 0..3usize {
        let (ax_u, ax_v) = plane_axes(p);
        let u = tap(coords[(b * 3 + ax_u) * n + s], resolution);
        let v = tap(coords[(b * 3 + ax_v) * n + s], resolution);
        let base = (p * channels as usize + ch) * r * r;
        let t00 = planes[base + v.i0 as usize * r + u.i0 as usize];
        let t01 = planes[base + v.i0 as usize * r + u.i1 as usize];
        let t10 = planes[base + v.i1 as usize * r + u.i0 as usize];
        let t11 = planes[base + v.i1 as usize * r + u.i1 as usize];
        value += (1.0 - v.frac) * ((1.0 - u.frac) * t00 + u.frac * t01)
            + v.frac * ((1.0 - u.frac) * t10 + u.frac * t11);
    }
    out[pos] = value;
}

/// The reverse pass, one unit per point `(b, s)`: texel gradients `w g` added atomically into
/// `grad_planes` (zeroed), and the coordinate gradient through the bilinear weights.
#[cube(launch)]
fn sample_backward_kernel(
    planes: &Tensor<f32>,
    coords: &Tensor<f32>,
    grad: &Tensor<f32>,
    grad_planes: &mut Tensor<Atomic<f32>>,
    grad_coords: &mut Tensor<f32>,
    points: u32,
    channels: u32,
    resolution: u32,
) {
    let pos = ABSOLUTE_POS;
    let n = points as usize;
    if pos >= grad_coords.len() / 3 {
        terminate!();
    }
    let s = pos % n;
    let b = pos / n;
    let r = resolution as usize;
    let c = channels as usize;
    let mut g_axis = Array::<f32>::new(3usize);
    #[unroll]
    for k in 0..3 {
        g_axis[k] = 0.0;
    }
    #[unroll]
    for p in 0..3usize {
        let (ax_u, ax_v) = plane_axes(p);
        let u = tap(coords[(b * 3 + ax_u) * n + s], resolution);
        let v = tap(coords[(b * 3 + ax_v) * n + s], resolution);
        let w00 = (1.0 - v.frac) * (1.0 - u.frac);
        let w01 = (1.0 - v.frac) * u.frac;
        let w10 = v.frac * (1.0 - u.frac);
        let w11 = v.frac * u.frac;
        let mut du = 0.0f32;
        let mut dv = 0.0f32;
        for ch in 0..c {
            let g = grad[(b * c + ch) * n + s];
            let base = (p * c + ch) * r * r;
            let i00 = base + v.i0 as usize * r + u.i0 as usize;
            let i01 = base + v.i0 as usize * r + u.i1 as usize;
            let i10 = base + v.i1 as usize * r + u.i0 as usize;
            let i11 = base + v.i1 as usize * r + u.i1 as usize;
            if w00 != 0.0 {
                grad_planes[i00].fetch_add(w00 * g);
            }
            if w01 != 0.0 {
                grad_planes[i01].fetch_add(w01 * g);
            }
            if w10 != 0.0 {
                grad_planes[i10].fetch_add(w10 * g);
            }
            if w11 != 0.0 {
                grad_planes[i11].fetch_add(w11 * g);
            }
            let (t00, t01, t10, t11) = (planes[i00], planes[i01], planes[i10], planes[i11]);
            du += g * ((1.0 - v.frac) * (t01 - t00) + v.frac * (t11 - t10));
            dv += g * ((1.0 - u.frac) * (t10 - t00) + u.frac * (t11 - t01));
        }
        g_axis[ax_u] += du * u.slope;
        g_axis[ax_v] += dv * v.slope;
    }
    #[unroll]
    for k in 0..3usize {
        grad_coords[(b * 3 + k) * n + s] = g_axis[k];
    }
}

impl TriplaneDeviceOps for CubeBackend {
    fn triplane_device_forward(planes: CubeTensor, coords: CubeTensor) -> CubeTensor {
        let (planes, coords) = (prepared(planes), prepared(coords));
        let p = planes.meta.shape().clone();
        let c = coords.meta.shape().clone();
        let out = empty_device_dtype(
            coords.client.clone(),
            coords.device.clone(),
            Shape::from(vec![c[0], p[1], c[2], c[3]]),
            DType::F32,
        );
        let (count, dim) = elementwise(&out, c[0] * p[1] * c[2] * c[3]);
        sample_kernel::launch(
            &out.client,
            count,
            dim,
            planes.into_tensor_arg(),
            coords.into_tensor_arg(),
            out.clone().into_tensor_arg(),
            (c[2] * c[3]) as u32,
            p[1] as u32,
            p[2] as u32,
        );
        out
    }

    fn triplane_device_backward(
        planes: CubeTensor,
        coords: CubeTensor,
        grad: CubeTensor,
    ) -> (CubeTensor, CubeTensor) {
        let (planes, coords, grad) = (prepared(planes), prepared(coords), prepared(grad));
        let p = planes.meta.shape().clone();
        let c = coords.meta.shape().clone();
        let (client, device) = (coords.client.clone(), coords.device.clone());
        require_float_atomics(&coords);
        let grad_planes = zeros_client(client.clone(), device.clone(), p.clone(), DType::F32);
        let grad_coords = empty_device_dtype(client.clone(), device, c.clone(), DType::F32);
        let (count, dim) = elementwise(&grad_coords, c[0] * c[2] * c[3]);
        sample_backward_kernel::launch(
            &client,
            count,
            dim,
            planes.into_tensor_arg(),
            coords.into_tensor_arg(),
            grad.into_tensor_arg(),
            grad_planes.clone().into_tensor_arg(),
            grad_coords.clone().into_tensor_arg(),
            (c[2] * c[3]) as u32,
            p[1] as u32,
            p[2] as u32,
        );
        (grad_planes, grad_coords)
    }
}
