//! The rendered buffers.

/// The renderer's output, row-major, `width * height` entries per buffer.
#[derive(Clone, Debug, PartialEq)]
pub struct RenderOutput {
    /// Image width in pixels.
    pub width: usize,
    /// Image height in pixels.
    pub height: usize,
    /// Colour composited on the background, display values in [0, 1].
    pub rgb: Vec<[f32; 3]>,
    /// Coverage in [0, 1]: the fraction of the pixel's sub-samples that hit the mesh.
    pub alpha: Vec<f32>,
    /// World point hit by the ray through the pixel centre; `[0, 0, 0]` when it misses.
    pub points: Vec<[f32; 3]>,
    /// Camera-space depth (z) of that point; 0 when the centre ray misses.
    pub depth: Vec<f32>,
}

impl RenderOutput {
    /// All-zero buffers of the given size.
    pub(crate) fn empty(width: usize, height: usize) -> Self {
        let n = width * height;
        Self {
            width,
            height,
            rgb: vec![[0.0; 3]; n],
            alpha: vec![0.0; n],
            points: vec![[0.0; 3]; n],
            depth: vec![0.0; n],
        }
    }

    /// Row-major index of pixel `(x, y)`.
    pub fn index(&self, x: usize, y: usize) -> usize {
        y * self.width + x
    }

    /// Whether the ray through the centre of pixel `(x, y)` hits the mesh (the pixels that
    /// carry a point).
    pub fn centre_covered(&self, x: usize, y: usize) -> bool {
        self.depth[self.index(x, y)] > 0.0
    }
}
