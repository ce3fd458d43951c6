//! Triangle meshes as the CPU renderer draws them.

use glam::{Vec2, Vec3};
use thiserror::Error;

use crate::material::{Material, Shading};

/// A mesh whose parts do not fit together (an index out of range or a length mismatch).
#[derive(Debug, Error, PartialEq)]
pub enum MeshError {
    /// A per-element list has the wrong length.
    #[error("mesh has {found} {what}, expected {expected}")]
    Length {
        /// Which list.
        what: &'static str,
        /// Its length.
        found: usize,
        /// The length it must have.
        expected: usize,
    },
    /// An index points past the end of the list it indexes.
    #[error("triangle {triangle} uses {what} {index}, but there are only {count}")]
    Index {
        /// Triangle number.
        triangle: usize,
        /// What the index refers to.
        what: &'static str,
        /// The offending index.
        index: u32,
        /// Number of elements it may refer to.
        count: usize,
    },
}

/// A triangle mesh in world space with a colour per vertex and optional materials.
///
/// Procedural humans fill only `positions`, `triangles` and `colors` (see
/// [`Mesh::with_vertex_colors`]). Loaded scans add `materials` (textures or flat colours), a
/// material per triangle and UVs per triangle corner (a vertex can have different UVs in the
/// triangles around it, at texture seams). Colours are display values in [0, 1] (8-bit sRGB
/// divided by 255), as they are written to PNG.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Mesh {
    /// Vertex positions (metres, world space).
    pub positions: Vec<Vec3>,
    /// Triangles as indices into `positions`, counter-clockwise seen from outside.
    pub triangles: Vec<[u32; 3]>,
    /// One colour per vertex (used by triangles whose material is
    /// [`Shading::VertexColors`], and by every triangle when `materials` is empty).
    pub colors: Vec<[f32; 3]>,
    /// Materials; empty means that every triangle uses the vertex colours.
    pub materials: Vec<Material>,
    /// Material index per triangle; empty when `materials` is empty.
    pub triangle_materials: Vec<u32>,
    /// Texture coordinates per triangle corner (OBJ convention, v up); empty when no
    /// material has a texture.
    pub corner_uvs: Vec<[Vec2; 3]>,
}

impl Mesh {
    /// A mesh with per-vertex colours.
    ///
    /// # Panics
    /// If `colors` and `positions` differ in length (a programming error).
    pub fn with_vertex_colors(
        positions: Vec<Vec3>,
        triangles: Vec<[u32; 3]>,
        colors: Vec<[f32; 3]>,
    ) -> Self {
        assert_eq!(positions.len(), colors.len(), "one colour per vertex");
        Self {
            positions,
            triangles,
            colors,
            ..Self::default()
        }
    }

    /// Checks that every index is in range and every per-element list has its length.
    pub fn validate(&self) -> Result<(), MeshError> {
        let length = |what, found, expected| {
            if found == expected {
                Ok(())
            } else {
                Err(MeshError::Length {
                    what,
                    found,
                    expected,
                })
            }
        };
        length("vertex colours", self.colors.len(), self.positions.len())?;
        let n = self.triangles.len();
        if self.materials.is_empty() {
            length("triangle materials", self.triangle_materials.len(), 0)?;
        } else {
            length("triangle materials", self.triangle_materials.len(), n)?;
        }
        let textured = self
            .materials
            .iter()
            .any(|m| matches!(m.shading, Shading::Texture(_)));
        if textured || !self.corner_uvs.is_empty() {
            length("corner UVs", self.corner_uvs.len(), n)?;
        }
        for (t, tri) in self.triangles.iter().enumerate() {
            for &index in tri {
                if index as usize >= self.positions.len() {
                    return Err(MeshError::Index {
                        triangle: t,
                        what: "vertex",
                        index,
                        count: self.positions.len(),
                    });
                }
            }
        }
        for (t, &index) in self.triangle_materials.iter().enumerate() {
            if index as usize >= self.materials.len() {
                return Err(MeshError::Index {
                    triangle: t,
                    what: "material",
                    index,
                    count: self.materials.len(),
                });
            }
        }
        Ok(())
    }

