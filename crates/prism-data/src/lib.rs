//! Data for prism: cameras and Plücker rays, the paper's viewing protocol, the SMPL-X body
//! model, procedural humans, textured scans (OBJ / glTF) and the CPU rasterizer that renders
//! both, the dataset format and training batches.
//!
//! Conventions (shared by every crate of the workspace): metres, world Y-up, subjects stand on
//! `y = 0` facing +Z; OpenCV cameras (x right, y down, looking along +z) given by pixel
//! intrinsics and a 4x4 camera-to-world matrix; pixel centres at `(x + 0.5, y + 0.5)`;
//! images as `[B, 3, H, W]` tensors in [0, 1].

pub mod backend;
pub mod body;
pub mod camera;
pub mod dataset;
pub mod material;
pub mod mesh;
pub mod people;
pub mod protocol;
pub mod raster;
pub mod rays;
pub mod reads;
pub mod scan;
pub mod scan_dataset;
pub mod synth;

pub use backend::{BackendError, BackendKind};
pub use body::{BodyError, BodyLayer, BodyModel, BodyParams};
pub use camera::{Camera, Intrinsics};
pub use material::{Material, Shading, Texture};
pub use mesh::{Mesh, MeshError};
pub use protocol::{Placement, ViewAngles, ViewingProtocol};
pub use raster::{RenderError, RenderOptions, RenderOutput, render};
pub use scan::{Facing, ScanError, ScanOptions, UpAxis, load_scan, normalise};
