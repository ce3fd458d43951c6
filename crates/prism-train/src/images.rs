//! Images out of the model: sample grids, error maps, animated GIFs, all written through
//! `prism_core::files` (atomic). Tensor and float conversions are `prism_core::images`'.

use std::path::Path;

use image::codecs::gif::{GifEncoder, Repeat};
use image::{Delay, Frame, Rgb, RgbImage, RgbaImage};
use prism_core::images::to_u8;
use prism_core::{files, images};

use crate::error::{Result, TrainError};

/// Mean absolute error (over R, G, B) that an error map draws as white; smaller errors go
/// through red and yellow, 0 is black.
pub const ERROR_MAP_FULL_SCALE: f32 = 0.25;

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

/// Writes an 8-bit RGB image as a PNG, atomically (`prism_core::images::save_png`).
///
/// # Errors
/// I/O or encoding errors, naming the file.
pub fn save_png(path: &Path, image: &RgbImage) -> Result<()> {
    images::save_png(path, image).map_err(|e| TrainError::io(path, e))
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
    files::write_atomic(path, |out| {
        let mut encoder = GifEncoder::new_with_speed(out, 10);
        encoder
            .set_repeat(Repeat::Infinite)
            .map_err(std::io::Error::other)?;
        for frame in frames {
            let rgba: RgbaImage = image::DynamicImage::ImageRgb8(frame.clone()).to_rgba8();
            encoder
                .encode_frame(Frame::from_parts(
                    rgba,
                    0,
                    0,
                    Delay::from_numer_denom_ms(delay_ms, 1),
                ))
                .map_err(std::io::Error::other)?;
        }
        Ok(())
    })
    .map_err(|e| TrainError::io(path, e))
}

/// Writes a text file, atomically.
///
/// # Errors
/// I/O errors, naming the file.
pub fn save_text(path: &Path, text: &str) -> Result<()> {
    files::write_bytes(path, text.as_bytes()).map_err(|e| TrainError::io(path, e))
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
            std::fs::File::open(&path).unwrap(),
        ))
        .unwrap();
        use image::AnimationDecoder;
        let decoded = decoder.into_frames().collect_frames().unwrap();
        assert_eq!(decoded.len(), 3);
        assert_eq!(decoded[2].buffer().get_pixel(4, 4).0[0], 160);
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
    }
}
