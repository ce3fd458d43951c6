//! Triplane sampling: forward against Burn's own `grid_sample_2d` (an independent
//! implementation: bilinear, border padding, corners not aligned), gradients of the planes and
//! of the coordinates against central finite differences, and the flex backend against ndarray.

use burn::tensor::ops::{GridSampleOptions, GridSamplePaddingMode, InterpolateMode};
use burn::tensor::{Device, Tensor, TensorData};
use prism_core::BackendKind;
use prism_render::triplane::{PLANE_AXES, sample_triplane};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

#[cfg(feature = "wgpu")]
use crate::common;

fn device() -> Device {
    BackendKind::Ndarray.device().unwrap()
}

fn random(rng: &mut ChaCha8Rng, n: usize, lo: f32, hi: f32) -> Vec<f32> {
    (0..n).map(|_| rng.random_range(lo..hi)).collect()
}

fn host<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data().convert::<f32>().try_to_vec::<f32>().unwrap()
}

/// The reference: `grid_sample_2d` of each plane at its two coordinates, summed.
fn reference(planes: &Tensor<4>, coords: &Tensor<4>) -> Tensor<4> {
    let [b, _, h, w] = coords.dims();
    let [_, c, r, _] = planes.dims();
    let options = GridSampleOptions::new(InterpolateMode::Bilinear)
        .with_padding_mode(GridSamplePaddingMode::Border)
        .with_align_corners(false);
    let mut sum: Option<Tensor<4>> = None;
    for (p, axes) in PLANE_AXES.iter().enumerate() {
        let plane = planes.clone().narrow(0, p, 1).expand([b, c, r, r]);
        let grid = Tensor::cat(
            vec![
                coords.clone().narrow(1, axes[0], 1),
                coords.clone().narrow(1, axes[1], 1),
            ],
            1,
        );
        let grid = prism_core::axes::permute(grid, [0, 2, 3, 1]);
        assert_eq!(grid.dims(), [b, h, w, 2]);
        let s = plane.grid_sample_2d(grid, options.clone());
        sum = Some(match sum {
            Some(acc) => acc + s,
            None => s,
        });
    }
    sum.unwrap()
}

#[test]
fn forward_matches_grid_sample() {
    let device = device();
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let (b, c, r, h, w) = (2, 5, 7, 6, 9);
    let planes = Tensor::<4>::from_data(
        TensorData::new(random(&mut rng, 3 * c * r * r, -1.0, 1.0), [3, c, r, r]),
        &device,
    );
    // Some coordinates outside [-1, 1] to exercise the border padding.
    let coords = Tensor::<4>::from_data(
        TensorData::new(random(&mut rng, b * 3 * h * w, -1.2, 1.2), [b, 3, h, w]),
        &device,
    );
    let ours = host(sample_triplane(planes.clone(), coords.clone()).unwrap());
    let theirs = host(reference(&planes, &coords));
    assert_eq!(ours.len(), b * c * h * w);
    let err = ours
        .iter()
        .zip(&theirs)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f32::max);
    assert!(err < 1e-5, "max difference {err}");

    // The same on flex.
    let flex = BackendKind::Flex.device().unwrap();
    let on_flex = host(sample_triplane(planes.to_device(&flex), coords.to_device(&flex)).unwrap());
    let err = ours
        .iter()
        .zip(&on_flex)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f32::max);
    assert!(err < 1e-6, "flex differs by {err}");
}

#[test]
fn gradients_match_finite_differences() {
    check_gradients(&device());
}

/// The device kernels (wgpu) against finite differences, and against the host path on
/// coordinates that also leave the planes (border clamping).
#[cfg(feature = "wgpu")]
#[test]
#[cfg_attr(not(wgpu_adapter), ignore = "no wgpu adapter on this machine")]
fn the_device_kernels_match_finite_differences_and_the_host() {
    let _serial = common::serial();
    let Some(gpu) = common::wgpu() else { return };
    check_gradients(&gpu);
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    let (b, c, r, h, w) = (2, 5, 7, 6, 5);
    let planes = random(&mut rng, 3 * c * r * r, -1.0, 1.0);
    let coords = random(&mut rng, b * 3 * h * w, -1.3, 1.3);
    let weights = random(&mut rng, b * c * h * w, -1.0, 1.0);
    let run = |device: &Device| {
        let ad = device.clone().autodiff();
        let p = Tensor::<4>::from_data(TensorData::new(planes.clone(), [3, c, r, r]), &ad)
            .require_grad();
        let x = Tensor::<4>::from_data(TensorData::new(coords.clone(), [b, 3, h, w]), &ad)
            .require_grad();
        let wt = Tensor::<4>::from_data(TensorData::new(weights.clone(), [b, c, h, w]), &ad);
        let out = sample_triplane(p.clone(), x.clone()).unwrap();
        let grads = (out.clone() * wt).sum().backward();
        [out, p.grad(&grads).unwrap(), x.grad(&grads).unwrap()]
    };
    let reads = prism_core::reads::geometry_host_reads();
    let got = run(&gpu);
    assert_eq!(
        prism_core::reads::geometry_host_reads(),
        reads,
        "triplane sampling read from the device"
    );
    let got = got.map(host);
    let want = run(&device()).map(host);
    for (name, (a, b)) in ["samples", "plane gradients", "coordinate gradients"]
        .iter()
        .zip(got.iter().zip(&want))
    {
        for (x, y) in a.iter().zip(b) {
            assert!(
                (x - y).abs() <= 1e-5 * (1.0 + y.abs()),
                "{name}: {x} vs {y}"
            );
        }
    }
}

