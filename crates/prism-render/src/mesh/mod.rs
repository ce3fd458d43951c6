//! Mesh rasterization for position maps (paper Sec. 3.2, the SMPL-X branch): which triangle
//! of a mesh is visible at each pixel of a camera, with its barycentric coordinates, and the
//! differentiable interpolation of per-vertex attributes (such as canonical rest-pose
//! positions) over those pixels.
//!
//! Visibility ([`rasterize`]) runs on the host and carries no gradient: it is a function of the
//! posed mesh only through a discrete choice. [`Fragments::interpolate`] then blends vertex
//! attributes with the (constant) barycentrics by tensor gathers, so that gradients reach the
//! attributes: `A(pixel) = sum_i b_i a_{f_i}` over the corners `f_i` of the visible face.

#[cfg(any(feature = "wgpu", feature = "cuda"))]
mod device;
pub mod op;
mod raster;

use std::sync::Arc;

use burn::backend::Dispatch;
use burn::tensor::{Device, Int, Tensor, TensorData};
use glam::Vec3;
use prism_core::Camera;
use prism_core::axes::permute;

pub use raster::{BAND_ROWS, NEAR_PLANE};

use crate::RenderError;
use crate::image_size::image_size;
use op::{MeshBackend, MeshCameras, MeshFaces};

/// What [`rasterize`] sees at every pixel centre of `B` cameras of `H x W` pixels. Buffers are
/// batch-major, then row-major (`(b * H + y) * W + x`).
#[derive(Clone, Debug, PartialEq)]
pub struct Fragments {
    /// `B`, the number of cameras (one mesh each).
    pub batch: usize,
    /// `W`, pixels.
    pub width: usize,
    /// `H`, pixels.
    pub height: usize,
    /// The visible triangle at each pixel, `-1` where the ray misses the mesh.
    pub faces: Vec<i32>,
    /// Perspective-correct barycentrics of the visible point (`sum_i b_i v_i` is the 3D point on
    /// the pixel's ray); zeros where nothing is visible.
    pub barycentrics: Vec<[f32; 3]>,
    /// Camera-space depth `z` of the visible point, 0 where nothing is visible.
    pub depth: Vec<f32>,
}

/// Rasterizes mesh `b` (world-space `meshes[b]`, triangles `faces` shared by all) into
/// `cameras[b]`: the nearest triangle through each pixel centre `(x + 0.5, y + 0.5)` and its
/// barycentrics. Triangles with a corner closer than [`NEAR_PLANE`] to the camera plane are
/// skipped; both orientations are drawn. Parallel over bands of [`BAND_ROWS`] rows.
///
/// # Errors
/// [`RenderError::Input`] when the number of meshes and cameras differ, the cameras do not
/// share one non-empty image size, the meshes differ in vertex count or a face indexes past the
/// vertices.
pub fn rasterize(
    meshes: &[&[Vec3]],
    faces: &[[u32; 3]],
    cameras: &[Camera],
) -> Result<Fragments, RenderError> {
    if meshes.len() != cameras.len() {
        return Err(RenderError::Input(format!(
            "{} meshes for {} cameras",
            meshes.len(),
            cameras.len()
        )));
    }
    let (w, h) = image_size(cameras)?;
    let v = meshes[0].len();
    if meshes.iter().any(|m| m.len() != v) {
        return Err(RenderError::Input(
            "the meshes of a batch must have the same vertex count".into(),
        ));
    }
    check_faces(faces, v)?;
    let (width, height) = (w as usize, h as usize);
    let (faces_out, barycentrics, depth) = raster::rasterize(meshes, faces, cameras, width, height);
    Ok(Fragments {
        batch: meshes.len(),
        width,
        height,
        faces: faces_out,
        barycentrics,
        depth,
    })
}

impl Fragments {
    /// The visible face at pixel `(x, y)` of camera `b`.
    pub fn face_at(&self, b: usize, x: usize, y: usize) -> Option<usize> {
        let f = self.faces[(b * self.height + y) * self.width + x];
        (f >= 0).then_some(f as usize)
    }

    /// Covered pixels: `[B, 1, H, W]`, 1 where a face is visible, else 0.
    pub fn mask(&self, device: &Device) -> Tensor<4> {
        let data: Vec<f32> = self
            .faces
            .iter()
            .map(|&f| if f >= 0 { 1.0 } else { 0.0 })
            .collect();
        Tensor::from_data(
            TensorData::new(data, [self.batch, 1, self.height, self.width]),
            device,
        )
    }

    /// Interpolates per-vertex attributes over the visible faces: `attributes` `[B, V, C]`
    /// (mesh `b`'s vertices, with the `faces` given to [`rasterize`]) to `[B, C, H, W]`,
    /// `A(pixel) = sum_i b_i a_{f_i}`, zero where nothing is visible. Differentiable in
    /// `attributes` (gathers with constant weights).
    ///
    /// # Panics
    /// If `attributes` does not have `B` batch elements or a face indexes past `V`.
    pub fn interpolate(&self, attributes: Tensor<3>, faces: &[[u32; 3]]) -> Tensor<4> {
        let [b, v, c] = attributes.dims();
        assert_eq!(
            b, self.batch,
            "interpolate: {b} meshes for {} cameras",
            self.batch
        );
        let plane = self.width * self.height;
        let n = b * plane;
        let mut index = Vec::with_capacity(3 * n);
        let mut weight = Vec::with_capacity(3 * n);
        for (pixel, (&f, bary)) in self.faces.iter().zip(&self.barycentrics).enumerate() {
            let base = (pixel / plane * v) as i64;
            if f < 0 {
                index.extend([base; 3]);
                weight.extend([0.0f32; 3]);
                continue;
            }
            let corners = faces[f as usize];
            assert!(
                corners.iter().all(|&i| (i as usize) < v),
                "interpolate: face {f} indexes past {v} vertices"
            );
            index.extend(corners.map(|i| base + i64::from(i)));
            weight.extend(bary);
        }
        let device = attributes.device();
        let index = Tensor::<1, Int>::from_data(TensorData::new(index, [3 * n]), &device);
        let weight = Tensor::<2>::from_data(TensorData::new(weight, [3 * n, 1]), &device);
        let gathered = attributes.reshape([b * v, c]).select(0, index) * weight;
        permute(
            gathered
                .reshape([n, 3, c])
                .sum_dim(1)
                .reshape([b, self.height, self.width, c]),
            [0, 3, 1, 2],
        )
    }
}

