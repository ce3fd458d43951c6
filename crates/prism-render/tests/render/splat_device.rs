//! The rasterizer's device kernels (wgpu) against the host rasterizer (ndarray): forward values
//! and every gradient, on scenes that stress them, and no geometry read on the way. Runs with
//! the `wgpu` feature (on in the workspace's default build) on a machine with a Vulkan, Metal
//! or DX12 adapter (Mesa's lavapipe is enough); with `PRISM_REQUIRE_WGPU` set, a missing
//! adapter is a failure instead of a skip.
#![cfg(feature = "wgpu")]

use crate::common;

use burn::tensor::Device;
use common::{Scene, device, host, orbit_camera, serial, tracked, wgpu};
use prism_core::Camera;
use prism_core::reads::geometry_host_reads;
use prism_render::splat::{Gaussians, render};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// The rendered `[features, alpha, depth]` and the five gradients of a fixed weighted loss.
fn render_and_grads(
    scene: &Scene,
    cameras: &[Camera],
    dev: &Device,
) -> (Vec<Vec<f32>>, Vec<Vec<f32>>) {
    let plain = render(&scene.tensors(dev), cameras).unwrap();
    let images = vec![host(plain.features), host(plain.alpha), host(plain.depth)];
    let g = scene.tensors(&dev.clone().autodiff());
    let g = tracked(g);
    let r = render(&g, cameras).unwrap();
    let loss = r.features.powi_scalar(2).sum() + r.alpha.sum() + r.depth.sum() * 0.3;
    let grads = loss.backward();
    let grads = vec![
        host(g.means.grad(&grads).unwrap()),
        host(g.log_scales.grad(&grads).unwrap()),
        host(g.rotations.grad(&grads).unwrap()),
        host(g.opacity_logits.grad(&grads).unwrap()),
        host(g.features.grad(&grads).unwrap()),
    ];
    (images, grads)
}

/// Entries' magnitudes below this fraction of the tensor's largest are compared as if they had
/// it: the floor of the per-entry relative error, below which float rounding of sums that
/// cancel dominates.
const FLOOR: f32 = 1e-3;

/// Asserts that every entry of `got` matches `want` within `tol` of its own magnitude, floored
/// at [`FLOOR`] times `want`'s largest magnitude, allowing `spare` entries off (a pixel or
/// Gaussian whose discrete decision, a 1/255 alpha cut or the transmittance stop, falls the
/// other way under the GPU's rounding).
fn assert_close(what: &str, got: &[f32], want: &[f32], tol: f32, spare: usize) {
    assert_eq!(got.len(), want.len(), "{what}: lengths");
    let largest = want.iter().fold(0.0f32, |m, v| m.max(v.abs())).max(1e-12);
    let off: Vec<(usize, f32, f32)> = got
        .iter()
        .zip(want)
        .enumerate()
        // A NaN on either side counts as off.
        .filter(|(_, (g, w))| {
            let allowed = tol * w.abs().max(FLOOR * largest);
            (*g - *w).abs().is_nan() || (*g - *w).abs() > allowed
        })
        .map(|(i, (g, w))| (i, *g, *w))
        .collect();
    assert!(
        off.len() <= spare,
        "{what}: {} of {} entries off by more than {tol} of their magnitude (floor {FLOOR} x \
         {largest}; first: {:?})",
        off.len(),
        got.len(),
        &off[..off.len().min(5)]
    );
}

fn compare(scene: &Scene, cameras: &[Camera], spare: usize) {
    let _serial = serial();
    let Some(gpu) = wgpu() else { return };
    let (images, grads) = render_and_grads(scene, cameras, &gpu);
    let (images_ref, grads_ref) = render_and_grads(scene, cameras, &device());
    assert!(images_ref[1].iter().any(|&a| a > 0.1), "an empty render");
    for (name, (a, b)) in ["features", "alpha", "depth"]
        .iter()
        .zip(images.iter().zip(&images_ref))
    {
        assert_close(name, a, b, 2e-4, spare);
    }
    let names = [
        "means",
        "log_scales",
        "rotations",
        "opacity_logits",
        "features",
    ];
    for (name, (a, b)) in names.iter().zip(grads.iter().zip(&grads_ref)) {
        assert!(
            b.iter().any(|v| v.abs() > 0.0),
            "{name}: all gradients zero"
        );
        assert_close(name, a, b, 1e-3, spare);
    }
}

