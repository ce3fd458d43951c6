//! Forward and backward time of the Gaussian rasterizer.
//!
//! ```text
//! cargo run --release -p prism-render --example splat_bench -- \
//!     [--backend flex] [--gaussians 65536] [--size 256] [--channels 3] [--iters 10]
//! ```
//!
//! Random Gaussians fill the view frustum between 2 and 4 m (about 1 to 4 px wide, opacities
//! around 0.5); one camera of `size x size` pixels, `fx = fy = size`. Prints the median time of
//! the forward pass on the plain device, and of the forward and the backward pass on the
//! autodiff device (loss: a weighted sum of the features plus the alpha).

use std::time::Instant;

use burn::tensor::{Distribution, Tensor};
use prism_core::{BackendKind, Camera, Intrinsics};
use prism_render::splat::{Gaussians, render};

struct Options {
    backend: BackendKind,
    gaussians: usize,
    size: u32,
    channels: usize,
    iters: usize,
}

fn options() -> Options {
    let mut o = Options {
        backend: BackendKind::Flex,
        gaussians: 65536,
        size: 256,
        channels: 3,
        iters: 10,
    };
    let args: Vec<String> = std::env::args().skip(1).collect();
    for pair in args.chunks(2) {
        let value = pair.get(1).expect("every option takes a value");
        match pair[0].as_str() {
            "--backend" => o.backend = value.parse().expect("backend"),
            "--gaussians" => o.gaussians = value.parse().expect("count"),
            "--size" => o.size = value.parse().expect("size"),
            "--channels" => o.channels = value.parse().expect("channels"),
            "--iters" => o.iters = value.parse().expect("iterations"),
            other => panic!("unknown option {other}"),
        }
    }
    o
}

fn scene(n: usize, channels: usize, device: &burn::tensor::Device) -> Gaussians {
    let u = |shape: [usize; 3], lo: f64, hi: f64| {
        Tensor::<3>::random(shape, Distribution::Uniform(lo, hi), device)
    };
    let depth = u([1, n, 1], 2.0, 4.0);
    let lateral = u([1, n, 2], -0.5, 0.5) * depth.clone();
    Gaussians {
        means: Tensor::cat(vec![lateral, depth], 2),
        log_scales: u([1, n, 3], (0.004f64).ln(), (0.03f64).ln()),
        rotations: Tensor::random([1, n, 4], Distribution::Normal(0.0, 1.0), device),
        opacity_logits: Tensor::random([1, n, 1], Distribution::Normal(0.0, 1.0), device),
        features: u([1, n, channels], 0.0, 1.0),
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() {
    let o = options();
    let device = o.backend.device().expect("backend");
    let camera = Camera::new(
        Intrinsics::protocol_default(o.size, o.size),
        glam::Mat4::IDENTITY,
    );
    let plain = scene(o.gaussians, o.channels, &device);

    let mut forward = Vec::new();
    for i in 0..=o.iters {
        let t = Instant::now();
        let r = render(&plain, &[camera]).unwrap();
        let _ = r.features.into_data();
        if i > 0 {
            forward.push(t.elapsed().as_secs_f64());
        }
    }

    let ad = device.clone().autodiff();
    let to_ad = |t: Tensor<3>| Tensor::<3>::from_data(t.into_data(), &ad).require_grad();
    let g = Gaussians {
        means: to_ad(plain.means.clone()),
        log_scales: to_ad(plain.log_scales.clone()),
        rotations: to_ad(plain.rotations.clone()),
        opacity_logits: to_ad(plain.opacity_logits.clone()),
        features: to_ad(plain.features.clone()),
    };
    let s = o.size as usize;
    let weights = Tensor::<4>::random([1, o.channels, s, s], Distribution::Default, &ad);
    let (mut fwd_ad, mut bwd) = (Vec::new(), Vec::new());
    let mut coverage = 0.0;
    for i in 0..=o.iters {
        let t = Instant::now();
        let r = render(&g, &[camera]).unwrap();
        let loss = (r.features * weights.clone()).sum() + r.alpha.clone().sum();
        let _ = loss.clone().into_data();
        let t_fwd = t.elapsed().as_secs_f64();
        let t = Instant::now();
        let grads = loss.backward();
        let _ = g.means.grad(&grads).unwrap().into_data();
        let t_bwd = t.elapsed().as_secs_f64();
        if i > 0 {
            fwd_ad.push(t_fwd);
            bwd.push(t_bwd);
        } else {
            coverage = r.alpha.mean().into_scalar::<f32>();
        }
    }
    println!(
        "splat {} Gaussians, {s}x{s}, C = {}, {} backend, {} threads, mean alpha {coverage:.2}",
        o.gaussians,
        o.channels,
        o.backend,
        rayon::current_num_threads()
    );
    println!(
        "forward (inference device): {:8.1} ms",
        1e3 * median(forward)
    );
    println!(
        "forward (autodiff device):  {:8.1} ms",
        1e3 * median(fwd_ad)
    );
    println!("backward:                   {:8.1} ms", 1e3 * median(bwd));
}
