//! Triplane sampling on plain `f32` buffers: forward and exact reverse pass, parallel with
//! rayon.
//!
//! Planes are taken channel-last here (`[3, R, R, C]`) so that one bilinear tap reads `C`
//! contiguous values; the tensor layout `[3, C, R, R]` is transposed on the way in and out.

use multiversion::multiversion;
use rayon::prelude::*;

/// The two coordinate axes each plane is indexed by: plane 0 `(x, y)`, plane 1 `(x, z)`,
/// plane 2 `(y, z)`; the first gives the column, the second the row.
pub const PLANE_AXES: [[usize; 2]; 3] = [[0, 1], [0, 2], [1, 2]];

/// Points per unit of parallel work.
const CHUNK: usize = 1024;
/// Groups of chunks whose plane gradients the backward pass accumulates apart, one buffer of
/// the planes' size each: a fixed count, so that the sum does not depend on the threads.
const GROUPS: usize = 4;

/// One group's gradients: of the planes, and of each of its chunks' coordinates (with the
/// chunk's first point).
type GroupGradients = (Vec<f32>, Vec<(usize, Vec<f32>)>);

/// One bilinear tap along one axis: the lower texel, the weight of the upper one, and
/// `d(texel coordinate) / d(coordinate)` (0 where the coordinate is clamped at the border).
#[derive(Clone, Copy, Debug)]
struct Tap {
    i0: usize,
    i1: usize,
    frac: f32,
    slope: f32,
}

impl Tap {
    /// Texel coordinate `t = (c + 1) R / 2 - 0.5` (texel centres at `i + 0.5` of `2 / R`-wide
    /// texels over `[-1, 1]`, "align corners = false"), clamped to `[0, R - 1]` (border
    /// padding).
    fn new(c: f32, r: usize) -> Self {
        let half = r as f32 * 0.5;
        let t = (c + 1.0) * half - 0.5;
        let max = (r - 1) as f32;
        if r == 1 || t.is_nan() || t <= 0.0 || t >= max {
            // Clamped (NaN lands here too): constant in c.
            let i = if r > 1 && t >= max { r - 1 } else { 0 };
            return Self {
                i0: i,
                i1: i,
                frac: 0.0,
                slope: 0.0,
            };
        }
        let i0 = t.floor() as usize;
        Self {
            i0,
            i1: i0 + 1,
            frac: t - i0 as f32,
            slope: half,
        }
    }
}

/// `[3, C, R, R]` to `[3, R, R, C]`.
pub fn to_channel_last(planes: &[f32], c: usize, r: usize) -> Vec<f32> {
    let mut out = vec![0.0; planes.len()];
    for p in 0..3 {
        for ch in 0..c {
            let src = &planes[(p * c + ch) * r * r..(p * c + ch + 1) * r * r];
            for (texel, &v) in src.iter().enumerate() {
                out[(p * r * r + texel) * c + ch] = v;
            }
        }
    }
    out
}

/// `[3, R, R, C]` to `[3, C, R, R]`.
fn to_channel_first(planes: &[f32], c: usize, r: usize) -> Vec<f32> {
    let mut out = vec![0.0; planes.len()];
    for p in 0..3 {
        for texel in 0..r * r {
            for ch in 0..c {
                out[(p * c + ch) * r * r + texel] = planes[(p * r * r + texel) * c + ch];
            }
        }
    }
    out
}

/// Sizes of one call: `B` images of `S = H W` points, `C` channels, planes of `R x R`.
#[derive(Clone, Copy, Debug)]
pub struct Dims {
    /// Batch `B`.
    pub batch: usize,
    /// Points per batch element `S`.
    pub points: usize,
    /// Channels `C`.
    pub channels: usize,
    /// Plane resolution `R`.
    pub resolution: usize,
}

/// The coordinate of point `s` of batch element `b` along `axis`, from `[B, 3, S]`.
fn coord(coords: &[f32], dims: Dims, b: usize, s: usize, axis: usize) -> f32 {
    coords[(b * 3 + axis) * dims.points + s]
}

