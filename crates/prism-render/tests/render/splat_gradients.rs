//! The backward pass of the rasterizer against central finite differences, for every kind of
//! parameter, on small scenes.
//!
//! The scenes keep the rendered image a smooth function of the parameters (the finite
//! differences are meaningless across a discontinuity): every Gaussian's 3-sigma support
//! covers the whole image, opacities stay below the 0.99 clamp, depths are well apart, and the
//! transmittance stays far above the 1e-4 stop.

use crate::common;

use burn::tensor::{Device, Tensor, TensorData};
use common::{Scene, device, host, orbit_camera, tracked};
use prism_core::Camera;
use prism_render::splat::{Gaussians, render};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Four large Gaussians around the orbit centre, at distinct depths along the view axis.
fn scene(seed: u64, camera: &Camera, channels: usize) -> Scene {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let centre = glam::Vec3::new(0.1, 0.9, -0.05);
    let forward = camera.rotation().z_axis;
    let mut s = Scene::new(1, channels);
    for (k, along) in [-0.6f32, 0.6, -0.2, 0.2].iter().enumerate() {
        let lateral = glam::Vec3::new(
            rng.random_range(-0.08..0.08),
            rng.random_range(-0.08..0.08),
            rng.random_range(-0.08..0.08),
        );
        let mean = centre + forward * *along + lateral;
        // Anisotropic, so that rotations matter.
        let log_scale = [
            rng.random_range(-0.2f32..0.3),
            rng.random_range(-0.6f32..-0.2),
            rng.random_range(-1.0f32..-0.6),
        ];
        let mut rotation: [f32; 4] = std::array::from_fn(|_| rng.random_range(-1.0f32..1.0));
        rotation[0] += 1.5 * (k as f32 - 1.5).signum();
        let opacity = rng.random_range(0.5f32..0.85);
        let features: Vec<f32> = (0..channels)
            .map(|_| rng.random_range(-0.5f32..1.0))
            .collect();
        s.push(mean.to_array(), log_scale, rotation, opacity, &features);
    }
    s
}

/// Random per-pixel weights of the features, the alpha and the depth.
struct Weights {
    features: Vec<f32>,
    alpha: Vec<f32>,
    depth: Vec<f32>,
    dims: [usize; 3],
}

impl Weights {
    /// Smooth random fields (a few waves per channel), so that moving, turning or growing a
    /// Gaussian changes the loss coherently and the gradients stand well above the f32
    /// rounding of the finite differences.
    fn new(seed: u64, c: usize, h: usize, w: usize) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut field = |channels: usize| {
            let mut out = Vec::with_capacity(channels * h * w);
            for _ in 0..channels {
                let waves: Vec<[f32; 4]> = (0..3)
                    .map(|_| {
                        [
                            rng.random_range(-0.4..0.4),
                            rng.random_range(-0.4..0.4),
                            rng.random_range(0.0..6.3),
                            rng.random_range(-1.0..1.0),
                        ]
                    })
                    .collect();
                for y in 0..h {
                    for x in 0..w {
                        let v: f32 = waves
                            .iter()
                            .map(|[a, b, p, amp]| amp * (a * x as f32 + b * y as f32 + p).sin())
                            .sum();
                        out.push(v);
                    }
                }
            }
            out
        };
        Self {
            features: field(c),
            alpha: field(1),
            depth: field(1),
            dims: [c, h, w],
        }
    }

    fn tensor(&self, values: &[f32], c: usize, device: &Device) -> Tensor<4> {
        let [_, h, w] = self.dims;
        Tensor::from_data(TensorData::new(values.to_vec(), [1, c, h, w]), device)
    }

    /// The loss as a tensor, for autodiff.
    fn loss(&self, g: &Gaussians, camera: &Camera, device: &Device) -> Tensor<1> {
        let r = render(g, &[*camera]).unwrap();
        let c = self.dims[0];
        (r.features * self.tensor(&self.features, c, device)).sum()
            + (r.alpha * self.tensor(&self.alpha, 1, device)).sum()
            + (r.depth * self.tensor(&self.depth, 1, device)).sum()
    }

    /// The same loss accumulated in f64 on the host, for finite differences.
    fn loss_f64(&self, g: &Gaussians, camera: &Camera) -> f64 {
        let r = render(g, &[*camera]).unwrap();
        let dot = |t: Tensor<4>, w: &[f32]| -> f64 {
            host(t)
                .iter()
                .zip(w)
                .map(|(a, b)| *a as f64 * *b as f64)
                .sum()
        };
        dot(r.features, &self.features) + dot(r.alpha, &self.alpha) + dot(r.depth, &self.depth)
    }
}

fn check_gradients(seed: u64, camera: Camera, channels: usize) {
    check_gradients_on(&device(), seed, camera, channels);
}

/// The device kernels (wgpu) against finite differences on the same scenes.
#[cfg(feature = "wgpu")]
#[test]
#[cfg_attr(not(wgpu_adapter), ignore = "no wgpu adapter on this machine")]
fn device_gradients_match_finite_differences() {
    let _serial = common::serial();
    let Some(gpu) = common::wgpu() else { return };
    check_gradients_on(&gpu, 3, orbit_camera(24, 20, 40.0, 10.0, -5.0), 3);
}

