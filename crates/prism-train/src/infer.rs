//! `prism infer`: novel views of a person from one photo (or each frame of a video).
//!
//! A photo has no camera: it gets the viewing protocol's frontal camera (view 0). The person
//! is found from a mask or the photo's alpha channel and framed like the training data: in the
//! frontal view the protocol's subject (1.80 m, at 2 m, focal length = image height) spans
//! [`PERSON_HEIGHT_FRACTION`] of the image height, centred. The model then synthesises the
//! views of a sweep (yaw, pitch or both within +-30 degrees).

use std::path::{Path, PathBuf};

use burn::tensor::Device;
use image::{DynamicImage, GrayImage, Rgb, Rgb32FImage, RgbImage, Rgba32FImage};
use indicatif::ProgressBar;
use prism_core::{BackendKind, Camera, Intrinsics, ViewAngles, ViewingProtocol};
use prism_model::{Precision, Prism};

use crate::checkpoint::load_inference_model;
use crate::error::{Result, TrainError};
use crate::images::{save_gif, save_png};
use crate::predict::{Pairs, forward_pairs, inference_model, synthesise};
use prism_core::images::HostImages;

/// Fraction of the image height the person's bounding box spans in the frontal view of the
/// training data. The protocol's 1.80 m subject seen from 2.0 m with a focal length of one
/// image height would be 0.90 for a flat figure; perspective (the body's front is nearer than
/// the orbit centre, the feet nearer than the head) and the anti-aliased mask edge make it
/// larger: 0.948 is the mean over the frontal views of the small config's 24 synthetic people
/// (`mask/000.png`, alpha > 0.5; range 0.90 to 0.99).
pub const PERSON_HEIGHT_FRACTION: f32 = 0.948;
/// Where the centre of the person's bounding box sits in the training data's frontal view, as
/// a fraction of the image height from the top: 0.517, the mean over the same 24 views (0.50
/// to 0.53; the nearer feet reach further down than the head up).
pub const PERSON_CENTRE_Y: f32 = 0.517;
/// File name of the sweep's animated GIF.
pub const SWEEP_GIF: &str = "sweep.gif";
/// File name of the framed input photo written next to the views.
pub const INPUT_PNG: &str = "input.png";

/// Which novel views to synthesise.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Sweep {
    /// Yaw from -max to +max, pitch 0.
    Yaw,
    /// Pitch from -max to +max, yaw 0.
    Pitch,
    /// Every (yaw, pitch) of the two sweeps, row by row (pitch outer).
    Grid,
}

impl std::str::FromStr for Sweep {
    type Err = String;

    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s {
            "yaw" => Ok(Self::Yaw),
            "pitch" => Ok(Self::Pitch),
            "grid" => Ok(Self::Grid),
            _ => Err(format!("unknown sweep `{s}` (yaw, pitch or grid)")),
        }
    }
}

/// The angles of a sweep: `-max, -max + step, ..., max` (the last one always `max`) along the
/// swept axes, as protocol views numbered from 0.
pub fn sweep_views(sweep: Sweep, step_deg: f32, max_deg: f32) -> Vec<ViewAngles> {
    let step = step_deg.abs().max(1e-3);
    let mut angles = Vec::new();
    let mut a = -max_deg;
    while a < max_deg - 1e-3 {
        angles.push(a);
        a += step;
    }
    angles.push(max_deg);
    let pairs: Vec<(f32, f32)> = match sweep {
        Sweep::Yaw => angles.iter().map(|&y| (y, 0.0)).collect(),
        Sweep::Pitch => angles.iter().map(|&p| (0.0, p)).collect(),
        Sweep::Grid => angles
            .iter()
            .flat_map(|&p| angles.iter().map(move |&y| (y, p)))
            .collect(),
    };
    pairs
        .into_iter()
        .enumerate()
        .map(|(index, (yaw_deg, pitch_deg))| ViewAngles {
            index,
            yaw_deg,
            pitch_deg,
        })
        .collect()
}

/// The file name of a synthesised view: `view_INDEX_yaw+YY_pitch+PP.png`.
pub fn view_file_name(view: &ViewAngles) -> String {
    format!(
        "view_{:03}_yaw{:+03.0}_pitch{:+03.0}.png",
        view.index, view.yaw_deg, view.pitch_deg
    )
}

/// Where the person in a photo was found.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Framing {
    /// From the mask given.
    Mask,
    /// From the photo's alpha channel.
    Alpha,
    /// Neither: the whole photo (centre-cropped to a square) is the input.
    WholeImage,
}

/// A photo framed like the training data, composited on the background.
#[derive(Clone, Debug)]
pub struct FramedPhoto {
    /// The model's input, `resolution x resolution`, RGB in [0, 1].
    pub image: Rgb32FImage,
    /// How the person was found.
    pub framing: Framing,
}

