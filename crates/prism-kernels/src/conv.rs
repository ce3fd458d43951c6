//! 2D convolutions on host slices (groups 1, dilation 1, any kernel, stride and symmetric zero
//! padding) as matrix products over an im2col buffer, forward and backward.
//!
//! Per image, the buffer `cols` is `[C k_h k_w, H_o W_o]`: row `(c k_h + i) k_w + j` holds input
//! channel `c` read at offset `(i, j)` of the kernel for every output pixel (zero outside the
//! image). With the weight `W` as `[O, C k_h k_w]` (its own row-major layout):
//!
//! ```text
//! y = W cols + b,   dW = sum_images dy cols^T,   d cols = W^T dy  (scattered back: dx),
//! db = sum_images, pixels dy
//! ```
//!
//! Images are spread over the threads, each product single-threaded. Layout: `x` is
//! `[B, C, H, W]`, `y` and `dy` are `[B, O, H_o, W_o]`, row-major.

use rayon::prelude::*;

use crate::buffer::{Written, written_init, zeroed};
use crate::matrix::{View, matmul, matmul_into};

/// Sizes of a convolution call.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ConvDims {
    /// Images.
    pub batch: usize,
    /// Input channels `C`.
    pub channels: usize,
    /// Output channels `O`.
    pub outputs: usize,
    /// Input height and width.
    pub size: [usize; 2],
    /// Kernel height and width.
    pub kernel: [usize; 2],
    /// Stride along the height and the width.
    pub stride: [usize; 2],
    /// Zeros added on both sides of the height and of the width.
    pub padding: [usize; 2],
}

impl ConvDims {
    /// The output's height and width, `(n + 2 p - k) / s + 1` along each axis; `None` where the
    /// kernel is larger than the padded input or a stride is 0.
    pub fn output_size(&self) -> Option<[usize; 2]> {
        let axis = |a: usize| {
            let padded = self.size[a] + 2 * self.padding[a];
            (self.stride[a] > 0 && self.kernel[a] > 0 && padded >= self.kernel[a])
                .then(|| (padded - self.kernel[a]) / self.stride[a] + 1)
        };
        Some([axis(0)?, axis(1)?])
    }

    /// Rows of the im2col buffer: `C k_h k_w`.
    fn taps(&self) -> usize {
        self.channels * self.kernel[0] * self.kernel[1]
    }

    /// Output pixels per image.
    fn pixels(&self) -> usize {
        let [h, w] = self.output_size().expect("a valid convolution");
        h * w
    }

    /// Values of one input image.
    fn image(&self) -> usize {
        self.channels * self.size[0] * self.size[1]
    }

    /// Whether the im2col buffer is the input itself (a 1 x 1 kernel, stride 1, no padding).
    fn pointwise(&self) -> bool {
        self.kernel == [1, 1] && self.stride == [1, 1] && self.padding == [0, 0]
    }

    fn check(&self, x: usize, w: usize) {
        assert!(self.output_size().is_some(), "conv: no output for {self:?}");
        assert_eq!(
            x,
            self.batch * self.image(),
            "conv: input size for {self:?}"
        );
        assert_eq!(
            w,
            self.outputs * self.taps(),
            "conv: weight size for {self:?}"
        );
    }
}

/// For kernel offset `k` along an axis: the output positions `lo..hi` that read inside the
/// input (`o s + k - p` in `0..n`), and the first one's input position.
fn valid_range(n: usize, out: usize, k: usize, s: usize, p: usize) -> (usize, usize, usize) {
    // o s + k >= p  and  o s + k - p < n.
    let lo = p.saturating_sub(k).div_ceil(s);
    let hi = if n + p > k {
        ((n + p - k - 1) / s + 1).min(out)
    } else {
        0
    };
    let lo = lo.min(hi);
    (lo, hi, (lo * s + k).saturating_sub(p))
}

