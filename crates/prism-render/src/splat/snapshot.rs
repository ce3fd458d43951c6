//! Rendering a [`GaussianCloud`] to an 8-bit RGB image (what `prism splat render` does).

use std::path::Path;

use burn::tensor::Device;
use image::RgbImage;
use prism_core::Camera;

use super::ply::GaussianCloud;
use super::render::{background as background_tensor, render};
use crate::RenderError;

/// Parses a background colour `R,G,B` with components in [0, 1].
///
/// # Errors
/// [`RenderError::Value`] naming the bad component.
pub fn parse_background(text: &str) -> Result<[f32; 3], RenderError> {
    let bad = |m: String| RenderError::Value(format!("background `{text}`: {m}"));
    let parts: Vec<&str> = text.split(',').map(str::trim).collect();
    if parts.len() != 3 {
        return Err(bad(format!(
            "expected R,G,B, got {} components",
            parts.len()
        )));
    }
    let mut out = [0.0; 3];
    for (o, p) in out.iter_mut().zip(&parts) {
        let v: f32 = p
            .parse()
            .map_err(|_| bad(format!("`{p}` is not a number")))?;
        if !(0.0..=1.0).contains(&v) {
            return Err(bad(format!("component {v} is outside [0, 1]")));
        }
        *o = v;
    }
    Ok(out)
}

/// Renders `cloud` (colours from its degree-0 term) into `camera` over `background`.
///
/// # Errors
/// [`RenderError::Input`] when the cloud is inconsistent.
pub fn render_cloud(
    cloud: &GaussianCloud,
    camera: &Camera,
    background: [f32; 3],
    device: &Device,
) -> Result<RgbImage, RenderError> {
    cloud.check().map_err(RenderError::Input)?;
    let rendered = render(&cloud.to_gaussians(device), &[*camera])?;
    let image = rendered.over(background_tensor(&background, device));
    Ok(prism_core::images::HostImages::from_tensor(image).rgb8(0))
}

/// Saves an image as PNG, atomically.
///
/// # Errors
/// [`RenderError::Io`] naming the file.
pub fn save_png(image: &RgbImage, path: &Path) -> Result<(), RenderError> {
    prism_core::images::save_png(path, image).map_err(|e| RenderError::io(path, e))
}
