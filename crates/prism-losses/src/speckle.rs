//! The speckle score: how much pixel-level high-frequency noise a prediction has where the
//! truth is smooth.
//!
//! The score of a set of predictions is the mean absolute Laplacian of the predictions over the
//! mean absolute Laplacian of the truth, both taken on the same pixels: those where the truth
//! is smooth. A prediction as smooth as the truth scores 1; colour dots over a smooth shirt
//! raise it. Edges the truth has are left out by construction (the truth is not smooth there),
//! so a sharp edge in the right place costs nothing, and a blur of the truth scores at most 1.
//!
//! - The Laplacian of a pixel is the 4-neighbour `4 c - n - s - e - w`, its magnitude the mean
//!   of its absolute value over the 3 channels (interior pixels only).
//! - The truth is smooth at a pixel when the truth's Laplacian magnitude is below
//!   [`SMOOTH_LAPLACIAN`] on the pixel and its 8 neighbours (an edge is kept out with a
//!   one-pixel margin).
//! - Only the pixels inside an optional region count (`prism evaluate` passes the target's
//!   foreground: the score is about the person, not the flat background).

/// The truth's Laplacian magnitude (image values in [0, 1]) under which a pixel is smooth:
/// about 8 levels of an 8-bit image, above the rounding noise of a stored image.
pub const SMOOTH_LAPLACIAN: f32 = 0.03;

/// Sums of Laplacian magnitudes over the smooth pixels of one or more images, to be pooled
/// before [`SpeckleSums::score`] divides them.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SpeckleSums {
    /// The prediction's Laplacian magnitude, summed over the smooth pixels.
    pub prediction: f64,
    /// The truth's Laplacian magnitude over the same pixels.
    pub truth: f64,
    /// The number of smooth pixels.
    pub pixels: usize,
}

impl SpeckleSums {
    /// Adds another image's sums.
    pub fn add(&mut self, other: SpeckleSums) {
        self.prediction += other.prediction;
        self.truth += other.truth;
        self.pixels += other.pixels;
    }

    /// The speckle score: the prediction's mean Laplacian magnitude over the truth's (NaN
    /// without smooth pixels or when the truth is exactly flat there).
    pub fn score(&self) -> f64 {
        if self.pixels == 0 || self.truth <= 0.0 {
            return f64::NAN;
        }
        self.prediction / self.truth
    }

    /// The truth's own mean Laplacian magnitude over the smooth pixels (NaN without any).
    pub fn truth_mean(&self) -> f64 {
        if self.pixels == 0 {
            return f64::NAN;
        }
        self.truth / self.pixels as f64
    }
}

/// The per-pixel Laplacian magnitude of a `[3, H, W]` image (row-major planes); 0 on the
/// border, which has no 4 neighbours.
pub fn laplacian_magnitude(image: &[f32], width: usize, height: usize) -> Vec<f32> {
    let plane = width * height;
    assert_eq!(image.len(), 3 * plane, "a [3, {height}, {width}] image");
    let mut out = vec![0.0f32; plane];
    if width < 3 || height < 3 {
        return out;
    }
    for c in 0..3 {
        let p = &image[c * plane..(c + 1) * plane];
        for y in 1..height - 1 {
            for x in 1..width - 1 {
                let i = y * width + x;
                let lap = 4.0 * p[i] - p[i - 1] - p[i + 1] - p[i - width] - p[i + width];
                out[i] += lap.abs() / 3.0;
            }
        }
    }
    out
}

/// The speckle sums of one prediction against its truth, both `[3, H, W]` in [0, 1], over the
/// truth's smooth pixels inside `region` (`[H, W]`, inside where > 0.5; every pixel when
/// `None`).
///
/// # Panics
/// If the buffers do not have the given size.
pub fn speckle_sums(
    prediction: &[f32],
    truth: &[f32],
    region: Option<&[f32]>,
    width: usize,
    height: usize,
) -> SpeckleSums {
    let pred = laplacian_magnitude(prediction, width, height);
    let gt = laplacian_magnitude(truth, width, height);
    if let Some(region) = region {
        assert_eq!(region.len(), width * height, "a [{height}, {width}] region");
    }
    let mut sums = SpeckleSums::default();
    for y in 2..height.saturating_sub(2) {
        for x in 2..width.saturating_sub(2) {
            let i = y * width + x;
            if region.is_some_and(|r| r[i] <= 0.5) {
                continue;
            }
            let smooth = (y - 1..=y + 1)
                .all(|yy| (x - 1..=x + 1).all(|xx| gt[yy * width + xx] < SMOOTH_LAPLACIAN));
            if smooth {
                sums.prediction += f64::from(pred[i]);
                sums.truth += f64::from(gt[i]);
                sums.pixels += 1;
            }
        }
    }
    sums
}

