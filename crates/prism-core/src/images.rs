//! Images between tensors, float buffers and 8-bit files: the one quantisation rule
//! ([`to_u8`]), the conversions built on it, and PNG saving through [`crate::files`].

use std::io;
use std::path::Path;

use burn::tensor::Tensor;
use image::codecs::png::PngEncoder;
use image::{
    EncodableLayout, GrayImage, ImageBuffer, ImageEncoder, Luma, PixelWithColorType, Rgb,
    Rgb32FImage, RgbImage,
};

use crate::files::write_atomic;

/// `v` in [0, 1] to 0..=255: clamped, rounded to nearest.
pub fn to_u8(v: f32) -> u8 {
    (v.clamp(0.0, 1.0) * 255.0).round() as u8
}

/// A float RGB image in [0, 1] as 8-bit RGB.
pub fn rgb32_to_rgb8(image: &Rgb32FImage) -> RgbImage {
    let bytes = image.as_raw().iter().map(|&v| to_u8(v)).collect();
    RgbImage::from_raw(image.width(), image.height(), bytes).expect("same size")
}

/// A float grey image (a mask) in [0, 1] as 8-bit grey.
pub fn gray32_to_gray8(image: &ImageBuffer<Luma<f32>, Vec<f32>>) -> GrayImage {
    let bytes = image.as_raw().iter().map(|&v| to_u8(v)).collect();
    GrayImage::from_raw(image.width(), image.height(), bytes).expect("same size")
}

/// A channel-major `[3, H, W]` buffer in [0, 1] as 8-bit RGB.
///
/// # Panics
/// If `chw` holds fewer than `3 * width * height` values.
pub fn chw_to_rgb8(chw: &[f32], width: usize, height: usize) -> RgbImage {
    let plane = width * height;
    RgbImage::from_fn(width as u32, height as u32, |x, y| {
        let i = y as usize * width + x as usize;
        Rgb([0, 1, 2].map(|c| to_u8(chw[c * plane + i])))
    })
}

/// A host copy of a batch of images, `[B, 3, H, W]` in [0, 1], as B channel-major float
/// buffers.
#[derive(Clone, Debug)]
pub struct HostImages {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// One `[3, H, W]` buffer per image.
    pub images: Vec<Vec<f32>>,
}

impl HostImages {
    /// Reads `[B, 3, H, W]` back from the device.
    ///
    /// # Panics
    /// If the tensor does not have 3 channels.
    pub fn from_tensor(tensor: Tensor<4>) -> Self {
        let [b, c, height, width] = tensor.dims();
        assert_eq!(c, 3, "RGB images have 3 channels, got {c}");
        let data: Vec<f32> = tensor
            .into_data()
            .convert::<f32>()
            .try_into_vec()
            .expect("float image data");
        let plane = 3 * height * width;
        Self {
            width,
            height,
            images: data
                .chunks_exact(plane.max(1))
                .take(b)
                .map(<[f32]>::to_vec)
                .collect(),
        }
    }

    /// Image `i` as 8-bit RGB.
    pub fn rgb8(&self, i: usize) -> RgbImage {
        chw_to_rgb8(&self.images[i], self.width, self.height)
    }
}

/// Writes an 8-bit image (RGB, grey, ...) as a PNG, atomically.
///
/// # Errors
/// I/O errors, or the encoder's as `io::Error::other`; the file is then untouched.
pub fn save_png<P>(path: &Path, image: &ImageBuffer<P, Vec<P::Subpixel>>) -> io::Result<()>
where
    P: PixelWithColorType,
    [P::Subpixel]: EncodableLayout,
{
    write_atomic(path, |out| {
        PngEncoder::new(out)
            .write_image(
                image.as_raw().as_bytes(),
                image.width(),
                image.height(),
                P::COLOR_TYPE,
            )
            .map_err(io::Error::other)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantisation_clamps_and_rounds() {
        assert_eq!(to_u8(-0.5), 0);
        assert_eq!(to_u8(0.5 / 255.0 + 1e-6), 1);
        assert_eq!(to_u8(2.0), 255);
    }

    #[test]
    fn png_round_trip_is_exact_and_named_errors_leave_nothing() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.png");
        let img = RgbImage::from_fn(5, 3, |x, y| Rgb([x as u8 * 40, y as u8 * 80, 7]));
        save_png(&path, &img).unwrap();
        assert_eq!(image::open(&path).unwrap().to_rgb8(), img);
        let grey = gray32_to_gray8(&ImageBuffer::from_pixel(2, 2, Luma([0.5f32])));
        save_png(&dir.path().join("m.png"), &grey).unwrap();
        assert_eq!(
            image::open(dir.path().join("m.png")).unwrap().to_luma8(),
            grey
        );
        assert!(save_png(&dir.path().join("missing/b.png"), &img).is_err());
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 2);
    }

    #[test]
    fn chw_buffers_become_pixels() {
        let chw = [0.0, 1.0, 0.5, 0.5, 1.0, 0.0];
        let img = chw_to_rgb8(&chw, 2, 1);
        assert_eq!(img.get_pixel(0, 0).0, [0, 128, 255]);
        assert_eq!(img.get_pixel(1, 0).0, [255, 128, 0]);
    }
}
