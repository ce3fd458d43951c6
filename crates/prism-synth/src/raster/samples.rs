//! The sub-sample pattern of supersampling.

/// Where a pixel is sampled: an `s x s` grid of sub-samples, plus the pixel centre.
///
/// Colour and coverage average the grid; the point map and depth come from the ray through
/// the pixel centre. For odd `s` the centre is a grid sample; for even `s` it is an extra
/// sample that only feeds the point map.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct SamplePattern {
    /// Offsets from the pixel's top-left corner, in pixels: the grid, then the extra centre
    /// sample when `s` is even.
    pub offsets: Vec<(f64, f64)>,
    /// Number of grid samples (`s * s`): the first `grid` offsets.
    pub grid: usize,
    /// Index of the pixel-centre sample in `offsets`.
    pub centre: usize,
    /// Distance between neighbouring grid samples, in pixels (`1 / s`).
    pub spacing: f64,
}

impl SamplePattern {
    /// The regular `s x s` grid with sub-sample centres at `((i + 0.5) / s, (j + 0.5) / s)`.
    pub fn grid(s: usize) -> Self {
        let spacing = 1.0 / s as f64;
        let mut offsets: Vec<(f64, f64)> = (0..s * s)
            .map(|k| {
                let (i, j) = (k % s, k / s);
                ((i as f64 + 0.5) * spacing, (j as f64 + 0.5) * spacing)
            })
            .collect();
        let centre = if s % 2 == 1 {
            (s / 2) * s + s / 2
        } else {
            offsets.push((0.5, 0.5));
            s * s
        };
        Self {
            offsets,
            grid: s * s,
            centre,
            spacing,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn centre_sample_is_the_pixel_centre() {
        for s in 1..=4 {
            let p = SamplePattern::grid(s);
            assert_eq!(p.offsets[p.centre], (0.5, 0.5));
            assert_eq!(p.grid, s * s);
            assert_eq!(p.offsets.len(), s * s + (s + 1) % 2);
            let mean_x: f64 = p.offsets[..p.grid].iter().map(|o| o.0).sum::<f64>() / p.grid as f64;
            assert!((mean_x - 0.5).abs() < 1e-12);
        }
    }
}
