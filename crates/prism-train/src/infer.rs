//! Inference from one photo (`prism infer`): the person is cut out (mask or alpha channel),
//! centred and scaled as in the training data, given the viewing protocol's frontal camera,
//! and rendered along a sweep of novel views (PNG frames and an animated GIF); optionally the
//! 3DGS head's Gaussians are saved as a PLY file.

use std::fmt;
use std::path::{Path, PathBuf};
use std::str::FromStr;

use burn::tensor::Device;
use image::imageops::{FilterType, resize};
use image::{DynamicImage, ImageBuffer, Luma, Rgb, Rgb32FImage, RgbImage, Rgba};
use prism_data::camera::{Camera, Intrinsics};
use prism_data::protocol::{ViewAngles, ViewingProtocol};

use crate::error::{Result, TrainError};
use crate::evaluate::{EVAL_BATCH, progress_bar};
use crate::images::{HostImages, rgb32_to_rgb8, save_gif, save_png};
use crate::predict::{Pairs, export_gaussians, nvs_model, synthesise};
use prism_model::Prism;

/// The file name of a sweep's animated GIF.
pub const SWEEP_GIF: &str = "sweep.gif";
/// The file name of the centred input image.
pub const INPUT_PNG: &str = "input.png";
/// Milliseconds per frame of the GIF.
pub const GIF_DELAY_MS: u32 = 120;
/// Image extensions read from a folder of video frames.
pub const FRAME_EXTENSIONS: [&str; 3] = ["png", "jpg", "jpeg"];

/// Which novel views to render.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Sweep {
    /// Yaw from `-max` to `+max`, pitch 0.
    #[default]
    Yaw,
    /// Pitch from `-max` to `+max`, yaw 0.
    Pitch,
    /// Every (yaw, pitch) of the two sweeps, row by row (pitch outer).
    Grid,
}

impl fmt::Display for Sweep {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Sweep::Yaw => "yaw",
            Sweep::Pitch => "pitch",
            Sweep::Grid => "grid",
        })
    }
}

impl FromStr for Sweep {
    type Err = String;

    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s {
            "yaw" => Ok(Sweep::Yaw),
            "pitch" => Ok(Sweep::Pitch),
            "grid" => Ok(Sweep::Grid),
            other => Err(format!(
                "unknown sweep `{other}` (expected yaw, pitch or grid)"
            )),
        }
    }
}

/// The angles of a sweep: `-max, -max + step, ..., max` (the last one kept even when `step`
/// does not divide `2 max`), for yaw, pitch or both.
///
/// # Errors
/// A step that is not finite or below 0.1 degree.
pub fn sweep_views(sweep: Sweep, step_deg: f32, max_deg: f32) -> Result<Vec<ViewAngles>> {
    if !(step_deg.is_finite() && step_deg >= 0.1) {
        return Err(TrainError::input(
            "--step",
            format!("{step_deg} is not a step of at least 0.1 degree"),
        ));
    }
    let mut angles = Vec::new();
    let mut a = -max_deg;
    while a < max_deg - 1e-3 {
        angles.push(a);
        a += step_deg;
    }
    angles.push(max_deg);
    let views: Vec<(f32, f32)> = match sweep {
        Sweep::Yaw => angles.iter().map(|&y| (y, 0.0)).collect(),
        Sweep::Pitch => angles.iter().map(|&p| (0.0, p)).collect(),
        Sweep::Grid => angles
            .iter()
            .flat_map(|&p| angles.iter().map(move |&y| (y, p)))
            .collect(),
    };
    Ok(views
        .into_iter()
        .enumerate()
        .map(|(index, (yaw_deg, pitch_deg))| ViewAngles {
            index,
            yaw_deg,
            pitch_deg,
        })
        .collect())
}

