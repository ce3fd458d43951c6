//! The rasterizer on the wgpu backend (through host memory) agrees with ndarray, forward and
//! backward. Runs with `--features wgpu` on a machine with a Vulkan/Metal/DX12 device (Mesa's
//! software Vulkan is enough).
#![cfg(feature = "wgpu")]

mod common;

use common::{Scene, device, host, orbit_camera};
use prism_data::BackendKind;
use prism_render::splat::{Gaussians, render};

fn scene() -> Scene {
    let mut s = Scene::new(1, 2);
    let q = [0.9, 0.1, -0.3, 0.25];
    s.push([0.1, 0.9, 0.0], [-1.0, -1.3, -1.6], q, 0.7, &[1.0, 0.2]);
    s.push(
        [0.15, 0.85, -0.3],
        [-1.2, -1.0, -1.5],
        [1.0, 0.0, 0.0, 0.0],
        0.6,
        &[0.3, 0.8],
    );
    s.push(
        [0.0, 0.95, 0.3],
        [-1.4, -1.6, -1.1],
        [0.5, 0.5, 0.5, -0.5],
        0.8,
        &[0.5, -0.4],
    );
    s
}

fn render_and_grads(dev: &burn::tensor::Device) -> (Vec<f32>, Vec<Vec<f32>>) {
    let camera = orbit_camera(40, 34, 60.0, 12.0, -7.0);
    let plain = render(&scene().tensors(dev), &[camera]).unwrap();
    let image = host(plain.features);
    let g = scene().tensors(&dev.clone().autodiff());
    let g = Gaussians {
        means: g.means.require_grad(),
        log_scales: g.log_scales.require_grad(),
        rotations: g.rotations.require_grad(),
        opacity_logits: g.opacity_logits.require_grad(),
        features: g.features.require_grad(),
    };
    let r = render(&g, &[camera]).unwrap();
    let grads = (r.features.powi_scalar(2).sum() + r.alpha.sum() + r.depth.sum()).backward();
    let grads = vec![
        host(g.means.grad(&grads).unwrap()),
        host(g.log_scales.grad(&grads).unwrap()),
        host(g.rotations.grad(&grads).unwrap()),
        host(g.opacity_logits.grad(&grads).unwrap()),
        host(g.features.grad(&grads).unwrap()),
    ];
    (image, grads)
}

#[test]
fn wgpu_renders_and_differentiates_like_ndarray() {
    let wgpu = BackendKind::Wgpu.device().unwrap();
    let (image, grads) = render_and_grads(&wgpu);
    let (image_ref, grads_ref) = render_and_grads(&device());
    assert_eq!(image, image_ref);
    assert!(image.iter().any(|&v| v > 0.1));
    for (a, b) in grads.iter().zip(&grads_ref) {
        let scale = b.iter().fold(0.0f32, |m, v| m.max(v.abs()));
        assert!(scale > 0.0);
        for (x, y) in a.iter().zip(b) {
            assert!((x - y).abs() <= 1e-5 * scale, "{x} vs {y}");
        }
    }
}
