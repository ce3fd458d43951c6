//! The mesh rasterizer on the GPU: CubeCL kernels computing what the host rasterizer
//! (`raster.rs`) computes, in `f32` where the host uses `f64` (pixels on a shared edge may go
//! to the other face; the surface position they interpolate is the same).
//!
//! `project_faces_kernel` projects every triangle of every mesh once (screen corners, inverse
//! depths, signed area, pixel bounds); `raster_kernel` runs one cube per 16x16 tile, stages the
//! triangles in chunks of 256 in shared memory, compacted to those whose bounds meet the tile
//! (face order kept), and each pixel keeps the nearest covering face, the first in face order
//! on a tie, as the host does.

use burn::backend::fusion::custom::TensorSpec;
use burn::tensor::{DType, Shape, TensorData};
use burn_cubecl::CubeBackend;
use burn_cubecl::ops::numeric::empty_device_dtype;
use burn_cubecl::tensor::CubeTensor;
use cubecl::prelude::*;

use super::op::{FragmentTensors, FragmentTensorsMetadata, MeshBackend, MeshCameras, MeshFaces};
use super::raster::NEAR_PLANE;
use crate::launch::{PINHOLE, cameras_tensor, elementwise, prepared};
use crate::splat::TILE_SIZE as TILE;
use crate::tiles::{compact, tile_pixel};

/// Floats per projected triangle: `s0x s0y s1x s1y s2x s2y iz0 iz1 iz2 area x0 y0 x1 y1 valid`.
const TRIANGLE: usize = 15;
/// The triangles staged per chunk: one per unit of a tile's cube.
const BLOCK: usize = TILE * TILE;

/// The output shapes of [`MeshBackend::mesh_rasterize`].
pub(crate) fn rasterize_meta(
    vertices: &TensorSpec,
    _faces: &MeshFaces,
    cameras: &MeshCameras,
) -> FragmentTensorsMetadata {
    let b = vertices.shape[0];
    let k = cameras.0[0].intrinsics;
    let (h, w) = (k.height as usize, k.width as usize);
    let spec = |shape: Vec<usize>| TensorSpec::new(Shape::from(shape), DType::F32);
    FragmentTensorsMetadata {
        faces: spec(vec![b, h, w]),
        barycentrics: spec(vec![b, h, w, 3]),
        depth: spec(vec![b, h, w]),
    }
}

/// One corner of a triangle in the camera: screen position, inverse depth, and whether it is
/// finite and in front of the near plane.
#[derive(CubeType, Clone, Copy)]
struct Corner {
    sx: f32,
    sy: f32,
    iz: f32,
    ok: bool,
}

#[cube]
fn corner(vertices: &Tensor<f32>, views: &Tensor<f32>, v: usize, vb: usize) -> Corner {
    let (px, py, pz) = (vertices[3 * v], vertices[3 * v + 1], vertices[3 * v + 2]);
    let x = views[vb] * px + views[vb + 1] * py + views[vb + 2] * pz + views[vb + 9];
    let y = views[vb + 3] * px + views[vb + 4] * py + views[vb + 5] * pz + views[vb + 10];
    let z = views[vb + 6] * px + views[vb + 7] * py + views[vb + 8] * pz + views[vb + 11];
    // Finite: a NaN or an infinity fails the comparison.
    let finite = f32::abs(x) <= f32::MAX && f32::abs(y) <= f32::MAX && f32::abs(z) <= f32::MAX;
    Corner {
        sx: views[vb + 12] * x / z + views[vb + 14],
        sy: views[vb + 13] * y / z + views[vb + 15],
        iz: 1.0 / z,
        ok: finite && z >= NEAR_PLANE,
    }
}

/// `edge(a, b, p)`: twice the signed area of `a b p` (host `edge`).
#[cube]
fn edge(ax: f32, ay: f32, bx: f32, by: f32, px: f32, py: f32) -> f32 {
    (bx - ax) * (py - ay) - (by - ay) * (px - ax)
}

