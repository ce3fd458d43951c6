//! Differentiable renderers of prism on Burn tensors.
//!
//! - [`splat`]: 3D Gaussian splatting (EWA projection, tiled front-to-back compositing) with a
//!   hand-written backward pass, the standard 3DGS PLY format and a PNG renderer for it.
//!
//! Conventions are the workspace's (see `prism_data`): OpenCV pinhole cameras given by pixel
//! intrinsics and a camera-to-world matrix, pixel centres at `(x + 0.5, y + 0.5)`, images as
//! `[B, C, H, W]` tensors.

pub mod error;
pub mod files;
pub mod splat;

pub use error::RenderError;