#[test]
#[cfg_attr(not(wgpu_adapter), ignore = "no wgpu adapter on this machine")]
fn three_gaussians_render_and_differentiate_like_the_host() {
    let mut s = Scene::new(1, 2);
    s.push(
        [0.1, 0.9, 0.0],
        [-1.0, -1.3, -1.6],
        [0.9, 0.1, -0.3, 0.25],
        0.7,
        &[1.0, 0.2],
    );
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
    compare(&s, &[orbit_camera(40, 34, 60.0, 12.0, -7.0)], 0);
}

/// Overlapping and coincident Gaussians (equal depths: the order falls back to the index),
/// Gaussians behind the camera and outside the image, needle-thin ones, empty tiles, and one
/// tile holding a few thousand Gaussians (several chunks of the kernels' shared memory).
#[test]
#[cfg_attr(not(wgpu_adapter), ignore = "no wgpu adapter on this machine")]
fn a_stress_scene_renders_and_differentiates_like_the_host() {
    let camera = orbit_camera(72, 56, 70.0, 8.0, -4.0);
    let centre = glam::Vec3::new(0.1, 0.9, -0.05);
    let to_world = |x: f32, y: f32, depth: f32| {
        let dir = camera.c2w.transform_vector3(glam::Vec3::new(x, y, 1.0));
        (camera.c2w.w_axis.truncate() + dir * depth).to_array()
    };
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let mut s = Scene::new(1, 3);
    let colour = |rng: &mut ChaCha8Rng| -> [f32; 3] {
        std::array::from_fn(|_| rng.random_range(0.0f32..1.0))
    };
    // A dense cluster in the top-left tile: 2500 small Gaussians.
    for _ in 0..2500 {
        let (x, y) = (
            rng.random_range(-0.5f32..-0.38),
            rng.random_range(-0.4f32..-0.3),
        );
        let depth = rng.random_range(2.0f32..3.0);
        let q = [
            1.0,
            rng.random_range(-0.3..0.3),
            rng.random_range(-0.3..0.3),
            0.1,
        ];
        s.push(
            to_world(x, y, depth),
            [-4.6, -4.8, -4.7],
            q,
            rng.random_range(0.05..0.6),
            &colour(&mut rng),
        );
    }
    // Larger overlapping Gaussians over the middle.
    for _ in 0..40 {
        let p = centre
            + glam::Vec3::new(
                rng.random_range(-0.2..0.2),
                rng.random_range(-0.2..0.2),
                rng.random_range(-0.2..0.2),
            );
        let ls = [
            rng.random_range(-3.0..-2.0),
            rng.random_range(-3.0..-2.0),
            rng.random_range(-3.0..-2.0),
        ];
        let q = std::array::from_fn(|_| rng.random_range(-1.0f32..1.0));
        s.push(
            p.to_array(),
            ls,
            q,
            rng.random_range(0.2..0.9),
            &colour(&mut rng),
        );
    }
    // Coincident pairs: the same Gaussian twice.
    for k in 0..3 {
        let p = to_world(0.1 * k as f32, 0.15, 2.4);
        let c = colour(&mut rng);
        for _ in 0..2 {
            s.push(p, [-2.5, -2.7, -2.6], [0.9, 0.2, 0.1, 0.0], 0.5, &c);
        }
    }
    // Needle-thin Gaussians.
    for k in 0..4 {
        let p = to_world(0.3, -0.1 + 0.05 * k as f32, 2.2);
        s.push(
            p,
            [-1.8, -7.0, -6.5],
            [0.8, 0.1 * k as f32, 0.3, -0.2],
            0.8,
            &colour(&mut rng),
        );
    }
    // Behind the camera and far outside the image.
    s.push(
        to_world(0.0, 0.0, -1.0),
        [-2.0; 3],
        [1.0, 0.0, 0.0, 0.0],
        0.9,
        &[1.0, 1.0, 1.0],
    );
    s.push(
        to_world(3.0, 0.0, 2.0),
        [-2.0; 3],
        [1.0, 0.0, 0.0, 0.0],
        0.9,
        &[1.0, 1.0, 1.0],
    );
    s.push(
        to_world(0.0, -4.0, 2.0),
        [-2.0; 3],
        [1.0, 0.0, 0.0, 0.0],
        0.9,
        &[1.0, 1.0, 1.0],
    );
    compare(&s, &[camera], 6);
}

