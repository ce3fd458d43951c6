//! LayerNorm (no bias) and RMSNorm over the last dimension on host slices, forward and
//! backward, one pass over each row per output (the unfused Burn graph makes about eight).
//! Rows are split over threads; the gain's gradient is summed per task and then added up.

use std::mem::MaybeUninit;

use multiversion::multiversion;

use crate::buffer::{Written, written, written_values};
use crate::math;

/// Which normalisation.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum NormKind {
    /// `(x - mean) / sqrt(var + eps) * gamma` (biased variance, as Burn's LayerNorm).
    Layer,
    /// `x / sqrt(mean(x^2) + eps) * gamma` (as Burn's RmsNorm).
    Rms,
}

/// Rows per parallel task for a row width `d`: about 16k elements.
pub(crate) fn rows_per_task(d: usize) -> usize {
    ((1 << 14) / d.max(1)).max(1)
}

/// The row's centre (the mean for LayerNorm, 0 for RMSNorm) and `1 / sqrt(var + eps)`.
#[inline(always)]
fn stats(kind: NormKind, row: &[f32], eps: f32) -> (f32, f32) {
    let d = row.len() as f32;
    let centre = match kind {
        NormKind::Layer => math::sum_map(row, |x| x) / d,
        NormKind::Rms => 0.0,
    };
    let var = math::sum_map(row, |x| (x - centre) * (x - centre)) / d;
    (centre, 1.0 / (var + eps).sqrt())
}

/// The normalisation of `x` (rows of `gamma.len()` values) scaled by `gamma`.
pub fn forward(kind: NormKind, x: &[f32], gamma: &[f32], eps: f32) -> Vec<f32> {
    let d = gamma.len();
    assert!(
        d > 0 && x.len().is_multiple_of(d),
        "norm: {} values are not rows of {d}",
        x.len()
    );
    let task = rows_per_task(d) * d;
    written_values(x.len(), task, |i, y| {
        Written::of(forward_rows(kind, &x[i * task..][..y.len()], gamma, eps, y))
    })
}

/// [`forward`] on the rows of `x` into the unwritten `y` (as long as `x`), on this thread.
#[multiversion(targets("x86_64+avx512f+avx512vl+avx512dq", "x86_64+avx2+fma"))]
pub(crate) fn forward_rows<'y>(
    kind: NormKind,
    x: &[f32],
    gamma: &[f32],
    eps: f32,
    y: &'y mut [MaybeUninit<f32>],
) -> &'y mut [f32] {
    let d = gamma.len();
    assert_rows(x.len(), y.len(), d);
    for (y, x) in y.chunks_exact_mut(d).zip(x.chunks_exact(d)) {
        let (centre, rstd) = stats(kind, x, eps);
        for ((y, &x), &g) in y.iter_mut().zip(x).zip(gamma) {
            y.write((x - centre) * rstd * g);
        }
    }
    // SAFETY: `y` is whole rows of `d` (asserted above), and each of its rows had its `d`
    // values written in the loop.
    unsafe { y.assume_init_mut() }
}

/// Panics unless an output of `out` values is whole rows of `d` matching an input of `len`.
#[inline(always)]
fn assert_rows(len: usize, out: usize, d: usize) {
    assert!(
        out == len && d > 0 && len.is_multiple_of(d),
        "norm: {out} outputs for {len} inputs in rows of {d}"
    );
}

