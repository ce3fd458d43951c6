//! One band of image rows: z-buffer over the sub-samples, then shading and resolve.

use glam::{DMat4, DVec3};

use super::samples::SamplePattern;
use super::setup::RasterTriangle;
use super::shade::Shader;

/// Rows per band, the unit of parallel work.
pub(crate) const BAND_ROWS: usize = 8;

/// No triangle at this sample.
const NONE: u32 = u32::MAX;

/// The output slices of one band (`rows * width` entries each).
pub(crate) struct Targets<'a> {
    pub rgb: &'a mut [[f32; 3]],
    pub alpha: &'a mut [f32],
    pub points: &'a mut [[f32; 3]],
    pub depth: &'a mut [f32],
}

/// What every band shares: the sample pattern, the camera and the compositing background.
pub(crate) struct Frame<'a> {
    /// Image width in pixels.
    pub width: usize,
    /// Sub-sample pattern.
    pub pattern: &'a SamplePattern,
    /// Inverse near distance: hits with `1 / z` above it are too close.
    pub inv_near: f64,
    /// Intrinsics `fx, fy, cx, cy`.
    pub intrinsics: [f64; 4],
    /// Camera-to-world transform in double precision.
    pub c2w: DMat4,
    /// Background colour.
    pub background: [f32; 3],
}

impl Frame<'_> {
    /// Renders the `rows` rows from `y0`: `bin` lists the (indices of) `triangles` that may
    /// cover them.
    pub fn render_band(
        &self,
        y0: usize,
        rows: usize,
        triangles: &[RasterTriangle],
        bin: &[u32],
        shader: &Shader<'_>,
        out: Targets<'_>,
    ) {
        let ns = self.pattern.offsets.len();
        let n = rows * self.width * ns;
        // Inverse depth `1 / z = sum_i a_i` of the nearest hit so far (0: none) and its
        // (raster) triangle, per sub-sample.
        let mut inv_depth = vec![0.0f64; n];
        let mut winner = vec![NONE; n];
        for &t in bin {
            let tri = &triangles[t as usize];
            let [x0, ty0, x1, ty1] = tri.bounds;
            let (r0, r1) = (ty0.max(y0), ty1.min(y0 + rows - 1));
            for y in r0..=r1 {
                for x in x0..=x1 {
                    let base = ((y - y0) * self.width + x) * ns;
                    for (k, &(ox, oy)) in self.pattern.offsets.iter().enumerate() {
                        let a = tri.weights(x as f64 + ox, y as f64 + oy);
                        if !tri.covers(&a) {
                            continue;
                        }
                        let s = a[0] + a[1] + a[2];
                        if s > inv_depth[base + k] && s < self.inv_near {
                            inv_depth[base + k] = s;
                            winner[base + k] = t;
                        }
                    }
                }
            }
        }
        self.resolve(y0, rows, triangles, &inv_depth, &winner, shader, out);
    }

    /// Shades the visible sub-samples, averages them over each pixel on the background, and
    /// writes the centre ray's point and depth.
    #[allow(clippy::too_many_arguments)]
    fn resolve(
        &self,
        y0: usize,
        rows: usize,
        triangles: &[RasterTriangle],
        inv_depth: &[f64],
        winner: &[u32],
        shader: &Shader<'_>,
        out: Targets<'_>,
    ) {
        let p = self.pattern;
        let ns = p.offsets.len();
        let [fx, fy, cx, cy] = self.intrinsics;
        for row in 0..rows {
            let y = y0 + row;
            for x in 0..self.width {
                let pixel = row * self.width + x;
                let base = pixel * ns;
                let mut sum = [0.0f32; 3];
                let mut covered = 0usize;
                for k in 0..p.grid {
                    let t = winner[base + k];
                    let c = if t == NONE {
                        self.background
                    } else {
                        covered += 1;
                        let (ox, oy) = p.offsets[k];
                        shader.color(
                            &triangles[t as usize],
                            x as f64 + ox,
                            y as f64 + oy,
                            p.spacing,
                        )
                    };
                    for i in 0..3 {
                        sum[i] += c[i];
                    }
                }
                out.rgb[pixel] = sum.map(|s| s / p.grid as f32);
                out.alpha[pixel] = covered as f32 / p.grid as f32;
                if winner[base + p.centre] != NONE {
                    // The hit lies on the centre ray by construction: X_cam = z * d.
                    let z = 1.0 / inv_depth[base + p.centre];
                    let (u, v) = (x as f64 + 0.5, y as f64 + 0.5);
                    let cam = DVec3::new((u - cx) / fx * z, (v - cy) / fy * z, z);
                    let world = self.c2w.transform_point3(cam);
                    out.points[pixel] = world.as_vec3().to_array();
                    out.depth[pixel] = z as f32;
                }
            }
        }
    }
}
