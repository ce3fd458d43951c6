//! Geometry helpers for clothes and hair: the body's radius around a vertical axis, surfaces of
//! revolution with a closed profile, swept tubes, vertex normals and subdivision.

use glam::Vec3;

/// What extra geometry is made of (its colour is computed after refinement).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum Material {
    Hair,
    /// A skirt, with the height of its hem.
    Skirt {
        hem: f32,
    },
}

/// Extra geometry in the shaped rest frame, with per-vertex skinning weights and materials.
#[derive(Clone, Debug, Default)]
pub(crate) struct Piece {
    pub positions: Vec<Vec3>,
    pub triangles: Vec<[u32; 3]>,
    pub weights: Vec<Vec<(usize, f32)>>,
    pub material: Vec<Material>,
}

impl Piece {
    pub fn append(&mut self, other: Piece) {
        let base = self.positions.len() as u32;
        self.positions.extend(other.positions);
        self.triangles
            .extend(other.triangles.iter().map(|t| t.map(|i| i + base)));
        self.weights.extend(other.weights);
        self.material.extend(other.material);
    }
}

/// The body's extent around a vertical axis: for height bins and angle bins (angle 0 towards
/// +Z, increasing towards +X), the largest horizontal distance of the sampled points.
#[derive(Clone, Debug)]
pub(crate) struct RadialProfile {
    pub axis: Vec3,
    pub y0: f32,
    pub dy: f32,
    pub angles: usize,
    radius: Vec<f32>,
    rows: usize,
}

impl RadialProfile {
    /// The outer extent of a closed surface (`triangles` over `positions`) seen from the
    /// vertical axis through `axis`: for each height bin between `y0` and `y1` (step `dy`) and
    /// each of `angles` directions, the farthest crossing of the horizontal ray with the
    /// surface. Directions the surface does not cross are filled from their neighbours.
    pub fn from_mesh(
        positions: &[Vec3],
        triangles: &[[u32; 3]],
        axis: Vec3,
        y0: f32,
        y1: f32,
        dy: f32,
        angles: usize,
    ) -> Self {
        let rows = (((y1 - y0) / dy).ceil() as usize).max(1) + 1;
        let mut radius = vec![f32::NAN; rows * angles];
        // Bucket the triangles by the rows they span.
        let mut buckets: Vec<Vec<usize>> = vec![Vec::new(); rows];
        for (t, tri) in triangles.iter().enumerate() {
            let ys = tri.map(|i| positions[i as usize].y);
            let lo = ys.iter().copied().fold(f32::INFINITY, f32::min);
            let hi = ys.iter().copied().fold(f32::NEG_INFINITY, f32::max);
            let r0 = ((lo - y0) / dy).ceil().max(0.0) as usize;
            let r1 = ((hi - y0) / dy).floor();
            if r1 < 0.0 {
                continue;
            }
            for row in buckets
                .iter_mut()
                .take((r1 as usize).min(rows - 1) + 1)
                .skip(r0)
            {
                row.push(t);
            }
        }
        for (row, tris) in buckets.iter().enumerate() {
            let y = y0 + row as f32 * dy;
            // Cross-section segments of the surface at height y, relative to the axis.
            let mut segments: Vec<(glam::Vec2, glam::Vec2)> = Vec::new();
            for &t in tris {
                let p = triangles[t].map(|i| positions[i as usize] - axis);
                let mut pts = Vec::with_capacity(2);
                for k in 0..3 {
                    let (a, b) = (p[k], p[(k + 1) % 3]);
                    if (a.y - (y - axis.y)) * (b.y - (y - axis.y)) < 0.0
                        || (a.y == y - axis.y && b.y != a.y)
                    {
                        let f = ((y - axis.y) - a.y) / (b.y - a.y);
                        let q = a + (b - a) * f;
                        pts.push(glam::Vec2::new(q.x, q.z));
                    }
                }
                if pts.len() >= 2 {
                    segments.push((pts[0], pts[1]));
                }
            }
            for k in 0..angles {
                let a = std::f32::consts::TAU * k as f32 / angles as f32;
                let d = glam::Vec2::new(a.sin(), a.cos());
                let mut best = f32::NAN;
                for (p, q) in &segments {
                    // Solve p + s (q - p) = r d for r >= 0, s in [0, 1].
                    let e = *q - *p;
                    let den = d.x * e.y - d.y * e.x;
                    if den.abs() < 1e-12 {
                        continue;
                    }
                    let s = (p.x * d.y - p.y * d.x) / den;
                    if !(0.0..=1.0).contains(&s) {
                        continue;
                    }
                    let r = (p.x * e.y - p.y * e.x) / den;
                    if r > 0.0 && (best.is_nan() || r > best) {
                        best = r;
                    }
                }
                radius[row * angles + k] = best;
            }
        }
        Self::filled(axis, y0, dy, angles, rows, radius)
    }

