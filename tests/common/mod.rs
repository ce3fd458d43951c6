//! Helpers shared by the command-line tests (each `tests/*.rs` is its own crate: a file uses
//! the helpers it needs).
#![allow(dead_code)]

use std::path::Path;

use image::RgbImage;

/// PSNR (dB) of two 8-bit RGB images as the metric defines it: `10 log10(1 / MSE)` over all
/// pixels and channels, values in [0, 1].
pub fn psnr_8bit(a: &RgbImage, b: &RgbImage) -> f64 {
    assert_eq!(a.dimensions(), b.dimensions());
    let mse = a
        .as_raw()
        .iter()
        .zip(b.as_raw())
        .map(|(&x, &y)| ((x as f64 - y as f64) / 255.0).powi(2))
        .sum::<f64>()
        / a.as_raw().len() as f64;
    10.0 * (1.0 / mse).log10()
}

/// Asserts that `path` is a run's training-curves PNG: the plot's size, curves drawn on white
/// (between 2 % and half of the pixels not white).
pub fn assert_training_curves(path: &Path) {
    let plot = image::open(path).unwrap().to_rgb8();
    assert_eq!(plot.dimensions(), prism_train::PLOT_SIZE);
    let drawn = plot.pixels().filter(|p| p.0 != [255, 255, 255]).count();
    let total = plot.pixels().len();
    assert!(
        drawn > total / 50 && drawn < total / 2,
        "{}: {drawn} of {total} pixels drawn",
        path.display()
    );
}
