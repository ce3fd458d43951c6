//! Fitting Gaussians to an image by gradient descent through the rasterizer (Adam).

use crate::common;

use burn::module::{Module, Param};
use burn::optim::{AdamConfig, GradientsParams};
use burn::tensor::{Tensor, TensorData};
use common::{axis_camera, device};
use prism_render::splat::{Gaussians, background, render};

/// The Gaussians being fitted, as a module so that the optimizer sees their parameters.
#[derive(Module, Debug)]
struct Splats {
    means: Param<Tensor<3>>,
    log_scales: Param<Tensor<3>>,
    rotations: Param<Tensor<3>>,
    opacity_logits: Param<Tensor<3>>,
    colours: Param<Tensor<3>>,
}

impl Splats {
    fn gaussians(&self) -> Gaussians {
        Gaussians {
            means: self.means.val(),
            log_scales: self.log_scales.val(),
            rotations: self.rotations.val(),
            opacity_logits: self.opacity_logits.val(),
            features: self.colours.val(),
        }
    }
}

/// A 32x32 target: colour waves and a disc.
fn target(size: usize) -> Vec<f32> {
    let mut t = vec![0.0; 3 * size * size];
    for y in 0..size {
        for x in 0..size {
            let (xf, yf) = (x as f32, y as f32);
            let disc = ((xf - 20.0).powi(2) + (yf - 12.0).powi(2)).sqrt() < 7.0;
            let i = y * size + x;
            t[i] = 0.5 + 0.4 * (xf / 5.0).sin();
            t[size * size + i] = 0.5 + 0.4 * (yf / 4.0).cos();
            t[2 * size * size + i] = if disc { 0.9 } else { 0.1 };
        }
    }
    t
}

#[test]
fn fitting_a_few_hundred_gaussians_to_an_image_cuts_the_error_tenfold() {
    let dev = device().autodiff();
    let (size, grid) = (32usize, 16usize);
    let (f, z) = (32.0f32, 2.0f32);
    let camera = axis_camera(f, 16.0, 16.0, size as u32, size as u32);
    let n = grid * grid;
    // A 16 x 16 grid of Gaussians 2 px apart, each about 1.5 px wide, grey and half opaque.
    let mut means = Vec::with_capacity(3 * n);
    for gy in 0..grid {
        for gx in 0..grid {
            let (u, v) = (1.0 + 2.0 * gx as f32, 1.0 + 2.0 * gy as f32);
            means.extend([(u - 16.0) * z / f, (v - 16.0) * z / f, z]);
        }
    }
    let t3 = |v: Vec<f32>, c: usize| {
        Param::from_tensor(Tensor::<3>::from_data(TensorData::new(v, [1, n, c]), &dev))
    };
    let mut splats = Splats {
        means: t3(means, 3),
        log_scales: t3(vec![(1.5 * z / f).ln(); 3 * n], 3),
        rotations: t3([1.0, 0.0, 0.0, 0.0].repeat(n), 4),
        opacity_logits: t3(vec![0.0; n], 1),
        colours: t3(vec![0.5; 3 * n], 3),
    };
    let target = Tensor::<4>::from_data(TensorData::new(target(size), [1, 3, size, size]), &dev);
    let black = background(&[0.0, 0.0, 0.0], &dev);
    let mse = |s: &Splats| {
        let image = render(&s.gaussians(), &[camera])
            .unwrap()
            .over(black.clone());
        (image - target.clone()).powi_scalar(2).mean()
    };

    let mut optim = AdamConfig::new().init();
    let initial = mse(&splats).into_scalar::<f32>();
    for _ in 0..150 {
        let loss = mse(&splats);
        let grads = GradientsParams::from_grads(loss.backward(), &splats);
        splats = optim.step(0.02, splats, grads);
    }
    let last = mse(&splats).into_scalar::<f32>();
    eprintln!("MSE {initial} -> {last}");
    assert!(
        last * 10.0 < initial,
        "MSE went from {initial} to {last}, less than a tenfold cut"
    );
}
