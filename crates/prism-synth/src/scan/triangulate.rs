//! Triangulation of polygonal faces (quads and n-gons) by ear clipping.

use glam::{Vec2, Vec3};

/// Splits a polygon with corners `points` (in order) into triangles of corner indices.
///
/// The polygon is projected onto the plane of its Newell normal and ear-clipped, so that
/// concave faces are split inside their outline; a degenerate polygon (no ear found, e.g.
/// all corners on a line) falls back to a fan from the first corner. Triangles keep the
/// polygon's winding.
pub(crate) fn triangulate(points: &[Vec3]) -> Vec<[usize; 3]> {
    let n = points.len();
    if n < 3 {
        return Vec::new();
    }
    if n == 3 {
        return vec![[0, 1, 2]];
    }
    let fan = || (1..n - 1).map(|i| [0, i, i + 1]).collect();
    // Newell's normal: robust for non-planar and concave polygons.
    let mut normal = Vec3::ZERO;
    for i in 0..n {
        let (a, b) = (points[i], points[(i + 1) % n]);
        normal += Vec3::new(
            (a.y - b.y) * (a.z + b.z),
            (a.z - b.z) * (a.x + b.x),
            (a.x - b.x) * (a.y + b.y),
        );
    }
    if normal.length_squared() <= f32::MIN_POSITIVE {
        return fan();
    }
    let normal = normal.normalize();
    let tangent = normal.any_orthonormal_vector();
    let bitangent = normal.cross(tangent);
    // In (tangent, bitangent) coordinates the polygon winds counter-clockwise.
    let flat: Vec<Vec2> = points
        .iter()
        .map(|p| Vec2::new(p.dot(tangent), p.dot(bitangent)))
        .collect();
    let cross = |o: Vec2, a: Vec2, b: Vec2| (a - o).perp_dot(b - o);
    let mut remaining: Vec<usize> = (0..n).collect();
    let mut triangles = Vec::with_capacity(n - 2);
    while remaining.len() > 3 {
        let m = remaining.len();
        let ear = (0..m).find(|&i| {
            let (p, c, q) = (
                remaining[(i + m - 1) % m],
                remaining[i],
                remaining[(i + 1) % m],
            );
            if cross(flat[p], flat[c], flat[q]) <= 0.0 {
                return false; // reflex or degenerate corner
            }
            remaining.iter().all(|&r| {
                r == p
                    || r == c
                    || r == q
                    || !(cross(flat[p], flat[c], flat[r]) >= 0.0
                        && cross(flat[c], flat[q], flat[r]) >= 0.0
                        && cross(flat[q], flat[p], flat[r]) >= 0.0)
            })
        });
        let Some(i) = ear else {
            return fan();
        };
        let m = remaining.len();
        triangles.push([
            remaining[(i + m - 1) % m],
            remaining[i],
            remaining[(i + 1) % m],
        ]);
        remaining.remove(i);
    }
    triangles.push([remaining[0], remaining[1], remaining[2]]);
    triangles
}

#[cfg(test)]
mod tests {
    use super::*;

    fn area(points: &[Vec3], tris: &[[usize; 3]]) -> f32 {
        tris.iter()
            .map(|t| {
                let (a, b, c) = (points[t[0]], points[t[1]], points[t[2]]);
                (b - a).cross(c - a).length() / 2.0
            })
            .sum()
    }

    #[test]
    fn quads_and_concave_polygons_are_covered_exactly() {
        let quad = [Vec3::ZERO, Vec3::X, Vec3::new(1.0, 1.0, 0.0), Vec3::Y];
        let t = triangulate(&quad);
        assert_eq!(t.len(), 2);
        assert!((area(&quad, &t) - 1.0).abs() < 1e-6);
        // An L shape (concave at (1, 1)), in the y = 2 plane, area 3: a fan from corner 0
        // would leave the outline (and sum to an area of 4).
        let l: Vec<Vec3> = [(2., 1.), (1., 1.), (1., 2.), (0., 2.), (0., 0.), (2., 0.)]
            .iter()
            .map(|&(x, z)| Vec3::new(x, 2.0, z))
            .collect();
        let t = triangulate(&l);
        assert_eq!(t.len(), 4);
        assert!((area(&l, &t) - 3.0).abs() < 1e-5);
        // Winding is kept: counter-clockwise in (x, z), so every normal points to -y.
        for tri in &t {
            let m = (l[tri[1]] - l[tri[0]]).cross(l[tri[2]] - l[tri[0]]);
            assert!(m.y < 0.0, "{tri:?}");
        }
    }
}