/// The viewing protocol's camera of `view` for square images of `resolution` px (the frontal
/// camera for yaw = pitch = 0): what a photo without a camera is given.
pub fn protocol_camera(view: &ViewAngles, resolution: u32) -> Camera {
    ViewingProtocol::default().camera(view, Intrinsics::protocol_default(resolution, resolution))
}

/// Where the person's outline came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Cutout {
    /// The `--mask` file.
    Mask,
    /// The photo's alpha channel.
    Alpha,
    /// Neither: the whole image was used.
    WholeImage,
}

/// A photo prepared for the model: square, `resolution` px, the person centred and scaled as
/// in the training data, composited on the background.
#[derive(Clone, Debug)]
pub struct PreparedPhoto {
    /// RGB in [0, 1].
    pub image: Rgb32FImage,
    /// Where the person's outline came from.
    pub cutout: Cutout,
}

/// Fraction of the image height that the person's bounding box fills in the training data's
/// frontal view. The protocol puts a 1.80 m subject 2.0 m from the camera with `fy = H`, which
/// is 0.90 of the height for a flat figure; perspective (the body's front is closer) and the
/// mask's anti-aliased edge make it larger: 0.948 is the mean over the frontal views of the
/// small config's 24 synthetic people (0.90 to 0.99).
pub const PERSON_HEIGHT_FRACTION: f32 = 0.948;
/// Where the centre of the person's bounding box sits in the training data's frontal view, as
/// a fraction of the image height from the top (mean over the same 24 views; the feet, being
/// closer, reach further down than the head up).
pub const PERSON_CENTRE_Y: f32 = 0.517;

/// Reads `photo` (and `mask`, a grey image of the same size where the person is white) and
/// prepares it for the model (see [`prepare_photo`]).
///
/// # Errors
/// Unreadable images, a mask of another size, an empty mask.
pub fn load_photo(
    photo: &Path,
    mask: Option<&Path>,
    resolution: u32,
    background: [f32; 3],
) -> Result<PreparedPhoto> {
    let decoded = open_image(photo)?;
    let rgb = decoded.to_rgb32f();
    let (alpha, cutout) = match mask {
        Some(mask_path) => {
            let m = open_image(mask_path)?.to_luma32f();
            if m.dimensions() != rgb.dimensions() {
                return Err(TrainError::input(
                    mask_path,
                    format!(
                        "the mask is {}x{} but the photo {} is {}x{}",
                        m.width(),
                        m.height(),
                        photo.display(),
                        rgb.width(),
                        rgb.height()
                    ),
                ));
            }
            (m, Cutout::Mask)
        }
        None if decoded.color().has_alpha() => {
            let rgba = decoded.to_rgba32f();
            let a = ImageBuffer::from_fn(rgba.width(), rgba.height(), |x, y| {
                Luma([rgba.get_pixel(x, y).0[3]])
            });
            if a.pixels().all(|p| p.0[0] >= 1.0) {
                (a, Cutout::WholeImage)
            } else {
                (a, Cutout::Alpha)
            }
        }
        None => (
            ImageBuffer::from_pixel(rgb.width(), rgb.height(), Luma([1.0])),
            Cutout::WholeImage,
        ),
    };
    let image = prepare_photo(&rgb, &alpha, cutout, resolution, background)
        .map_err(|message| TrainError::input(mask.unwrap_or(photo), message))?;
    Ok(PreparedPhoto { image, cutout })
}