/// Projects triangle `f` of mesh `b`, one unit per `(b, f)` (host `project`).
#[cube(launch)]
fn project_faces_kernel(
    vertices: &Tensor<f32>,
    faces: &Tensor<u32>,
    views: &Tensor<f32>,
    out: &mut Tensor<f32>,
    num_vertices: u32,
    num_faces: u32,
    width: u32,
    height: u32,
) {
    let pos = ABSOLUTE_POS;
    if pos >= out.len() / TRIANGLE {
        terminate!();
    }
    let nf = num_faces as usize;
    let (b, f) = (pos / nf, pos % nf);
    let base = b * num_vertices as usize;
    let vb = b * PINHOLE;
    let c0 = corner(vertices, views, base + faces[3 * f] as usize, vb);
    let c1 = corner(vertices, views, base + faces[3 * f + 1] as usize, vb);
    let c2 = corner(vertices, views, base + faces[3 * f + 2] as usize, vb);
    let area = edge(c0.sx, c0.sy, c1.sx, c1.sy, c2.sx, c2.sy);
    let lo_x = f32::min(f32::min(c0.sx, c1.sx), c2.sx);
    let hi_x = f32::max(f32::max(c0.sx, c1.sx), c2.sx);
    let lo_y = f32::min(f32::min(c0.sy, c1.sy), c2.sy);
    let hi_y = f32::max(f32::max(c0.sy, c1.sy), c2.sy);
    let x0 = f32::max(f32::ceil(lo_x - 0.5), 0.0);
    let y0 = f32::max(f32::ceil(lo_y - 0.5), 0.0);
    let x1 = f32::min(f32::floor(hi_x - 0.5), f32::cast_from(width) - 1.0);
    let y1 = f32::min(f32::floor(hi_y - 0.5), f32::cast_from(height) - 1.0);
    let valid = c0.ok && c1.ok && c2.ok && area != 0.0 && x0 <= x1 && y0 <= y1;
    let o = pos * TRIANGLE;
    out[o] = c0.sx;
    out[o + 1] = c0.sy;
    out[o + 2] = c1.sx;
    out[o + 3] = c1.sy;
    out[o + 4] = c2.sx;
    out[o + 5] = c2.sy;
    out[o + 6] = c0.iz;
    out[o + 7] = c1.iz;
    out[o + 8] = c2.iz;
    out[o + 9] = area;
    out[o + 10] = x0;
    out[o + 11] = y0;
    out[o + 12] = x1;
    out[o + 13] = y1;
    out[o + 14] = select(valid, 1.0f32, 0.0f32);
}

/// The nearest covering face per pixel, one cube per tile (host `render_band`).
#[cube(launch)]
fn raster_kernel(
    triangles: &Tensor<f32>,
    out_faces: &mut Tensor<f32>,
    out_barycentrics: &mut Tensor<f32>,
    out_depth: &mut Tensor<f32>,
    num_faces: u32,
    width: u32,
    height: u32,
) {
    let here = tile_pixel(width, height);
    let (b, inside, px, py) = (here.b, here.inside, here.px, here.py);
    let (qx, qy) = (px + 0.5, py + 0.5);
    let tile_x0 = f32::cast_from(CUBE_POS_X * TILE as u32);
    let tile_y0 = f32::cast_from(CUBE_POS_Y * TILE as u32);
    let last = (TILE - 1) as f32;
    let t = UNIT_POS as usize;
    let nf = num_faces as usize;
    let mut scan = Shared::<[u32]>::new_slice(BLOCK);
    let mut ids = Shared::<[u32]>::new_slice(BLOCK);
    let mut staged = Shared::<[f32]>::new_slice(BLOCK * TRIANGLE);
    let mut best = 0.0f32;
    // The visible face plus one (0: none).
    let mut face = 0u32;
    let mut w0 = 0.0f32;
    let mut w1 = 0.0f32;
    let mut w2 = 0.0f32;
    let chunks = nf.div_ceil(BLOCK);
    for chunk in 0..chunks {
        let f = chunk * BLOCK + t;
        let mut hit = false;
        let o = (b * nf + f) * TRIANGLE;
        if f < nf {
            hit = triangles[o + 14] > 0.5
                && triangles[o + 10] <= tile_x0 + last
                && triangles[o + 12] >= tile_x0
                && triangles[o + 11] <= tile_y0 + last
                && triangles[o + 13] >= tile_y0;
        }
        let slot = compact(&mut scan, hit, BLOCK);
        if hit {
            let at = (slot - 1) as usize;
            ids[at] = f as u32;
            #[unroll]
            for k in 0..TRIANGLE {
                staged[at * TRIANGLE + k] = triangles[o + k];
            }
        }
        sync_cube();
        let hits = scan[BLOCK - 1] as usize;
        for s in 0..hits {
            let o = s * TRIANGLE;
            if inside
                && px >= staged[o + 10]
                && px <= staged[o + 12]
                && py >= staged[o + 11]
                && py <= staged[o + 13]
            {
                let (s0x, s0y) = (staged[o], staged[o + 1]);
                let (s1x, s1y) = (staged[o + 2], staged[o + 3]);
                let (s2x, s2y) = (staged[o + 4], staged[o + 5]);
                let inv_area = 1.0 / staged[o + 9];
                let l0 = edge(s1x, s1y, s2x, s2y, qx, qy) * inv_area;
                let l1 = edge(s2x, s2y, s0x, s0y, qx, qy) * inv_area;
                let l2 = edge(s0x, s0y, s1x, s1y, qx, qy) * inv_area;
                if l0 >= 0.0 && l1 >= 0.0 && l2 >= 0.0 {
                    let a = l0 * staged[o + 6];
                    let c = l1 * staged[o + 7];
                    let d = l2 * staged[o + 8];
                    let inv_depth = a + c + d;
                    if inv_depth > best {
                        best = inv_depth;
                        face = ids[s] + 1;
                        w0 = a / inv_depth;
                        w1 = c / inv_depth;
                        w2 = d / inv_depth;
                    }
                }
            }
        }
        sync_cube();
    }
    if inside {
        let pix = b * here.hw + here.pix;
        out_faces[pix] = f32::cast_from(face) - 1.0;
        out_barycentrics[3 * pix] = w0;
        out_barycentrics[3 * pix + 1] = w1;
        out_barycentrics[3 * pix + 2] = w2;
        let mut depth = 0.0f32;
        if best > 0.0 {
            depth = 1.0 / best;
        }
        out_depth[pix] = depth;
    }
}