/// The im2col buffer `[C k_h k_w, H_o W_o]` of one image `x` (`[C, H, W]`).
fn im2col(x: &[f32], d: &ConvDims, cols: &mut [f32]) {
    let [h, w] = d.size;
    let [oh, ow] = d.output_size().expect("a valid convolution");
    let [kh, kw] = d.kernel;
    let [sh, sw] = d.stride;
    // A stride of 1 and an output as wide as the input ("same" padding): each row of the
    // buffer is the input's plane shifted, one copy.
    let shifted_planes = sh == 1 && sw == 1 && ow == w;
    let rows = cols.chunks_exact_mut(oh * ow);
    for (row, dst) in rows.enumerate() {
        let (c, i, j) = (row / (kh * kw), row / kw % kh, row % kw);
        let (y0, y1, iy0) = valid_range(h, oh, i, sh, d.padding[0]);
        let (x0, x1, ix0) = valid_range(w, ow, j, sw, d.padding[1]);
        if shifted_planes {
            // An empty window's first input pixel may lie past the input's end.
            if y0 < y1 && x0 < x1 {
                shifted_plane(&x[(c * h + iy0) * w + ix0..], ow, (y0, y1), (x0, x1), dst);
            } else {
                dst.fill(0.0);
            }
            continue;
        }
        dst[..y0 * ow].fill(0.0);
        dst[y1 * ow..].fill(0.0);
        for (k, oy) in (y0..y1).enumerate() {
            let src = &x[(c * h + iy0 + k * sh) * w..][..w];
            let line = &mut dst[oy * ow..(oy + 1) * ow];
            line[..x0].fill(0.0);
            line[x1..].fill(0.0);
            if sw == 1 {
                line[x0..x1].copy_from_slice(&src[ix0..ix0 + (x1 - x0)]);
            } else {
                for (t, v) in line[x0..x1].iter_mut().enumerate() {
                    *v = src[ix0 + t * sw];
                }
            }
        }
    }
}

/// One row of [`im2col`]'s buffer (`dst`, rows of `width`) where the input rows are `width`
/// wide too and the stride is 1: output pixel `(oy, ox)` of rows `y0..y1` and columns `x0..x1`
/// (a window that is not empty) reads `src[(oy - y0) width + ox - x0]`, so the whole window is
/// one copy; the columns outside `x0..x1` (copied over with the rows' neighbours) and the rows
/// outside `y0..y1` are zeroed after it.
fn shifted_plane(
    src: &[f32],
    width: usize,
    (y0, y1): (usize, usize),
    (x0, x1): (usize, usize),
    dst: &mut [f32],
) {
    let (start, end) = (y0 * width + x0, (y1 - 1) * width + x1);
    dst[start..end].copy_from_slice(&src[..end - start]);
    dst[..start].fill(0.0);
    dst[end..].fill(0.0);
    for oy in y0..y1 - 1 {
        dst[oy * width + x1..(oy + 1) * width + x0].fill(0.0);
    }
}

/// The adjoint of [`im2col`]: adds each buffer value to the input pixel it was read from.
fn col2im(cols: &[f32], d: &ConvDims, dx: &mut [f32]) {
    let [h, w] = d.size;
    let [oh, ow] = d.output_size().expect("a valid convolution");
    let [kh, kw] = d.kernel;
    let [sh, sw] = d.stride;
    for (row, src) in cols.chunks_exact(oh * ow).enumerate() {
        let (c, i, j) = (row / (kh * kw), row / kw % kh, row % kw);
        let (y0, y1, iy0) = valid_range(h, oh, i, sh, d.padding[0]);
        let (x0, x1, ix0) = valid_range(w, ow, j, sw, d.padding[1]);
        for (k, oy) in (y0..y1).enumerate() {
            let dst = &mut dx[(c * h + iy0 + k * sh) * w..][..w];
            let src = &src[oy * ow + x0..oy * ow + x1];
            if sw == 1 {
                // Contiguous on both sides, so the adds run as vectors (the strided loop
                // below runs one value at a time); the same adds, so the same values.
                let dst = &mut dst[ix0..ix0 + src.len()];
                dst.iter_mut().zip(src).for_each(|(d, &v)| *d += v);
            } else {
                for (t, &v) in src.iter().enumerate() {
                    dst[ix0 + t * sw] += v;
                }
            }
        }
    }
}

