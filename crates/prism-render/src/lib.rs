//! Differentiable renderers of prism on Burn tensors.
//!
//! - [`mesh`]: triangle rasterization of meshes for position maps (visible face and
//!   barycentrics per pixel) and differentiable interpolation of vertex attributes;
//! - [`triplane`]: bilinear sampling of triplane feature planes, with its own backward pass;
//! - [`splat`]: 3D Gaussian splatting (EWA projection, tiled front-to-back compositing) with a
//!   hand-written backward pass, the standard 3DGS PLY format and a PNG renderer for it.
//!
//! Conventions are the workspace's (see `prism_core`): OpenCV pinhole cameras given by pixel
//! intrinsics and a camera-to-world matrix, pixel centres at `(x + 0.5, y + 0.5)`, images as
//! `[B, C, H, W]` tensors.

pub mod error;
pub mod image_size;
#[cfg(any(feature = "wgpu", feature = "cuda"))]
mod launch;
pub mod mesh;
pub mod served;
pub mod splat;
#[cfg(any(feature = "wgpu", feature = "cuda"))]
mod tiles;
mod transfer;
pub mod triplane;

pub use error::RenderError;