impl MeshBackend for CubeBackend {
    fn mesh_rasterize(
        vertices: CubeTensor,
        faces: MeshFaces,
        cameras: MeshCameras,
    ) -> FragmentTensors<Self> {
        let vertices = prepared(vertices);
        let shape = vertices.meta.shape().clone();
        let (b, v) = (shape[0], shape[1]);
        let (client, device) = (vertices.client.clone(), vertices.device.clone());
        let k = cameras.0[0].intrinsics;
        let (w, h) = (k.width as usize, k.height as usize);
        let nf = faces.0.len();
        let flat: Vec<u32> = faces.0.iter().flatten().copied().collect();
        let faces_tensor =
            <CubeBackend as burn::backend::ops::IntTensorOps<CubeBackend>>::int_from_data(
                TensorData::new(flat, [nf, 3]),
                &device,
            );
        let views = cameras_tensor(&cameras.0, |_| Vec::new(), &device);
        let empty = |shape: Vec<usize>| {
            empty_device_dtype(
                client.clone(),
                device.clone(),
                Shape::from(shape),
                DType::F32,
            )
        };
        let triangles = empty(vec![b, nf, TRIANGLE]);
        let (count, dim) = elementwise(&triangles, b * nf);
        project_faces_kernel::launch(
            &client,
            count,
            dim,
            vertices.into_tensor_arg(),
            faces_tensor.into_tensor_arg(),
            views.into_tensor_arg(),
            triangles.clone().into_tensor_arg(),
            v as u32,
            nf as u32,
            w as u32,
            h as u32,
        );
        let out: FragmentTensors<Self> = FragmentTensors {
            faces: empty(vec![b, h, w]),
            barycentrics: empty(vec![b, h, w, 3]),
            depth: empty(vec![b, h, w]),
        };
        raster_kernel::launch(
            &client,
            CubeCount::Static(w.div_ceil(TILE) as u32, h.div_ceil(TILE) as u32, b as u32),
            CubeDim::new_2d(TILE as u32, TILE as u32),
            triangles.into_tensor_arg(),
            out.faces.clone().into_tensor_arg(),
            out.barycentrics.clone().into_tensor_arg(),
            out.depth.clone().into_tensor_arg(),
            nf as u32,
            w as u32,
            h as u32,
        );
        out
    }
}
