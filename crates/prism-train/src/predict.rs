//! Novel views from a trained model: the one place where evaluation and inference call the
//! model's forward pass.

use burn::tensor::{Device, Tensor, TensorData};
use image::Rgb32FImage;
use prism_core::Camera;
use prism_core::rays::plucker_rays;
use prism_data::PrismBatch;
use prism_data::batch::rgb_chw;
use prism_model::{Prism, PrismOutput, Views};

/// A batch of `B` (source, target) pairs as the model takes them, with their cameras.
#[derive(Clone, Debug)]
pub struct Pairs {
    /// Source images `[B, 3, H, W]` in [0, 1].
    pub source_image: Tensor<4>,
    /// Source Plücker rays `[B, 6, H, W]`.
    pub source_rays: Tensor<4>,
    /// Target Plücker rays `[B, 6, H, W]`.
    pub target_rays: Tensor<4>,
    /// The source camera of each pair.
    pub source_cameras: Vec<Camera>,
    /// The target camera of each pair.
    pub target_cameras: Vec<Camera>,
    /// The background the images are composited on, RGB in [0, 1].
    pub background: [f32; 3],
}

impl Pairs {
    /// The pairs of a dataset batch, whose images are composited on `background`.
    pub fn of_batch(batch: &PrismBatch, background: [f32; 3]) -> Self {
        Self {
            source_image: batch.source_image.clone(),
            source_rays: batch.source_rays.clone(),
            target_rays: batch.target_rays.clone(),
            source_cameras: batch.source_cameras.clone(),
            target_cameras: batch.target_cameras.clone(),
            background,
        }
    }

    /// One source view (an image at its camera's size) paired with each of `targets` (cameras
    /// of the same image size).
    ///
    /// # Panics
    /// If `targets` is empty or the sizes differ.
    pub fn from_source(
        image: &Rgb32FImage,
        source: Camera,
        targets: &[Camera],
        background: [f32; 3],
        device: &Device,
    ) -> Self {
        let (w, h) = (image.width() as usize, image.height() as usize);
        assert_eq!(
            (
                source.intrinsics.width as usize,
                source.intrinsics.height as usize
            ),
            (w, h),
            "the source camera must match the source image"
        );
        let b = targets.len();
        let one = Tensor::<4>::from_data(TensorData::new(rgb_chw(image), [1, 3, h, w]), device);
        let source_cameras = vec![source; b];
        Self {
            source_image: one.repeat_dim(0, b),
            source_rays: plucker_rays(&source_cameras[..1], device).repeat_dim(0, b),
            target_rays: plucker_rays(targets, device),
            source_cameras,
            target_cameras: targets.to_vec(),
            background,
        }
    }

    /// Number of pairs.
    pub fn len(&self) -> usize {
        self.source_cameras.len()
    }

    /// Whether there is no pair.
    pub fn is_empty(&self) -> bool {
        self.source_cameras.is_empty()
    }

    /// Pairs `start..start + len`.
    pub fn slice(&self, start: usize, len: usize) -> Self {
        Self {
            source_image: self.source_image.clone().narrow(0, start, len),
            source_rays: self.source_rays.clone().narrow(0, start, len),
            target_rays: self.target_rays.clone().narrow(0, start, len),
            source_cameras: self.source_cameras[start..start + len].to_vec(),
            target_cameras: self.target_cameras[start..start + len].to_vec(),
            background: self.background,
        }
    }
}

impl Pairs {
    /// The cameras and background of the pairs, as the geometry parts take them.
    pub fn views(&self) -> Views {
        Views::new(
            self.source_cameras.clone(),
            self.target_cameras.clone(),
            self.background,
        )
    }
}

/// The full forward pass of `model` on `pairs` (`model` is an inference model: on a device
/// without autodiff, or `Module::valid`). With a 3DGS head the output holds its Gaussians.
pub fn forward_pairs(model: &Prism, pairs: &Pairs) -> PrismOutput {
    model.forward_views(
        pairs.source_image.clone(),
        pairs.source_rays.clone(),
        pairs.target_rays.clone(),
        &pairs.views(),
        &[],
    )
}

/// The target views `I_t` the model synthesises for `pairs`, `[B, 3, H, W]` clamped to [0, 1].
/// A model with a 3DGS head runs it too (a training signal): pass [`inference_model`] to skip
/// its cost.
pub fn synthesise(model: &Prism, pairs: &Pairs) -> Tensor<4> {
    forward_pairs(model, pairs).image.clamp(0.0, 1.0)
}

/// `model` as evaluation times and serves it: the NVS output alone (see
/// [`Prism::without_training_heads`]).
pub fn inference_model(model: &Prism) -> Prism {
    model.clone().without_training_heads()
}
