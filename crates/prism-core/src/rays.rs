//! Plücker ray maps: per pixel `(d, o x d)` (paper Eq. 1), as host buffers and Burn tensors.

use burn::tensor::{Device, Tensor, TensorData};
use rayon::prelude::*;

use crate::camera::Camera;

/// The Plücker ray map of a camera as a channel-major `[6, H, W]` buffer: channels are
/// `d.x, d.y, d.z, m.x, m.y, m.z` with `d` the unit ray direction through each pixel centre and
/// `m = o x d` its moment.
pub fn plucker_map(camera: &Camera) -> Vec<f32> {
    let (w, h) = (
        camera.intrinsics.width as usize,
        camera.intrinsics.height as usize,
    );
    let plane = w * h;
    let mut out = vec![0.0f32; 6 * plane];
    let rows: Vec<Vec<[f32; 6]>> = (0..h)
        .into_par_iter()
        .map(|y| (0..w).map(|x| camera.plucker(x as u32, y as u32)).collect())
        .collect();
    for (y, row) in rows.iter().enumerate() {
        for (x, ray) in row.iter().enumerate() {
            for (c, value) in ray.iter().enumerate() {
                out[c * plane + y * w + x] = *value;
            }
        }
    }
    out
}

/// The Plücker ray maps of a batch of cameras as a `[B, 6, H, W]` tensor.
///
/// All cameras must share one image size.
///
/// # Panics
/// If the batch is empty or the cameras' image sizes differ (a programming error: batches are
/// built from one dataset resolution).
pub fn plucker_rays(cameras: &[Camera], device: &Device) -> Tensor<4> {
    let first = cameras
        .first()
        .expect("plucker_rays needs at least one camera");
    let (w, h) = (
        first.intrinsics.width as usize,
        first.intrinsics.height as usize,
    );
    let mut data = Vec::with_capacity(cameras.len() * 6 * w * h);
    for camera in cameras {
        assert_eq!(
            (
                camera.intrinsics.width as usize,
                camera.intrinsics.height as usize
            ),
            (w, h),
            "cameras of one batch must share an image size"
        );
        data.extend(plucker_map(camera));
    }
    Tensor::from_data(TensorData::new(data, [cameras.len(), 6, h, w]), device)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::Intrinsics;
    use glam::Vec3;

    #[test]
    fn tensor_matches_per_pixel_rays() {
        let device = crate::BackendKind::Ndarray.device().unwrap();
        let a = Camera::orbit(
            10.0,
            5.0,
            2.0,
            Vec3::new(0.0, 0.9, 0.0),
            Intrinsics::protocol_default(6, 4),
        );
        let b = Camera::orbit(
            -20.0,
            -5.0,
            2.0,
            Vec3::new(0.0, 0.9, 0.0),
            Intrinsics::protocol_default(6, 4),
        );
        let t = plucker_rays(&[a, b], &device);
        assert_eq!(t.dims(), [2, 6, 4, 6]);
        let values = t.into_data().try_into_vec::<f32>().unwrap();
        for (bi, cam) in [a, b].iter().enumerate() {
            for (x, y) in [(0u32, 0u32), (5, 3), (2, 1)] {
                let r = cam.plucker(x, y);
                for (c, v) in r.iter().enumerate() {
                    let idx = ((bi * 6 + c) * 4 + y as usize) * 6 + x as usize;
                    assert_eq!(values[idx], *v);
                }
            }
        }
    }
}
