//! The engine of `prism view`: one or two loaded models, the current input (an uploaded photo,
//! a webcam frame or a held-out person of a dataset) and the frames they synthesise at a
//! camera within the viewing protocol. The web server in the binary only moves bytes; every
//! image the page shows is made here, by the same calls as `prism infer`.

use std::path::{Path, PathBuf};
use std::time::Instant;

use burn::tensor::{Device, Tensor, TensorData};
use image::imageops::{FilterType, resize};
use image::{DynamicImage, Rgb32FImage, RgbImage};
use prism_core::BackendKind;
use prism_core::camera::{Camera, Intrinsics};
use prism_core::images::{HostImages, rgb32_to_rgb8};
use prism_core::protocol::{SOURCE_VIEW, ViewAngles, ViewingProtocol};
use prism_data::batch::rgb_chw;
use prism_data::{CameraRecord, DatasetReader, SplitKind};
use prism_losses::psnr;
use prism_model::{Precision, Prism};

use crate::checkpoint::load_inference_model;
use crate::error::{Result, TrainError};
use crate::infer::{Framing, frame_photo, frontal_camera};
use crate::predict::{Pairs, forward_pairs};

/// The largest photo or webcam frame the viewer decodes, in pixels per side.
pub const MAX_INPUT_SIDE: u32 = 4096;

/// A model the viewer can switch to.
#[derive(Debug)]
struct ViewerModel {
    /// Its name on the page (the checkpoint's folder name).
    name: String,
    /// The model, with its 3DGS head when it has one (for `I_gs`).
    model: Prism,
}

/// What the models see: the framed input at the models' resolution and its camera.
#[derive(Clone, Debug)]
struct Input {
    /// RGB in [0, 1], `resolution` square.
    image: Rgb32FImage,
    /// The source camera.
    camera: Camera,
    /// For a dataset person: the subject and its recorded views (the ground truth).
    person: Option<Person>,
}

/// A held-out person of the dataset as an input.
#[derive(Clone, Debug)]
struct Person {
    /// Subject folder name.
    subject: String,
    /// Its recorded views' cameras, at the dataset's image size.
    cameras: Vec<CameraRecord>,
}

/// One synthesised frame and what the page shows beside it.
#[derive(Clone, Debug)]
pub struct Frame {
    /// The model's novel view `I_t`.
    pub nvs: RgbImage,
    /// Its 3DGS head's render `I_gs` (none for a model without the head).
    pub gs: Option<RgbImage>,
    /// The framed input.
    pub source: RgbImage,
    /// For a dataset person: the recorded view the camera snapped to.
    pub truth: Option<RgbImage>,
    /// PSNR (dB) of `nvs` against `truth`.
    pub psnr: Option<f64>,
    /// The camera's yaw and pitch, degrees (after clamping to the protocol, and snapping for a
    /// dataset person).
    pub yaw_deg: f32,
    /// See `yaw_deg`.
    pub pitch_deg: f32,
    /// Seconds of the model's forward pass and read-back on the server.
    pub seconds: f64,
}

/// The loaded models and the current input.
#[derive(Debug)]
pub struct Viewer {
    models: Vec<ViewerModel>,
    device: Device,
    backend: BackendKind,
    resolution: u32,
    background: [f32; 3],
    protocol: ViewingProtocol,
    data: Option<DatasetReader>,
    people: Vec<String>,
    input: Option<Input>,
}

impl Viewer {
    /// Loads `checkpoints` (checkpoint or run folders, all of one resolution) on `backend`, their
    /// transformer blocks in `precision`, with the held-out people of the dataset at `data`
    /// (when given) as inputs; the first person, if any, is the first input.
    ///
    /// # Errors
    /// Unreadable checkpoints, checkpoints of different resolutions or backgrounds, a dataset
    /// that cannot be opened, a precision the backend does not compute in.
    pub fn open(
        checkpoints: &[PathBuf],
        data: Option<&Path>,
        backend: BackendKind,
        precision: Precision,
    ) -> Result<Self> {
        let device = backend.device()?;
        let mut models = Vec::new();
        let mut shape: Option<(u32, [f32; 3])> = None;
        for path in checkpoints {
            let (model, config) = load_inference_model(path, backend, &device, precision)?;
            let this = (config.model.resolution as u32, config.data.background);
            if let Some(first) = shape
                && first != this
            {
                return Err(TrainError::checkpoint(
                    path,
                    format!(
                        "its resolution and background ({} px, {:?}) differ from the first \
                         checkpoint's ({} px, {:?}): view checkpoints of one config together",
                        this.0, this.1, first.0, first.1
                    ),
                ));
            }
            shape = Some(this);
            models.push(ViewerModel {
                name: model_name(path, models.len()),
                model,
            });
        }
        let Some((resolution, background)) = shape else {
            return Err(TrainError::io(
                Path::new("--checkpoint"),
                std::io::Error::other("no checkpoint given"),
            ));
        };
        let data = data.map(DatasetReader::open).transpose()?;
        let people = data
            .as_ref()
            .map(|d| d.meta().subjects_of(SplitKind::Test).to_vec())
            .unwrap_or_default();
        let mut viewer = Self {
            models,
            device,
            backend,
            resolution,
            background,
            protocol: ViewingProtocol::default(),
            data,
            people,
            input: None,
        };
        if !viewer.people.is_empty() {
            viewer.set_person(0)?;
        }
        Ok(viewer)
    }