/// Forward: `planes` channel-last `[3, R, R, C]`, `coords` `[B, 3, S]`; returns `[B, C, S]`
/// with `out = sum_p bilinear(plane_p, (c_{a_p}, c_{b_p}))`.
pub fn forward(planes_last: &[f32], coords: &[f32], dims: Dims) -> Vec<f32> {
    let Dims {
        batch,
        points,
        channels: c,
        ..
    } = dims;
    // Point-major results first, transposed per batch element afterwards.
    let mut rows = vec![0.0f32; batch * points * c];
    rows.par_chunks_mut(CHUNK * c)
        .enumerate()
        .for_each(|(chunk, out)| sample_chunk(planes_last, coords, dims, chunk * CHUNK, out));
    let mut out = vec![0.0f32; batch * c * points];
    out.par_chunks_mut(c * points)
        .enumerate()
        .for_each(|(b, image)| {
            for s in 0..points {
                let src = &rows[(b * points + s) * c..(b * points + s + 1) * c];
                for (ch, &v) in src.iter().enumerate() {
                    image[ch * points + s] = v;
                }
            }
        });
    out
}

/// The points from `first` on, one row of `C` values each in `out` (zeros on entry): the sum
/// over the planes of each point's bilinear taps. Compiled for AVX-512 and AVX2 too, chosen
/// at run time: a tap's channels are a few vectors of lanes.
#[multiversion(targets("x86_64+avx512f+avx512vl+avx512dq", "x86_64+avx2+fma"))]
fn sample_chunk(planes_last: &[f32], coords: &[f32], dims: Dims, first: usize, out: &mut [f32]) {
    let (c, r, points) = (dims.channels, dims.resolution, dims.points);
    for (k, value) in out.chunks_exact_mut(c).enumerate() {
        let global = first + k;
        let (b, s) = (global / points, global % points);
        for (p, axes) in PLANE_AXES.iter().enumerate() {
            let u = Tap::new(coord(coords, dims, b, s, axes[0]), r);
            let v = Tap::new(coord(coords, dims, b, s, axes[1]), r);
            let texel = |row: usize, col: usize| {
                let start = (p * r * r + row * r + col) * c;
                &planes_last[start..start + c]
            };
            let (t00, t01) = (texel(v.i0, u.i0), texel(v.i0, u.i1));
            let (t10, t11) = (texel(v.i1, u.i0), texel(v.i1, u.i1));
            let w00 = (1.0 - v.frac) * (1.0 - u.frac);
            let w01 = (1.0 - v.frac) * u.frac;
            let w10 = v.frac * (1.0 - u.frac);
            let w11 = v.frac * u.frac;
            for ch in 0..c {
                value[ch] += w00 * t00[ch] + w01 * t01[ch] + w10 * t10[ch] + w11 * t11[ch];
            }
        }
    }
}

