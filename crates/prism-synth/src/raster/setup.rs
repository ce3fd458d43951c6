//! Per-triangle set-up of the rasterizer: homogeneous edge functions and screen bounds.
//!
//! With the eye at the origin of camera space and the ray of continuous pixel `(u, v)`
//! written `d(u, v) = ((u - cx) / fx, (v - cy) / fy, 1)`, a triangle `V0 V1 V2` (camera space)
//! is hit by the ray iff `d = a0 V0 + a1 V1 + a2 V2` with every `a_i >= 0`, where
//!
//! `a_i = d . (V_j x V_k) / (V0 . (V1 x V2))`, `(i, j, k)` cyclic.
//!
//! Each `a_i` is affine in `(u, v)` (the "homogeneous rasterization" of Olano and Greer), the
//! hit depth is `z = 1 / (a0 + a1 + a2)` and the perspective-correct barycentrics are
//! `b_i = a_i / (a0 + a1 + a2)`. No division by depth happens per vertex, so triangles that
//! cross the camera plane need no special case: their behind-the-camera part simply has some
//! `a_i < 0`. Clipping at the near plane is only used to bound the screen area to scan.

use glam::{DMat4, DVec3};
use rayon::prelude::*;

use crate::mesh::Mesh;
use prism_core::camera::Camera;

/// One triangle ready to rasterize.
#[derive(Clone, Copy, Debug)]
pub(crate) struct RasterTriangle {
    /// Index of the triangle in the mesh.
    pub index: u32,
    /// `a_i(u, v) = planes[i][0] * u + planes[i][1] * v + planes[i][2]`.
    pub planes: [[f64; 3]; 3],
    /// For samples exactly on edge `i` (`a_i == 0`): whether the edge belongs to this
    /// triangle (a top-left style rule, so that a sample on an edge shared by two triangles is
    /// covered by exactly one of them).
    pub owns_edge: [bool; 3],
    /// Inclusive pixel range `[x0, y0, x1, y1]` that can hold covered samples.
    pub bounds: [usize; 4],
}

impl RasterTriangle {
    /// The three `a_i` at continuous pixel coordinates `(u, v)`.
    #[inline]
    pub fn weights(&self, u: f64, v: f64) -> [f64; 3] {
        self.planes.map(|p| p[0] * u + p[1] * v + p[2])
    }

    /// Whether the ray through `(u, v)` hits the triangle: every `a_i` positive, or zero on
    /// an edge this triangle owns.
    #[inline]
    pub fn covers(&self, a: &[f64; 3]) -> bool {
        (0..3).all(|i| a[i] > 0.0 || (a[i] == 0.0 && self.owns_edge[i]))
    }
}

/// The camera's world-to-camera transform in double precision.
pub(crate) fn world_to_camera(camera: &Camera) -> DMat4 {
    camera.c2w.as_dmat4().inverse()
}

/// Sets up every triangle of `mesh` that can be visible in `camera` beyond `near` metres.
pub(crate) fn setup_triangles(mesh: &Mesh, camera: &Camera, near: f64) -> Vec<RasterTriangle> {
    let w2c = world_to_camera(camera);
    let cam: Vec<DVec3> = mesh
        .positions
        .par_iter()
        .map(|p| w2c.transform_point3(p.as_dvec3()))
        .collect();
    let k = &camera.intrinsics;
    let (fx, fy, cx, cy) = (k.fx as f64, k.fy as f64, k.cx as f64, k.cy as f64);
    let (width, height) = (k.width as usize, k.height as usize);
    mesh.triangles
        .par_iter()
        .enumerate()
        .filter_map(|(index, tri)| {
            let v = tri.map(|i| cam[i as usize]);
            let bounds = screen_bounds(&v, near, [fx, fy, cx, cy], width, height)?;
            let det = v[0].dot(v[1].cross(v[2]));
            let scale = v[0].length() * v[1].length() * v[2].length();
            if det.is_nan() || det.abs() <= 1e-12 * scale {
                // Degenerate, or seen exactly edge-on: covers no area on screen.
                return None;
            }
            let mut planes = [[0.0; 3]; 3];
            for (i, plane) in planes.iter_mut().enumerate() {
                let n = v[(i + 1) % 3].cross(v[(i + 2) % 3]) / det;
                *plane = [n.x / fx, n.y / fy, n.z - n.x * cx / fx - n.y * cy / fy];
            }
            let owns_edge = planes.map(|p| p[0] > 0.0 || (p[0] == 0.0 && p[1] > 0.0));
            Some(RasterTriangle {
                index: index as u32,
                planes,
                owns_edge,
                bounds,
            })
        })
        .collect()
}

/// The inclusive pixel range covered by the part of the triangle in front of the near plane,
/// clipped to the image; `None` when it is empty.
fn screen_bounds(
    v: &[DVec3; 3],
    near: f64,
    [fx, fy, cx, cy]: [f64; 4],
    width: usize,
    height: usize,
) -> Option<[usize; 4]> {
    let (mut lo_x, mut lo_y) = (f64::INFINITY, f64::INFINITY);
    let (mut hi_x, mut hi_y) = (f64::NEG_INFINITY, f64::NEG_INFINITY);
    let mut add = |p: DVec3| {
        let (x, y) = (fx * p.x / p.z + cx, fy * p.y / p.z + cy);
        lo_x = lo_x.min(x);
        hi_x = hi_x.max(x);
        lo_y = lo_y.min(y);
        hi_y = hi_y.max(y);
    };
    // Sutherland-Hodgman against z >= near: keep front vertices, add edge crossings.
    for i in 0..3 {
        let (a, b) = (v[i], v[(i + 1) % 3]);
        if a.z >= near {
            add(a);
        }
        if (a.z >= near) != (b.z >= near) {
            let t = (near - a.z) / (b.z - a.z);
            add(a + (b - a) * t);
        }
    }
    if !(lo_x <= hi_x && lo_y <= hi_y) || hi_x < 0.0 || hi_y < 0.0 {
        return None;
    }
    if lo_x >= width as f64 || lo_y >= height as f64 {
        return None;
    }
    let clamp = |x: f64, n: usize| x.floor().clamp(0.0, (n - 1) as f64) as usize;
    Some([
        clamp(lo_x, width),
        clamp(lo_y, height),
        clamp(hi_x, width),
        clamp(hi_y, height),
    ])
}
