//! Refining the posed body mesh: each level splits every triangle in four, placing new
//! vertices on curved (Phong-tessellated) edges so that silhouettes stay smooth, and carrying
//! the attributes that colours are computed from (rest position, region, jaw weight).

use std::collections::HashMap;

use glam::Vec3;

/// A posed mesh with per-vertex attributes.
#[derive(Clone, Debug)]
pub(crate) struct Refinable<T: Copy> {
    pub positions: Vec<Vec3>,
    pub normals: Vec<Vec3>,
    /// Position in the shaped rest body (for colours and patterns).
    pub rest: Vec<Vec3>,
    /// A discrete tag per vertex (body region, or the material of extra geometry).
    pub region: Vec<T>,
    pub jaw: Vec<f32>,
    pub triangles: Vec<[u32; 3]>,
}

/// Phong tessellation's shape factor (0: flat, 1: fully curved).
const ALPHA: f32 = 0.6;

impl<T: Copy> Refinable<T> {
    /// One level of subdivision.
    pub fn subdivide(&self) -> Refinable<T> {
        let mut out = self.clone();
        let mut mid: HashMap<(u32, u32), u32> = HashMap::with_capacity(self.triangles.len() * 2);
        let mut midpoint = |a: u32, b: u32, out: &mut Refinable<T>| -> u32 {
            let key = (a.min(b), a.max(b));
            if let Some(&m) = mid.get(&key) {
                return m;
            }
            let (ia, ib) = (a as usize, b as usize);
            let (pa, pb) = (self.positions[ia], self.positions[ib]);
            let (na, nb) = (self.normals[ia], self.normals[ib]);
            let m = 0.5 * (pa + pb);
            let proj_a = m - (m - pa).dot(na) * na;
            let proj_b = m - (m - pb).dot(nb) * nb;
            let p = (1.0 - ALPHA) * m + ALPHA * 0.5 * (proj_a + proj_b);
            let idx = out.positions.len() as u32;
            out.positions.push(p);
            out.normals.push((na + nb).normalize_or(na));
            out.rest.push(0.5 * (self.rest[ia] + self.rest[ib]));
            // A midpoint between tags takes the lower-indexed vertex's tag.
            out.region.push(self.region[key.0 as usize]);
            out.jaw.push(0.5 * (self.jaw[ia] + self.jaw[ib]));
            mid.insert(key, idx);
            idx
        };
        let mut triangles = Vec::with_capacity(self.triangles.len() * 4);
        for &[a, b, c] in &self.triangles {
            let ab = midpoint(a, b, &mut out);
            let bc = midpoint(b, c, &mut out);
            let ca = midpoint(c, a, &mut out);
            triangles.push([a, ab, ca]);
            triangles.push([ab, b, bc]);
            triangles.push([ca, bc, c]);
            triangles.push([ab, bc, ca]);
        }
        out.triangles = triangles;
        out
    }
}