/// `y = conv(x, weight) + bias`: `[B, O, H_o, W_o]` from `x` `[B, C, H, W]`, `weight`
/// `[O, C, k_h, k_w]` and `bias` `[O]`.
pub fn forward(x: &[f32], weight: &[f32], bias: &[f32], d: ConvDims) -> Vec<f32> {
    d.check(x.len(), weight.len());
    assert_eq!(bias.len(), d.outputs, "conv: bias size");
    let (taps, pixels) = (d.taps(), d.pixels());
    let len = d.batch * d.outputs * pixels;
    if len == 0 || taps == 0 {
        return vec![0.0; len];
    }
    let w = View::rows(weight, d.outputs, taps);
    let image = d.image();
    let (y, _) = written_init(len, d.outputs * pixels, Vec::new, |cols, i, y| {
        let cols = image_cols(&x[i * image..][..image], &d, cols);
        let y = matmul_into(y, w, View::rows(cols, taps, pixels), 1.0);
        for (row, &b) in y.chunks_exact_mut(pixels).zip(bias) {
            row.iter_mut().for_each(|v| *v += b);
        }
        (Written::of(y), ())
    });
    y
}

/// One image's im2col buffer: the image itself for a pointwise convolution, else `buffer`
/// filled by [`im2col`].
fn image_cols<'a>(x: &'a [f32], d: &ConvDims, buffer: &'a mut Vec<f32>) -> &'a [f32] {
    if d.pointwise() {
        return x;
    }
    buffer.resize(d.taps() * d.pixels(), 0.0);
    im2col(x, d, buffer);
    buffer
}

/// Which gradients [`backward`] computes.
#[derive(Clone, Copy, Debug)]
pub struct Wanted {
    /// `dx`.
    pub input: bool,
    /// `dweight` and `dbias`.
    pub weight: bool,
}

/// The gradients `(dx, dweight, dbias)` of [`forward`] for `dy`; those not [`Wanted`] are
/// empty. The weight and bias gradients sum the images' in their order, so a training step
/// gives the same values whatever the threads do.
pub fn backward(
    x: &[f32],
    weight: &[f32],
    dy: &[f32],
    d: ConvDims,
    wanted: Wanted,
) -> (Vec<f32>, Vec<f32>, Vec<f32>) {
    d.check(x.len(), weight.len());
    let (taps, pixels) = (d.taps(), d.pixels());
    assert_eq!(
        dy.len(),
        d.batch * d.outputs * pixels,
        "conv: gradient size"
    );
    let image = d.image().max(1);
    let (mut dw, mut db) = (vec![0.0f32; d.outputs * taps], vec![0.0f32; d.outputs]);
    if pixels == 0 || taps == 0 {
        let dx = if wanted.input {
            vec![0.0; x.len()]
        } else {
            Vec::new()
        };
        return (
            dx,
            wanted_only(dw, wanted.weight),
            wanted_only(db, wanted.weight),
        );
    }
    let w = View::rows(weight, d.outputs, taps);
    let image_dy = |i: usize| &dy[i * d.outputs * pixels..][..d.outputs * pixels];
    let dy_view = |i: usize| View::rows(image_dy(i), d.outputs, pixels);
    // One image's own weight and bias gradients (empty where not wanted).
    let image_weight_grads = |cols: &mut Vec<f32>, i: usize| -> (Vec<f32>, Vec<f32>) {
        if !wanted.weight {
            return Default::default();
        }
        let cols = image_cols(&x[i * image..][..image], &d, cols);
        let mut dw = vec![0.0f32; d.outputs * taps];
        let transposed = View::transposed(cols, pixels, taps);
        matmul(&mut dw, false, dy_view(i), transposed, 1.0);
        let db = image_dy(i)
            .chunks_exact(pixels)
            .map(|r| r.iter().sum())
            .collect();
        (dw, db)
    };
    // Per image: its input gradient, written whole, and its weight and bias gradients.
    let (dx, per_image) = if wanted.input {
        written_init(x.len(), image, Vec::new, |cols, i, dx| {
            let dx = if d.pointwise() {
                matmul_into(dx, w.t(), dy_view(i), 1.0)
            } else {
                cols.resize(taps * pixels, 0.0);
                matmul(cols, false, w.t(), dy_view(i), 1.0);
                let dx = zeroed(dx);
                col2im(cols, &d, dx);
                dx
            };
            (Written::of(dx), image_weight_grads(cols, i))
        })
    } else {
        let per_image = (0..d.batch)
            .into_par_iter()
            .map_init(Vec::new, image_weight_grads)
            .collect();
        (Vec::new(), per_image)
    };
    // Summed in the images' order: the same bits whatever the threads do.
    for (image_dw, image_db) in &per_image {
        dw.iter_mut().zip(image_dw).for_each(|(a, b)| *a += b);
        db.iter_mut().zip(image_db).for_each(|(a, b)| *a += b);
    }
    (
        dx,
        wanted_only(dw, wanted.weight),
        wanted_only(db, wanted.weight),
    )
}

