//! Differentiable 3D Gaussian splatting (Kerbl et al. 2023) on Burn tensors.
//!
//! - [`render`] draws `B x N` [`Gaussians`] into `B` cameras and returns [`Rendered`] features,
//!   alpha and depth; on an autodiff device it is differentiable with respect to every Gaussian
//!   parameter (a custom backward pass, see [`op`]).
//! - [`ply`] reads and writes the standard 3DGS PLY layout ([`GaussianCloud`]).
//!
//! The computation runs on the host (CPU, parallel over tiles) for every backend: see `host`.

mod host;
pub mod op;
pub mod ply;
pub mod render;

pub use host::{
    DILATION, EXTENT_SIGMAS, MAX_ALPHA, MIN_ALPHA, MIN_TRANSMITTANCE, NEAR_PLANE, TILE_SIZE,
};
pub use ply::GaussianCloud;
pub use render::{Gaussians, Rendered, background, render};