/// Convenience for one batch given as flat `[B, V, 3]` host values: splits it into meshes.
pub fn meshes_from_flat(values: &[f32], batch: usize) -> Vec<Vec<Vec3>> {
    let per = values.len() / batch.max(1);
    values
        .chunks(per.max(1))
        .take(batch)
        .map(|m| {
            m.chunks_exact(3)
                .map(|p| Vec3::new(p[0], p[1], p[2]))
                .collect()
        })
        .collect()
}

/// The fragments of [`rasterize_maps`] as tensors on the vertices' device (no autodiff: the
/// visibility is a discrete choice).
#[derive(Clone, Debug)]
pub struct FragmentMaps {
    /// `[B, H, W]` index of the visible face, `-1` where none.
    pub faces: Tensor<3>,
    /// `[B, H, W, 3]` perspective-correct barycentrics of the visible face's corners.
    pub barycentrics: Tensor<4>,
    /// `[B, H, W]` camera-space depth, 0 where no face.
    pub depth: Tensor<3>,
}

/// Rasterizes one mesh per camera given as a tensor `[B, V, 3]` of world-space vertices,
/// on the vertices' device: the host rasterizer on the CPU backends, the CubeCL one on the GPU
/// backends (which reads nothing back). The vertices' gradient, if any, is not followed.
///
/// # Errors
/// On a camera count that is not the batch size, cameras of different image sizes, an empty
/// image or a face indexing past the vertices.
pub fn rasterize_maps(
    vertices: Tensor<3>,
    faces: &[[u32; 3]],
    cameras: &[Camera],
) -> Result<FragmentMaps, RenderError> {
    let [b, v, _] = vertices.dims();
    if b != cameras.len() {
        return Err(RenderError::Input(format!(
            "{b} meshes for {} cameras",
            cameras.len()
        )));
    }
    image_size(cameras)?;
    check_faces(faces, v)?;
    let out = <Dispatch as MeshBackend>::mesh_rasterize(
        vertices.inner().into_dispatch(),
        MeshFaces(Arc::from(faces)),
        MeshCameras(Arc::from(cameras)),
    );
    Ok(FragmentMaps {
        faces: Tensor::from_dispatch(out.faces),
        barycentrics: Tensor::from_dispatch(out.barycentrics),
        depth: Tensor::from_dispatch(out.depth),
    })
}

impl FragmentMaps {
    /// `[B, 1, H, W]`: 1 where a face is visible, else 0.
    pub fn mask(&self) -> Tensor<4> {
        self.faces
            .clone()
            .greater_equal_elem(0.0)
            .float()
            .unsqueeze_dim(1)
    }

    /// Interpolates per-vertex `attributes` `[B, V, C]` over the visible faces: `[B, C, H, W]`,
    /// `A(pixel) = sum_i b_i a_{f_i}`, zero where no face is visible; differentiable in the
    /// attributes (the barycentrics are constants).
    pub fn interpolate(&self, attributes: Tensor<3>, faces: &[[u32; 3]]) -> Tensor<4> {
        let [b, v, c] = attributes.dims();
        let [fb, h, w] = self.faces.dims();
        assert_eq!(b, fb, "interpolate: {b} meshes for {fb} cameras");
        let n = b * h * w;
        let device = self.faces.device();
        let table: Vec<i64> = faces.iter().flatten().map(|&i| i64::from(i)).collect();
        let table = Tensor::<2, Int>::from_data(TensorData::new(table, [faces.len(), 3]), &device);
        let ids = self.faces.clone().clamp_min(0.0).int().reshape([n]);
        let base = Tensor::<1, Int>::arange(0..b as i64, &device)
            .mul_scalar(v as i64)
            .reshape([b, 1])
            .repeat_dim(1, h * w)
            .reshape([n, 1]);
        let index = (table.select(0, ids) + base).reshape([3 * n]);
        let visible = self.mask().reshape([b, h, w, 1]);
        let weight = (self.barycentrics.clone() * visible).reshape([3 * n, 1]);
        permute(
            (attributes.reshape([b * v, c]).select(0, index) * weight)
                .reshape([n, 3, c])
                .sum_dim(1)
                .reshape([b, h, w, c]),
            [0, 3, 1, 2],
        )
    }
}

/// Checks that every face indexes one of `vertices` vertices.
///
/// # Errors
/// [`RenderError::Input`] naming the first face that does not.
pub(crate) fn check_faces(faces: &[[u32; 3]], vertices: usize) -> Result<(), RenderError> {
    match faces
        .iter()
        .find(|f| f.iter().any(|&i| i as usize >= vertices))
    {
        Some(f) => Err(RenderError::Input(format!(
            "face {f:?} indexes past the {vertices} vertices"
        ))),
        None => Ok(()),
    }
}
