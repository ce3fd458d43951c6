//! Images out of the model: tensors to 8-bit RGB, sample grids, error maps, animated GIFs, all
//! written atomically (a temporary file in the same folder, then a rename).

use std::fs;
use std::path::Path;

use burn::tensor::Tensor;
use image::codecs::gif::{GifEncoder, Repeat};
use image::{Delay, Frame, Rgb, Rgb32FImage, RgbImage, RgbaImage};

use crate::error::{Result, TrainError};

/// Mean absolute error (over R, G, B) that an error map draws as white; smaller errors go
/// through red and yellow, 0 is black.
pub const ERROR_MAP_FULL_SCALE: f32 = 0.25;

/// A host copy of a batch of images, `[B, 3, H, W]` in [0, 1], as B channel-major float
/// buffers: what grids and error maps are made from.
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
            images: (0..b)
                .map(|i| data[i * plane..(i + 1) * plane].to_vec())
                .collect(),
        }
    }

    /// Image `i` as 8-bit RGB (values clamped to [0, 1], rounded).
    pub fn rgb8(&self, i: usize) -> RgbImage {
        chw_to_rgb8(&self.images[i], self.width, self.height)
    }
}

/// A channel-major `[3, H, W]` buffer in [0, 1] as 8-bit RGB.
pub fn chw_to_rgb8(chw: &[f32], width: usize, height: usize) -> RgbImage {
    let plane = width * height;
    RgbImage::from_fn(width as u32, height as u32, |x, y| {
        let i = y as usize * width + x as usize;
        Rgb([0, 1, 2].map(|c| to_u8(chw[c * plane + i])))
    })
}

/// A float RGB image in [0, 1] as 8-bit RGB.
pub fn rgb32_to_rgb8(image: &Rgb32FImage) -> RgbImage {
    RgbImage::from_fn(image.width(), image.height(), |x, y| {
        Rgb(image.get_pixel(x, y).0.map(to_u8))
    })
}

/// `v` in [0, 1] to 0..=255, rounded.
pub fn to_u8(v: f32) -> u8 {
    (v.clamp(0.0, 1.0) * 255.0).round() as u8
}

/// The error map of a prediction against its ground truth (both `[3, H, W]` in [0, 1]): per
/// pixel the mean absolute error over R, G, B, drawn on a heat ramp from black (0) through red
/// and yellow to white ([`ERROR_MAP_FULL_SCALE`] and above).
pub fn error_map(pred: &[f32], gt: &[f32], width: usize, height: usize) -> RgbImage {
    let plane = width * height;
    RgbImage::from_fn(width as u32, height as u32, |x, y| {
        let i = y as usize * width + x as usize;
        let err = (0..3)
            .map(|c| (pred[c * plane + i].clamp(0.0, 1.0) - gt[c * plane + i]).abs())
            .sum::<f32>()
            / 3.0;
        heat(err / ERROR_MAP_FULL_SCALE)
    })
}

/// The heat ramp at `t` in [0, 1]: black -> red -> yellow -> white.
fn heat(t: f32) -> Rgb<u8> {
    let t = t.clamp(0.0, 1.0) * 3.0;
    Rgb([t, t - 1.0, t - 2.0].map(to_u8))
}

/// Tiles equally sized images into a grid, `rows[r][c]` at row `r`, column `c`; rows may have
/// fewer images than the widest one (the rest stays black).
///
/// # Panics
/// If the images differ in size.
pub fn tile(rows: &[Vec<RgbImage>]) -> RgbImage {
    let Some(first) = rows.iter().flatten().next() else {
        return RgbImage::new(1, 1);
    };
    let (w, h) = first.dimensions();
    let cols = rows.iter().map(Vec::len).max().unwrap_or(0) as u32;
    let mut out = RgbImage::new(cols * w, rows.len() as u32 * h);
    for (r, row) in rows.iter().enumerate() {
        for (c, image) in row.iter().enumerate() {
            assert_eq!(image.dimensions(), (w, h), "grid images differ in size");
            image::imageops::replace(
                &mut out,
                image,
                i64::from(c as u32 * w),
                r as i64 * h as i64,
            );
        }
    }
    out
}

/// Writes an image as PNG atomically.
///
/// # Errors
/// I/O or encoding errors, naming the file.
pub fn save_png(path: &Path, image: &RgbImage) -> Result<()> {
    let tmp = partial_path(path);
    image
        .save_with_format(&tmp, image::ImageFormat::Png)
        .map_err(|e| TrainError::io(&tmp, std::io::Error::other(e)))?;
    fs::rename(&tmp, path).map_err(|e| TrainError::io(path, e))
}