/// Reverse pass: from `grad_out` `[B, C, S]`, the gradients of the planes (`[3, C, R, R]`,
/// tensor layout) and of the coordinates (`[B, 3, S]`).
pub fn backward(
    planes_last: &[f32],
    coords: &[f32],
    grad_out: &[f32],
    dims: Dims,
) -> (Vec<f32>, Vec<f32>) {
    let Dims {
        batch,
        points,
        channels: c,
        resolution: r,
    } = dims;
    let total = batch * points;
    let plane_len = 3 * r * r * c;
    // Each group of chunks of points accumulates into its own plane buffer; the buffers are
    // summed in the groups' order, so that the same inputs give the same bits on any number
    // of threads.
    let chunks = total.div_ceil(CHUNK);
    let per_group = chunks.div_ceil(GROUPS).max(1);
    let groups: Vec<GroupGradients> = (0..chunks)
        .collect::<Vec<_>>()
        .par_chunks(per_group)
        .map(|group| {
            let mut gp = vec![0.0f32; plane_len];
            let mut parts = Vec::with_capacity(group.len());
            let mut g = vec![0.0f32; c];
            for &chunk in group {
                let start = chunk * CHUNK;
                let end = (start + CHUNK).min(total);
                // Coordinate gradients of this chunk, `[k, 3]`.
                let mut gc = vec![0.0f32; (end - start) * 3];
                for global in start..end {
                    let (b, s) = (global / points, global % points);
                    for (ch, gv) in g.iter_mut().enumerate() {
                        *gv = grad_out[(b * c + ch) * points + s];
                    }
                    for (p, axes) in PLANE_AXES.iter().enumerate() {
                        let u = Tap::new(coord(coords, dims, b, s, axes[0]), r);
                        let v = Tap::new(coord(coords, dims, b, s, axes[1]), r);
                        let at = |row: usize, col: usize| (p * r * r + row * r + col) * c;
                        let idx = [
                            at(v.i0, u.i0),
                            at(v.i0, u.i1),
                            at(v.i1, u.i0),
                            at(v.i1, u.i1),
                        ];
                        let w = [
                            (1.0 - v.frac) * (1.0 - u.frac),
                            (1.0 - v.frac) * u.frac,
                            v.frac * (1.0 - u.frac),
                            v.frac * u.frac,
                        ];
                        // dL/d(texel) += w g.
                        for (&i, &wk) in idx.iter().zip(&w) {
                            if wk != 0.0 {
                                for (t, gv) in gp[i..i + c].iter_mut().zip(&g) {
                                    *t += wk * gv;
                                }
                            }
                        }
                        // dL/du and dL/dv through the bilinear weights.
                        if u.slope != 0.0 || v.slope != 0.0 {
                            let dot = |i: usize| -> f32 {
                                planes_last[i..i + c]
                                    .iter()
                                    .zip(&g)
                                    .map(|(a, b)| a * b)
                                    .sum()
                            };
                            let [t00, t01, t10, t11] = idx.map(dot);
                            let du = (1.0 - v.frac) * (t01 - t00) + v.frac * (t11 - t10);
                            let dv = (1.0 - u.frac) * (t10 - t00) + u.frac * (t11 - t01);
                            let k = global - start;
                            gc[k * 3 + axes[0]] += du * u.slope;
                            gc[k * 3 + axes[1]] += dv * v.slope;
                        }
                    }
                }
                parts.push((start, gc));
            }
            (gp, parts)
        })
        .collect();
    let mut grad_planes_last = vec![0.0f32; plane_len];
    let mut grad_coords_parts = Vec::with_capacity(chunks);
    for (gp, parts) in groups {
        for (x, y) in grad_planes_last.iter_mut().zip(&gp) {
            *x += y;
        }
        grad_coords_parts.extend(parts);
    }
    let mut grad_coords = vec![0.0f32; batch * 3 * points];
    for (start, gc) in grad_coords_parts {
        for (k, g3) in gc.chunks_exact(3).enumerate() {
            let global = start + k;
            let (b, s) = (global / points, global % points);
            for (axis, &g) in g3.iter().enumerate() {
                grad_coords[(b * 3 + axis) * points + s] = g;
            }
        }
    }
    (to_channel_first(&grad_planes_last, c, r), grad_coords)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The planes' gradient sums a fixed number of groups in their order: the same bits on
    /// one thread and on three, called from inside the pool.
    #[test]
    fn the_plane_gradient_is_the_same_on_any_number_of_threads() {
        let dims = Dims {
            batch: 2,
            points: 5000,
            channels: 4,
            resolution: 16,
        };
        let value = |i: usize| ((i * 7919 + 13) % 1009) as f32 / 1009.0 - 0.5;
        let planes: Vec<f32> = (0..3 * 16 * 16 * 4).map(value).collect();
        let coords: Vec<f32> = (0..2 * 3 * 5000).map(|i| 1.8 * value(i + 3)).collect();
        let grad: Vec<f32> = (0..2 * 4 * 5000).map(|i| value(i + 5)).collect();
        let on = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| backward(&planes, &coords, &grad, dims))
        };
        let one = on(1);
        for _ in 0..3 {
            assert_eq!(on(3), one);
        }
    }
}
