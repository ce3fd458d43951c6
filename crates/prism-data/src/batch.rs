//! Turning samples into tensors: a Burn [`Batcher`] that flattens every (source, target) pair
//! of a batch of samples into one row, as the model sees one sequence per pair.

use burn::data::dataloader::batcher::Batcher;
use burn::tensor::{Device, Tensor, TensorData};
use image::Rgb32FImage;

use super::io::PointMap;
use super::samples::{Sample, SampleMeta, ViewMeta};
use prism_body::BodyParams;
use prism_body::joints::{NUM_BETAS, NUM_EXPRESSION, NUM_JOINTS};
use prism_core::camera::Camera;
use prism_core::rays::plucker_map;

/// A batch of P (source, target) pairs; a sample with K targets gives K consecutive pairs.
#[derive(Clone, Debug)]
pub struct PrismBatch {
    /// Source images `[P, 3, H, W]` in [0, 1].
    pub source_image: Tensor<4>,
    /// Source Plücker rays `[P, 6, H, W]`.
    pub source_rays: Tensor<4>,
    /// Source foreground mask `[P, 1, H, W]`.
    pub source_mask: Tensor<4>,
    /// Source world-space point map `[P, 3, H, W]` (zeros off the mask).
    pub source_points: Tensor<4>,
    /// Target Plücker rays `[P, 6, H, W]`.
    pub target_rays: Tensor<4>,
    /// Target images `[P, 3, H, W]` in [0, 1].
    pub target_image: Tensor<4>,
    /// Target foreground mask `[P, 1, H, W]`.
    pub target_mask: Tensor<4>,
    /// Source camera of each pair.
    pub source_cameras: Vec<Camera>,
    /// Target camera of each pair.
    pub target_cameras: Vec<Camera>,
    /// Per pair: subject name, target view index, yaw and pitch.
    pub pairs: Vec<PairInfo>,
    /// Per pair: the subject's body-model fit when it has one.
    pub bodies: Vec<Option<BodyParams>>,
}

/// The body-model fits of a batch as tensors, one row per pair; rows without a fit are zeros
/// with `present` 0 (losses mask them out).
#[derive(Clone, Debug)]
pub struct BodyTensors {
    /// Shape coefficients `[P, 10]`.
    pub betas: Tensor<2>,
    /// Axis-angle joint rotations `[P, 55, 3]` (SMPL-X order).
    pub pose: Tensor<3>,
    /// Expression coefficients `[P, 10]`.
    pub expression: Tensor<2>,
    /// Model-to-world scale `[P]`.
    pub scale: Tensor<1>,
    /// Model-to-world translation `[P, 3]`.
    pub transl: Tensor<2>,
    /// 1 where the pair's subject has a fit, else 0, `[P]`.
    pub present: Tensor<1>,
}

impl PrismBatch {
    /// The fits as tensors on `device` (see [`BodyTensors`]).
    pub fn body_tensors(&self, device: &Device) -> BodyTensors {
        let p = self.bodies.len();
        let rest = BodyParams::rest("none");
        let mut b = (
            Vec::new(),
            Vec::new(),
            Vec::new(),
            Vec::new(),
            Vec::new(),
            Vec::new(),
        );
        for body in &self.bodies {
            let fit = body.as_ref().unwrap_or(&rest);
            let on = if body.is_some() { 1.0 } else { 0.0 };
            b.0.extend(fit.betas.map(|v| v * on));
            b.1.extend(fit.pose.iter().flatten().map(|v| v * on));
            b.2.extend(fit.expression.map(|v| v * on));
            b.3.push(fit.scale * on);
            b.4.extend(fit.transl.map(|v| v * on));
            b.5.push(on);
        }
        BodyTensors {
            betas: Tensor::from_data(TensorData::new(b.0, [p, NUM_BETAS]), device),
            pose: Tensor::from_data(TensorData::new(b.1, [p, NUM_JOINTS, 3]), device),
            expression: Tensor::from_data(TensorData::new(b.2, [p, NUM_EXPRESSION]), device),
            scale: Tensor::from_data(TensorData::new(b.3, [p]), device),
            transl: Tensor::from_data(TensorData::new(b.4, [p, 3]), device),
            present: Tensor::from_data(TensorData::new(b.5, [p]), device),
        }
    }
}

/// What a row of a [`PrismBatch`] is.
#[derive(Clone, Debug, PartialEq)]
pub struct PairInfo {
    /// Subject folder name.
    pub subject: String,
    /// Target view index.
    pub target_view: usize,
    /// Target yaw, degrees.
    pub yaw_deg: f32,
    /// Target pitch, degrees.
    pub pitch_deg: f32,
}

/// Channels of the pixel planes of a batch, in the order of [`BatchPixels::into_data`]:
/// source image, source rays, source mask, source points, target rays, target image, target
/// mask.
pub const PIXEL_PLANES: [usize; 7] = [3, 6, 1, 3, 6, 3, 1];

