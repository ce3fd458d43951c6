//! File helpers of the dataset layer: JSON, 8-bit PNG images and masks and `.npy` point maps,
//! all written through `prism_core::files` (atomic: no reader sees half a file).

use std::fs;
use std::path::Path;

use image::{ImageBuffer, Luma, Rgb32FImage};
use prism_core::{files, images};
use serde::Serialize;
use serde::de::DeserializeOwned;

use super::error::{DataError, Result};

/// A world-space point map: one point per pixel, row-major, `[0, 0, 0]` where there is none.
#[derive(Clone, Debug, PartialEq)]
pub struct PointMap {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// `width * height` points, row-major.
    pub points: Vec<[f32; 3]>,
}

/// A float mask in [0, 1].
pub type Mask = ImageBuffer<Luma<f32>, Vec<f32>>;

/// A depth map: the camera-space depth (z, metres) of the surface seen through each pixel
/// centre, 0 where the pixel's centre ray meets no surface.
pub type DepthMap = ImageBuffer<Luma<f32>, Vec<f32>>;

/// Depth PNGs store millimetres: 16 bits reach 65.535 m in steps of 1 mm.
pub const DEPTH_PNG_UNITS_PER_METRE: f32 = 1000.0;

/// Reads a JSON file into `T`.
pub fn read_json<T: DeserializeOwned>(path: &Path) -> Result<T> {
    let text = fs::read_to_string(path).map_err(|e| DataError::io(path, e))?;
    serde_json::from_str(&text).map_err(|source| DataError::Json {
        path: path.to_path_buf(),
        source,
    })
}

/// Writes `value` as pretty JSON, atomically.
pub fn write_json<T: Serialize>(path: &Path, value: &T) -> Result<()> {
    files::write_json(path, value).map_err(|e| DataError::io(path, e))
}

/// Writes a float RGB image as an 8-bit PNG, atomically.
pub fn write_rgb_png(path: &Path, image: &Rgb32FImage) -> Result<()> {
    images::save_png(path, &images::rgb32_to_rgb8(image)).map_err(|e| DataError::io(path, e))
}

/// Writes a float mask as an 8-bit grey PNG, atomically.
pub fn write_mask_png(path: &Path, mask: &Mask) -> Result<()> {
    images::save_png(path, &images::gray32_to_gray8(mask)).map_err(|e| DataError::io(path, e))
}

/// Reads an image as float RGB in [0, 1] (8-bit values / 255; alpha dropped).
pub fn read_rgb(path: &Path) -> Result<Rgb32FImage> {
    Ok(open_image(path)?.to_rgb32f())
}

/// Reads a grey image as a float mask in [0, 1].
pub fn read_mask(path: &Path) -> Result<Mask> {
    Ok(open_image(path)?.to_luma32f())
}

/// Writes a depth map as a 16-bit grey PNG in millimetres (0: no surface), atomically.
///
/// # Errors
/// A depth that is negative, not finite or past 65.535 m (named with the file), or I/O.
pub fn write_depth_png(path: &Path, depth: &DepthMap) -> Result<()> {
    let max = f32::from(u16::MAX) / DEPTH_PNG_UNITS_PER_METRE;
    if let Some(bad) = depth
        .pixels()
        .map(|p| p.0[0])
        .find(|d| !d.is_finite() || *d < 0.0 || *d > max)
    {
        return Err(DataError::invalid(
            path,
            format!("depth {bad} m cannot be stored (0 to {max} m)"),
        ));
    }
    let mm: ImageBuffer<Luma<u16>, Vec<u16>> =
        ImageBuffer::from_fn(depth.width(), depth.height(), |x, y| {
            Luma([(depth.get_pixel(x, y).0[0] * DEPTH_PNG_UNITS_PER_METRE).round() as u16])
        });
    images::save_png(path, &mm).map_err(|e| DataError::io(path, e))
}

/// Reads a 16-bit depth PNG written by [`write_depth_png`] as metres.
///
/// # Errors
/// I/O, an undecodable file, or an image that is not 16-bit grey (named with the file).
pub fn read_depth(path: &Path) -> Result<DepthMap> {
    let image::DynamicImage::ImageLuma16(mm) = open_image(path)? else {
        return Err(DataError::invalid(
            path,
            "a depth map must be a 16-bit grey PNG (millimetres)",
        ));
    };
    Ok(ImageBuffer::from_fn(mm.width(), mm.height(), |x, y| {
        Luma([f32::from(mm.get_pixel(x, y).0[0]) / DEPTH_PNG_UNITS_PER_METRE])
    }))
}

/// Decodes an image file; errors name the file (I/O apart from decoding).
fn open_image(path: &Path) -> Result<image::DynamicImage> {
    image::open(path).map_err(|source| match source {
        image::ImageError::IoError(e) => DataError::io(path, e),
        source => DataError::Image {
            path: path.to_path_buf(),
            source,
        },
    })
}