/// An opaque wall in front of a thousand Gaussians: every pixel saturates within the first
/// chunk, so the compositing stops early and the reverse pass skips the chunks behind.
#[test]
#[cfg_attr(not(wgpu_adapter), ignore = "no wgpu adapter on this machine")]
fn a_wall_that_hides_the_rest_renders_and_differentiates_like_the_host() {
    let camera = orbit_camera(40, 36, 50.0, 0.0, 0.0);
    let to_world = |x: f32, y: f32, depth: f32| {
        let dir = camera.c2w.transform_vector3(glam::Vec3::new(x, y, 1.0));
        (camera.c2w.w_axis.truncate() + dir * depth).to_array()
    };
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let mut s = Scene::new(1, 3);
    for k in 0..30 {
        let (x, y) = ((k % 6) as f32 * 0.16 - 0.4, (k / 6) as f32 * 0.2 - 0.4);
        let c = [rng.random_range(0.0..1.0), 0.5, 0.2];
        s.push(
            to_world(x, y, 1.2 + 0.001 * k as f32),
            [-1.6, -1.6, -2.5],
            [1.0, 0.0, 0.0, 0.0],
            0.99,
            &c,
        );
    }
    for _ in 0..1000 {
        let (x, y) = (
            rng.random_range(-0.4f32..0.4),
            rng.random_range(-0.4f32..0.4),
        );
        let c = [rng.random_range(0.0..1.0), rng.random_range(0.0..1.0), 0.0];
        s.push(
            to_world(x, y, rng.random_range(2.0..3.0)),
            [-3.0; 3],
            [1.0, 0.0, 0.0, 0.0],
            0.8,
            &c,
        );
    }
    compare(&s, &[camera], 4);
}

/// A batch of two cameras, each with its own Gaussians, of a count that is not a power of two.
#[test]
#[cfg_attr(not(wgpu_adapter), ignore = "no wgpu adapter on this machine")]
fn a_batch_renders_and_differentiates_like_the_host() {
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let one = |rng: &mut ChaCha8Rng| {
        let mut s = Scene::new(1, 2);
        for _ in 0..300 {
            let p = [
                rng.random_range(-0.2..0.4),
                rng.random_range(0.6..1.2),
                rng.random_range(-0.3..0.3),
            ];
            let ls = [
                rng.random_range(-3.5..-2.5),
                rng.random_range(-3.5..-2.5),
                rng.random_range(-3.5..-2.5),
            ];
            let q = std::array::from_fn(|_| rng.random_range(-1.0f32..1.0));
            let f = [rng.random_range(0.0..1.0), rng.random_range(0.0..1.0)];
            s.push(p, ls, q, rng.random_range(0.1..0.9), &f);
        }
        s
    };
    let (a, b) = (one(&mut rng), one(&mut rng));
    let mut s = a.clone();
    s.batch = 2;
    for ((_, x), (_, y)) in s.kinds_mut().into_iter().zip(b.clone().kinds_mut()) {
        x.extend_from_slice(y);
    }
    let cameras = [
        orbit_camera(36, 30, 50.0, 12.0, -7.0),
        orbit_camera(36, 30, 50.0, -20.0, 9.0),
    ];
    compare(&s, &cameras, 2);
}

/// The device path reads nothing back to the host: neither the forward nor the backward pass.
#[test]
#[cfg_attr(not(wgpu_adapter), ignore = "no wgpu adapter on this machine")]
fn the_device_path_makes_no_host_read() {
    let _serial = serial();
    let Some(gpu) = wgpu() else { return };
    let mut s = Scene::new(1, 3);
    s.push(
        [0.1, 0.9, 0.0],
        [-1.0, -1.3, -1.6],
        [0.9, 0.1, -0.3, 0.25],
        0.7,
        &[1.0, 0.2, 0.5],
    );
    let g = s.tensors(&gpu.autodiff());
    let means = g.means.clone().require_grad();
    let g = Gaussians {
        means: means.clone(),
        ..g
    };
    let before = geometry_host_reads();
    let r = render(&g, &[orbit_camera(40, 34, 60.0, 12.0, -7.0)]).unwrap();
    let grads = r.features.sum().backward();
    let grad = means.grad(&grads).unwrap();
    assert_eq!(
        geometry_host_reads(),
        before,
        "the rasterizer read from the device"
    );
    assert!(host(grad).iter().any(|v| *v != 0.0));
}