    /// The models' names, in the order of the checkpoints.
    pub fn models(&self) -> Vec<String> {
        self.models.iter().map(|m| m.name.clone()).collect()
    }

    /// The held-out people of the dataset that can be inputs.
    pub fn people(&self) -> &[String] {
        &self.people
    }

    /// The backend the models run on.
    pub fn backend(&self) -> BackendKind {
        self.backend
    }

    /// The models' image side, pixels.
    pub fn resolution(&self) -> u32 {
        self.resolution
    }

    /// The largest yaw and pitch the camera may take, degrees.
    pub fn max_angle_deg(&self) -> f32 {
        self.protocol.max_angle_deg
    }

    /// Makes an encoded photo (png or jpeg) the input, framed as `prism infer` frames it (by
    /// its alpha channel, else the whole photo); returns how the person was found.
    ///
    /// # Errors
    /// Bytes that are not an image, an image larger than [`MAX_INPUT_SIDE`], or an alpha
    /// channel that selects no pixel (a [`TrainError::Input`] saying so).
    pub fn set_photo(&mut self, bytes: &[u8]) -> Result<Framing> {
        let photo = decode(bytes)?;
        let framed = frame_photo(&photo, None, self.resolution, self.background)
            .map_err(TrainError::Input)?;
        self.input = Some(Input {
            image: framed.image,
            camera: frontal_camera(self.resolution),
            person: None,
        });
        Ok(framed.framing)
    }

    /// Makes held-out person `index` the input: its frontal view and camera, with its recorded
    /// views as the ground truth.
    ///
    /// # Errors
    /// An index past the people, unreadable files of the dataset.
    pub fn set_person(&mut self, index: usize) -> Result<()> {
        let (Some(data), Some(subject)) = (&self.data, self.people.get(index)) else {
            return Err(TrainError::Input(format!(
                "there is no held-out person {index} ({} in the dataset)",
                self.people.len()
            )));
        };
        let res = self.resolution;
        let cameras = data.cameras(subject)?;
        let (rgb, _) = data.view(subject, SOURCE_VIEW)?;
        self.input = Some(Input {
            image: at_resolution(rgb, res),
            camera: cameras[SOURCE_VIEW].camera().rescaled(res, res),
            person: Some(Person {
                subject: subject.clone(),
                cameras,
            }),
        });
        Ok(())
    }

    /// The frame of model `model` at `yaw_deg`, `pitch_deg` (clamped to the protocol's range;
    /// for a dataset person, snapped to the nearest of its recorded views, with that view as the
    /// ground truth).
    ///
    /// # Errors
    /// No input yet, a model index past the models, unreadable dataset files.
    pub fn frame(&self, model: usize, yaw_deg: f32, pitch_deg: f32) -> Result<Frame> {
        let input = self.input()?;
        let model = self.model(model)?;
        let max = self.max_angle_deg();
        let (yaw, pitch) = (yaw_deg.clamp(-max, max), pitch_deg.clamp(-max, max));
        let res = self.resolution;
        let (camera, yaw, pitch, truth) = match &input.person {
            Some(person) => {
                let record = nearest_view(&person.cameras, yaw, pitch);
                let (rgb, _) = self
                    .data
                    .as_ref()
                    .expect("a person comes from the dataset")
                    .view(&person.subject, record.index)?;
                let camera = record.camera().rescaled(res, res);
                (
                    camera,
                    record.yaw_deg,
                    record.pitch_deg,
                    Some(at_resolution(rgb, res)),
                )
            }
            None => {
                let view = ViewAngles {
                    index: 0,
                    yaw_deg: yaw,
                    pitch_deg: pitch,
                };
                let intrinsics = Intrinsics::protocol_default(res, res);
                (self.protocol.camera(&view, intrinsics), yaw, pitch, None)
            }
        };
        let start = Instant::now();
        let pairs = Pairs::from_source(
            &input.image,
            input.camera,
            &[camera],
            self.background,
            &self.device,
        );
        let out = forward_pairs(model, &pairs);
        let image = out.image.clamp(0.0, 1.0);
        let nvs = HostImages::from_tensor(image.clone());
        let gs = out
            .gaussians
            .map(|g| HostImages::from_tensor(g.image.clamp(0.0, 1.0)));
        let seconds = start.elapsed().as_secs_f64();
        let psnr = truth.as_ref().map(|t| {
            let (w, h) = (t.width() as usize, t.height() as usize);
            let truth = Tensor::from_data(TensorData::new(rgb_chw(t), [1, 3, h, w]), &self.device);
            psnr(image, truth)[0]
        });
        Ok(Frame {
            nvs: nvs.rgb8(0),
            gs: gs.map(|g| g.rgb8(0)),
            source: rgb32_to_rgb8(&input.image),
            truth: truth.as_ref().map(rgb32_to_rgb8),
            psnr,
            yaw_deg: yaw,
            pitch_deg: pitch,
            seconds,
        })
    }