/// Writes a point map as a float32 `.npy` of shape `[H, W, 3]`.
pub fn write_points(path: &Path, map: &PointMap) -> Result<()> {
    use npyz::WriterBuilder;
    let mut bytes = Vec::new();
    {
        let mut writer = npyz::WriteOptions::new()
            .default_dtype()
            .shape(&[map.height as u64, map.width as u64, 3])
            .writer(&mut bytes)
            .begin_nd()
            .map_err(|e| DataError::io(path, e))?;
        writer
            .extend(map.points.iter().flatten().copied())
            .map_err(|e| DataError::io(path, e))?;
        writer.finish().map_err(|e| DataError::io(path, e))?;
    }
    files::write_bytes(path, &bytes).map_err(|e| DataError::io(path, e))
}

/// Reads a float32 `[H, W, 3]` `.npy` point map.
pub fn read_points(path: &Path) -> Result<PointMap> {
    let bytes = fs::read(path).map_err(|e| DataError::io(path, e))?;
    let npy = npyz::NpyFile::new(&bytes[..])
        .map_err(|e| DataError::invalid(path, format!("not a .npy file: {e}")))?;
    let shape = npy.shape().to_vec();
    if shape.len() != 3 || shape[2] != 3 {
        return Err(DataError::invalid(
            path,
            format!("expected shape [H, W, 3], found {shape:?}"),
        ));
    }
    if npy.dtype() != npyz::DType::Plain("<f4".parse().expect("valid type string")) {
        return Err(DataError::invalid(
            path,
            format!("expected float32 (<f4), found {:?}", npy.dtype()),
        ));
    }
    let values: Vec<f32> = npy
        .into_vec()
        .map_err(|e| DataError::invalid(path, format!("unreadable data: {e}")))?;
    let points = values.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
    Ok(PointMap {
        width: shape[1] as u32,
        height: shape[0] as u32,
        points,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn points_round_trip_and_bad_shapes_are_named() {
        let d = tempfile::tempdir().unwrap();
        let map = PointMap {
            width: 3,
            height: 2,
            points: (0..6).map(|i| [i as f32, 0.5, -1.0]).collect(),
        };
        let path = d.path().join("p.npy");
        write_points(&path, &map).unwrap();
        assert_eq!(read_points(&path).unwrap(), map);
        fs::write(&path, b"garbage").unwrap();
        let err = read_points(&path).unwrap_err().to_string();
        assert!(err.contains("p.npy") && err.contains("not a .npy"), "{err}");
    }

    #[test]
    fn depth_round_trips_to_the_millimetre_and_bad_depths_are_refused() {
        let d = tempfile::tempdir().unwrap();
        let depth = DepthMap::from_fn(5, 3, |x, y| Luma([x as f32 * 0.7311 + y as f32 * 1.25]));
        let path = d.path().join("depth.png");
        write_depth_png(&path, &depth).unwrap();
        let back = read_depth(&path).unwrap();
        assert_eq!(back.dimensions(), (5, 3));
        for (a, b) in depth.pixels().zip(back.pixels()) {
            assert!((a.0[0] - b.0[0]).abs() <= 0.5e-3 + 1e-6, "{a:?} {b:?}");
        }
        assert_eq!(back.get_pixel(0, 0).0[0], 0.0, "no surface stays 0");
        for bad in [-0.1, f32::NAN, 70.0] {
            let mut depth = depth.clone();
            depth.put_pixel(1, 1, Luma([bad]));
            let err = write_depth_png(&d.path().join("bad.png"), &depth)
                .unwrap_err()
                .to_string();
            assert!(
                err.contains("bad.png") && err.contains("cannot be stored"),
                "{err}"
            );
        }
        assert!(!d.path().join("bad.png").exists());
        // An 8-bit image is not a depth map.
        let grey = d.path().join("grey.png");
        write_mask_png(&grey, &Mask::from_pixel(2, 2, Luma([0.5]))).unwrap();
        let err = read_depth(&grey).unwrap_err().to_string();
        assert!(err.contains("grey.png") && err.contains("16-bit"), "{err}");
    }

    #[test]
    fn png_round_trip_is_8_bit_exact() {
        let d = tempfile::tempdir().unwrap();
        let img = Rgb32FImage::from_fn(4, 3, |x, y| {
            image::Rgb([x as f32 / 3.0, y as f32 / 2.0, 0.25])
        });
        let path = d.path().join("a.png");
        write_rgb_png(&path, &img).unwrap();
        let back = read_rgb(&path).unwrap();
        for (a, b) in img.as_raw().iter().zip(back.as_raw()) {
            assert!((a - b).abs() <= 0.5 / 255.0 + 1e-6);
        }
        assert_eq!(fs::read_dir(d.path()).unwrap().count(), 1);
        let err = read_rgb(&d.path().join("missing.png"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("missing.png"), "{err}");
    }
}