/// Reads a photo (and an optional mask) and frames it: see [`frame_photo`].
///
/// # Errors
/// An unreadable image or mask, a mask of another size, or an empty mask.
pub fn read_photo(
    path: &Path,
    mask: Option<&Path>,
    resolution: u32,
    background: [f32; 3],
) -> Result<FramedPhoto> {
    let photo = read_image(path)?;
    let mask = match mask {
        Some(m) => {
            let mask = read_image(m)?.to_luma8();
            if mask.dimensions() != (photo.width(), photo.height()) {
                return Err(input_error(
                    m,
                    format!(
                        "the mask is {}x{} but the photo {} is {}x{}",
                        mask.width(),
                        mask.height(),
                        path.display(),
                        photo.width(),
                        photo.height()
                    ),
                ));
            }
            Some((m, mask))
        }
        None => None,
    };
    frame_photo(
        &photo,
        mask.as_ref().map(|(_, m)| m),
        resolution,
        background,
    )
    .map_err(|message| input_error(mask.as_ref().map_or(path, |(m, _)| m), message))
}

/// Frames a photo like the training data: the person (pixels whose mask, or else alpha, is
/// above one half) is scaled to span [`PERSON_HEIGHT_FRACTION`] of the image height, its
/// bounding box centred horizontally with its centre [`PERSON_CENTRE_Y`] of the height down,
/// the rest composited on `background`, at `resolution` pixels square.
/// Without a mask and alpha, the photo is centre-cropped to a square and resized.
///
/// # Errors
/// A message when the mask (or alpha) selects no pixel.
pub fn frame_photo(
    photo: &DynamicImage,
    mask: Option<&GrayImage>,
    resolution: u32,
    background: [f32; 3],
) -> std::result::Result<FramedPhoto, String> {
    let mut rgba: Rgba32FImage = photo.to_rgba32f();
    let framing = if let Some(mask) = mask {
        for (p, m) in rgba.pixels_mut().zip(mask.pixels()) {
            p.0[3] = f32::from(m.0[0]) / 255.0;
        }
        Framing::Mask
    } else if photo.color().has_alpha() && rgba.pixels().any(|p| p.0[3] < 1.0) {
        Framing::Alpha
    } else {
        Framing::WholeImage
    };
    let (w, h) = rgba.dimensions();
    // The square window of the photo that becomes the model's input: (left, top, side).
    let (left, top, side) = match framing {
        Framing::WholeImage => {
            let side = w.min(h) as f32;
            ((w as f32 - side) / 2.0, (h as f32 - side) / 2.0, side)
        }
        _ => {
            let mut bounds: Option<[u32; 4]> = None;
            for (x, y, p) in rgba.enumerate_pixels() {
                if p.0[3] > 0.5 {
                    let b = bounds.get_or_insert([x, y, x, y]);
                    *b = [b[0].min(x), b[1].min(y), b[2].max(x), b[3].max(y)];
                }
            }
            let [x0, y0, x1, y1] = bounds.ok_or("the mask selects no pixel (all below 0.5)")?;
            let side = (y1 + 1 - y0) as f32 / PERSON_HEIGHT_FRACTION;
            let (cx, cy) = ((x0 + x1 + 1) as f32 / 2.0, (y0 + y1 + 1) as f32 / 2.0);
            (cx - side / 2.0, cy - side * PERSON_CENTRE_Y, side)
        }
    };
    let premultiplied = Rgba32FImage::from_fn(w, h, |x, y| {
        let [r, g, b, a] = rgba.get_pixel(x, y).0;
        let a = if framing == Framing::WholeImage {
            1.0
        } else {
            a
        };
        image::Rgba([r * a, g * a, b * a, a])
    });
    let image = resample_window(&premultiplied, (left, top, side), resolution, background);
    Ok(FramedPhoto { image, framing })
}

/// The square window `(left, top, side)` of a premultiplied RGBA image, area-averaged into
/// `resolution x resolution` pixels and composited on `background` (outside the image: the
/// background).
fn resample_window(
    premultiplied: &Rgba32FImage,
    (left, top, side): (f32, f32, f32),
    resolution: u32,
    background: [f32; 3],
) -> Rgb32FImage {
    let (w, h) = premultiplied.dimensions();
    let scale = side / resolution as f32;
    // Samples per output pixel along each axis: enough to average the source pixels it covers.
    let n = (scale.ceil() as u32).clamp(1, 16);
    Rgb32FImage::from_fn(resolution, resolution, |ox, oy| {
        let mut acc = [0.0f32; 4];
        for sy in 0..n {
            for sx in 0..n {
                let x = left + (ox as f32 + (sx as f32 + 0.5) / n as f32) * scale;
                let y = top + (oy as f32 + (sy as f32 + 0.5) / n as f32) * scale;
                let sample = bilinear(premultiplied, x - 0.5, y - 0.5, w, h);
                for (a, s) in acc.iter_mut().zip(sample) {
                    *a += s;
                }
            }
        }
        let k = (n * n) as f32;
        let alpha = acc[3] / k;
        Rgb([0, 1, 2].map(|c| (acc[c] / k + (1.0 - alpha) * background[c]).clamp(0.0, 1.0)))
    })
}

