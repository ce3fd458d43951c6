//! The heads on `T_out` (paper Sec. 3.2, Stage III): the NVS decoder ([`nvs`]: target tokens
//! to `I_t`) and the 3DGS head ([`gaussian`]: source tokens to Gaussians and their render
//! `I_gs`, with its silhouette's rim Gaussians in [`rim`]).

pub(crate) mod gaussian;
pub(crate) mod nvs;
pub(crate) mod rim;

use burn::tensor::Tensor;

use crate::geometry::points::dpt::{resize, shuffle};
use crate::tokenizer::patch::unpatchify;

/// Values per token and channel of a head's projection: `p^2` for the per-patch unpatchify
/// (`upsample = 0`), `upsample^2` for the smooth map of [`head_map`].
pub(crate) fn values_per_channel(patch_size: usize, upsample: usize) -> usize {
    let k = if upsample == 0 { patch_size } else { upsample };
    k * k
}

/// A head's per-token projections `[B, (H/p)(W/p), C k^2]` as a `[B, C, H, W]` map of raw
/// values. With `upsample = 0` (the paper) each token writes its own `p x p` pixels, every one
/// free of its neighbours (an unpatchify); with `upsample = f` each token writes an `f x f`
/// grid, and the map at `f / p` of the image is upsampled bilinearly to the pixels, so the
/// values vary smoothly within and across patches (no pixel-level noise of their own).
pub(crate) fn head_map(
    tokens: Tensor<3>,
    channels: usize,
    height: usize,
    width: usize,
    patch_size: usize,
    upsample: usize,
) -> Tensor<4> {
    if upsample == 0 {
        return unpatchify(tokens, channels, height, width, patch_size);
    }
    let (rows, cols) = (height / patch_size, width / patch_size);
    let map = shuffle(tokens, channels, upsample, rows, cols);
    resize(map, height, width)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_util::{ndarray, values};
    use burn::tensor::Distribution;

    #[test]
    fn without_upsampling_a_head_map_is_the_unpatchify() {
        let device = ndarray();
        let tokens = Tensor::<3>::random([2, 6, 3 * 16], Distribution::Normal(0.0, 1.0), &device);
        let ours = values(&head_map(tokens.clone(), 3, 8, 12, 4, 0));
        let theirs = values(&unpatchify(tokens, 3, 8, 12, 4));
        assert_eq!(ours, theirs);
        assert_eq!(values_per_channel(4, 0), 16);
        assert_eq!(values_per_channel(8, 2), 4);
    }

    #[test]
    fn an_upsampled_head_map_is_smooth_and_keeps_its_grid_values() {
        let device = ndarray();
        // A 2 x 3 grid of patches of 8 px, 2 x 2 values per token and channel.
        let tokens = Tensor::<3>::random([1, 6, 3 * 4], Distribution::Normal(0.0, 1.0), &device);
        let map = head_map(tokens.clone(), 3, 16, 24, 8, 2);
        assert_eq!(map.dims(), [1, 3, 16, 24]);
        let grid = values(&shuffle(tokens, 3, 2, 2, 3));
        let out = values(&map);
        // Neighbouring pixels differ by at most a quarter of the largest step between
        // neighbouring grid values (each grid cell spans 4 pixels): no pixel-level jumps.
        let step = |v: &[f32], w: usize, h: usize| {
            let mut m = 0.0f32;
            for c in 0..3 {
                for y in 0..h {
                    for x in 0..w {
                        let i = (c * h + y) * w + x;
                        if x + 1 < w {
                            m = m.max((v[i + 1] - v[i]).abs());
                        }
                        if y + 1 < h {
                            m = m.max((v[i + w] - v[i]).abs());
                        }
                    }
                }
            }
            m
        };
        let (grid_step, pixel_step) = (step(&grid, 6, 4), step(&out, 24, 16));
        assert!(
            pixel_step <= grid_step / 4.0 + 1e-5,
            "{pixel_step} vs {grid_step}"
        );
        // Means over each grid cell's 4 x 4 pixels stay close to the grid values: the map
        // interpolates them rather than inventing new ones.
        let mean_err = (0..3 * 4 * 6)
            .map(|i| {
                let (c, gy, gx) = (i / 24, (i / 6) % 4, i % 6);
                let mut sum = 0.0;
                for y in 4 * gy..4 * gy + 4 {
                    for x in 4 * gx..4 * gx + 4 {
                        sum += out[(c * 16 + y) * 24 + x];
                    }
                }
                (sum / 16.0 - grid[i]).abs()
            })
            .fold(0.0f32, f32::max);
        assert!(mean_err <= grid_step, "{mean_err} vs {grid_step}");
    }
}
