//! What the host kernels of the layers save: forward and backward of `prism_kernels::conv2d`
//! and `prism_kernels::linear` against Burn's `Conv2d` and `Linear` on the same layer, on
//! flex. The convolutions at the shapes of the point branch's DPT head (trained: input, weight
//! and bias gradients) and of LPIPS's AlexNet at 128 px (frozen: the input's gradient alone),
//! batch 4; the linear layers at the small config's blocks (4 sequences of 512 tokens, width
//! 128: `qkv`, `out`, the MLP's two); `prism_kernels::gelu` against Burn's `gelu` at the
//! MLP's hidden size.
//!
//! ```bash
//! cargo run --release --example layers_bench -- [--iters 9]
//! ```
//!
//! Each row is the median of `--iters` runs of both, taking turns, after one warm-up each.

use std::time::Instant;

use burn::module::Module;
use burn::nn::PaddingConfig2d;
use burn::nn::conv::{Conv2d, Conv2dConfig};
use burn::nn::{Linear, LinearConfig};
use burn::tensor::{Device, Distribution, Tensor};

/// One benchmark row: a layer on an input of `shape`, trained or frozen.
struct Case {
    name: &'static str,
    layer: Layer,
    shape: [usize; 4],
}

/// The layer of a row.
enum Layer {
    Conv(Conv2d),
    Linear(Linear),
    /// GELU, on input of the row's shape.
    Gelu,
}

impl Layer {
    /// The layer on `x` (`[B, C, H, W]`; a linear layer reads `[B, T, d]` as `[B, 1, T, d]`),
    /// through prism's kernel or Burn's module.
    fn run(&self, x: Tensor<4>, prism: bool) -> Tensor<4> {
        match (self, prism) {
            (Self::Conv(l), true) => prism_kernels::conv2d(l, x),
            (Self::Conv(l), false) => l.forward(x),
            (Self::Linear(l), true) => prism_kernels::linear(l, x),
            (Self::Linear(l), false) => l.forward(x),
            (Self::Gelu, true) => prism_kernels::gelu(x),
            (Self::Gelu, false) => burn::tensor::activation::gelu(x),
        }
    }

    fn weight(&self) -> Option<Tensor<4>> {
        match self {
            Self::Conv(l) => Some(l.weight.val()),
            Self::Linear(l) => Some(l.weight.val().unsqueeze()),
            Self::Gelu => None,
        }
    }
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
    let case = |name, layer, shape| Case {
        name,
        layer: Layer::Conv(layer),
        shape,
    };
    let linear = |name, i, o| Case {
        name,
        layer: Layer::Linear(LinearConfig::new(i, o).init(device)),
        shape: [4, 1, 512, i],
    };
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
        linear("block qkv 128->384, 4x512 tokens", 128, 384),
        linear("block out 128->128, 4x512 tokens", 128, 128),
        linear("block MLP in 128->512, 4x512 tokens", 128, 512),
        linear("block MLP out 512->128, 4x512 tokens", 512, 128),
        Case {
            name: "GELU of the blocks' MLP, 4x512 tokens x 512",
            layer: Layer::Gelu,
            shape: [4, 1, 512, 512],
        },
    ]
}

fn main() {
    let mut iters = 9;
    let mut args = std::env::args().skip(1);
    while let Some(flag) = args.next() {
        match (flag.as_str(), args.next()) {
            ("--iters", Some(n)) => iters = n.parse().expect("--iters N"),
            _ => panic!("usage: layers_bench [--iters N]"),
        }
    }
    let device = Device::flex().autodiff();
    device.seed(0);
    println!("| layer, batch 4 | Burn's module (ms) | prism_kernels (ms) | ratio |");
    println!("|---|---:|---:|---:|");
    for Case { name, layer, shape } in cases(&device) {
        let x = Tensor::<4>::random(shape, Distribution::Normal(0.0, 1.0), &device).require_grad();
        let run = |fused: bool| {
            let start = Instant::now();
            let y = layer.run(x.clone(), fused);
            let grads = (y.clone() * y).sum().backward();
            let _ = x.grad(&grads).expect("x is tracked").into_data();
            if let Some(dw) = layer.weight().and_then(|w| w.grad(&grads)) {
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
