//! GELU on host slices, forward and backward: one pass each, vectorised, split over threads.

use multiversion::multiversion;
use rayon::prelude::*;

use std::mem::MaybeUninit;

use crate::buffer::{Written, write_each, written};
use crate::math;

/// Elements per parallel task: large enough to amortise scheduling, small enough to balance.
const CHUNK: usize = 1 << 14;

/// `x = GELU(x)` in place.
pub fn gelu(x: &mut [f32]) {
    x.par_chunks_mut(CHUNK).for_each(gelu_chunk);
}

/// `GELU(x)` into a new buffer, in one parallel pass that reads `x` and writes the result: for
/// an input that must be kept (autodiff keeps it for the reverse pass), where copying it first
/// and then working in place would be a serial copy and a second pass.
pub fn gelu_of(x: &[f32]) -> Vec<f32> {
    written(x.len(), CHUNK, |i, y| {
        let y = gelu_chunk_into(&x[i * CHUNK..i * CHUNK + y.len()], y);
        (Written::of(y), ())
    })
    .0
}

/// `dx = grad * GELU'(x)`.
pub fn gelu_backward(x: &[f32], grad: &[f32]) -> Vec<f32> {
    assert_eq!(
        x.len(),
        grad.len(),
        "gelu_backward: input and gradient sizes differ"
    );
    written(x.len(), CHUNK, |i, dx| {
        let chunk = i * CHUNK..i * CHUNK + dx.len();
        // Copied in cache, then the in-place kernel: one kernel for both paths.
        let dx = dx.write_copy_of_slice(&grad[chunk.clone()]);
        gelu_backward_chunk_in_place(&x[chunk], dx);
        (Written::of(dx), ())
    })
    .0
}

/// [`gelu_backward`] in place of `grad`, for a gradient no other tensor holds: no new buffer
/// to zero and write, the same values.
pub fn gelu_backward_in_place(x: &[f32], grad: &mut [f32]) {
    assert_eq!(
        x.len(),
        grad.len(),
        "gelu_backward: input and gradient sizes differ"
    );
    grad.par_chunks_mut(CHUNK)
        .zip(x.par_chunks(CHUNK))
        .for_each(|(grad, x)| gelu_backward_chunk_in_place(x, grad));
}

#[multiversion(targets("x86_64+avx512f+avx512vl+avx512dq", "x86_64+avx2+fma"))]
fn gelu_chunk(x: &mut [f32]) {
    for x in x.iter_mut() {
        *x = math::gelu(*x);
    }
}

#[multiversion(targets("x86_64+avx512f+avx512vl+avx512dq", "x86_64+avx2+fma"))]
fn gelu_chunk_into<'y>(x: &[f32], y: &'y mut [MaybeUninit<f32>]) -> &'y mut [f32] {
    write_each(y, x, math::gelu)
}

#[multiversion(targets("x86_64+avx512f+avx512vl+avx512dq", "x86_64+avx2+fma"))]
fn gelu_backward_chunk_in_place(x: &[f32], grad: &mut [f32]) {
    for (g, &x) in grad.iter_mut().zip(x) {
        *g *= math::gelu_derivative(x);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_util::bits;

    /// The in-place reverse pass gives the new buffer's values bit for bit, over several chunks
    /// and a partial last one.
    #[test]
    fn in_place_backward_is_the_backward() {
        let n = 2 * CHUNK + 77;
        let x: Vec<f32> = crate::test_util::values(n, 1)
            .iter()
            .map(|v| 4.0 * v)
            .collect();
        let grad = crate::test_util::values(n, 2);
        let want = gelu_backward(&x, &grad);
        let mut got = grad.clone();
        gelu_backward_in_place(&x, &mut got);
        assert_eq!(bits(&want), bits(&got));
    }
}
