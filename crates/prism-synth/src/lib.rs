//! Dataset synthesis: procedural people on the SMPL-X body model, textured scans (OBJ / glTF),
//! and the CPU mesh rasterizer that renders both under the paper's viewing protocol into
//! prism's dataset format (`prism data synth`, `prism data render`).

pub mod cache;
pub mod material;
pub mod mesh;
pub mod people;
pub mod raster;
pub mod render_subject;
pub mod scan;
pub mod scan_dataset;
pub mod synth;

pub use cache::{
    CACHE_ENV, cache_dir, ensure_synthetic_dataset, ensure_synthetic_dataset_in,
    synthetic_dataset_dir, synthetic_dataset_dir_in,
};
pub use material::{Material, Shading, Texture};
pub use mesh::{Mesh, MeshError};
pub use raster::{RenderError, RenderOptions, RenderOutput, render};
pub use render_subject::ProtocolRenderer;
pub use scan::{Facing, ScanError, ScanOptions, UpAxis, load_scan, normalise};