fn check_gradients(device: &Device) {
    let device = device.clone();
    let ad = device.clone().autodiff();
    let mut rng = ChaCha8Rng::seed_from_u64(2);
    let (b, c, r, h, w) = (2, 3, 6, 3, 4);
    let planes = random(&mut rng, 3 * c * r * r, -1.0, 1.0);
    // Inside the non-clamped range, away from texel centres (the kinks of bilinear filtering):
    // texel coordinate t = (x + 1) r / 2 - 0.5 kept at fractional parts in [0.2, 0.8].
    let coords: Vec<f32> = (0..b * 3 * h * w)
        .map(|_| {
            let t = rng.random_range(0..r - 1) as f32 + rng.random_range(0.2f32..0.8);
            (t + 0.5) * 2.0 / r as f32 - 1.0
        })
        .collect();
    let weights = random(&mut rng, b * c * h * w, -1.0, 1.0);
    let loss = |planes: &[f32], coords: &[f32], device: &Device| -> Tensor<1> {
        let p = Tensor::<4>::from_data(TensorData::new(planes.to_vec(), [3, c, r, r]), device);
        let x = Tensor::<4>::from_data(TensorData::new(coords.to_vec(), [b, 3, h, w]), device);
        let wt = Tensor::<4>::from_data(TensorData::new(weights.clone(), [b, c, h, w]), device);
        (sample_triplane(p, x).unwrap() * wt).sum()
    };
    let p =
        Tensor::<4>::from_data(TensorData::new(planes.clone(), [3, c, r, r]), &ad).require_grad();
    let x =
        Tensor::<4>::from_data(TensorData::new(coords.clone(), [b, 3, h, w]), &ad).require_grad();
    let wt = Tensor::<4>::from_data(TensorData::new(weights.clone(), [b, c, h, w]), &ad);
    let grads = (sample_triplane(p.clone(), x.clone()).unwrap() * wt)
        .sum()
        .backward();
    let gp = host(p.grad(&grads).unwrap());
    let gx = host(x.grad(&grads).unwrap());

    let value =
        |planes: &[f32], coords: &[f32]| -> f64 { host(loss(planes, coords, &device))[0] as f64 };
    // The loss is linear in the planes: a finite difference of any step is exact up to rounding.
    let eps = 1e-2f32;
    for i in (0..planes.len()).step_by(7) {
        let (mut up, mut down) = (planes.clone(), planes.clone());
        up[i] += eps;
        down[i] -= eps;
        let fd = (value(&up, &coords) - value(&down, &coords)) / (2.0 * eps as f64);
        assert!(
            (fd - gp[i] as f64).abs() < 1e-3 * (1.0 + fd.abs()),
            "plane {i}: {fd} vs {}",
            gp[i]
        );
    }
    let eps = 1e-3f32;
    let mut checked = 0;
    for i in 0..coords.len() {
        let (mut up, mut down) = (coords.clone(), coords.clone());
        up[i] += eps;
        down[i] -= eps;
        let fd = (value(&planes, &up) - value(&planes, &down)) / (2.0 * eps as f64);
        let rel = (fd - gx[i] as f64).abs() / (fd.abs().max(gx[i].abs() as f64).max(1e-2));
        assert!(rel < 1e-2, "coordinate {i}: {fd} vs {}", gx[i]);
        checked += 1;
    }
    assert_eq!(checked, b * 3 * h * w);
}

#[test]
fn clamped_coordinates_get_no_gradient_and_bad_shapes_are_errors() {
    let device = device().autodiff();
    let planes = Tensor::<4>::ones([3, 2, 4, 4], &device).require_grad();
    let coords = Tensor::<4>::from_data(
        TensorData::new(vec![1.5f32, -2.0, 3.0], [1, 3, 1, 1]),
        &device,
    )
    .require_grad();
    let out = sample_triplane(planes.clone(), coords.clone()).unwrap();
    assert_eq!(host(out.clone()), vec![3.0, 3.0]);
    let grads = out.sum().backward();
    assert_eq!(host(coords.grad(&grads).unwrap()), vec![0.0; 3]);
    // Each plane's gradient is one corner texel (border padding), weight 1 per channel.
    let gp = host(planes.grad(&grads).unwrap());
    assert_eq!(gp.iter().sum::<f32>(), 6.0);

    let bad = Tensor::<4>::zeros([2, 2, 4, 4], &device);
    assert!(sample_triplane(bad, coords.clone()).is_err());
    let bad_coords = Tensor::<4>::zeros([1, 2, 1, 1], &device);
    assert!(sample_triplane(planes, bad_coords).is_err());
}
