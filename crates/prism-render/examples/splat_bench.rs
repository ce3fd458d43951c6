//! Forward and backward time of the Gaussian rasterizer.
//!
//! ```text
//! cargo run --release -p prism-render --example splat_bench -- \
//!     [--backend flex] [--scene random|person] [--gaussians 65536] [--size 256] \
//!     [--channels 3] [--iters 10]
//! ```
//!
//! `random` (the default): Gaussians fill the view frustum between 2 and 4 m (about 1 to 4 px
//! wide, opacities around 0.5); one camera of `size x size` pixels, `fx = fy = size`.
//! `person`: the main job's kind of scene, a batch of 4 surfaces of `size x size`
//! pixel-aligned Gaussians (one per source pixel, as the 3DGS head and the point branch give
//! them: an opaque wavy figure about 2 m away on a faint backdrop, each Gaussian half a source
//! pixel's footprint wide), each seen from a target camera 10 to 30 degrees to the side
//! (`--gaussians` is ignored). Prints the median time of
//! the forward pass on the plain device, and of the forward and the backward pass on the
//! autodiff device (loss: a weighted sum of the features plus the alpha).

use std::time::Instant;

use burn::tensor::{Distribution, Tensor, TensorData};
use prism_core::{BackendKind, Camera, Intrinsics};
use prism_render::splat::{Gaussians, render};

/// Which Gaussians are drawn.
#[derive(Clone, Copy, PartialEq)]
enum Scene {
    Random,
    Person,
}

struct Options {
    backend: BackendKind,
    scene: Scene,
    gaussians: usize,
    size: u32,
    channels: usize,
    iters: usize,
}

fn options() -> Options {
    let mut o = Options {
        backend: BackendKind::Flex,
        scene: Scene::Random,
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
            "--scene" => {
                o.scene = match value.as_str() {
                    "random" => Scene::Random,
                    "person" => Scene::Person,
                    other => panic!("unknown scene {other} (random or person)"),
                }
            }
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

/// Distance of the person's figure from the cameras, in metres.
const DISTANCE: f32 = 2.0;

/// The `person` scene: 4 batch elements of `size x size` pixel-aligned Gaussians and their
/// target cameras.
fn person(size: u32, channels: usize, device: &burn::tensor::Device) -> (Gaussians, Vec<Camera>) {
    let intrinsics = Intrinsics::protocol_default(size, size);
    let source = Camera::orbit(0.0, 0.0, DISTANCE, glam::Vec3::ZERO, intrinsics);
    let cameras: Vec<Camera> = [(10.0, 5.0), (-20.0, -5.0), (30.0, 0.0), (-30.0, 10.0)]
        .into_iter()
        .map(|(yaw, pitch)| Camera::orbit(yaw, pitch, DISTANCE, glam::Vec3::ZERO, intrinsics))
        .collect();
    let (mut means, mut log_scales, mut opacity_logits, mut features) =
        (vec![], vec![], vec![], vec![]);
    let side = size as f32;
    for b in 0..cameras.len() {
        for y in 0..size {
            for x in 0..size {
                let (u, v) = (x as f32 + 0.5, y as f32 + 0.5);
                let (nx, ny) = (2.0 * u / side - 1.0, 2.0 * v / side - 1.0);
                // The figure: an upright ellipse, in front of the backdrop.
                let inside = (nx / 0.45).powi(2) + (ny / 0.9).powi(2) < 1.0;
                let depth = if inside {
                    DISTANCE - 0.15 * (1.0 - nx * nx).sqrt() + 0.02 * (9.0 * ny).sin()
                } else {
                    DISTANCE + 0.5
                };
                let mean = source.unproject(u, v, depth);
                means.extend([mean.x, mean.y, mean.z]);
                log_scales.extend([(0.5 * depth / intrinsics.fx).ln(); 3]);
                opacity_logits.push(if inside { 3.0 } else { -3.0 });
                let phase = (b * 7 + x as usize * 3 + y as usize * 5) as f32;
                features.extend((0..channels).map(|c| 0.5 + 0.5 * (phase + c as f32).sin()));
            }
        }
    }
    let (b, n) = (cameras.len(), (size * size) as usize);
    let t = |values: Vec<f32>, last: usize| {
        Tensor::<3>::from_data(TensorData::new(values, [b, n, last]), device)
    };
    let gaussians = Gaussians {
        means: t(means, 3),
        log_scales: t(log_scales, 3),
        rotations: t([1.0, 0.0, 0.0, 0.0].repeat(b * n), 4),
        opacity_logits: t(opacity_logits, 1),
        features: t(features, channels),
    };
    (gaussians, cameras)
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() {
    let o = options();
    let device = o.backend.device().expect("backend");
    let (plain, cameras) = match o.scene {
        Scene::Random => {
            let camera = Camera::new(
                Intrinsics::protocol_default(o.size, o.size),
                glam::Mat4::IDENTITY,
            );
            (scene(o.gaussians, o.channels, &device), vec![camera])
        }
        Scene::Person => person(o.size, o.channels, &device),
    };
    let count = plain.means.dims()[0] * plain.means.dims()[1];

    let mut forward = Vec::new();
    for i in 0..=o.iters {
        let t = Instant::now();
        let r = render(&plain, &cameras).unwrap();
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
    let weights = Tensor::<4>::random(
        [cameras.len(), o.channels, s, s],
        Distribution::Default,
        &ad,
    );
    let (mut fwd_ad, mut bwd) = (Vec::new(), Vec::new());
    let mut coverage = 0.0;
    for i in 0..=o.iters {
        let t = Instant::now();
        let r = render(&g, &cameras).unwrap();
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
        "splat {count} Gaussians into {} camera(s), {s}x{s}, C = {}, {} backend, {} threads, mean alpha {coverage:.2}",
        cameras.len(),
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
