//! Normalisation of a scan to the viewing protocol: Y-up, facing +Z, feet on `y = 0`,
//! centred horizontally and scaled to the drawn height, whatever the file's unit and axes.

use std::str::FromStr;

use glam::{DMat4, DVec3, Mat4};
use serde::{Deserialize, Serialize};

use super::error::ScanError;
use crate::mesh::Mesh;
use prism_core::protocol::Placement;

/// The file's up axis (recorded in `dataset.json` as `"y"` or `"z"`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum UpAxis {
    /// +Y is up (OBJ exports of most scanners, THuman).
    #[default]
    #[serde(rename = "y")]
    Y,
    /// +Z is up (Blender-style exports): the file's -Y becomes the facing direction +Z.
    #[serde(rename = "z")]
    Z,
}

impl FromStr for UpAxis {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.to_ascii_lowercase().as_str() {
            "y" | "+y" => Ok(Self::Y),
            "z" | "+z" => Ok(Self::Z),
            _ => Err(format!("up axis must be y or z, got '{s}'")),
        }
    }
}

/// Where the subject faces, once the up axis is Y (for `--up z` that is after turning the
/// file's +Z into +Y, which takes the file's -Y to +Z); recorded as `"+z"`, `"-z"`, `"+x"` or
/// `"-x"`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum Facing {
    /// Facing +Z (the protocol's convention).
    #[default]
    #[serde(rename = "+z")]
    PlusZ,
    /// Facing -Z.
    #[serde(rename = "-z")]
    MinusZ,
    /// Facing +X.
    #[serde(rename = "+x")]
    PlusX,
    /// Facing -X.
    #[serde(rename = "-x")]
    MinusX,
}

impl FromStr for Facing {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.to_ascii_lowercase().as_str() {
            "+z" | "z" => Ok(Self::PlusZ),
            "-z" => Ok(Self::MinusZ),
            "+x" | "x" => Ok(Self::PlusX),
            "-x" => Ok(Self::MinusX),
            _ => Err(format!("facing must be one of +z, -z, +x, -x, got '{s}'")),
        }
    }
}

/// How a scan's file is oriented.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ScanOptions {
    /// The file's up axis (`--up`, default y).
    pub up: UpAxis,
    /// The subject's facing direction (`--facing`, default +z).
    pub facing: Facing,
}

impl ScanOptions {
    /// The rotation taking the file's axes to the protocol's (Y up, facing +Z).
    pub fn orientation(&self) -> Mat4 {
        use std::f32::consts::{FRAC_PI_2, PI};
        // Z-up: a -90 degree turn about X maps (x, y, z) to (x, z, -y).
        let up = match self.up {
            UpAxis::Y => Mat4::IDENTITY,
            UpAxis::Z => Mat4::from_rotation_x(-FRAC_PI_2),
        };
        // A turn about Y that takes the facing direction to +Z.
        let facing = match self.facing {
            Facing::PlusZ => Mat4::IDENTITY,
            Facing::MinusZ => Mat4::from_rotation_y(PI),
            Facing::PlusX => Mat4::from_rotation_y(-FRAC_PI_2),
            Facing::MinusX => Mat4::from_rotation_y(FRAC_PI_2),
        };
        facing * up
    }
}

/// Places a scan in the world as the viewing protocol draws it and returns the placed mesh
/// with `mesh_to_world`, the similarity it applied:
///
/// `mesh_to_world = placement.transform(h) * T(-c_x, -y_min, -c_z) * R`
///
/// where `R` is [`ScanOptions::orientation`], `y_min` the lowest point and `(c_x, c_z)` the
/// centre of the horizontal bounding box after `R`, and `h` the height after `R`. The result
/// stands on `y = 0`, is `placement.height` tall and is shifted by `placement.translation`.
pub fn normalise(
    mesh: &Mesh,
    options: &ScanOptions,
    placement: &Placement,
) -> Result<(Mesh, Mat4), ScanError> {
    let rotation = options.orientation().as_dmat4();
    let mut lo = DVec3::splat(f64::INFINITY);
    let mut hi = DVec3::splat(f64::NEG_INFINITY);
    for p in &mesh.positions {
        let q = rotation.transform_point3(p.as_dvec3());
        lo = lo.min(q);
        hi = hi.max(q);
    }
    let height = hi.y - lo.y;
    if !(height.is_finite() && height > 0.0) {
        return Err(ScanError::Degenerate(format!(
            "the mesh has no height along its up axis ({:?}): wrong --up?",
            options.up
        )));
    }
    let centre = DVec3::new((lo.x + hi.x) / 2.0, lo.y, (lo.z + hi.z) / 2.0);
    let m =
        placement.transform(height as f32).as_dmat4() * DMat4::from_translation(-centre) * rotation;
    let mut placed = mesh.clone();
    for p in &mut placed.positions {
        *p = m.transform_point3(p.as_dvec3()).as_vec3();
    }
    Ok((placed, m.as_mat4()))
}
