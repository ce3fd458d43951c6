//! Surface materials of a [`Mesh`](crate::Mesh): vertex colours, a flat colour or a texture.
//!
//! Rendering is unlit: the pixel is the material's colour. Textures are kept as a mip pyramid
//! and sampled trilinearly with a level chosen from the sample's footprint, so that a 4k scan
//! texture seen in a 512 px view is low-passed instead of aliased. Colours stay in display
//! (sRGB-encoded) values in [0, 1] throughout, as they are read from and written to image files.

use std::fmt;
use std::sync::Arc;

use glam::Vec2;

/// How the triangles of one material get their colour.
#[derive(Clone, Debug, PartialEq)]
pub enum Shading {
    /// Interpolate the mesh's per-vertex colours.
    VertexColors,
    /// One colour for the whole material (display values in [0, 1]).
    Flat([f32; 3]),
    /// Sample a texture at the triangles' corner UVs.
    Texture(Arc<Texture>),
}

/// A named material (the `newmtl` name of an MTL file, or a generated one).
#[derive(Clone, Debug, PartialEq)]
pub struct Material {
    /// Name, for messages.
    pub name: String,
    /// How its triangles are coloured.
    pub shading: Shading,
}

impl Material {
    /// A material with the given name and shading.
    pub fn new(name: impl Into<String>, shading: Shading) -> Self {
        Self {
            name: name.into(),
            shading,
        }
    }
}

/// One level of a mip pyramid: 8-bit RGB texels, row-major from the top row.
#[derive(Clone, PartialEq)]
struct MipLevel {
    width: usize,
    height: usize,
    texels: Vec<[u8; 3]>,
}

impl MipLevel {
    /// The next, half-sized level: each texel is the box average of the source texels it
    /// covers (odd sizes give the last texel of a row or column a three-wide box).
    fn downsampled(&self) -> MipLevel {
        let width = (self.width / 2).max(1);
        let height = (self.height / 2).max(1);
        let span = |i: usize, out: usize, src: usize| {
            let lo = i * src / out;
            let hi = ((i + 1) * src / out).max(lo + 1);
            lo..hi
        };
        let mut texels = Vec::with_capacity(width * height);
        for y in 0..height {
            let ys = span(y, height, self.height);
            for x in 0..width {
                let xs = span(x, width, self.width);
                let mut sum = [0u32; 3];
                let mut n = 0u32;
                for sy in ys.clone() {
                    for sx in xs.clone() {
                        let t = self.texels[sy * self.width + sx];
                        for c in 0..3 {
                            sum[c] += t[c] as u32;
                        }
                        n += 1;
                    }
                }
                texels.push(sum.map(|s| ((s + n / 2) / n) as u8));
            }
        }
        MipLevel {
            width,
            height,
            texels,
        }
    }

    /// Bilinear sample at continuous texel coordinates in `[0, width] x [0, height]`
    /// (texel centres at `+0.5`), wrapping around the edges (the OBJ default,
    /// `-clamp off`).
    fn bilinear(&self, x: f32, y: f32) -> [f32; 3] {
        let (fx, fy) = (x - 0.5, y - 0.5);
        let (x0, y0) = (fx.floor(), fy.floor());
        let (tx, ty) = (fx - x0, fy - y0);
        // The two texels around a coordinate in [-1, n]: wrap by one period at most.
        let wrap = |i: f32, n: usize| {
            let i = i as i64;
            if i < 0 {
                n - 1
            } else if i as usize >= n {
                (i as usize) % n
            } else {
                i as usize
            }
        };
        let (xa, xb) = (wrap(x0, self.width), wrap(x0 + 1.0, self.width));
        let (ya, yb) = (wrap(y0, self.height), wrap(y0 + 1.0, self.height));
        let at = |x: usize, y: usize| self.texels[y * self.width + x];
        let (a, b, c, d) = (at(xa, ya), at(xb, ya), at(xa, yb), at(xb, yb));
        let mut out = [0.0; 3];
        for k in 0..3 {
            let top = a[k] as f32 * (1.0 - tx) + b[k] as f32 * tx;
            let bottom = c[k] as f32 * (1.0 - tx) + d[k] as f32 * tx;
            out[k] = (top * (1.0 - ty) + bottom * ty) / 255.0;
        }
        out
    }
}

/// An RGB texture with its mip pyramid, sampled trilinearly.
///
/// UVs follow the OBJ / OpenGL convention: `(0, 0)` is the bottom-left corner of the image,
/// `(1, 1)` the top-right; outside [0, 1] the texture repeats.
#[derive(Clone, PartialEq)]
pub struct Texture {
    levels: Vec<MipLevel>,
}

impl fmt::Debug for Texture {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "Texture({}x{}, {} levels)",
            self.width(),
            self.height(),
            self.levels.len()
        )
    }
}

impl Texture {
    /// A texture from 8-bit RGB texels in row-major order from the top row; builds the mip
    /// pyramid down to 1x1.
    ///
    /// # Panics
    /// If `texels.len() != width * height` or a size is zero (a programming error; image
    /// decoders guarantee both).
    pub fn from_rgb8(width: usize, height: usize, texels: Vec<[u8; 3]>) -> Self {
        assert!(width > 0 && height > 0, "texture size must be positive");
        assert_eq!(texels.len(), width * height, "one texel per pixel");
        let mut levels = vec![MipLevel {
            width,
            height,
            texels,
        }];
        while let Some(last) = levels.last().filter(|l| l.width > 1 || l.height > 1) {
            let next = last.downsampled();
            levels.push(next);
        }
        Self { levels }
    }

