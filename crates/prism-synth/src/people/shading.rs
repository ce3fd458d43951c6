//! Baked lighting: vertex colours darkened by a soft key light and a sky term, as scans carry
//! the lighting of their capture; it gives the flat vertex colours their 3D form.

use glam::Vec3;

use super::geometry::vertex_normals;

/// Scales every vertex colour by `ambient + key * max(0, n . light) + sky * (n.y + 1) / 2`.
pub(crate) fn bake(
    positions: &[Vec3],
    triangles: &[[u32; 3]],
    colors: &mut [[f32; 3]],
    light: Vec3,
) {
    let normals = vertex_normals(positions, triangles);
    let light = light.normalize();
    for (c, n) in colors.iter_mut().zip(normals) {
        let diffuse = n.dot(light).max(0.0);
        let sky = 0.5 * (n.y + 1.0);
        let shade = 0.40 + 0.52 * diffuse + 0.16 * sky;
        *c = c.map(|x| (x * shade).clamp(0.0, 1.0));
    }
}
