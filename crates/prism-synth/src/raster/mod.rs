//! The CPU triangle rasterizer that draws the dataset: RGB on a background colour, an alpha
//! mask, a world-space point map and depth, from a [`Mesh`] seen by a [`Camera`].
//!
//! - Visibility: a z-buffer over an `s x s` grid of sub-samples per pixel (supersampling
//!   anti-aliasing), with homogeneous edge functions (see `setup`), so triangles behind or
//!   crossing the camera need no clipping and attributes are perspective-correct by
//!   construction. Nothing is culled: scans are not always closed.
//! - Colour: the unlit colour of every covered sub-sample (vertex colours, flat, or a
//!   trilinearly filtered texture), uncovered sub-samples take the background, and the pixel
//!   is their mean. Alpha is the covered fraction of the sub-samples.
//! - Point map and depth: from the ray through the pixel centre only, so the point of a pixel
//!   is exactly where the nearest surface meets that ray and reprojects onto the pixel centre.
//! - Parallel with rayon over bands of rows; the output does not depend on the thread count.

mod band;
mod output;
mod samples;
mod setup;
mod shade;

use rayon::prelude::*;
use thiserror::Error;

use crate::mesh::{Mesh, MeshError};
use prism_core::camera::Camera;

pub use output::RenderOutput;

use band::{BAND_ROWS, Frame, Targets};
use samples::SamplePattern;
use setup::setup_triangles;
use shade::Shader;

/// What can go wrong when rendering.
#[derive(Debug, Error, PartialEq)]
pub enum RenderError {
    /// The mesh's parts do not fit together.
    #[error("invalid mesh: {0}")]
    Mesh(#[from] MeshError),
    /// The camera's image has no pixels.
    #[error("image size {width}x{height} has no pixels")]
    EmptyImage {
        /// Width in pixels.
        width: u32,
        /// Height in pixels.
        height: u32,
    },
    /// An option is out of range.
    #[error("invalid render option: {0}")]
    Option(String),
}

/// How to render.
#[derive(Clone, Debug, PartialEq)]
pub struct RenderOptions {
    /// Supersampling factor `s`: `s x s` sub-samples per pixel (1 disables anti-aliasing).
    pub supersample: u32,
    /// Background colour (display values in [0, 1]) that the image is composited on.
    pub background: [f32; 3],
    /// Near plane distance in metres: surfaces closer to the camera (along its axis) are not
    /// drawn.
    pub near: f32,
}

impl Default for RenderOptions {
    /// 3x3 supersampling on a white background, near plane at 1 cm.
    fn default() -> Self {
        Self {
            supersample: 3,
            background: [1.0; 3],
            near: 0.01,
        }
    }
}

/// Renders `mesh` as seen by `camera` at the camera's image size.
///
/// Pixel `p` gets `rgb = mean_k c_k` over its sub-samples, where `c_k` is the colour of the
/// nearest surface at sub-sample `k` or the background; `alpha` = the fraction of covered
/// sub-samples; `points` = the world point where the ray through the pixel centre first meets
/// the mesh and `depth` its camera-space z (both 0 when the centre ray misses).
pub fn render(
    mesh: &Mesh,
    camera: &Camera,
    options: &RenderOptions,
) -> Result<RenderOutput, RenderError> {
    mesh.validate()?;
    let (width, height) = (camera.intrinsics.width, camera.intrinsics.height);
    if width == 0 || height == 0 {
        return Err(RenderError::EmptyImage { width, height });
    }
    if !(1..=16).contains(&options.supersample) {
        return Err(RenderError::Option(format!(
            "supersample must be in 1..=16, got {}",
            options.supersample
        )));
    }
    if !(options.near > 0.0 && options.near.is_finite()) {
        return Err(RenderError::Option(format!(
            "near plane must be positive, got {}",
            options.near
        )));
    }
    let (width, height) = (width as usize, height as usize);
    let pattern = SamplePattern::grid(options.supersample as usize);
    let triangles = setup_triangles(mesh, camera, options.near as f64);

    // Bin triangles into bands of rows; a band scans its triangles in mesh order, so ties in
    // depth resolve the same way whatever the thread count.
    let num_bands = height.div_ceil(BAND_ROWS);
    let mut bins: Vec<Vec<u32>> = vec![Vec::new(); num_bands];
    for (i, tri) in triangles.iter().enumerate() {
        for bin in &mut bins[tri.bounds[1] / BAND_ROWS..=tri.bounds[3] / BAND_ROWS] {
            bin.push(i as u32);
        }
    }

    let shader = Shader::new(mesh);
    let k = &camera.intrinsics;
    let frame = Frame {
        width,
        pattern: &pattern,
        inv_near: 1.0 / options.near as f64,
        intrinsics: [k.fx as f64, k.fy as f64, k.cx as f64, k.cy as f64],
        c2w: camera.c2w.as_dmat4(),
        background: options.background,
    };
    let mut out = RenderOutput::empty(width, height);
    let chunk = width * BAND_ROWS;
    out.rgb
        .par_chunks_mut(chunk)
        .zip(out.alpha.par_chunks_mut(chunk))
        .zip(out.points.par_chunks_mut(chunk))
        .zip(out.depth.par_chunks_mut(chunk))
        .zip(bins.par_iter())
        .enumerate()
        .for_each(|(b, ((((rgb, alpha), points), depth), bin))| {
            let rows = alpha.len() / width;
            let targets = Targets {
                rgb,
                alpha,
                points,
                depth,
            };
            frame.render_band(b * BAND_ROWS, rows, &triangles, bin, &shader, targets);
        });
    Ok(out)
}

#[cfg(test)]
mod tests;
