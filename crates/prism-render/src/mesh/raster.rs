//! The host triangle rasterizer behind [`super::rasterize`]: visibility only (the nearest
//! triangle at each pixel centre and its barycentric coordinates), parallel over bands of rows.
//!
//! Per camera, every vertex is moved to camera space (`p = W v + t`, OpenCV axes) and projected
//! to continuous pixel coordinates `(u, v) = (fx x / z + cx, fy y / z + cy)`. A pixel centre
//! `q = (x + 0.5, y + 0.5)` is inside a triangle when its three screen-space edge functions
//! `e_i(q)` (twice the signed areas of the sub-triangles opposite each vertex) share the sign of
//! the triangle's area `A = e_0 + e_1 + e_2`. The screen barycentrics `l_i = e_i / A` are
//! made perspective-correct, `b_i = (l_i / z_i) / sum_j (l_j / z_j)`, so that `sum_i b_i v_i` is
//! the 3D point of the triangle on the pixel's ray, at camera depth `z = 1 / sum_j (l_j / z_j)`.
//! The nearest such point wins. Both orientations are drawn (no back-face culling).

use glam::{DVec3, Mat3, Vec3};
use prism_core::Camera;
use rayon::prelude::*;

/// Rows of one unit of parallel work.
pub const BAND_ROWS: usize = 16;

/// Triangles with a vertex closer than this to the camera plane (metres along its axis) are
/// not drawn.
pub const NEAR_PLANE: f32 = 0.01;

/// One triangle projected into one camera.
#[derive(Clone, Copy, Debug)]
struct Projected {
    /// Screen positions of the three corners (pixels, continuous).
    screen: [[f64; 2]; 3],
    /// `1 / z` of the three corners.
    inv_z: [f64; 3],
    /// Twice the signed screen area.
    area: f64,
    /// Inclusive pixel bounds `[x0, y0, x1, y1]` whose centres may be inside.
    bounds: [usize; 4],
    /// Index of the triangle in the mesh.
    face: u32,
}

/// A camera's rotation, translation and intrinsics, in the form the rasterizer uses.
struct View {
    rotation: Mat3,
    translation: Vec3,
    intrinsics: [f64; 4],
    width: usize,
    height: usize,
}

impl View {
    fn new(camera: &Camera) -> Self {
        let w2c = camera.w2c();
        let k = camera.intrinsics;
        Self {
            rotation: Mat3::from_mat4(w2c),
            translation: w2c.w_axis.truncate(),
            intrinsics: [k.fx as f64, k.fy as f64, k.cx as f64, k.cy as f64],
            width: k.width as usize,
            height: k.height as usize,
        }
    }
}

/// The 2D edge function `(b - a) x (p - a)`.
fn edge(a: [f64; 2], b: [f64; 2], p: [f64; 2]) -> f64 {
    (b[0] - a[0]) * (p[1] - a[1]) - (b[1] - a[1]) * (p[0] - a[0])
}

/// Projects the triangles of one mesh into `view`, dropping those that cannot cover a pixel
/// centre (behind the near plane, degenerate, or outside the image).
fn project(vertices: &[Vec3], faces: &[[u32; 3]], view: &View) -> Vec<Projected> {
    let [fx, fy, cx, cy] = view.intrinsics;
    let camera_space: Vec<DVec3> = vertices
        .iter()
        .map(|&v| (view.rotation * v + view.translation).as_dvec3())
        .collect();
    let near = f64::from(NEAR_PLANE);
    faces
        .iter()
        .enumerate()
        .filter_map(|(f, tri)| {
            let p = tri.map(|i| camera_space[i as usize]);
            if p.iter().any(|q| q.z < near || !q.is_finite()) {
                return None;
            }
            let screen = p.map(|q| [fx * q.x / q.z + cx, fy * q.y / q.z + cy]);
            let area = edge(screen[0], screen[1], screen[2]);
            if area == 0.0 {
                return None;
            }
            let lo = |axis: usize| screen.iter().map(|s| s[axis]).fold(f64::INFINITY, f64::min);
            let hi = |axis: usize| {
                screen
                    .iter()
                    .map(|s| s[axis])
                    .fold(f64::NEG_INFINITY, f64::max)
            };
            // Pixel x is covered only if lo <= x + 0.5 <= hi.
            let x0 = (lo(0) - 0.5).ceil().max(0.0);
            let y0 = (lo(1) - 0.5).ceil().max(0.0);
            let x1 = (hi(0) - 0.5).floor().min(view.width as f64 - 1.0);
            let y1 = (hi(1) - 0.5).floor().min(view.height as f64 - 1.0);
            if !(x0 <= x1 && y0 <= y1) {
                return None;
            }
            Some(Projected {
                screen,
                inv_z: p.map(|q| 1.0 / q.z),
                area,
                bounds: [x0 as usize, y0 as usize, x1 as usize, y1 as usize],
                face: f as u32,
            })
        })
        .collect()
}

