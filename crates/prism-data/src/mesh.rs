//! Triangle meshes as the CPU renderer draws them.

use glam::Vec3;

/// A triangle mesh in world space with a colour per vertex.
///
/// Procedural humans fill it directly; loaded scans add textures (see the renderer). Colours
/// are display values in [0, 1] (8-bit sRGB divided by 255), as they are written to PNG.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Mesh {
    /// Vertex positions (metres, world space).
    pub positions: Vec<Vec3>,
    /// Triangles as indices into `positions`, counter-clockwise seen from outside.
    pub triangles: Vec<[u32; 3]>,
    /// One colour per vertex.
    pub colors: Vec<[f32; 3]>,
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
        }
    }

    /// Appends another mesh (its indices shifted past this one's vertices).
    pub fn append(&mut self, other: &Mesh) {
        let offset = self.positions.len() as u32;
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
}
