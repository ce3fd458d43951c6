//! The mesh rasterizer as a backend operation: the CPU backends run the host rasterizer
//! (`raster.rs`, reading the vertices to host memory), the GPU backends its CubeCL twin
//! (`device.rs`), which reads nothing back. The output is tensors on the vertices' device, so
//! that the position map is built there (see [`super::FragmentMaps`]).
//!
//! Visibility carries no gradient (a discrete choice); callers pass vertices without autodiff.

// burn-ndarray is deprecated upstream, but the project's tests run on it.
#![allow(deprecated)]

use std::sync::Arc;

use burn::backend::tensor::FloatTensor;
use burn::backend::{Backend, ExtensionType, Flex, NdArray, TensorMetadata, backend_extension};
use burn::tensor::TensorData;
use prism_core::Camera;

use super::{meshes_from_flat, raster};
use crate::transfer::{to_device, to_host};

/// The triangles of the meshes (shared by every mesh of a batch).
#[derive(Clone, Debug)]
pub struct MeshFaces(pub Arc<[[u32; 3]]>);

/// One camera per mesh; all share one image size.
#[derive(Clone, Debug)]
pub struct MeshCameras(pub Arc<[Camera]>);

/// Per pixel of each camera: the visible face, its perspective-correct barycentrics and depth.
#[derive(ExtensionType, Clone, Debug)]
#[extension_type(fusion: cfg(any(feature = "wgpu", feature = "cuda")))]
pub struct FragmentTensors<B: Backend> {
    /// `[B, H, W]` index of the visible face, `-1` where no face covers the pixel.
    pub faces: FloatTensor<B>,
    /// `[B, H, W, 3]` barycentric weights of the face's corners (0 where no face).
    pub barycentrics: FloatTensor<B>,
    /// `[B, H, W]` camera-space depth (0 where no face).
    pub depth: FloatTensor<B>,
}

/// The mesh rasterizer as a backend operation.
#[backend_extension(
    Flex,
    NdArray,
    Remote,
    Cube: cfg(any(feature = "wgpu", feature = "cuda")),
    Fusion: cfg(any(feature = "wgpu", feature = "cuda"))
)]
pub trait MeshBackend: Backend {
    /// Rasterizes `vertices` `[B, V, 3]` (world space, one mesh per camera) with `faces`.
    #[fusion(meta = crate::mesh::device::rasterize_meta)]
    fn mesh_rasterize(
        vertices: FloatTensor<Self>,
        faces: MeshFaces,
        cameras: MeshCameras,
    ) -> FragmentTensors<Self>;
}

/// The host rasterizer for any backend: the vertices are read to host memory (counted).
fn rasterize_on_host<B: Backend>(
    vertices: FloatTensor<B>,
    faces: &MeshFaces,
    cameras: &MeshCameras,
) -> FragmentTensors<B> {
    let device = vertices.device();
    let batch = vertices.shape()[0];
    let values = to_host::<B>(vertices);
    let meshes = meshes_from_flat(&values, batch);
    let meshes: Vec<&[glam::Vec3]> = meshes.iter().map(Vec::as_slice).collect();
    let k = cameras.0[0].intrinsics;
    let (w, h) = (k.width as usize, k.height as usize);
    let (ids, barycentrics, depth) = raster::rasterize(&meshes, &faces.0, &cameras.0, w, h);
    let ids: Vec<f32> = ids.iter().map(|&f| f as f32).collect();
    let barycentrics: Vec<f32> = barycentrics.into_iter().flatten().collect();
    FragmentTensors {
        faces: to_device::<B>(ids, vec![batch, h, w], &device),
        barycentrics: B::float_from_data(TensorData::new(barycentrics, [batch, h, w, 3]), &device),
        depth: to_device::<B>(depth, vec![batch, h, w], &device),
    }
}

/// The CPU backends: the host rasterizer.
macro_rules! host_mesh {
    ($backend:ty) => {
        impl MeshBackend for $backend {
            fn mesh_rasterize(
                vertices: FloatTensor<Self>,
                faces: MeshFaces,
                cameras: MeshCameras,
            ) -> FragmentTensors<Self> {
                rasterize_on_host::<Self>(vertices, &faces, &cameras)
            }
        }
    };
}

host_mesh!(Flex);
host_mesh!(NdArray);