/// Centres and scales the person like the training data: the bounding box of `alpha > 0.5`
/// is scaled to [`PERSON_HEIGHT_FRACTION`] of the image height and its centre moved to the
/// horizontal centre, [`PERSON_CENTRE_Y`] down; the photo is resampled with
/// premultiplied alpha and composited on `background`. With [`Cutout::WholeImage`] the whole
/// image is fitted into the square instead.
///
/// # Errors
/// A message when the mask is empty.
pub fn prepare_photo(
    rgb: &Rgb32FImage,
    alpha: &ImageBuffer<Luma<f32>, Vec<f32>>,
    cutout: Cutout,
    resolution: u32,
    background: [f32; 3],
) -> std::result::Result<Rgb32FImage, String> {
    let (w, h) = rgb.dimensions();
    let r = resolution as f32;
    // (photo x, photo y) that lands on (0.5 R, centre_y R); photo pixels per output pixel
    let (cx, cy, per_pixel, centre_y) = if cutout == Cutout::WholeImage {
        (w as f32 / 2.0, h as f32 / 2.0, w.max(h) as f32 / r, 0.5)
    } else {
        let (mut x0, mut y0, mut x1, mut y1) = (u32::MAX, u32::MAX, 0, 0);
        for (x, y, p) in alpha.enumerate_pixels() {
            if p.0[0] > 0.5 {
                x0 = x0.min(x);
                y0 = y0.min(y);
                x1 = x1.max(x + 1);
                y1 = y1.max(y + 1);
            }
        }
        if x0 == u32::MAX {
            return Err("the mask is empty: no pixel of the person (alpha > 0.5) was found".into());
        }
        let box_h = (y1 - y0) as f32;
        (
            (x0 + x1) as f32 / 2.0,
            (y0 + y1) as f32 / 2.0,
            box_h / (PERSON_HEIGHT_FRACTION * r),
            PERSON_CENTRE_Y,
        )
    };
    // The square window of the photo that becomes the output, premultiplied RGBA.
    let side = (per_pixel * r).ceil().max(1.0) as u32;
    let left = cx - side as f32 / 2.0;
    let top = cy - side as f32 * centre_y;
    let window = ImageBuffer::<Rgba<f32>, Vec<f32>>::from_fn(side, side, |x, y| {
        let sx = (left + x as f32 + 0.5).floor();
        let sy = (top + y as f32 + 0.5).floor();
        if sx < 0.0 || sy < 0.0 || sx >= w as f32 || sy >= h as f32 {
            return Rgba([0.0; 4]);
        }
        let (sx, sy) = (sx as u32, sy as u32);
        let a = alpha.get_pixel(sx, sy).0[0].clamp(0.0, 1.0);
        let c = rgb.get_pixel(sx, sy).0;
        Rgba([c[0] * a, c[1] * a, c[2] * a, a])
    });
    let small = resize(&window, resolution, resolution, FilterType::Triangle);
    Ok(Rgb32FImage::from_fn(resolution, resolution, |x, y| {
        let p = small.get_pixel(x, y).0;
        let a = p[3].clamp(0.0, 1.0);
        Rgb([0, 1, 2].map(|c| (p[c] + background[c] * (1.0 - a)).clamp(0.0, 1.0)))
    }))
}

/// What [`render_sweep`] wrote.
#[derive(Clone, Debug)]
pub struct SweepOutput {
    /// The centred input.
    pub input: PathBuf,
    /// One PNG per view, in sweep order.
    pub frames: Vec<PathBuf>,
    /// The animated GIF of the frames.
    pub gif: PathBuf,
    /// The PLY of the 3DGS head's Gaussians, when asked for.
    pub ply: Option<PathBuf>,
}

/// The file name of a sweep frame: `NNN_yaw+10_pitch-5.png`.
pub fn frame_name(view: &ViewAngles) -> String {
    format!(
        "{:03}_yaw{:+}_pitch{:+}.png",
        view.index,
        round_tenth(view.yaw_deg),
        round_tenth(view.pitch_deg)
    )
}

fn round_tenth(v: f32) -> f32 {
    let r = (v * 10.0).round() / 10.0;
    if r == 0.0 { 0.0 } else { r }
}