/// `v` where it was wanted, else empty.
fn wanted_only(v: Vec<f32>, wanted: bool) -> Vec<f32> {
    if wanted { v } else { Vec::new() }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_util::values;

    /// The convolution by its definition, in f64.
    fn reference(x: &[f32], weight: &[f32], bias: &[f32], d: &ConvDims) -> Vec<f64> {
        let [h, w] = d.size;
        let [oh, ow] = d.output_size().unwrap();
        let [kh, kw] = d.kernel;
        let mut y = vec![0.0f64; d.batch * d.outputs * oh * ow];
        for b in 0..d.batch {
            for o in 0..d.outputs {
                for oy in 0..oh {
                    for ox in 0..ow {
                        let mut s = bias[o] as f64;
                        for c in 0..d.channels {
                            for i in 0..kh {
                                for j in 0..kw {
                                    let iy =
                                        (oy * d.stride[0] + i) as isize - d.padding[0] as isize;
                                    let ix =
                                        (ox * d.stride[1] + j) as isize - d.padding[1] as isize;
                                    if iy < 0 || ix < 0 || iy >= h as isize || ix >= w as isize {
                                        continue;
                                    }
                                    let xv = x[((b * d.channels + c) * h + iy as usize) * w
                                        + ix as usize];
                                    let wv = weight[((o * d.channels + c) * kh + i) * kw + j];
                                    s += xv as f64 * wv as f64;
                                }
                            }
                        }
                        y[((b * d.outputs + o) * oh + oy) * ow + ox] = s;
                    }
                }
            }
        }
        y
    }

    /// Kernels, strides and paddings of the model's heads and of LPIPS's AlexNet, on small odd
    /// sizes, including a kernel wider than the unpadded input.
    fn cases() -> Vec<ConvDims> {
        let d = |batch, channels, outputs, size, kernel, stride, padding| ConvDims {
            batch,
            channels,
            outputs,
            size,
            kernel,
            stride,
            padding,
        };
        vec![
            d(2, 3, 4, [7, 6], [3, 3], [1, 1], [1, 1]),
            d(3, 2, 5, [9, 11], [5, 5], [2, 3], [2, 2]),
            d(1, 3, 2, [13, 12], [11, 11], [4, 4], [2, 2]),
            d(2, 4, 3, [5, 4], [1, 1], [1, 1], [0, 0]),
            d(1, 2, 2, [2, 3], [3, 3], [1, 1], [1, 1]),
            d(2, 1, 2, [6, 5], [3, 2], [1, 2], [0, 1]),
            d(1, 2, 3, [6, 7], [5, 5], [1, 1], [2, 2]),
            d(1, 2, 2, [4, 1], [3, 3], [1, 1], [1, 1]),
            d(1, 2, 2, [1, 1], [3, 3], [1, 1], [1, 1]),
        ]
    }

    /// Every value of the im2col buffer is its tap's input pixel, or 0 in the padding, exactly:
    /// row `(c, i, j)`, column `(oy, ox)` holds `x[c, oy s + i - p, ox s + j - p]`.
    #[test]
    fn im2col_holds_each_taps_input_value() {
        for d in cases() {
            let x = values(d.image(), 9);
            let [h, w] = d.size;
            let [oh, ow] = d.output_size().unwrap();
            let [kh, kw] = d.kernel;
            let mut cols = vec![f32::NAN; d.taps() * d.pixels()];
            im2col(&x, &d, &mut cols);
            for (row, values) in cols.chunks_exact(oh * ow).enumerate() {
                let (c, i, j) = (row / (kh * kw), row / kw % kh, row % kw);
                for (o, &v) in values.iter().enumerate() {
                    let iy = (o / ow * d.stride[0] + i) as isize - d.padding[0] as isize;
                    let ix = (o % ow * d.stride[1] + j) as isize - d.padding[1] as isize;
                    let inside = (0..h as isize).contains(&iy) && (0..w as isize).contains(&ix);
                    let want = if inside {
                        x[(c * h + iy as usize) * w + ix as usize]
                    } else {
                        0.0
                    };
                    assert_eq!(v.to_bits(), want.to_bits(), "{d:?} row {row} pixel {o}");
                }
            }
        }
    }

    #[test]
    fn forward_matches_the_definition() {
        for d in cases() {
            let x = values(d.batch * d.image(), 1);
            let w = values(d.outputs * d.taps(), 2);
            let b = values(d.outputs, 3);
            let want = reference(&x, &w, &b, &d);
            let got = forward(&x, &w, &b, d);
            assert_eq!(got.len(), want.len(), "{d:?}");
            for (g, r) in got.iter().zip(&want) {
                assert!((*g as f64 - r).abs() < 1e-4, "{d:?}: {g} against {r}");
            }
        }
    }

    /// The gradients against central differences of `sum(y * r)` for a fixed `r`: linear in
    /// each of `x`, `w` and `b`, so the differences are exact up to rounding.
    #[test]
    fn gradients_match_finite_differences() {
        for d in cases() {
            let x = values(d.batch * d.image(), 4);
            let w = values(d.outputs * d.taps(), 5);
            let b = values(d.outputs, 6);
            let r = values(forward(&x, &w, &b, d).len(), 7);
            let loss = |x: &[f32], w: &[f32], b: &[f32]| -> f64 {
                let y = reference(x, w, b, &d);
                y.iter().zip(&r).map(|(y, r)| y * *r as f64).sum()
            };
            let all = Wanted {
                input: true,
                weight: true,
            };
            let (dx, dw, db) = backward(&x, &w, &r, d, all);
            let eps = 1e-2f32;
            let check = |name: &str, grad: &[f32], at: &dyn Fn(usize, f32) -> f64| {
                for (i, &g) in grad.iter().enumerate() {
                    let fd = (at(i, eps) - at(i, -eps)) / (2.0 * eps as f64);
                    assert!(
                        (g as f64 - fd).abs() < 1e-3,
                        "{d:?} d{name}[{i}]: {g} against {fd}"
                    );
                }
            };
            let bumped = |v: &[f32], i: usize, e: f32| {
                let mut v = v.to_vec();
                v[i] += e;
                v
            };
            check("x", &dx, &|i, e| loss(&bumped(&x, i, e), &w, &b));
            check("w", &dw, &|i, e| loss(&x, &bumped(&w, i, e), &b));
            check("b", &db, &|i, e| loss(&x, &w, &bumped(&b, i, e)));
            // Each part alone gives the same values.
            let input = backward(
                &x,
                &w,
                &r,
                d,
                Wanted {
                    input: true,
                    weight: false,
                },
            );
            let weight = backward(
                &x,
                &w,
                &r,
                d,
                Wanted {
                    input: false,
                    weight: true,
                },
            );
            assert_eq!((input.0, input.1.len()), (dx, 0), "{d:?}");
            assert_eq!((weight.0.len(), weight.1, weight.2), (0, dw, db), "{d:?}");
        }
    }
}
