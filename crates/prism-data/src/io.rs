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