/// Renders `photo` (prepared, at the model's resolution, seen by the frontal camera) in each of
/// `views` with `model` on `device`, writing `input.png`, one PNG per view and `sweep.gif` into
/// `out`; with `ply`, also the 3DGS head's Gaussians there.
///
/// # Errors
/// Output that cannot be written; [`TrainError::NoGaussianHead`] for `ply` on a model without
/// a 3DGS head.
#[allow(clippy::too_many_arguments)]
pub fn render_sweep(
    model: &Prism,
    photo: &Rgb32FImage,
    views: &[ViewAngles],
    background: [f32; 3],
    device: &Device,
    out: &Path,
    ply: Option<&Path>,
    progress: bool,
) -> Result<SweepOutput> {
    let resolution = photo.width();
    if photo.height() != resolution {
        return Err(TrainError::input(
            out,
            format!(
                "the prepared photo must be square, got {}x{}",
                photo.width(),
                photo.height()
            ),
        ));
    }
    std::fs::create_dir_all(out).map_err(|e| TrainError::io(out, e))?;
    let frontal = protocol_camera(
        &ViewAngles {
            index: 0,
            yaw_deg: 0.0,
            pitch_deg: 0.0,
        },
        resolution,
    );
    let ply = match ply {
        Some(path) => {
            let pairs = Pairs::from_source(photo, frontal, &[frontal], background, device);
            export_gaussians(model, &pairs, path)?;
            Some(path.to_path_buf())
        }
        None => None,
    };
    let model = nvs_model(model);
    let input = out.join(INPUT_PNG);
    save_png(&input, &rgb32_to_rgb8(photo))?;
    let bar = progress_bar(progress, views.len() as u64, "rendering views");
    let mut frames = Vec::new();
    let mut images: Vec<RgbImage> = Vec::new();
    for chunk in views.chunks(EVAL_BATCH) {
        let cameras: Vec<Camera> = chunk
            .iter()
            .map(|v| protocol_camera(v, resolution))
            .collect();
        let pairs = Pairs::from_source(photo, frontal, &cameras, background, device);
        let host = HostImages::from_tensor(synthesise(&model, &pairs));
        for (i, view) in chunk.iter().enumerate() {
            let path = out.join(frame_name(view));
            let image = host.rgb8(i);
            save_png(&path, &image)?;
            frames.push(path);
            images.push(image);
        }
        bar.inc(chunk.len() as u64);
    }
    bar.finish_and_clear();
    let gif = out.join(SWEEP_GIF);
    save_gif(&gif, &images, GIF_DELAY_MS)?;
    Ok(SweepOutput {
        input,
        frames,
        gif,
        ply,
    })
}

/// The image files (png, jpg, jpeg) directly inside `dir`, sorted by name: the frames of a
/// video.
///
/// # Errors
/// An unreadable folder, or one without images.
pub fn list_frames(dir: &Path) -> Result<Vec<PathBuf>> {
    let mut frames = Vec::new();
    for entry in std::fs::read_dir(dir).map_err(|e| TrainError::io(dir, e))? {
        let path = entry.map_err(|e| TrainError::io(dir, e))?.path();
        let is_image = path
            .extension()
            .and_then(|e| e.to_str())
            .is_some_and(|e| FRAME_EXTENSIONS.contains(&e.to_ascii_lowercase().as_str()));
        if path.is_file() && is_image {
            frames.push(path);
        }
    }
    if frames.is_empty() {
        return Err(TrainError::input(
            dir,
            "the folder holds no image (png, jpg, jpeg)",
        ));
    }
    frames.sort();
    Ok(frames)
}