/// Bilinear sample at continuous pixel coordinates (pixel centres at integers); transparent
/// outside the image's area.
fn bilinear(image: &Rgba32FImage, x: f32, y: f32, w: u32, h: u32) -> [f32; 4] {
    let (wf, hf) = (w as f32, h as f32);
    if x < -0.5 || y < -0.5 || x > wf - 0.5 || y > hf - 0.5 {
        return [0.0; 4];
    }
    // Inside the image's area: clamp to the outer pixel centres (edge pixels extend).
    let (x, y) = (x.clamp(0.0, wf - 1.0), y.clamp(0.0, hf - 1.0));
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = (x - x0, y - y0);
    let at = |xi: f32, yi: f32| -> [f32; 4] {
        if xi < 0.0 || yi < 0.0 || xi >= w as f32 || yi >= h as f32 {
            [0.0; 4]
        } else {
            image.get_pixel(xi as u32, yi as u32).0
        }
    };
    let (a, b, c, d) = (
        at(x0, y0),
        at(x0 + 1.0, y0),
        at(x0, y0 + 1.0),
        at(x0 + 1.0, y0 + 1.0),
    );
    std::array::from_fn(|i| {
        (a[i] * (1.0 - fx) + b[i] * fx) * (1.0 - fy) + (c[i] * (1.0 - fx) + d[i] * fx) * fy
    })
}

/// The protocol's frontal camera (view 0) at `resolution` pixels square: the camera a photo
/// without one is given.
pub fn frontal_camera(resolution: u32) -> Camera {
    let protocol = ViewingProtocol::default();
    protocol.camera(
        &ViewAngles {
            index: 0,
            yaw_deg: 0.0,
            pitch_deg: 0.0,
        },
        Intrinsics::protocol_default(resolution, resolution),
    )
}

/// The views `model` (an inference model on `device`) synthesises of `image` (framed, seen by
/// the frontal camera) at the cameras of `views`, `batch` pairs per forward pass, as 8-bit RGB.
pub fn synthesise_views(
    model: &Prism,
    image: &Rgb32FImage,
    views: &[ViewAngles],
    background: [f32; 3],
    batch: usize,
    device: &Device,
    bar: &ProgressBar,
) -> Vec<RgbImage> {
    let res = image.width();
    let protocol = ViewingProtocol::default();
    let intrinsics = Intrinsics::protocol_default(res, res);
    let mut frames = Vec::new();
    for chunk in views.chunks(batch.max(1)) {
        let targets: Vec<Camera> = chunk
            .iter()
            .map(|v| protocol.camera(v, intrinsics))
            .collect();
        let pairs = Pairs::from_source(image, frontal_camera(res), &targets, background, device);
        let host = HostImages::from_tensor(synthesise(model, &pairs));
        frames.extend((0..chunk.len()).map(|i| host.rgb8(i)));
        bar.inc(chunk.len() as u64);
    }
    frames
}

/// How `prism infer` runs.
#[derive(Clone, Debug)]
pub struct InferOptions {
    /// The views to synthesise.
    pub sweep: Sweep,
    /// Degrees between consecutive views of the sweep.
    pub step_deg: f32,
    /// Pairs per forward pass.
    pub batch: usize,
    /// Milliseconds per frame of the GIF.
    pub gif_delay_ms: u32,
    /// Draw a progress bar on stderr.
    pub progress: bool,
    /// The precision of the transformer blocks ([`Prism::with_block_precision`]).
    pub precision: Precision,
}

impl Default for InferOptions {
    fn default() -> Self {
        Self {
            sweep: Sweep::Yaw,
            step_deg: 10.0,
            batch: 8,
            gif_delay_ms: 120,
            progress: false,
            precision: Precision::F32,
        }
    }
}

/// What `prism infer` wrote for one photo.
#[derive(Clone, Debug)]
pub struct InferredPhoto {
    /// The photo.
    pub input: PathBuf,
    /// How its person was found.
    pub framing: Framing,
    /// The folder of its views.
    pub dir: PathBuf,
    /// One PNG per view of the sweep.
    pub views: Vec<PathBuf>,
    /// The animated GIF of the sweep.
    pub gif: PathBuf,
}