    /// Appends another mesh (its indices shifted past this one's vertices and materials).
    ///
    /// When only one of the two has materials or UVs, the other's triangles get a
    /// vertex-colour material and zero UVs, so that the result stays consistent.
    pub fn append(&mut self, other: &Mesh) {
        let offset = self.positions.len() as u32;
        let (own, theirs) = (self.triangles.len(), other.triangles.len());
        if !self.materials.is_empty() || !other.materials.is_empty() {
            if self.materials.is_empty() {
                self.materials
                    .push(Material::new("vertex colours", Shading::VertexColors));
                self.triangle_materials = vec![0; own];
            }
            let material_offset = self.materials.len() as u32;
            if other.materials.is_empty() {
                self.materials
                    .push(Material::new("vertex colours", Shading::VertexColors));
                self.triangle_materials
                    .extend(std::iter::repeat_n(material_offset, theirs));
            } else {
                self.materials.extend_from_slice(&other.materials);
                self.triangle_materials
                    .extend(other.triangle_materials.iter().map(|m| m + material_offset));
            }
        }
        if !self.corner_uvs.is_empty() || !other.corner_uvs.is_empty() {
            self.corner_uvs.resize(own, [Vec2::ZERO; 3]);
            if other.corner_uvs.is_empty() {
                self.corner_uvs
                    .extend(std::iter::repeat_n([Vec2::ZERO; 3], theirs));
            } else {
                self.corner_uvs.extend_from_slice(&other.corner_uvs);
            }
        }
        self.positions.extend_from_slice(&other.positions);
        self.colors.extend_from_slice(&other.colors);
        self.triangles.extend(
            other
                .triangles
                .iter()
                .map(|t| [t[0] + offset, t[1] + offset, t[2] + offset]),
        );
    }

    /// Axis-aligned bounds `(min, max)`; `None` for a mesh without vertices.
    pub fn bounds(&self) -> Option<(Vec3, Vec3)> {
        let first = *self.positions.first()?;
        Some(
            self.positions
                .iter()
                .fold((first, first), |(lo, hi), p| (lo.min(*p), hi.max(*p))),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn append_shifts_indices_and_bounds_cover_both() {
        let tri = |z: f32| {
            Mesh::with_vertex_colors(
                vec![
                    Vec3::new(0.0, 0.0, z),
                    Vec3::new(1.0, 0.0, z),
                    Vec3::new(0.0, 1.0, z),
                ],
                vec![[0, 1, 2]],
                vec![[1.0, 0.0, 0.0]; 3],
            )
        };
        let mut m = tri(0.0);
        m.append(&tri(2.0));
        assert_eq!(m.triangles, vec![[0, 1, 2], [3, 4, 5]]);
        assert_eq!(m.bounds(), Some((Vec3::ZERO, Vec3::new(1.0, 1.0, 2.0))));
    }

    #[test]
    fn append_keeps_materials_and_uvs_consistent() {
        let plain = Mesh::with_vertex_colors(
            vec![Vec3::ZERO, Vec3::X, Vec3::Y],
            vec![[0, 1, 2]],
            vec![[0.5; 3]; 3],
        );
        let mut flat = plain.clone();
        flat.materials = vec![Material::new("a", Shading::Flat([1.0, 0.0, 0.0]))];
        flat.triangle_materials = vec![0];
        flat.corner_uvs = vec![[Vec2::ONE; 3]];
        let mut m = plain.clone();
        m.append(&flat);
        m.append(&plain);
        assert_eq!(m.validate(), Ok(()));
        assert_eq!(m.triangle_materials, vec![0, 1, 2]);
        assert_eq!(m.materials[0].shading, Shading::VertexColors);
        assert_eq!(m.materials[2].shading, Shading::VertexColors);
        assert_eq!(
            m.corner_uvs,
            vec![[Vec2::ZERO; 3], [Vec2::ONE; 3], [Vec2::ZERO; 3]]
        );
        assert_eq!(m.triangles[2], [6, 7, 8]);
    }

    #[test]
    fn validate_names_what_does_not_fit() {
        let mut m = Mesh::with_vertex_colors(
            vec![Vec3::ZERO, Vec3::X, Vec3::Y],
            vec![[0, 1, 2]],
            vec![[0.5; 3]; 3],
        );
        m.materials = vec![Material::new("a", Shading::Flat([1.0; 3]))];
        assert!(matches!(
            m.validate(),
            Err(MeshError::Length {
                what: "triangle materials",
                ..
            })
        ));
        m.triangle_materials = vec![1];
        assert!(matches!(
            m.validate(),
            Err(MeshError::Index {
                what: "material",
                index: 1,
                ..
            })
        ));
        m.triangle_materials = vec![0];
        assert_eq!(m.validate(), Ok(()));
        m.colors.pop();
        assert!(
            m.validate()
                .unwrap_err()
                .to_string()
                .contains("vertex colours")
        );
    }
}
