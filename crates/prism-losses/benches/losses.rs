//! Timings of the losses and metrics: `cargo bench -p prism-losses [-- ndarray|flex]`.
//!
//! Prints the median of a few runs for LPIPS (metric forward, loss forward + backward), SSIM,
//! PSNR and `L_pts` (forward + backward) at training-like sizes.

use std::time::Instant;

use burn::tensor::{Device, Distribution, Tensor};
use prism_core::BackendKind;
use prism_losses::{Lpips, point_loss, psnr, ssim};

fn median_ms(runs: usize, mut f: impl FnMut()) -> f64 {
    f(); // warm-up
    let mut times: Vec<f64> = (0..runs)
        .map(|_| {
            let t = Instant::now();
            f();
            t.elapsed().as_secs_f64() * 1e3
        })
        .collect();
    times.sort_by(f64::total_cmp);
    times[runs / 2]
}

fn images(shape: [usize; 4], device: &Device) -> Tensor<4> {
    Tensor::random(shape, Distribution::Uniform(0.0, 1.0), device)
}

fn bench(kind: BackendKind) {
    let device = kind.device().unwrap();
    let ad = device.clone().autodiff();
    let lpips = Lpips::load_default(None, &device).unwrap();
    let lpips_ad = Lpips::load_default(None, &ad).unwrap();
    let s = 256;
    let (a, b) = (images([4, 3, s, s], &device), images([4, 3, s, s], &device));
    let t = median_ms(5, || {
        lpips.distance(a.clone(), b.clone());
    });
    println!("{kind}: LPIPS metric, 4 x 3 x {s} x {s}: {t:.1} ms");
    let t = median_ms(5, || {
        let x = images([4, 3, s, s], &ad).require_grad();
        let y = images([4, 3, s, s], &ad);
        let g = lpips_ad.forward(x.clone(), y).mean().backward();
        let _ = x.grad(&g).unwrap().into_data();
    });
    println!("{kind}: LPIPS loss forward + backward, 4 x 3 x {s} x {s}: {t:.1} ms");
    let s = 512;
    let (a, b) = (images([4, 3, s, s], &device), images([4, 3, s, s], &device));
    let t = median_ms(5, || {
        ssim(a.clone(), b.clone());
    });
    println!("{kind}: SSIM, 4 x 3 x {s} x {s}: {t:.1} ms");
    let t = median_ms(5, || {
        psnr(a.clone(), b.clone());
    });
    println!("{kind}: PSNR, 4 x 3 x {s} x {s}: {t:.1} ms");
    let t = median_ms(5, || {
        let x = images([4, 3, s, s], &ad).require_grad();
        let gt = images([4, 3, s, s], &ad);
        let conf = images([4, 1, s, s], &ad).add_scalar(1.0).require_grad();
        let mask = images([4, 1, s, s], &ad);
        let g = point_loss(x.clone(), gt, conf, mask, 0.2)
            .total()
            .backward();
        let _ = x.grad(&g).unwrap().into_data();
    });
    println!("{kind}: L_pts forward + backward, 4 x 3 x {s} x {s}: {t:.1} ms");
}

fn main() {
    let wanted: Vec<String> = std::env::args()
        .skip(1)
        .filter(|a| !a.starts_with('-'))
        .collect();
    for kind in [BackendKind::Flex, BackendKind::Ndarray] {
        if wanted.is_empty() || wanted.iter().any(|w| w == &kind.to_string()) {
            bench(kind);
        }
    }
}