    fn filled(
        axis: Vec3,
        y0: f32,
        dy: f32,
        angles: usize,
        rows: usize,
        mut radius: Vec<f32>,
    ) -> Self {
        // Fill gaps: around each row, then along the columns.
        for row in 0..rows {
            let cells = &mut radius[row * angles..(row + 1) * angles];
            if cells.iter().all(|c| c.is_nan()) {
                continue;
            }
            for _ in 0..angles {
                let snapshot = cells.to_vec();
                let mut changed = false;
                for i in 0..angles {
                    if snapshot[i].is_nan() {
                        let l = snapshot[(i + angles - 1) % angles];
                        let r = snapshot[(i + 1) % angles];
                        let v = match (l.is_nan(), r.is_nan()) {
                            (false, false) => 0.5 * (l + r),
                            (false, true) => l,
                            (true, false) => r,
                            _ => continue,
                        };
                        cells[i] = v;
                        changed = true;
                    }
                }
                if !changed {
                    break;
                }
            }
        }
        for i in 0..angles {
            for row in 0..rows {
                if radius[row * angles + i].is_nan() {
                    let near = (1..rows).find_map(|d| {
                        [row.checked_sub(d), Some(row + d)]
                            .into_iter()
                            .flatten()
                            .filter(|&r| r < rows)
                            .map(|r| radius[r * angles + i])
                            .find(|v| !v.is_nan())
                    });
                    radius[row * angles + i] = near.unwrap_or(0.05);
                }
            }
        }
        Self {
            axis,
            y0,
            dy,
            angles,
            radius,
            rows,
        }
    }

    /// The same profile with every height's cross-section replaced by its convex hull (how
    /// cloth and hair bridge the hollows between legs or around the neck).
    pub fn convex(&self) -> RadialProfile {
        let mut radius = self.radius.clone();
        for row in 0..self.rows {
            let pts: Vec<glam::Vec2> = (0..self.angles)
                .map(|k| {
                    let a = std::f32::consts::TAU * k as f32 / self.angles as f32;
                    glam::Vec2::new(a.sin(), a.cos()) * self.radius[row * self.angles + k]
                })
                .collect();
            let hull = convex_hull(&pts);
            for k in 0..self.angles {
                let a = std::f32::consts::TAU * k as f32 / self.angles as f32;
                let d = glam::Vec2::new(a.sin(), a.cos());
                let mut best = radius[row * self.angles + k];
                for i in 0..hull.len() {
                    let (p, q) = (hull[i], hull[(i + 1) % hull.len()]);
                    let e = q - p;
                    let den = d.x * e.y - d.y * e.x;
                    if den.abs() < 1e-12 {
                        continue;
                    }
                    let s = (p.x * d.y - p.y * d.x) / den;
                    let r = (p.x * e.y - p.y * e.x) / den;
                    if (-1e-4..=1.0001).contains(&s) && r > best {
                        best = r;
                    }
                }
                radius[row * self.angles + k] = best;
            }
        }
        RadialProfile {
            radius,
            ..self.clone()
        }
    }

    /// The body radius at height `y` and angle `a` (bilinear).
    pub fn at(&self, y: f32, a: f32) -> f32 {
        let fy = ((y - self.y0) / self.dy).clamp(0.0, (self.rows - 1) as f32);
        let fa = a.rem_euclid(std::f32::consts::TAU) / std::f32::consts::TAU * self.angles as f32;
        let (r0, ty) = (fy.floor() as usize, fy.fract());
        let r1 = (r0 + 1).min(self.rows - 1);
        let (a0, ta) = (fa.floor() as usize % self.angles, fa.fract());
        let a1 = (a0 + 1) % self.angles;
        let g = |r: usize, c: usize| self.radius[r * self.angles + c];
        let top = g(r0, a0) * (1.0 - ta) + g(r0, a1) * ta;
        let bottom = g(r1, a0) * (1.0 - ta) + g(r1, a1) * ta;
        top * (1.0 - ty) + bottom * ty
    }

    /// The point at height `y`, angle `a` and horizontal distance `r` from the axis.
    pub fn point(&self, y: f32, a: f32, r: f32) -> Vec3 {
        Vec3::new(self.axis.x + r * a.sin(), y, self.axis.z + r * a.cos())
    }
}

/// The convex hull of 2D points, counter-clockwise (Andrew's monotone chain).
fn convex_hull(points: &[glam::Vec2]) -> Vec<glam::Vec2> {
    let mut p = points.to_vec();
    p.sort_by(|a, b| a.x.total_cmp(&b.x).then(a.y.total_cmp(&b.y)));
    if p.len() < 3 {
        return p;
    }
    let cross = |o: glam::Vec2, a: glam::Vec2, b: glam::Vec2| (a - o).perp_dot(b - o);
    let mut hull: Vec<glam::Vec2> = Vec::with_capacity(2 * p.len());
    for &pt in p.iter().chain(p.iter().rev().skip(1)) {
        while hull.len() >= 2 && cross(hull[hull.len() - 2], hull[hull.len() - 1], pt) <= 0.0 {
            hull.pop();
        }
        hull.push(pt);
    }
    hull.pop();
    hull
}