    /// The 3DGS head's Gaussians of the current input by model `model`, as a standard 3DGS PLY
    /// file's bytes.
    ///
    /// # Errors
    /// No input yet, a model without a 3DGS head.
    pub fn ply(&self, model: usize) -> Result<Vec<u8>> {
        let input = self.input()?;
        let pairs = Pairs::from_source(
            &input.image,
            input.camera,
            &[input.camera],
            self.background,
            &self.device,
        );
        let Some(gaussians) = forward_pairs(self.model(model)?, &pairs).gaussians else {
            return Err(TrainError::Input(
                "this model has no 3DGS head: it has no Gaussians to export".into(),
            ));
        };
        gaussians.cloud(0)?.to_bytes().map_err(TrainError::Input)
    }

    fn input(&self) -> Result<&Input> {
        self.input.as_ref().ok_or_else(|| {
            TrainError::Input("no input yet: upload a photo or pick a person".into())
        })
    }

    fn model(&self, index: usize) -> Result<&Prism> {
        self.models.get(index).map(|m| &m.model).ok_or_else(|| {
            TrainError::Input(format!(
                "there is no model {index} ({} loaded)",
                self.models.len()
            ))
        })
    }
}

/// The name of checkpoint `path` on the page: its folder's name, or `model N`.
fn model_name(path: &Path, index: usize) -> String {
    path.file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| format!("model {}", index + 1))
}

/// Decodes an uploaded image, refusing one larger than [`MAX_INPUT_SIDE`] before decoding it.
fn decode(bytes: &[u8]) -> Result<DynamicImage> {
    let not_an_image =
        |e: image::ImageError| TrainError::Input(format!("not a png or jpeg image ({e})"));
    let reader = image::ImageReader::new(std::io::Cursor::new(bytes))
        .with_guessed_format()
        .map_err(|e| TrainError::Input(format!("unreadable upload ({e})")))?;
    let (w, h) = reader.into_dimensions().map_err(not_an_image)?;
    if w.max(h) > MAX_INPUT_SIDE {
        return Err(TrainError::Input(format!(
            "the image is {w}x{h}: at most {MAX_INPUT_SIDE} pixels per side"
        )));
    }
    image::ImageReader::new(std::io::Cursor::new(bytes))
        .with_guessed_format()
        .map_err(|e| TrainError::Input(format!("unreadable upload ({e})")))?
        .decode()
        .map_err(not_an_image)
}

/// `rgb` resized to `res` square (a dataset's own size is kept as it is).
fn at_resolution(rgb: Rgb32FImage, res: u32) -> Rgb32FImage {
    if rgb.dimensions() == (res, res) {
        rgb
    } else {
        resize(&rgb, res, res, FilterType::Triangle)
    }
}

/// The recorded view (not the source) nearest to `yaw`, `pitch` in angle.
fn nearest_view(cameras: &[CameraRecord], yaw: f32, pitch: f32) -> &CameraRecord {
    cameras
        .iter()
        .filter(|c| c.index != SOURCE_VIEW)
        .min_by(|a, b| {
            let d = |c: &CameraRecord| (c.yaw_deg - yaw).hypot(c.pitch_deg - pitch);
            d(a).total_cmp(&d(b))
        })
        .unwrap_or(&cameras[SOURCE_VIEW])
}