/// The output of one band: per pixel the face (`-1` for none), barycentrics and depth.
struct BandOut<'a> {
    faces: &'a mut [i32],
    barycentrics: &'a mut [[f32; 3]],
    depth: &'a mut [f32],
}

/// Rasterizes the rows `y0..y0 + rows` of one camera: `bin` lists the triangles that may cover
/// them.
fn render_band(
    triangles: &[Projected],
    bin: &[u32],
    y0: usize,
    rows: usize,
    width: usize,
    out: BandOut<'_>,
) {
    // Largest `1 / z` so far (0: nothing yet).
    let mut best = vec![0.0f64; rows * width];
    for &t in bin {
        let tri = &triangles[t as usize];
        let [x0, ty0, x1, ty1] = tri.bounds;
        let (r0, r1) = (ty0.max(y0), ty1.min(y0 + rows - 1));
        let [s0, s1, s2] = tri.screen;
        let inv_area = 1.0 / tri.area;
        for y in r0..=r1 {
            let py = y as f64 + 0.5;
            for x in x0..=x1 {
                let q = [x as f64 + 0.5, py];
                let l0 = edge(s1, s2, q) * inv_area;
                let l1 = edge(s2, s0, q) * inv_area;
                let l2 = edge(s0, s1, q) * inv_area;
                if l0 < 0.0 || l1 < 0.0 || l2 < 0.0 {
                    continue;
                }
                let w = [l0 * tri.inv_z[0], l1 * tri.inv_z[1], l2 * tri.inv_z[2]];
                let inv_depth = w[0] + w[1] + w[2];
                let i = (y - y0) * width + x;
                if inv_depth <= best[i] {
                    continue;
                }
                best[i] = inv_depth;
                out.faces[i] = tri.face as i32;
                out.barycentrics[i] = w.map(|v| (v / inv_depth) as f32);
                out.depth[i] = (1.0 / inv_depth) as f32;
            }
        }
    }
}

/// Rasterizes `meshes[b]` (world-space vertices sharing `faces`) into `cameras[b]`, all of
/// `width x height`; returns per pixel (batch-major, then row-major) the visible face (`-1`
/// for none), its perspective-correct barycentrics and the camera depth (0 for none).
pub fn rasterize(
    meshes: &[&[Vec3]],
    faces: &[[u32; 3]],
    cameras: &[Camera],
    width: usize,
    height: usize,
) -> (Vec<i32>, Vec<[f32; 3]>, Vec<f32>) {
    let plane = width * height;
    let n = meshes.len() * plane;
    let mut out_faces = vec![-1i32; n];
    let mut out_bary = vec![[0.0f32; 3]; n];
    let mut out_depth = vec![0.0f32; n];
    let bands = height.div_ceil(BAND_ROWS);

    // Projection and binning per camera, in parallel.
    let setups: Vec<(Vec<Projected>, Vec<Vec<u32>>)> = meshes
        .par_iter()
        .zip(cameras.par_iter())
        .map(|(vertices, camera)| {
            let view = View::new(camera);
            let triangles = project(vertices, faces, &view);
            let mut bins = vec![Vec::new(); bands];
            for (t, tri) in triangles.iter().enumerate() {
                for bin in &mut bins[tri.bounds[1] / BAND_ROWS..=tri.bounds[3] / BAND_ROWS] {
                    bin.push(t as u32);
                }
            }
            (triangles, bins)
        })
        .collect();

    // Bands of every camera, in parallel.
    let band_len = BAND_ROWS * width;
    let mut work = Vec::with_capacity(meshes.len() * bands);
    for (b, ((faces_out, bary_out), depth_out)) in out_faces
        .chunks_mut(plane)
        .zip(out_bary.chunks_mut(plane))
        .zip(out_depth.chunks_mut(plane))
        .enumerate()
    {
        for (band, ((f, bc), d)) in faces_out
            .chunks_mut(band_len)
            .zip(bary_out.chunks_mut(band_len))
            .zip(depth_out.chunks_mut(band_len))
            .enumerate()
        {
            work.push((
                b,
                band,
                BandOut {
                    faces: f,
                    barycentrics: bc,
                    depth: d,
                },
            ));
        }
    }
    work.into_par_iter().for_each(|(b, band, out)| {
        let (triangles, bins) = &setups[b];
        let rows = out.faces.len() / width;
        render_band(triangles, &bins[band], band * BAND_ROWS, rows, width, out);
    });
    (out_faces, out_bary, out_depth)
}