/// Opens an image, naming the file in the error.
fn open_image(path: &Path) -> Result<DynamicImage> {
    image::ImageReader::open(path)
        .map_err(|e| TrainError::io(path, e))?
        .with_guessed_format()
        .map_err(|e| TrainError::io(path, e))?
        .decode()
        .map_err(|e| TrainError::input(path, format!("cannot decode the image: {e}")))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sweeps_cover_minus_to_plus_max() {
        let yaw = sweep_views(Sweep::Yaw, 10.0, 30.0).unwrap();
        assert_eq!(
            yaw.iter().map(|v| v.yaw_deg).collect::<Vec<_>>(),
            vec![-30.0, -20.0, -10.0, 0.0, 10.0, 20.0, 30.0]
        );
        assert!(yaw.iter().all(|v| v.pitch_deg == 0.0));
        let pitch = sweep_views(Sweep::Pitch, 25.0, 30.0).unwrap();
        assert_eq!(
            pitch.iter().map(|v| v.pitch_deg).collect::<Vec<_>>(),
            vec![-30.0, -5.0, 20.0, 30.0]
        );
        let grid = sweep_views(Sweep::Grid, 30.0, 30.0).unwrap();
        assert_eq!(grid.len(), 9);
        assert_eq!((grid[5].yaw_deg, grid[5].pitch_deg), (30.0, 0.0));
        assert_eq!(grid[8].index, 8);
        assert!(sweep_views(Sweep::Yaw, 0.0, 30.0).is_err());
        assert_eq!("grid".parse::<Sweep>(), Ok(Sweep::Grid));
        assert!("roll".parse::<Sweep>().is_err());
    }

    #[test]
    fn frame_names_sort_in_sweep_order() {
        let v = ViewAngles {
            index: 3,
            yaw_deg: -0.0,
            pitch_deg: 12.5,
        };
        assert_eq!(frame_name(&v), "003_yaw+0_pitch+12.5.png");
    }

    /// A person box in a large photo ends up centred, [`PERSON_HEIGHT_FRACTION`] of the height.
    #[test]
    fn the_person_is_centred_and_scaled_like_the_training_data() {
        let (w, h) = (300u32, 200u32);
        // A 40 x 100 px red box at x 20..60, y 50..150 on a black, transparent canvas.
        let inside = |x: u32, y: u32| (20..60).contains(&x) && (50..150).contains(&y);
        let rgb = Rgb32FImage::from_fn(w, h, |x, y| {
            Rgb(if inside(x, y) {
                [1.0, 0.0, 0.0]
            } else {
                [0.0; 3]
            })
        });
        let alpha = ImageBuffer::from_fn(w, h, |x, y| Luma([if inside(x, y) { 1.0 } else { 0.0 }]));
        let out = prepare_photo(&rgb, &alpha, Cutout::Alpha, 100, [1.0, 1.0, 1.0]).unwrap();
        // 100 px of box become 94.8 px centred on row 51.7: rows 4.3..99.1; 40 px wide ->
        // 37.9: cols 31.0..69.0.
        let red = |x: u32, y: u32| {
            let p = out.get_pixel(x, y).0;
            p[0] > 0.9 && p[1] < 0.1
        };
        let white = |x: u32, y: u32| out.get_pixel(x, y).0.iter().all(|&c| c > 0.9);
        assert!(red(50, 50) && red(32, 5) && red(67, 98));
        assert!(white(50, 3) && white(29, 50) && white(70, 50));
        assert!(white(0, 0) && white(99, 0));
        let empty = ImageBuffer::from_pixel(w, h, Luma([0.0]));
        assert!(prepare_photo(&rgb, &empty, Cutout::Mask, 100, [1.0; 3]).is_err());
    }

    #[test]
    fn a_whole_image_is_fitted_into_the_square() {
        let rgb = Rgb32FImage::from_pixel(40, 20, Rgb([0.0, 0.0, 1.0]));
        let alpha = ImageBuffer::from_pixel(40, 20, Luma([1.0]));
        let out = prepare_photo(&rgb, &alpha, Cutout::WholeImage, 20, [1.0; 3]).unwrap();
        // 40 x 20 -> 20 x 10 in rows 5..15.
        assert!(out.get_pixel(10, 10).0[2] > 0.99 && out.get_pixel(10, 10).0[0] < 0.01);
        assert!(out.get_pixel(10, 2).0.iter().all(|&c| c > 0.99));
    }
}
