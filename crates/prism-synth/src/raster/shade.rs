//! Colour of a visible sample: vertex colours, a flat colour or a filtered texture sample.

use glam::Vec2;

use crate::material::Shading;
use crate::mesh::Mesh;

use super::setup::RasterTriangle;

/// Shading of the mesh, with the vertex-colour fallback resolved once.
pub(crate) struct Shader<'a> {
    mesh: &'a Mesh,
}

impl<'a> Shader<'a> {
    /// A shader for a validated mesh.
    pub fn new(mesh: &'a Mesh) -> Self {
        Self { mesh }
    }

    /// The unlit colour of `tri` at continuous pixel `(u, v)`, for samples `spacing` pixels
    /// apart (the footprint that picks the texture's level of detail).
    ///
    /// Attributes use the perspective-correct barycentrics `b_i = a_i / sum_j a_j` of the
    /// homogeneous edge functions. For textures the UV footprint is the analytic derivative
    /// `d b_i / du = (A_i - b_i sum_j A_j) / sum_j a_j` (and likewise in v) times `spacing`.
    pub fn color(&self, tri: &RasterTriangle, u: f64, v: f64, spacing: f64) -> [f32; 3] {
        let mesh = self.mesh;
        let t = tri.index as usize;
        let shading = match mesh.triangle_materials.get(t) {
            Some(&m) => &mesh.materials[m as usize].shading,
            None => &Shading::VertexColors,
        };
        let a = tri.weights(u, v);
        let sum = a[0] + a[1] + a[2];
        let b = a.map(|x| x / sum);
        match shading {
            Shading::Flat(c) => *c,
            Shading::VertexColors => {
                let corners = mesh.triangles[t].map(|i| mesh.colors[i as usize]);
                [0, 1, 2].map(|c| {
                    (b[0] * corners[0][c] as f64
                        + b[1] * corners[1][c] as f64
                        + b[2] * corners[2][c] as f64) as f32
                })
            }
            Shading::Texture(texture) => {
                let uv = mesh.corner_uvs[t];
                let (sa, sb) = (
                    tri.planes.iter().map(|p| p[0]).sum::<f64>(),
                    tri.planes.iter().map(|p| p[1]).sum::<f64>(),
                );
                let mut at = [0.0f64; 2];
                let mut du = [0.0f64; 2];
                let mut dv = [0.0f64; 2];
                for i in 0..3 {
                    let dbu = (tri.planes[i][0] - b[i] * sa) / sum * spacing;
                    let dbv = (tri.planes[i][1] - b[i] * sb) / sum * spacing;
                    let c = [uv[i].x as f64, uv[i].y as f64];
                    for k in 0..2 {
                        at[k] += b[i] * c[k];
                        du[k] += dbu * c[k];
                        dv[k] += dbv * c[k];
                    }
                }
                let vec = |x: [f64; 2]| Vec2::new(x[0] as f32, x[1] as f32);
                texture.sample(vec(at), vec(du), vec(dv))
            }
        }
    }
}