    /// A texture from a decoded image.
    pub fn from_image(image: &image::RgbImage) -> Self {
        let texels = image.pixels().map(|p| p.0).collect();
        Self::from_rgb8(image.width() as usize, image.height() as usize, texels)
    }

    /// Width of the full-resolution level, in texels.
    pub fn width(&self) -> usize {
        self.levels[0].width
    }

    /// Height of the full-resolution level, in texels.
    pub fn height(&self) -> usize {
        self.levels[0].height
    }

    /// Number of mip levels (the full image included).
    pub fn num_levels(&self) -> usize {
        self.levels.len()
    }

    /// The colour at `uv` for a sample whose footprint spans `duv_dx` and `duv_dy` in UV
    /// units (the UV change from this sample to its right and lower neighbours).
    ///
    /// Trilinear filtering: level of detail `lambda = log2(max(|duv_dx * size|, |duv_dy *
    /// size|))` in level-0 texels, clamped to the pyramid; bilinear samples of the two
    /// nearest levels blended by the fractional part. Magnified samples (`lambda <= 0`) are
    /// bilinear on the full image.
    pub fn sample(&self, uv: Vec2, duv_dx: Vec2, duv_dy: Vec2) -> [f32; 3] {
        let size = Vec2::new(self.width() as f32, self.height() as f32);
        let rho = (duv_dx * size).length().max((duv_dy * size).length());
        let max_level = (self.levels.len() - 1) as f32;
        let lambda = if rho > 1.0 {
            rho.log2().min(max_level)
        } else {
            0.0
        };
        let lo = lambda.floor();
        let t = lambda - lo;
        let a = self.sample_level(lo as usize, uv);
        if t <= 0.0 {
            return a;
        }
        let b = self.sample_level(lo as usize + 1, uv);
        [0, 1, 2].map(|k| a[k] * (1.0 - t) + b[k] * t)
    }

    /// Bilinear sample of one level at `uv` (v flipped: v = 1 is the top row).
    fn sample_level(&self, level: usize, uv: Vec2) -> [f32; 3] {
        let l = &self.levels[level];
        // Keep the coordinates small so that f32 keeps sub-texel precision for repeated UVs.
        let (u, v) = (uv.x - uv.x.floor(), uv.y - uv.y.floor());
        l.bilinear(u * l.width as f32, (1.0 - v) * l.height as f32)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn checker(n: usize) -> Texture {
        let texels = (0..n * n)
            .map(|i| {
                if (i % n + i / n).is_multiple_of(2) {
                    [255; 3]
                } else {
                    [0; 3]
                }
            })
            .collect();
        Texture::from_rgb8(n, n, texels)
    }

    #[test]
    fn pyramid_goes_down_to_one_texel_and_averages() {
        let t = checker(16);
        assert_eq!(t.num_levels(), 5);
        let top = t.levels.last().unwrap();
        assert_eq!((top.width, top.height), (1, 1));
        // A checker averages to mid grey (rounded).
        assert!((top.texels[0][0] as i32 - 128).abs() <= 1);
        // Non-power-of-two sizes still reach 1x1.
        let odd = Texture::from_rgb8(5, 3, vec![[10, 20, 30]; 15]);
        assert_eq!(odd.levels.last().map(|l| (l.width, l.height)), Some((1, 1)));
        assert_eq!(odd.levels.last().unwrap().texels[0], [10, 20, 30]);
    }

    #[test]
    fn magnified_samples_hit_texel_centres_with_v_up() {
        // 2x2: top row red, green; bottom row blue, white.
        let t = Texture::from_rgb8(
            2,
            2,
            vec![[255, 0, 0], [0, 255, 0], [0, 0, 255], [255, 255, 255]],
        );
        let s = |u: f32, v: f32| t.sample(Vec2::new(u, v), Vec2::ZERO, Vec2::ZERO);
        assert_eq!(s(0.25, 0.75), [1.0, 0.0, 0.0]);
        assert_eq!(s(0.75, 0.75), [0.0, 1.0, 0.0]);
        assert_eq!(s(0.25, 0.25), [0.0, 0.0, 1.0]);
        // Halfway between red and green: their average.
        let mid = s(0.5, 0.75);
        assert!((mid[0] - 0.5).abs() < 1e-6 && (mid[1] - 0.5).abs() < 1e-6);
        // Repeats outside [0, 1].
        assert_eq!(s(1.25, -0.25), [1.0, 0.0, 0.0]);
    }

    #[test]
    fn minified_samples_are_filtered() {
        let t = checker(64);
        // A footprint of 16 texels: level 4 of a 1-texel checker is uniform grey.
        let d = Vec2::new(16.0 / 64.0, 0.0);
        for i in 0..20 {
            let uv = Vec2::new(0.013 + i as f32 * 0.047, 0.37 + i as f32 * 0.021);
            let c = t.sample(uv, d, d.perp());
            assert!((c[0] - 0.5).abs() < 0.02, "{c:?} at {uv}");
        }
    }
}