/// The gradients `(dx, dgamma)` of the normalisation given the output's gradient `grad`:
/// with `xh` the normalised row and `gg = grad * gamma`,
/// LayerNorm `dx = rstd (gg - mean(gg) - xh mean(gg xh))`, RMSNorm
/// `dx = rstd (gg - xh mean(gg xh))`, and `dgamma = sum over rows of grad * xh`.
pub fn backward(
    kind: NormKind,
    x: &[f32],
    gamma: &[f32],
    grad: &[f32],
    eps: f32,
) -> (Vec<f32>, Vec<f32>) {
    let d = gamma.len();
    assert!(
        d > 0 && x.len().is_multiple_of(d),
        "norm: {} values are not rows of {d}",
        x.len()
    );
    assert_eq!(
        x.len(),
        grad.len(),
        "norm backward: input and gradient sizes differ"
    );
    let task = rows_per_task(d) * d;
    let (dx, parts) = written(x.len(), task, |i, dx| {
        let rows = i * task..i * task + dx.len();
        let mut dgamma = vec![0.0; d];
        let dx = backward_rows(
            kind,
            &x[rows.clone()],
            gamma,
            &grad[rows],
            eps,
            dx,
            &mut dgamma,
        );
        (Written::of(dx), dgamma)
    });
    // Summed in the tasks' order, not in rayon's reduction tree, whose shape follows which
    // thread stole what: the same inputs give the same bits on any number of threads.
    let mut dgamma = vec![0.0; d];
    for part in parts {
        dgamma.iter_mut().zip(&part).for_each(|(a, b)| *a += b);
    }
    (dx, dgamma)
}

/// [`backward`] on the rows of `x` into the unwritten `dx` (as long as `x` and `grad`), on
/// this thread, adding the rows' share of the gain's gradient to `dgamma`.
#[multiversion(targets("x86_64+avx512f+avx512vl+avx512dq", "x86_64+avx2+fma"))]
pub(crate) fn backward_rows<'dx>(
    kind: NormKind,
    x: &[f32],
    gamma: &[f32],
    grad: &[f32],
    eps: f32,
    dx: &'dx mut [MaybeUninit<f32>],
    dgamma: &mut [f32],
) -> &'dx mut [f32] {
    let d = gamma.len();
    let n = d as f32;
    assert_rows(x.len(), dx.len(), d);
    assert_rows(x.len(), grad.len(), d);
    for ((dx, x), g) in dx
        .chunks_exact_mut(d)
        .zip(x.chunks_exact(d))
        .zip(grad.chunks_exact(d))
    {
        let (centre, rstd) = stats(kind, x, eps);
        // dx holds gg = grad * gamma until the last loop.
        for ((dx, &g), &w) in dx.iter_mut().zip(g).zip(gamma) {
            dx.write(g * w);
        }
        // SAFETY: the row's `d` values were written on the lines above.
        let dx = unsafe { dx.assume_init_mut() };
        let mean_gg = match kind {
            NormKind::Layer => math::sum_map(dx, |v| v) / n,
            NormKind::Rms => 0.0,
        };
        let mean_gg_xh = math::sum_zip(dx, x, |gg, x| gg * (x - centre) * rstd) / n;
        for (((dx, &x), &g), dg) in dx.iter_mut().zip(x).zip(g).zip(dgamma.iter_mut()) {
            let xh = (x - centre) * rstd;
            *dg += g * xh;
            *dx = rstd * (*dx - mean_gg - xh * mean_gg_xh);
        }
    }
    // SAFETY: `dx` is whole rows of `d` (asserted above), each written in the loop.
    unsafe { dx.assume_init_mut() }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `dgamma` sums the tasks' parts in their order: the same bits on one thread and on
    /// three, called from inside the pool, where rayon's reduction tree would follow the steals.
    #[test]
    fn the_gamma_gradient_is_the_same_on_any_number_of_threads() {
        let d = 128;
        let rows = 40 * rows_per_task(d) + 7;
        let value = |i: usize| ((i * 7919 + 13) % 1009) as f32 / 1009.0 - 0.5;
        let x: Vec<f32> = (0..rows * d).map(value).collect();
        let grad: Vec<f32> = (0..rows * d).map(|i| value(i + 5)).collect();
        let gamma: Vec<f32> = (0..d).map(|i| 1.0 + value(i + 11)).collect();
        let on = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| backward(NormKind::Layer, &x, &gamma, &grad, 1e-5))
        };
        let one = on(1);
        for _ in 0..3 {
            assert_eq!(on(3), one);
        }
    }
}
