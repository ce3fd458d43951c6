//! The cameras of a batch of (source, target) pairs: what the geometry parts need besides the
//! image and ray tensors (placing the body, rasterizing it and splatting points and Gaussians
//! into the target view).

use burn::tensor::{Device, Tensor, TensorData};
use prism_core::Camera;
use prism_data::PrismBatch;

/// The cameras of `B` (source, target) pairs and the background colour that the 3DGS head
/// composites over (the dataset's, `dataset.json`).
///
/// Cameras whose stored image size differs from the tensors' are rescaled to them
/// ([`Camera::rescaled`]), so a dataset's cameras work at any loading resolution.
#[derive(Clone, Debug, PartialEq)]
pub struct Views {
    /// The source camera of each pair.
    pub source: Vec<Camera>,
    /// The target camera of each pair.
    pub target: Vec<Camera>,
    /// RGB background in `[0, 1]`.
    pub background: [f32; 3],
}

impl Views {
    /// The views of `B` pairs.
    pub fn new(source: Vec<Camera>, target: Vec<Camera>, background: [f32; 3]) -> Self {
        Self {
            source,
            target,
            background,
        }
    }

    /// The views of a batch: its source and target cameras, with the dataset's background
    /// (`DatasetMeta::background`).
    pub fn of_batch(batch: &PrismBatch, background: [f32; 3]) -> Self {
        Self::new(
            batch.source_cameras.clone(),
            batch.target_cameras.clone(),
            background,
        )
    }

    /// Number of pairs.
    pub fn len(&self) -> usize {
        self.source.len()
    }

    /// Whether there is no pair.
    pub fn is_empty(&self) -> bool {
        self.source.is_empty()
    }

    /// Checks the views against a batch of `batch` pairs.
    ///
    /// # Panics
    /// If the number of source or target cameras is not `batch`.
    pub(crate) fn check(&self, batch: usize) {
        assert!(
            self.source.len() == batch && self.target.len() == batch,
            "{} source and {} target cameras for a batch of {batch} pairs",
            self.source.len(),
            self.target.len()
        );
    }

    /// The source cameras at `width x height`.
    pub(crate) fn source_at(&self, width: usize, height: usize) -> Vec<Camera> {
        at_size(&self.source, width, height)
    }

    /// The target cameras at `width x height`.
    pub(crate) fn target_at(&self, width: usize, height: usize) -> Vec<Camera> {
        at_size(&self.target, width, height)
    }
}

/// `cameras` rescaled to `width x height` where their size differs.
fn at_size(cameras: &[Camera], width: usize, height: usize) -> Vec<Camera> {
    cameras
        .iter()
        .map(|c| {
            let k = c.intrinsics;
            if (k.width as usize, k.height as usize) == (width, height) {
                *c
            } else {
                c.rescaled(width as u32, height as u32)
            }
        })
        .collect()
}

/// The camera centres as a `[B, 3, 1, 1]` tensor (to broadcast over ray maps).
pub(crate) fn centres(cameras: &[Camera], device: &Device) -> Tensor<4> {
    let data: Vec<f32> = cameras.iter().flat_map(|c| c.center().to_array()).collect();
    Tensor::from_data(TensorData::new(data, [cameras.len(), 3, 1, 1]), device)
}

/// Each camera's mean focal length `(fx + fy) / 2` in pixels, `[B, 1, 1, 1]`.
pub(crate) fn focals(cameras: &[Camera], device: &Device) -> Tensor<4> {
    let data: Vec<f32> = cameras
        .iter()
        .map(|c| 0.5 * (c.intrinsics.fx + c.intrinsics.fy))
        .collect();
    Tensor::from_data(TensorData::new(data, [cameras.len(), 1, 1, 1]), device)
}

/// The world points `o + t d` of per-pixel ray distances `t` `[B, 1, H, W]` along the unit
/// ray directions `d`, the first three channels of Plücker rays `[B, 6, H, W]`, from the
/// camera centres `o`: `[B, 3, H, W]`.
pub(crate) fn points_along_rays(
    rays: &Tensor<4>,
    distance: Tensor<4>,
    cameras: &[Camera],
) -> Tensor<4> {
    let directions = rays.clone().narrow(1, 0, 3);
    centres(cameras, &rays.device()) + directions * distance
}
