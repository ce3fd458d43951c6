//! prism's geometry operations on a served device run on the server (custom operations of
//! Burn's remote backend): splatting, triplane sampling and mesh rasterization give the same
//! values as on this machine's flex, and the splatting's and the sampling's gradients reach
//! the served inputs with the same values.

use crate::common::served_device;
use burn::tensor::{Device, Tensor, TensorData};
use glam::Vec3;
use prism_core::{Camera, Intrinsics};
use prism_render::mesh::rasterize_maps;
use prism_render::splat::{Gaussians, render};
use prism_render::triplane::sample_triplane;

/// Deterministic values in about [-1, 1].
fn values(n: usize, seed: u32) -> Vec<f32> {
    (0..n)
        .map(|i| ((i as f32 * 0.618 + seed as f32 * 0.377).fract() * 2.0 - 1.0) * 0.9)
        .collect()
}

fn tensor<const D: usize>(data: &[f32], shape: [usize; D], device: &Device) -> Tensor<D> {
    Tensor::from_data(TensorData::new(data.to_vec(), shape), device)
}

fn host<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data()
        .convert::<f32>()
        .try_into_vec::<f32>()
        .unwrap()
}

fn assert_close(served: &[f32], local: &[f32], what: &str) {
    assert_eq!(served.len(), local.len(), "{what}");
    let diff = served
        .iter()
        .zip(local)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f32::max);
    assert!(diff <= 1e-6, "{what}: max difference {diff}");
    assert!(local.iter().any(|v| *v != 0.0), "{what}: all zero");
}

fn camera() -> Camera {
    Camera::look_at(
        Vec3::new(0.2, 0.3, 2.5),
        Vec3::ZERO,
        Vec3::Y,
        Intrinsics::protocol_default(24, 16),
    )
}

/// Splatting and its gradients, with every Gaussian input tracked.
fn splat(device: &Device) -> Vec<Vec<f32>> {
    let device = device.clone().autodiff();
    let n = 6;
    let means: Vec<f32> = values(n * 3, 1).iter().map(|v| v * 0.4).collect();
    let log_scales: Vec<f32> = values(n * 3, 2).iter().map(|v| v * 0.3 - 1.5).collect();
    let parameters = [
        tensor(&means, [1, n, 3], &device),
        tensor(&log_scales, [1, n, 3], &device),
        tensor(&values(n * 4, 3), [1, n, 4], &device),
        tensor(&values(n, 4), [1, n, 1], &device),
        tensor(&values(n * 3, 5), [1, n, 3], &device),
    ]
    .map(Tensor::require_grad);
    let [means, log_scales, rotations, opacity_logits, features] = parameters.clone();
    let gaussians = Gaussians {
        means,
        log_scales,
        rotations,
        opacity_logits,
        features,
    };
    let rendered = render(&gaussians, &[camera()]).unwrap();
    let image = Tensor::cat(vec![rendered.features, rendered.alpha], 1);
    let weights = tensor(&values(4 * 16 * 24, 6), [1, 4, 16, 24], &device);
    let grads = (image.clone() * weights).sum().backward();
    let mut out = vec![host(image.inner())];
    out.extend(parameters.map(|p| host(p.grad(&grads).unwrap())));
    out
}

/// Triplane sampling and its gradients, both inputs tracked.
fn triplane(device: &Device) -> Vec<Vec<f32>> {
    let device = device.clone().autodiff();
    let planes = tensor(&values(3 * 2 * 5 * 5, 7), [3, 2, 5, 5], &device).require_grad();
    let coords = tensor(&values(2 * 3 * 4 * 6, 8), [2, 3, 4, 6], &device).require_grad();
    let samples = sample_triplane(planes.clone(), coords.clone()).unwrap();
    let weights = tensor(&values(2 * 2 * 4 * 6, 9), [2, 2, 4, 6], &device);
    let grads = (samples.clone() * weights).sum().backward();
    vec![
        host(samples.inner()),
        host(planes.grad(&grads).unwrap()),
        host(coords.grad(&grads).unwrap()),
    ]
}

/// Mesh rasterization of two triangles facing the camera.
fn mesh(device: &Device) -> Vec<Vec<f32>> {
    let vertices = [
        -0.5, -0.4, 0.0, 0.5, -0.4, 0.1, 0.0, 0.5, 0.0, -0.6, 0.3, -0.3, 0.4, 0.4, -0.2,
    ];
    let vertices = tensor(&vertices, [1, 5, 3], device);
    let maps = rasterize_maps(vertices, &[[0, 1, 2], [0, 3, 4]], &[camera()]).unwrap();
    vec![host(maps.faces), host(maps.barycentrics), host(maps.depth)]
}

#[test]
fn geometry_runs_on_the_server_with_the_local_values_and_gradients() {
    let served = served_device();
    let local = Device::flex();
    for (name, op) in [
        ("splat", splat as fn(&Device) -> Vec<Vec<f32>>),
        ("triplane", triplane),
        ("mesh", mesh),
    ] {
        let (ours, theirs) = (op(&served), op(&local));
        assert_eq!(ours.len(), theirs.len());
        for (k, (a, b)) in ours.iter().zip(&theirs).enumerate() {
            assert_close(a, b, &format!("{name} output {k}"));
        }
    }
}
