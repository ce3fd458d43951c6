//! Rendering one subject of the viewing protocol into a dataset: every view's RGB, mask and
//! depth, the source point map, the cameras and the records. Shared by `data synth` (procedural
//! people) and `data render` (scans), so both produce the same format from the same renderer.

use image::{Luma, Rgb, Rgb32FImage};
use rayon::prelude::*;
use serde::Serialize;

use crate::mesh::Mesh;
use crate::raster::{RenderOptions, RenderOutput, render};
use prism_core::camera::Intrinsics;
use prism_core::protocol::{SOURCE_VIEW, ViewAngles, ViewingProtocol};
use prism_data::error::{DataError, Result};
use prism_data::io::{DepthMap, Mask, PointMap};
use prism_data::schema::{CameraRecord, SubjectRecord};
use prism_data::writer::DatasetWriter;

/// The renderer of a protocol dataset: the viewing protocol, square images of one resolution
/// and the renderer's settings, shared by every subject.
#[derive(Clone, Debug)]
pub struct ProtocolRenderer {
    /// The viewing protocol (the paper's).
    pub protocol: ViewingProtocol,
    /// Intrinsics of every view.
    pub intrinsics: Intrinsics,
    /// Renderer settings.
    pub options: RenderOptions,
}

impl ProtocolRenderer {
    /// The paper's protocol at `resolution` x `resolution` px, composited on `background`, with
    /// `supersample` x `supersample` samples per pixel.
    pub fn new(resolution: u32, background: [f32; 3], supersample: u32) -> Self {
        Self {
            protocol: ViewingProtocol::default(),
            intrinsics: Intrinsics::protocol_default(resolution, resolution),
            options: RenderOptions {
                supersample,
                background,
                ..Default::default()
            },
        }
    }

    /// Renders the protocol's views drawn from `seed` of `mesh` (already placed in the world)
    /// and writes subject `name` (see [`SubjectRender::write`]).
    #[allow(clippy::too_many_arguments)]
    pub fn write<B: Serialize + Sync>(
        &self,
        writer: &DatasetWriter,
        name: &str,
        seed: u64,
        mesh: &Mesh,
        record: &SubjectRecord,
        body: Option<&B>,
        on_view: &(dyn Fn() + Sync),
    ) -> Result<()> {
        let views = self.protocol.views(seed);
        SubjectRender {
            protocol: &self.protocol,
            views: &views,
            intrinsics: self.intrinsics,
            options: &self.options,
        }
        .write(writer, name, mesh, record, body, on_view)
    }
}

/// What to render a subject with.
#[derive(Clone, Debug)]
pub struct SubjectRender<'a> {
    /// The protocol giving the cameras.
    pub protocol: &'a ViewingProtocol,
    /// The views to render (the protocol's 105 for one subject).
    pub views: &'a [ViewAngles],
    /// Intrinsics of every view.
    pub intrinsics: Intrinsics,
    /// Renderer settings (supersampling, background).
    pub options: &'a RenderOptions,
}

impl SubjectRender<'_> {
    /// Renders `mesh` (already in world space) from every view and writes subject `name`
    /// atomically, with its record and optional body fit. `on_view` is called after each view
    /// (for progress bars).
    pub fn write<B: Serialize + Sync>(
        &self,
        writer: &DatasetWriter,
        name: &str,
        mesh: &Mesh,
        record: &SubjectRecord,
        body: Option<&B>,
        on_view: &(dyn Fn() + Sync),
    ) -> Result<()> {
        let subject = writer.begin_subject(name)?;
        let dir = writer.root().join(name);
        let outputs: Vec<(CameraRecord, Option<PointMap>)> = self
            .views
            .par_iter()
            .map(|view| {
                let camera = self.protocol.camera(view, self.intrinsics);
                let out = render(mesh, &camera, self.options).map_err(|e| {
                    DataError::invalid(&dir, format!("cannot render view {}: {e}", view.index))
                })?;
                let (rgb, mask, depth) = images(&out);
                subject.write_view(view.index, &rgb, &mask, &depth)?;
                on_view();
                let points = (view.index == SOURCE_VIEW).then_some(PointMap {
                    width: out.width as u32,
                    height: out.height as u32,
                    points: out.points,
                });
                Ok((CameraRecord::new(view, &camera), points))
            })
            .collect::<Result<_>>()?;
        let mut cameras = Vec::with_capacity(outputs.len());
        let mut source_points = None;
        for (camera, points) in outputs {
            cameras.push(camera);
            source_points = source_points.or(points);
        }
        let points = source_points.ok_or_else(|| {
            DataError::invalid(&dir, "the views do not include the source view 0")
        })?;
        subject.finish(&cameras, &points, record, body)
    }
}

/// The float RGB image, mask and depth map of a render.
fn images(out: &RenderOutput) -> (Rgb32FImage, Mask, DepthMap) {
    let (w, h) = (out.width as u32, out.height as u32);
    let at = |x: u32, y: u32| out.index(x as usize, y as usize);
    let rgb = Rgb32FImage::from_fn(w, h, |x, y| Rgb(out.rgb[at(x, y)]));
    let mask = Mask::from_fn(w, h, |x, y| Luma([out.alpha[at(x, y)]]));
    let depth = DepthMap::from_fn(w, h, |x, y| Luma([out.depth[at(x, y)]]));
    (rgb, mask, depth)
}
