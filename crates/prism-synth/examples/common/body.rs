//! A synthetic person-sized mesh shared by the benchmarks.

use glam::{Vec2, Vec3};
use prism_synth::Mesh;

/// A closed ellipsoid about the size of a standing person (1.8 m tall) with `2 * rings *
/// segments` triangles, vertex colours and per-corner UVs.
pub fn body(rings: usize, segments: usize) -> Mesh {
    let mut positions = Vec::new();
    let mut colors = Vec::new();
    let mut uvs = Vec::new();
    for r in 0..=rings {
        let theta = std::f32::consts::PI * r as f32 / rings as f32;
        for s in 0..=segments {
            let phi = std::f32::consts::TAU * s as f32 / segments as f32;
            let p = Vec3::new(
                0.25 * theta.sin() * phi.cos(),
                0.9 + 0.9 * theta.cos(),
                0.15 * theta.sin() * phi.sin(),
            );
            positions.push(p);
            colors.push([0.5 + 0.5 * phi.cos(), r as f32 / rings as f32, 0.4]);
            uvs.push(Vec2::new(
                s as f32 / segments as f32,
                1.0 - r as f32 / rings as f32,
            ));
        }
    }
    let mut triangles = Vec::new();
    let mut corner_uvs = Vec::new();
    let at = |r: usize, s: usize| (r * (segments + 1) + s) as u32;
    for r in 0..rings {
        for s in 0..segments {
            let q = [at(r, s), at(r + 1, s), at(r + 1, s + 1), at(r, s + 1)];
            for t in [[q[0], q[1], q[2]], [q[0], q[2], q[3]]] {
                triangles.push(t);
                corner_uvs.push(t.map(|i| uvs[i as usize]));
            }
        }
    }
    let mut mesh = Mesh::with_vertex_colors(positions, triangles, colors);
    mesh.corner_uvs = corner_uvs;
    mesh
}
