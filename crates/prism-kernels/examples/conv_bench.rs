//! What the host convolution kernel saves: forward and backward of `prism_kernels::conv2d`
//! against Burn's `Conv2d` on the same layer, at the shapes of the point branch's DPT head
//! (trained: input, weight and bias gradients) and of LPIPS's AlexNet at 128 px (frozen: the
//! input's gradient alone), batch 4, on flex.
//!
//! ```bash
//! cargo run --release --example conv_bench -- [--iters 9]
//! ```
//!
//! Each row is the median of `--iters` runs of both, taking turns, after one warm-up each.

use std::time::Instant;

use burn::module::Module;
use burn::nn::PaddingConfig2d;
use burn::nn::conv::{Conv2d, Conv2dConfig};
use burn::tensor::{Device, Distribution, Tensor};

/// One benchmark row: a layer on an input of `shape`, trained or frozen.
struct Case {
    name: &'static str,
    layer: Conv2d,
    shape: [usize; 4],
}

fn cases(device: &Device) -> Vec<Case> {
    let same = |i, o| {
        Conv2dConfig::new([i, o], [3, 3])
            .with_padding(PaddingConfig2d::Same)
            .init(device)
    };
    let alexnet = |i, o, k, s, p| {
        Conv2dConfig::new([i, o], [k, k])
            .with_stride([s, s])
            .with_padding(PaddingConfig2d::Explicit(p, p, p, p))
            .init(device)
            .no_grad()
    };
    let case = |name, layer, shape| Case { name, layer, shape };
    vec![
        case("DPT refine 32->32, 64x64", same(32, 32), [4, 32, 64, 64]),
        case("DPT head 32->16, 64x64", same(32, 16), [4, 32, 64, 64]),
        case("DPT refine 32->32, 32x32", same(32, 32), [4, 32, 32, 32]),
        case("DPT refine 32->32, 16x16", same(32, 32), [4, 32, 16, 16]),
        case(
            "LPIPS conv1 3->64 11x11/4",
            alexnet(3, 64, 11, 4, 2),
            [4, 3, 128, 128],
        ),
        case(
            "LPIPS conv2 64->192 5x5",
            alexnet(64, 192, 5, 1, 2),
            [4, 64, 15, 15],
        ),
        case(
            "LPIPS conv3 192->384 3x3",
            alexnet(192, 384, 3, 1, 1),
            [4, 192, 7, 7],
        ),
    ]
}

fn main() {
    let mut iters = 9;
    let mut args = std::env::args().skip(1);
    while let Some(flag) = args.next() {
        match (flag.as_str(), args.next()) {
            ("--iters", Some(n)) => iters = n.parse().expect("--iters N"),
            _ => panic!("usage: conv_bench [--iters N]"),
        }
    }
    let device = Device::flex().autodiff();
    device.seed(0);
    println!("| layer, batch 4 | Burn's Conv2d (ms) | prism_kernels::conv2d (ms) | ratio |");
    println!("|---|---:|---:|---:|");
    for Case { name, layer, shape } in cases(&device) {
        let x = Tensor::<4>::random(shape, Distribution::Normal(0.0, 1.0), &device).require_grad();
        let run = |fused: bool| {
            let start = Instant::now();
            let y = if fused {
                prism_kernels::conv2d(&layer, x.clone())
            } else {
                layer.forward(x.clone())
            };
            let grads = (y.clone() * y).sum().backward();
            let _ = x.grad(&grads).expect("x is tracked").into_data();
            if let Some(dw) = layer.weight.val().grad(&grads) {
                let _ = dw.into_data();
            }
            start.elapsed().as_secs_f64() * 1e3
        };
        let (mut burn, mut prism) = (Vec::new(), Vec::new());
        for i in 0..=iters {
            let (b, p) = (run(false), run(true));
            if i > 0 {
                burn.push(b);
                prism.push(p);
            }
        }
        let median = |mut v: Vec<f64>| {
            v.sort_by(f64::total_cmp);
            v[v.len() / 2]
        };
        let (b, p) = (median(burn), median(prism));
        println!("| {name} | {b:.2} | {p:.2} | {:.2}x |", p / b);
    }
}
