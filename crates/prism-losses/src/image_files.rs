//! Scoring rendered image files against ground truth, one pair or two folders: the library
//! side of `prism metrics` and `prism evaluate --pred/--gt`, through [`score_images`] and
//! [`ScoreTable`].

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use burn::tensor::{Device, Tensor, TensorData};
use prism_core::axes::permute;
use serde::Serialize;

use crate::{
    GroundTruth, ImageScores, LPIPS_MIN_SIDE, LossError, Lpips, SSIM_WINDOW, ScoreTable,
    score_images,
};

/// File extensions scored in folders (case-insensitive).
pub const IMAGE_EXTENSIONS: [&str; 3] = ["png", "jpg", "jpeg"];

/// The scores of two folders: the mean and each image by file name.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct FolderScores {
    /// The mean over the images of each metric.
    pub mean: ImageScores,
    /// Each image's scores, by file name.
    pub images: BTreeMap<String, ImageScores>,
}

/// The result of [`score_paths`]: one pair of images or two folders.
#[derive(Clone, Debug, PartialEq, Serialize)]
#[serde(untagged)]
pub enum Scores {
    /// Two image files: `{"psnr", "ssim", "lpips"}` in JSON.
    Pair(ImageScores),
    /// Two folders: `{"mean": {...}, "images": {NAME: {...}}}` in JSON.
    Folders(FolderScores),
}

impl Scores {
    /// The scores as one JSON object (see the variants).
    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).expect("scores serialise")
    }

    /// The scores as a Markdown table: a row for the pair, or a row per image and their mean.
    pub fn to_table(&self) -> String {
        let mut table = ScoreTable::new("image");
        match self {
            Scores::Pair(s) => table.row("pair", &[], s, &[]),
            Scores::Folders(f) => {
                for (name, s) in &f.images {
                    table.row(name.as_str(), &[], s, &[]);
                }
                table.row(format!("mean of {}", f.images.len()), &[], &f.mean, &[]);
            }
        }
        table.to_markdown()
    }
}

/// An 8-bit (or 16-bit) PNG/JPEG/GIF as a `[1, 3, H, W]` tensor in [0, 1] on `device`:
/// 8-bit values divided by 255, alpha dropped, grey replicated to RGB. The format is detected
/// from the content, not the extension.
///
/// # Errors
/// [`LossError::NotAnImage`] when the file cannot be read or decoded.
pub fn load_image(path: &Path, device: &Device) -> Result<Tensor<4>, LossError> {
    let not_an_image = |reason: String| LossError::NotAnImage {
        path: path.to_path_buf(),
        reason,
    };
    let decoded = image::ImageReader::open(path)
        .map_err(|e| not_an_image(e.to_string()))?
        .with_guessed_format()
        .map_err(|e| not_an_image(e.to_string()))?
        .decode()
        .map_err(|e| not_an_image(e.to_string()))?;
    let (width, height) = (decoded.width() as usize, decoded.height() as usize);
    let interleaved: Vec<f32> =
        match decoded.color().bytes_per_pixel() / decoded.color().channel_count() {
            1 => decoded
                .to_rgb8()
                .into_raw()
                .into_iter()
                .map(|v| f32::from(v) / 255.0)
                .collect(),
            _ => decoded.to_rgb32f().into_raw(),
        };
    let data = TensorData::new(interleaved, [1, height, width, 3]);
    Ok(permute(Tensor::<4>::from_data(data, device), [0, 3, 1, 2]))
}

/// Scores one image file against another (same size, at least 31 x 31).
///
/// # Errors
/// When a file is not an image, the sizes differ, or the images are too small.
pub fn score_files(
    pred: &Path,
    gt: &Path,
    lpips: &Lpips,
    device: &Device,
) -> Result<ImageScores, LossError> {
    let p = load_image(pred, device)?;
    let g = load_image(gt, device)?;
    let size = |t: &Tensor<4>| {
        let [_, _, h, w] = t.dims();
        [w as u32, h as u32]
    };
    if p.dims() != g.dims() {
        return Err(LossError::SizeMismatch {
            pred: pred.to_path_buf(),
            pred_size: size(&p),
            gt: gt.to_path_buf(),
            gt_size: size(&g),
        });
    }
    let [width, height] = size(&p);
    let min = LPIPS_MIN_SIDE.max(SSIM_WINDOW) as u32;
    if width < min || height < min {
        return Err(LossError::TooSmall {
            path: pred.to_path_buf(),
            width,
            height,
            min,
        });
    }
    Ok(score_images(p, &GroundTruth::new(g, Some(lpips)))[0])
}

/// Scores `pred` against `gt`: two image files, or two folders whose images (png, jpg, jpeg;
/// other files are ignored, subfolders are not searched) are matched by file name.
///
/// # Errors
/// When a path does not exist, one is a file and the other a folder, an image has no
/// counterpart (all are listed), a folder holds no image, or any pair fails [`score_files`].
pub fn score_paths(
    pred: &Path,
    gt: &Path,
    lpips: &Lpips,
    device: &Device,
) -> Result<Scores, LossError> {
    for path in [pred, gt] {
        if !path.exists() {
            return Err(LossError::Missing(path.to_path_buf()));
        }
    }
    match (pred.is_dir(), gt.is_dir()) {
        (false, false) => Ok(Scores::Pair(score_files(pred, gt, lpips, device)?)),
        (true, true) => {
            let pred_names = image_names(pred)?;
            let gt_names = image_names(gt)?;
            let mut unmatched: Vec<String> = pred_names
                .iter()
                .filter(|n| !gt_names.contains(n))
                .map(|n| {
                    format!(
                        "`{}` has no `{}`",
                        pred.join(n).display(),
                        gt.join(n).display()
                    )
                })
                .collect();
            unmatched.extend(
                gt_names
                    .iter()
                    .filter(|n| !pred_names.contains(n))
                    .map(|n| {
                        format!(
                            "`{}` has no `{}`",
                            gt.join(n).display(),
                            pred.join(n).display()
                        )
                    }),
            );
            if !unmatched.is_empty() {
                return Err(LossError::MissingCounterpart(unmatched));
            }
            let mut images = BTreeMap::new();
            for name in pred_names {
                let scores = score_files(&pred.join(&name), &gt.join(&name), lpips, device)?;
                images.insert(name, scores);
            }
            let all: Vec<ImageScores> = images.values().copied().collect();
            Ok(Scores::Folders(FolderScores {
                mean: ImageScores::mean(&all),
                images,
            }))
        }
        _ => Err(LossError::KindMismatch {
            pred: pred.to_path_buf(),
            gt: gt.to_path_buf(),
        }),
    }
}

/// Sorted names of the image files directly inside `dir`.
fn image_names(dir: &Path) -> Result<Vec<String>, LossError> {
    let folder_error = |e: std::io::Error| LossError::Folder {
        path: dir.to_path_buf(),
        reason: e.to_string(),
    };
    let mut names = Vec::new();
    for entry in std::fs::read_dir(dir).map_err(folder_error)? {
        let path: PathBuf = entry.map_err(folder_error)?.path();
        let is_image = path
            .extension()
            .and_then(|e| e.to_str())
            .is_some_and(|e| IMAGE_EXTENSIONS.contains(&e.to_ascii_lowercase().as_str()));
        if path.is_file()
            && is_image
            && let Some(name) = path.file_name().and_then(|n| n.to_str())
        {
            names.push(name.to_string());
        }
    }
    if names.is_empty() {
        return Err(LossError::EmptyFolder(dir.to_path_buf()));
    }
    names.sort();
    Ok(names)
}
