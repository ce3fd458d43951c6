//! Textured human scans (THuman, 2K2K, own captures) as renderable meshes: loading
//! (Wavefront OBJ with MTL materials and PNG / JPEG textures, glTF 2.0) and normalisation to the
//! viewing protocol.
//!
//! ```text
//! let (mesh, warnings) = load_scan(path)?;            // file coordinates and units
//! let placement = ViewingProtocol::default().placement(seed);
//! let (mesh, mesh_to_world) = normalise(&mesh, &ScanOptions::default(), &placement)?;
//! ```
//!
//! Problems that still allow a render (a missing texture or material library) are returned
//! as warnings and render grey; a file that cannot be read or parsed is a [`ScanError`]
//! naming the file (and line).

mod error;
mod gltf_file;
mod mtl;
mod normalise;
mod obj;
mod text;
mod textures;
mod triangulate;

#[cfg(test)]
mod tests;

use std::path::Path;

pub use error::ScanError;
pub use normalise::{Facing, ScanOptions, UpAxis, normalise};

use crate::mesh::Mesh;

/// The colour of surfaces whose texture or material is missing.
pub const GREY: [f32; 3] = [0.5, 0.5, 0.5];

/// Loads a scan mesh in its file's coordinates, with warnings about what could not be used
/// (missing textures, material libraries or materials, skipped statements).
///
/// The format follows the extension: `.obj`, `.gltf` or `.glb`.
pub fn load_scan(path: &Path) -> Result<(Mesh, Vec<String>), ScanError> {
    let extension = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    match extension.as_deref() {
        Some("obj") => obj::load_obj(path),
        Some("gltf") | Some("glb") => gltf_file::load_gltf(path),
        _ => Err(ScanError::Unsupported {
            path: path.to_path_buf(),
        }),
    }
}