/// The pixel planes of a batch on the host, one row per (source, target) pair: what is sent
/// to a device (or made on a device that loads its own share, see [`PrismBatch::assemble`]).
#[derive(Clone, Debug, Default)]
pub struct BatchPixels {
    pairs: usize,
    size: (usize, usize),
    planes: [Vec<f32>; 7],
}

impl BatchPixels {
    /// The planes of `samples`.
    ///
    /// # Panics
    /// If `samples` is empty or the samples differ in resolution (one dataset gives one size).
    pub fn of(samples: &[Sample]) -> Self {
        let first = samples.first().expect("a batch needs at least one sample");
        let size = (
            first.source.rgb.width() as usize,
            first.source.rgb.height() as usize,
        );
        let mut planes: [Vec<f32>; 7] = Default::default();
        let mut pairs = 0;
        for sample in samples {
            let source = [
                rgb_chw(&sample.source.rgb),
                plucker_map(&sample.source.camera),
                sample.source.mask.as_raw().clone(),
                points_chw(&sample.points),
            ];
            for target in &sample.targets {
                for (plane, values) in planes.iter_mut().zip(&source) {
                    plane.extend_from_slice(values);
                }
                planes[4].extend(plucker_map(&target.camera));
                planes[5].extend(rgb_chw(&target.rgb));
                planes[6].extend_from_slice(target.mask.as_raw());
                pairs += 1;
            }
        }
        Self {
            pairs,
            size,
            planes,
        }
    }

    /// The planes as `[P, C, H, W]` tensor data, in the order of [`PIXEL_PLANES`].
    pub fn into_data(self) -> [TensorData; 7] {
        let (w, h) = self.size;
        let mut channels = PIXEL_PLANES.iter();
        self.planes.map(|plane| {
            let c = *channels.next().expect("one channel count per plane");
            TensorData::new(plane, [self.pairs, c, h, w])
        })
    }
}

/// Builds [`PrismBatch`]es from [`Sample`]s.
#[derive(Clone, Debug, Default)]
pub struct PrismBatcher;

impl PrismBatcher {
    /// Batches `samples` on `device`.
    ///
    /// # Panics
    /// If `samples` is empty or the samples differ in resolution (one dataset gives one size).
    pub fn batch_samples(&self, samples: &[Sample], device: &Device) -> PrismBatch {
        let metas: Vec<SampleMeta> = samples.iter().map(Sample::meta).collect();
        let planes = BatchPixels::of(samples)
            .into_data()
            .map(|data| Tensor::from_data(data, device));
        PrismBatch::assemble(&metas, planes)
    }
}

impl PrismBatch {
    /// The batch of the samples described by `metas` from their pixel planes (`[P, C, H, W]`
    /// in the order of [`PIXEL_PLANES`], wherever they were made).
    pub fn assemble(metas: &[SampleMeta], planes: [Tensor<4>; 7]) -> Self {
        let mut pairs = Vec::new();
        let mut bodies = Vec::new();
        let mut source_cameras = Vec::new();
        let mut target_cameras = Vec::new();
        for meta in metas {
            for target in &meta.targets {
                source_cameras.push(meta.source_camera);
                target_cameras.push(target.camera);
                pairs.push(pair_info(&meta.subject, target));
                bodies.push(meta.body.clone());
            }
        }
        let [
            source_image,
            source_rays,
            source_mask,
            source_points,
            target_rays,
            target_image,
            target_mask,
        ] = planes;
        PrismBatch {
            source_image,
            source_rays,
            source_mask,
            source_points,
            target_rays,
            target_image,
            target_mask,
            source_cameras,
            target_cameras,
            pairs,
            bodies,
        }
    }
}

impl Batcher<Sample, PrismBatch> for PrismBatcher {
    fn batch(&self, items: Vec<Sample>, device: &Device) -> PrismBatch {
        self.batch_samples(&items, device)
    }
}

fn pair_info(subject: &str, target: &ViewMeta) -> PairInfo {
    PairInfo {
        subject: subject.to_string(),
        target_view: target.index,
        yaw_deg: target.yaw_deg,
        pitch_deg: target.pitch_deg,
    }
}

/// An interleaved RGB image as a channel-major `[3, H, W]` buffer.
pub fn rgb_chw(image: &Rgb32FImage) -> Vec<f32> {
    let plane = (image.width() * image.height()) as usize;
    let mut out = vec![0.0; 3 * plane];
    for (i, px) in image.pixels().enumerate() {
        for c in 0..3 {
            out[c * plane + i] = px.0[c];
        }
    }
    out
}

/// A point map as a channel-major `[3, H, W]` buffer.
pub fn points_chw(map: &PointMap) -> Vec<f32> {
    let plane = map.points.len();
    let mut out = vec![0.0; 3 * plane];
    for (i, p) in map.points.iter().enumerate() {
        for c in 0..3 {
            out[c * plane + i] = p[c];
        }
    }
    out
}
