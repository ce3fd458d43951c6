//! `prism infer`: novel views of a person from one photo (or each frame of a video).

use std::path::PathBuf;

use anyhow::{Context, bail};
use clap::Args;
use prism_data::BackendKind;
use prism_train::{Cutout, Sweep, list_frames, load_model, load_photo, render_sweep, sweep_views};

/// Render novel views of a person from one photo: a sweep of -30..=+30 degrees as PNG frames and
/// an animated GIF (sweep.gif), plus the centred input (input.png).
///
/// The photo gets the viewing protocol's frontal camera. The person is found from --mask (white
/// on black, the photo's size) or the photo's alpha channel, then centred and scaled like the
/// training data and composited on the training background; with neither, the whole image is
/// used (with a warning). --image may also be a folder of video frames: each frame is rendered
/// into its own subfolder of --out (--mask is then a folder with the same file names).
#[derive(Args, Debug)]
pub struct InferArgs {
    /// The model: a run folder (its latest checkpoint) or a checkpoint folder.
    #[arg(long, value_name = "RUN_OR_CKPT")]
    checkpoint: PathBuf,
    /// The photo (png, jpg), or a folder of video frames.
    #[arg(long, value_name = "PHOTO")]
    image: PathBuf,
    /// The person's mask (grey image, white = person), or a folder of masks for a folder of frames.
    #[arg(long, value_name = "MASK")]
    mask: Option<PathBuf>,
    /// Output folder.
    #[arg(long, value_name = "DIR")]
    out: PathBuf,
    /// Which views: yaw (pitch 0), pitch (yaw 0) or grid (every yaw x pitch).
    #[arg(long, default_value = "yaw", value_name = "yaw|pitch|grid")]
    sweep: Sweep,
    /// Degrees between two views of the sweep.
    #[arg(long, default_value_t = 5.0, value_name = "DEG")]
    step: f32,
    /// Also save the 3DGS head's Gaussians for the photo as a standard 3DGS PLY file (models
    /// with a 3DGS head; for a folder of frames one file per frame, FILE's name + frame name).
    #[arg(long, value_name = "FILE")]
    export_ply: Option<PathBuf>,
    /// Backend: ndarray, flex, wgpu or cuda.
    #[arg(long, default_value = "flex")]
    backend: BackendKind,
    /// No progress bar.
    #[arg(long)]
    quiet: bool,
}

impl InferArgs {
    /// Renders the sweep for the photo (or every frame) and prints where the files are.
    pub fn run(self) -> anyhow::Result<()> {
        let device = self.backend.device()?;
        let (model, config) = load_model(&self.checkpoint, &device)?;
        if self.export_ply.is_some() && model.gs_head.is_none() {
            return Err(prism_train::TrainError::NoGaussianHead)
                .with_context(|| format!("--export-ply with {}", self.checkpoint.display()));
        }
        let max = prism_data::protocol::ViewingProtocol::default().max_angle_deg;
        let views = sweep_views(self.sweep, self.step, max)?;
        let resolution = config.model.resolution as u32;
        let background = config.data.background;
        // (photo, mask, output folder, PLY file) per frame.
        let jobs: Vec<(PathBuf, Option<PathBuf>, PathBuf, Option<PathBuf>)> = if self.image.is_dir()
        {
            if self.mask.as_ref().is_some_and(|m| !m.is_dir()) {
                bail!(
                    "--image {} is a folder of frames: --mask must be a folder too",
                    self.image.display()
                );
            }
            list_frames(&self.image)?
                .into_iter()
                .map(|frame| {
                    let name = frame.file_name().expect("a file").to_owned();
                    let stem = frame
                        .file_stem()
                        .expect("a file")
                        .to_string_lossy()
                        .into_owned();
                    let mask = self.mask.as_ref().map(|m| m.join(&name));
                    let ply = self.export_ply.as_ref().map(|p| {
                        let base = p.file_stem().unwrap_or_default().to_string_lossy();
                        p.with_file_name(format!("{base}-{stem}.ply"))
                    });
                    (frame, mask, self.out.join(&stem), ply)
                })
                .collect()
        } else {
            vec![(
                self.image.clone(),
                self.mask.clone(),
                self.out.clone(),
                self.export_ply.clone(),
            )]
        };
        for (photo, mask, out, ply) in &jobs {
            let prepared = load_photo(photo, mask.as_deref(), resolution, background)?;
            if prepared.cutout == Cutout::WholeImage {
                eprintln!(
                    "warning: {} has no mask and no alpha channel: the whole image is taken as \
                     the person (pass --mask for better results)",
                    photo.display()
                );
            }
            if let Some(ply) = ply
                && let Some(parent) = ply.parent().filter(|p| !p.as_os_str().is_empty())
            {
                std::fs::create_dir_all(parent).with_context(|| parent.display().to_string())?;
            }
            let result = render_sweep(
                &model,
                &prepared.image,
                &views,
                background,
                &device,
                out,
                ply.as_deref(),
                !self.quiet,
            )
            .with_context(|| format!("rendering {}", photo.display()))?;
            println!(
                "{}: {} views ({} sweep, {} degree steps) in {}, animation {}",
                photo.display(),
                result.frames.len(),
                self.sweep,
                self.step,
                out.display(),
                result.gif.display()
            );
            if let Some(ply) = &result.ply {
                println!("gaussians: {}", ply.display());
            }
        }
        Ok(())
    }
}
