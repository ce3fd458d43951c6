//! `prism splat`: 3D Gaussian splatting utilities.

use std::path::PathBuf;

use anyhow::Context;
use clap::{Args, Subcommand};
use prism_core::BackendKind;
use prism_render::splat::{GaussianCloud, parse_background, read_camera, render_cloud, save_png};

/// Work with 3D Gaussian splats (standard 3DGS PLY files).
#[derive(Subcommand, Debug)]
pub enum SplatCommand {
    /// Render a 3DGS PLY file into one camera view and save a PNG.
    Render(RenderArgs),
}

impl SplatCommand {
    /// Runs the subcommand.
    pub fn run(self) -> anyhow::Result<()> {
        match self {
            Self::Render(args) => args.run(),
        }
    }
}

/// Arguments of `prism splat render`.
#[derive(Args, Debug)]
pub struct RenderArgs {
    /// The Gaussians: a standard 3DGS PLY file (binary little endian, SH degree 0 to 3; the
    /// colour comes from the degree-0 term).
    #[arg(long, value_name = "FILE")]
    pub ply: PathBuf,
    /// The view: a JSON object in the dataset's cameras.json schema (fx, fy, cx, cy, row-major
    /// 4x4 c2w in OpenCV axes, width, height).
    #[arg(long, value_name = "CAM.json")]
    pub camera: PathBuf,
    /// The PNG image to write (replaced atomically).
    #[arg(long, value_name = "IMG.png")]
    pub out: PathBuf,
    /// Background colour behind the Gaussians, three components in [0, 1].
    #[arg(long, value_name = "R,G,B", default_value = "0,0,0")]
    pub background: String,
    /// Backend to render with: ndarray, flex or wgpu.
    #[arg(long, default_value = "flex")]
    pub backend: String,
}

impl RenderArgs {
    /// Reads the PLY file and the camera, renders, writes the PNG.
    pub fn run(self) -> anyhow::Result<()> {
        let background = parse_background(&self.background)?;
        let device = self.backend.parse::<BackendKind>()?.device()?;
        let cloud = GaussianCloud::read(&self.ply)?;
        let camera = read_camera(&self.camera)?;
        let image = render_cloud(&cloud, &camera, background, &device)
            .with_context(|| format!("rendering {}", self.ply.display()))?;
        save_png(&image, &self.out)?;
        println!(
            "rendered {} Gaussians into {}x{} -> {}",
            cloud.len(),
            image.width(),
            image.height(),
            self.out.display()
        );
        Ok(())
    }
}