fn check_gradients_on(dev: &Device, seed: u64, camera: Camera, channels: usize) {
    let dev = dev.clone();
    let ad = dev.clone().autodiff();
    let (w, h) = (
        camera.intrinsics.width as usize,
        camera.intrinsics.height as usize,
    );
    let base = scene(seed, &camera, channels);
    let weights = Weights::new(seed + 100, channels, h, w);

    // The scene must be smooth in the image: every pixel covered.
    let r = render(&base.tensors(&dev), &[camera]).unwrap();
    let alpha = host(r.alpha);
    assert!(
        alpha.iter().all(|&a| a > 0.3 && a < 0.999),
        "not a smooth scene"
    );
    for i in 0..base.count {
        let mut one = base.clone();
        one.count = 1;
        for (_, v) in one.kinds_mut() {
            let per = v.len() / base.count;
            *v = v[i * per..(i + 1) * per].to_vec();
        }
        let alpha = host(render(&one.tensors(&dev), &[camera]).unwrap().alpha);
        assert!(
            alpha.iter().all(|&a| a > 0.0),
            "Gaussian {i} does not cover the image"
        );
    }

    // Analytic gradients through the autodiff graph.
    let g = base.tensors(&ad);
    let g = tracked(g);
    let grads = weights.loss(&g, &camera, &ad).backward();
    let analytic = [
        host(g.means.grad(&grads).unwrap()),
        host(g.log_scales.grad(&grads).unwrap()),
        host(g.rotations.grad(&grads).unwrap()),
        host(g.opacity_logits.grad(&grads).unwrap()),
        host(g.features.grad(&grads).unwrap()),
    ];

    let h_step = 2e-2f32;
    for (kind, an) in analytic.iter().enumerate() {
        let mut worst = (0.0f64, String::new());
        let scale = an.iter().fold(0.0f32, |m, v| m.max(v.abs())) as f64;
        assert!(scale > 1e-2, "kind {kind}: all gradients ~0");
        for (i, &a) in an.iter().enumerate() {
            let at = |d: f32| {
                let mut s = base.clone();
                s.kinds_mut()[kind].1[i] += d;
                weights.loss_f64(&s.tensors(&dev), &camera)
            };
            // Fourth-order central difference.
            let fd = (8.0 * (at(h_step) - at(-h_step)) - (at(2.0 * h_step) - at(-2.0 * h_step)))
                / (12.0 * h_step as f64);
            // Relative error, with a floor of 1% of the kind's largest gradient for entries
            // that are ~0 (where a relative error is meaningless).
            let denom = fd.abs().max(a.abs() as f64).max(1e-2 * scale);
            let rel = (a as f64 - fd).abs() / denom;
            if rel > worst.0 {
                let name = base.clone().kinds_mut()[kind].0;
                worst = (
                    rel,
                    format!("{name}[{i}]: analytic {a}, finite difference {fd}"),
                );
            }
        }
        assert!(worst.0 < 1e-2, "relative error {}: {}", worst.0, worst.1);
    }
}

#[test]
fn gradients_match_finite_differences_with_three_channels() {
    check_gradients(1, orbit_camera(40, 34, 60.0, 12.0, -7.0), 3);
}

#[test]
fn gradients_match_finite_differences_in_another_view_with_one_channel() {
    check_gradients(2, orbit_camera(30, 21, 45.0, -25.0, 14.0), 1);
}

/// The gradients of a batch are those of its elements, and flex computes what ndarray does.
#[test]
fn batched_gradients_are_per_element_gradients_on_ndarray_and_flex() {
    let cams = [
        orbit_camera(24, 18, 40.0, 12.0, -7.0),
        orbit_camera(24, 18, 40.0, -20.0, 10.0),
    ];
    let grads_of = |scene: &Scene, cams: &[Camera], dev: &Device| -> Vec<Vec<f32>> {
        let g = scene.tensors(dev);
        let g = tracked(g);
        let r = render(&g, cams).unwrap();
        let loss = (r.features.powi_scalar(2).sum() + r.alpha.sum() + r.depth.sum()).backward();
        vec![
            host(g.means.grad(&loss).unwrap()),
            host(g.log_scales.grad(&loss).unwrap()),
            host(g.rotations.grad(&loss).unwrap()),
            host(g.opacity_logits.grad(&loss).unwrap()),
            host(g.features.grad(&loss).unwrap()),
        ]
    };
    let ndarray = device().autodiff();
    let flex = prism_core::BackendKind::Flex.device().unwrap().autodiff();
    let elements: Vec<Scene> = (0..2)
        .map(|b| scene(10 + b, &cams[b as usize], 2))
        .collect();
    let mut batch = elements[0].clone();
    batch.batch = 2;
    for (k, (_, v)) in batch.kinds_mut().into_iter().enumerate() {
        v.extend(elements[1].clone().kinds_mut()[k].1.iter());
    }
    let batched = grads_of(&batch, &cams, &ndarray);
    assert_eq!(batched, grads_of(&batch, &cams, &flex));
    for (b, element) in elements.iter().enumerate() {
        let single = grads_of(element, &cams[b..b + 1], &ndarray);
        for (kind, values) in single.iter().enumerate() {
            let n = values.len();
            assert!(values.iter().any(|v| v.abs() > 1e-3));
            assert_eq!(&batched[kind][b * n..(b + 1) * n], &values[..]);
        }
    }
}