/// Runs inference with a checkpoint (a checkpoint folder or a run folder's latest) on `input`:
/// a photo (with an optional `mask`), or a folder of video frames (each frame on its own, into
/// `out/FRAME_NAME/`). Writes the framed input, the sweep's PNGs and its GIF; with `export_ply`
/// (one photo only) also the 3DGS head's Gaussians as a standard 3DGS PLY.
///
/// # Errors
/// Unreadable checkpoints or images, a mask of another size, an empty mask, a folder without
/// images, `export_ply` for a model without a 3DGS head or for a folder, I/O errors.
pub fn infer(
    checkpoint: &Path,
    input: &Path,
    mask: Option<&Path>,
    out: &Path,
    backend: BackendKind,
    export_ply: Option<&Path>,
    options: &InferOptions,
) -> Result<Vec<InferredPhoto>> {
    let photos = if input.is_dir() {
        if mask.is_some() || export_ply.is_some() {
            return Err(input_error(
                input,
                "--mask and --export-ply take one photo, not a folder of frames",
            ));
        }
        let photos = list_images(input)?;
        if photos.is_empty() {
            return Err(input_error(input, "the folder holds no png or jpg image"));
        }
        photos
    } else {
        vec![input.to_path_buf()]
    };
    let device = backend.device()?;
    let (model, config) = load_inference_model(checkpoint, backend, &device, options.precision)?;
    if export_ply.is_some() && model.gs_head.is_none() {
        return Err(TrainError::checkpoint(
            checkpoint,
            "the model has no 3DGS head (model.gs_head = false): nothing to export as PLY",
        ));
    }
    let resolution = config.model.resolution as u32;
    let background = config.data.background;
    let views = sweep_views(
        options.sweep,
        options.step_deg,
        ViewingProtocol::default().max_angle_deg,
    );
    let inference = inference_model(&model);
    let bar = progress_bar(options.progress, (photos.len() * views.len()) as u64);
    let mut results = Vec::new();
    for photo in &photos {
        let framed = read_photo(photo, mask, resolution, background)?;
        let dir = if input.is_dir() {
            out.join(photo.file_stem().unwrap_or_default())
        } else {
            out.to_path_buf()
        };
        std::fs::create_dir_all(&dir).map_err(|e| TrainError::io(&dir, e))?;
        save_png(
            &dir.join(INPUT_PNG),
            &prism_core::images::rgb32_to_rgb8(&framed.image),
        )?;
        let frames = synthesise_views(
            &inference,
            &framed.image,
            &views,
            background,
            options.batch,
            &device,
            &bar,
        );
        let mut paths = Vec::new();
        for (view, frame) in views.iter().zip(&frames) {
            let path = dir.join(view_file_name(view));
            save_png(&path, frame)?;
            paths.push(path);
        }
        let gif = dir.join(SWEEP_GIF);
        save_gif(&gif, &frames, options.gif_delay_ms)?;
        if let Some(ply) = export_ply {
            let camera = frontal_camera(resolution);
            let pairs = Pairs::from_source(&framed.image, camera, &[camera], background, &device);
            let gaussians = forward_pairs(&model, &pairs)
                .gaussians
                .expect("a model with a 3DGS head returns its Gaussians");
            gaussians.save_ply(0, ply)?;
        }
        results.push(InferredPhoto {
            input: photo.clone(),
            framing: framed.framing,
            dir,
            views: paths,
            gif,
        });
    }
    bar.finish_and_clear();
    Ok(results)
}

/// The png / jpg / jpeg files of a folder, sorted by name (the frames of a video).
fn list_images(dir: &Path) -> Result<Vec<PathBuf>> {
    let entries = std::fs::read_dir(dir).map_err(|e| TrainError::io(dir, e))?;
    let mut out = Vec::new();
    for entry in entries {
        let path = entry.map_err(|e| TrainError::io(dir, e))?.path();
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase);
        if path.is_file() && matches!(ext.as_deref(), Some("png" | "jpg" | "jpeg")) {
            out.push(path);
        }
    }
    out.sort();
    Ok(out)
}

fn read_image(path: &Path) -> Result<DynamicImage> {
    image::ImageReader::open(path)
        .map_err(|e| TrainError::io(path, e))?
        .with_guessed_format()
        .map_err(|e| TrainError::io(path, e))?
        .decode()
        .map_err(|e| input_error(path, format!("not a readable image: {e}")))
}

fn input_error(path: &Path, message: impl Into<String>) -> TrainError {
    TrainError::io(path, std::io::Error::other(message.into()))
}

fn progress_bar(show: bool, len: u64) -> ProgressBar {
    prism_core::progress::progress_bar(
        show,
        len,
        "synthesising views [{bar:30}] {pos}/{len} (ETA {eta})",
    )
}