/// Writes `frames` as an animated GIF that loops forever, `delay_ms` per frame, atomically.
///
/// # Errors
/// I/O or encoding errors, naming the file; no frames.
pub fn save_gif(path: &Path, frames: &[RgbImage], delay_ms: u32) -> Result<()> {
    if frames.is_empty() {
        return Err(TrainError::io(
            path,
            std::io::Error::other("an animated GIF needs at least one frame"),
        ));
    }
    let tmp = partial_path(path);
    let file = fs::File::create(&tmp).map_err(|e| TrainError::io(&tmp, e))?;
    let encode = || -> image::ImageResult<()> {
        let mut encoder = GifEncoder::new_with_speed(std::io::BufWriter::new(file), 10);
        encoder.set_repeat(Repeat::Infinite)?;
        for frame in frames {
            let rgba: RgbaImage = image::DynamicImage::ImageRgb8(frame.clone()).to_rgba8();
            encoder.encode_frame(Frame::from_parts(
                rgba,
                0,
                0,
                Delay::from_numer_denom_ms(delay_ms, 1),
            ))?;
        }
        Ok(())
    };
    encode().map_err(|e| TrainError::io(&tmp, std::io::Error::other(e)))?;
    fs::rename(&tmp, path).map_err(|e| TrainError::io(path, e))
}

/// Writes a text file atomically.
///
/// # Errors
/// I/O errors, naming the file.
pub fn save_text(path: &Path, text: &str) -> Result<()> {
    let tmp = partial_path(path);
    fs::write(&tmp, text).map_err(|e| TrainError::io(&tmp, e))?;
    fs::rename(&tmp, path).map_err(|e| TrainError::io(path, e))
}

/// `NAME.partial` next to `path`.
fn partial_path(path: &Path) -> std::path::PathBuf {
    let mut name = path.file_name().unwrap_or_default().to_os_string();
    name.push(".partial");
    path.with_file_name(name)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn heat_ramp_goes_black_red_yellow_white() {
        assert_eq!(heat(0.0), Rgb([0, 0, 0]));
        assert_eq!(heat(1.0 / 3.0), Rgb([255, 0, 0]));
        assert_eq!(heat(2.0 / 3.0), Rgb([255, 255, 0]));
        assert_eq!(heat(1.0), Rgb([255, 255, 255]));
        assert_eq!(heat(7.0), Rgb([255, 255, 255]));
    }

    #[test]
    fn error_map_of_equal_images_is_black_and_of_opposite_ones_white() {
        let a = vec![0.2f32; 3 * 4 * 2];
        let map = error_map(&a, &a, 4, 2);
        assert!(map.pixels().all(|p| *p == Rgb([0, 0, 0])));
        let b = vec![1.0f32; 3 * 4 * 2];
        let zeros = vec![0.0f32; 3 * 4 * 2];
        assert!(
            error_map(&b, &zeros, 4, 2)
                .pixels()
                .all(|p| *p == Rgb([255, 255, 255]))
        );
    }

    #[test]
    fn tiles_place_each_image() {
        let red = RgbImage::from_pixel(2, 3, Rgb([255, 0, 0]));
        let blue = RgbImage::from_pixel(2, 3, Rgb([0, 0, 255]));
        let grid = tile(&[vec![red.clone(), blue.clone()], vec![blue]]);
        assert_eq!(grid.dimensions(), (4, 6));
        assert_eq!(*grid.get_pixel(0, 0), Rgb([255, 0, 0]));
        assert_eq!(*grid.get_pixel(3, 2), Rgb([0, 0, 255]));
        assert_eq!(*grid.get_pixel(1, 5), Rgb([0, 0, 255]));
        assert_eq!(*grid.get_pixel(3, 5), Rgb([0, 0, 0]));
    }

    #[test]
    fn gif_holds_every_frame() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.gif");
        let frames: Vec<RgbImage> = (0..3)
            .map(|k| RgbImage::from_pixel(8, 8, Rgb([80 * k as u8, 0, 0])))
            .collect();
        save_gif(&path, &frames, 100).unwrap();
        let decoder = image::codecs::gif::GifDecoder::new(std::io::BufReader::new(
            fs::File::open(&path).unwrap(),
        ))
        .unwrap();
        use image::AnimationDecoder;
        let decoded = decoder.into_frames().collect_frames().unwrap();
        assert_eq!(decoded.len(), 3);
        assert_eq!(decoded[2].buffer().get_pixel(4, 4).0[0], 160);
        assert!(!dir.path().join("a.gif.partial").exists());
    }
}