/// A closed grid surface: `rings` rows of `cols` points; rows are joined in order, `wrap_rows`
/// joins the last row to the first, `wrap_cols` closes each row into a loop. Triangles face the
/// side given by `(next col) x (next row)` (callers order the points so that this is outside).
pub(crate) fn grid_triangles(
    rows: usize,
    cols: usize,
    wrap_rows: bool,
    wrap_cols: bool,
) -> Vec<[u32; 3]> {
    let mut tris = Vec::new();
    let row_pairs = if wrap_rows { rows } else { rows - 1 };
    let col_pairs = if wrap_cols { cols } else { cols - 1 };
    for i in 0..row_pairs {
        let i1 = (i + 1) % rows;
        for j in 0..col_pairs {
            let j1 = (j + 1) % cols;
            let a = (i * cols + j) as u32;
            let b = (i * cols + j1) as u32;
            let c = (i1 * cols + j1) as u32;
            let d = (i1 * cols + j) as u32;
            tris.push([a, b, c]);
            tris.push([a, c, d]);
        }
    }
    tris
}

/// A tube swept along `centres` with `radii`, `segments` around, closed by poles; returns the
/// points, outward triangles and for each point the index of its ring.
pub(crate) fn sweep(
    centres: &[Vec3],
    radii: &[f32],
    segments: usize,
) -> (Vec<Vec3>, Vec<[u32; 3]>, Vec<usize>) {
    let n = centres.len();
    let tangent = |i: usize| {
        let a = centres[i.saturating_sub(1)];
        let b = centres[(i + 1).min(n - 1)];
        (b - a).normalize()
    };
    // Parallel-transported frames.
    let t0 = tangent(0);
    let mut u = if t0.y.abs() < 0.9 { Vec3::Y } else { Vec3::X };
    u = (u - u.dot(t0) * t0).normalize();
    let mut pts = Vec::new();
    let mut ring = Vec::new();
    for i in 0..n {
        let t = tangent(i);
        u = (u - u.dot(t) * t).normalize();
        let w = t.cross(u);
        for j in 0..segments {
            let phi = std::f32::consts::TAU * j as f32 / segments as f32;
            pts.push(centres[i] + radii[i] * (phi.cos() * u + phi.sin() * w));
            ring.push(i);
        }
    }
    let mut tris = grid_triangles(n, segments, false, true);
    let start = pts.len() as u32;
    pts.push(centres[0] - tangent(0) * radii[0] * 0.5);
    ring.push(0);
    let end = pts.len() as u32;
    pts.push(centres[n - 1] + tangent(n - 1) * radii[n - 1] * 0.5);
    ring.push(n - 1);
    let s = segments as u32;
    let last = ((n - 1) * segments) as u32;
    for j in 0..s {
        tris.push([start, (j + 1) % s, j]);
        tris.push([last + j, last + (j + 1) % s, end]);
    }
    (pts, tris, ring)
}

/// Area-weighted vertex normals.
pub(crate) fn vertex_normals(positions: &[Vec3], triangles: &[[u32; 3]]) -> Vec<Vec3> {
    let mut n = vec![Vec3::ZERO; positions.len()];
    for t in triangles {
        let [a, b, c] = t.map(|i| i as usize);
        let f = (positions[b] - positions[a]).cross(positions[c] - positions[a]);
        n[a] += f;
        n[b] += f;
        n[c] += f;
    }
    n.into_iter().map(|v| v.normalize_or(Vec3::Y)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn swept_tube_is_outward() {
        let centres: Vec<Vec3> = (0..6)
            .map(|i| Vec3::new(0.0, -(i as f32) * 0.1, 0.02 * i as f32))
            .collect();
        let (p, t, _) = sweep(&centres, &[0.05; 6], 12);
        let vol: f32 = t
            .iter()
            .map(|f| {
                let [a, b, c] = f.map(|i| p[i as usize]);
                a.dot(b.cross(c)) / 6.0
            })
            .sum();
        assert!(vol > 0.0, "{vol}");
    }

    #[test]
    fn radial_profile_of_a_box() {
        // An axis-aligned box 0.4 wide (x), 0.2 deep (z), 1 tall, as 12 outward triangles.
        let (hx, hz) = (0.2f32, 0.1f32);
        let p: Vec<Vec3> = (0..8)
            .map(|i| {
                Vec3::new(
                    if i & 1 == 0 { -hx } else { hx },
                    if i & 2 == 0 { 0.0 } else { 1.0 },
                    if i & 4 == 0 { -hz } else { hz },
                )
            })
            .collect();
        let t = vec![
            [0, 2, 3],
            [0, 3, 1],
            [4, 5, 7],
            [4, 7, 6],
            [0, 1, 5],
            [0, 5, 4],
            [2, 6, 7],
            [2, 7, 3],
            [0, 4, 6],
            [0, 6, 2],
            [1, 3, 7],
            [1, 7, 5],
        ];
        let prof = RadialProfile::from_mesh(&p, &t, Vec3::ZERO, 0.0, 1.0, 0.05, 36);
        assert!((prof.at(0.5, 0.0) - hz).abs() < 1e-4);
        assert!((prof.at(0.5, std::f32::consts::FRAC_PI_2) - hx).abs() < 1e-4);
        assert!((prof.at(0.5, std::f32::consts::PI) - hz).abs() < 1e-4);
    }
}