#[cfg(test)]
mod tests {
    use super::*;

    const S: usize = 48;

    /// A smooth shaded image (a gentle quadratic in each channel, so its Laplacian is small
    /// but not zero) with a sharp vertical edge at x = 24 when `edge`.
    fn truth(edge: bool) -> Vec<f32> {
        let mut image = vec![0.0f32; 3 * S * S];
        for c in 0..3 {
            for y in 0..S {
                for x in 0..S {
                    let (fx, fy) = (x as f32 / S as f32, y as f32 / S as f32);
                    let mut v = 0.3 + 0.1 * c as f32 + 0.2 * (fx * fx + fy * fy);
                    if edge && x >= S / 2 {
                        v += 0.4;
                    }
                    image[(c * S + y) * S + x] = v;
                }
            }
        }
        image
    }

    /// Deterministic pseudo-random noise in [-amplitude, amplitude].
    fn noisy(image: &[f32], amplitude: f32) -> Vec<f32> {
        let mut state = 0x2545_f491_u32;
        image
            .iter()
            .map(|&v| {
                state ^= state << 13;
                state ^= state >> 17;
                state ^= state << 5;
                let u = state as f32 / u32::MAX as f32;
                v + amplitude * (2.0 * u - 1.0)
            })
            .collect()
    }

    #[test]
    fn noise_on_a_smooth_image_raises_the_score() {
        let gt = truth(false);
        let same = speckle_sums(&gt, &gt, None, S, S);
        assert!(
            same.pixels > (S - 4) * (S - 4) / 2,
            "most pixels are smooth"
        );
        assert!((same.score() - 1.0).abs() < 1e-9, "{}", same.score());
        let speckled = speckle_sums(&noisy(&gt, 0.05), &gt, None, S, S);
        assert_eq!(speckled.pixels, same.pixels, "the truth decides the pixels");
        assert!(speckled.score() > 10.0, "{}", speckled.score());
        let lighter = speckle_sums(&noisy(&gt, 0.01), &gt, None, S, S);
        assert!(
            lighter.score() > 1.5 && lighter.score() < speckled.score(),
            "{} vs {}",
            lighter.score(),
            speckled.score()
        );
    }

    #[test]
    fn a_sharp_edge_that_matches_the_truth_leaves_the_score_put() {
        let (smooth, edged) = (truth(false), truth(true));
        let without = speckle_sums(&smooth, &smooth, None, S, S);
        let with = speckle_sums(&edged, &edged, None, S, S);
        assert!((with.score() - without.score()).abs() < 1e-9);
        // The edge's columns (and a pixel either side) are not smooth, the rest is.
        assert!(with.pixels < without.pixels && with.pixels > without.pixels * 3 / 4);
        // Noise on top of the edged image is seen all the same.
        assert!(speckle_sums(&noisy(&edged, 0.05), &edged, None, S, S).score() > 10.0);
    }

    #[test]
    fn only_the_region_counts() {
        let gt = truth(false);
        let mut pred = gt.clone();
        // Noise in the left half only, the region the right half.
        let noise = noisy(&gt, 0.05);
        for c in 0..3 {
            for y in 0..S {
                for x in 0..S / 2 {
                    let i = (c * S + y) * S + x;
                    pred[i] = noise[i];
                }
            }
        }
        let region: Vec<f32> = (0..S * S)
            .map(|i| if i % S >= S / 2 + 2 { 1.0 } else { 0.0 })
            .collect();
        let inside = speckle_sums(&pred, &gt, Some(&region), S, S);
        assert!((inside.score() - 1.0).abs() < 1e-6, "{}", inside.score());
        assert!(speckle_sums(&pred, &gt, None, S, S).score() > 5.0);
    }
}
