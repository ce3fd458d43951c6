//! 2D max pooling on host slices (no padding, dilation 1), forward and backward.
//!
//! Each `[H, W]` plane is pooled on its own, planes spread over the threads. An output row is
//! the largest of its window's input rows, element by element (one pass over contiguous rows,
//! which vectorises), then the largest of each window's columns in that row. The backward pass
//! finds each window's largest input again, the first in row-major order, and adds the output's
//! gradient there. A NaN in a window wins, as in Burn's and PyTorch's pooling.
//!
//! Layout: `x` and `dx` are `[planes, H, W]`, `y` and `dy` are `[planes, H_o, W_o]`, row-major.

use rayon::prelude::*;

/// Sizes of a max-pooling call.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PoolDims {
    /// Planes: images times channels.
    pub planes: usize,
    /// Input height and width.
    pub size: [usize; 2],
    /// Window height and width.
    pub kernel: [usize; 2],
    /// Stride along the height and the width.
    pub stride: [usize; 2],
}

impl PoolDims {
    /// The output's height and width, `(n - k) / s + 1` along each axis; `None` where the window
    /// is empty or larger than the input, or a stride is 0.
    pub fn output_size(&self) -> Option<[usize; 2]> {
        let axis = |a: usize| {
            (self.stride[a] > 0 && self.kernel[a] > 0 && self.size[a] >= self.kernel[a])
                .then(|| (self.size[a] - self.kernel[a]) / self.stride[a] + 1)
        };
        Some([axis(0)?, axis(1)?])
    }
}

/// `v` where it beats `best` (larger, or a NaN), else `best`.
#[inline(always)]
fn pick(best: f32, v: f32) -> f32 {
    if v > best || v.is_nan() { v } else { best }
}

/// The max-pooled `[planes, H_o, W_o]`.
///
/// # Panics
/// If `x` does not hold `planes x H x W` values or the window does not fit.
pub fn forward(x: &[f32], d: PoolDims) -> Vec<f32> {
    let [h, w] = d.size;
    let [ho, wo] = d
        .output_size()
        .expect("max pool: the window fits the input");
    assert_eq!(x.len(), d.planes * h * w, "max pool: input size");
    let mut y = vec![0.0f32; d.planes * ho * wo];
    y.par_chunks_mut(ho * wo)
        .zip(x.par_chunks(h * w))
        .for_each(|(y, x)| {
            let mut rows = vec![0.0f32; w];
            for (oh, y) in y.chunks_exact_mut(wo).enumerate() {
                let top = oh * d.stride[0];
                rows.copy_from_slice(&x[top * w..(top + 1) * w]);
                for i in 1..d.kernel[0] {
                    let row = &x[(top + i) * w..(top + i + 1) * w];
                    for (m, &v) in rows.iter_mut().zip(row) {
                        *m = pick(*m, v);
                    }
                }
                for (ow, out) in y.iter_mut().enumerate() {
                    let window = &rows[ow * d.stride[1]..ow * d.stride[1] + d.kernel[1]];
                    *out = window[1..].iter().fold(window[0], |m, &v| pick(m, v));
                }
            }
        });
    y
}

/// `dL/dx` from `dL/dy`: each output's gradient added at its window's largest input (the first
/// in row-major order; the last NaN where there is one).
///
/// # Panics
/// If the slices do not fit `d`.
pub fn backward(x: &[f32], dy: &[f32], d: PoolDims) -> Vec<f32> {
    let [h, w] = d.size;
    let [ho, wo] = d
        .output_size()
        .expect("max pool: the window fits the input");
    assert_eq!(x.len(), d.planes * h * w, "max pool: input size");
    assert_eq!(dy.len(), d.planes * ho * wo, "max pool: gradient size");
    let mut dx = vec![0.0f32; x.len()];
    dx.par_chunks_mut(h * w)
        .zip(x.par_chunks(h * w))
        .zip(dy.par_chunks(ho * wo))
        .for_each(|((dx, x), dy)| {
            for oh in 0..ho {
                for ow in 0..wo {
                    let (top, left) = (oh * d.stride[0], ow * d.stride[1]);
                    let mut at = top * w + left;
                    for i in top..top + d.kernel[0] {
                        for j in left..left + d.kernel[1] {
                            let v = x[i * w + j];
                            if v > x[at] || v.is_nan() {
                                at = i * w + j;
                            }
                        }
                    }
                    dx[at] += dy[oh * wo + ow];
                }
            }
        });
    dx
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 3x3 window at stride 2 on a 5x7 plane, by hand: each output is its window's largest.
    #[test]
    fn windows_take_their_largest_value_and_pass_it_the_gradient() {
        let x: Vec<f32> = (0..35).map(|i| ((i * 17) % 35) as f32).collect();
        let d = PoolDims {
            planes: 1,
            size: [5, 7],
            kernel: [3, 3],
            stride: [2, 2],
        };
        assert_eq!(d.output_size(), Some([2, 3]));
        let y = forward(&x, d);
        for (o, &got) in y.iter().enumerate() {
            let (oh, ow) = (o / 3, o % 3);
            let want = (0..3)
                .flat_map(|i| (0..3).map(move |j| (2 * oh + i) * 7 + 2 * ow + j))
                .map(|k| x[k])
                .fold(f32::MIN, f32::max);
            assert_eq!(got, want, "output {o}");
        }
        let dy: Vec<f32> = (1..=6).map(|v| v as f32).collect();
        let dx = backward(&x, &dy, d);
        for (o, &g) in dy.iter().enumerate() {
            let at = x.iter().position(|&v| v == y[o]).unwrap();
            assert!(dx[at] >= g, "output {o}'s gradient not at its maximum");
        }
        assert_eq!(dx.iter().sum::<f32>(), dy.iter().sum::<f32>());
    }

    /// A NaN in a window makes that output NaN and takes its gradient.
    #[test]
    fn a_nan_wins_its_window() {
        let mut x = vec![1.0f32; 9];
        x[4] = f32::NAN;
        let d = PoolDims {
            planes: 1,
            size: [3, 3],
            kernel: [2, 2],
            stride: [1, 1],
        };
        let y = forward(&x, d);
        assert!(y.iter().all(|v| v.is_nan()), "{y:?}");
        let dx = backward(&x, &[1.0; 4], d);
        assert_eq!(dx[4], 4.0);
    }
}
