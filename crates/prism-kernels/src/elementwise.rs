//! GELU on host slices, forward and backward: one pass each, vectorised, split over threads.

use multiversion::multiversion;
use rayon::prelude::*;

use crate::buffer::filled;
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
    filled(x.len(), CHUNK, |i, y| {
        gelu_chunk_into(&x[i * CHUNK..i * CHUNK + y.len()], y);
    })
}

/// `dx = grad * GELU'(x)`.
pub fn gelu_backward(x: &[f32], grad: &[f32]) -> Vec<f32> {
    assert_eq!(
        x.len(),
        grad.len(),
        "gelu_backward: input and gradient sizes differ"
    );
    filled(x.len(), CHUNK, |i, dx| {
        let chunk = i * CHUNK..i * CHUNK + dx.len();
        gelu_backward_chunk(&x[chunk.clone()], &grad[chunk], dx);
    })
}

#[multiversion(targets("x86_64+avx512f+avx512vl+avx512dq", "x86_64+avx2+fma"))]
fn gelu_chunk(x: &mut [f32]) {
    for x in x.iter_mut() {
        *x = math::gelu(*x);
    }
}

#[multiversion(targets("x86_64+avx512f+avx512vl+avx512dq", "x86_64+avx2+fma"))]
fn gelu_chunk_into(x: &[f32], y: &mut [f32]) {
    for (y, &x) in y.iter_mut().zip(x) {
        *y = math::gelu(x);
    }
}

#[multiversion(targets("x86_64+avx512f+avx512vl+avx512dq", "x86_64+avx2+fma"))]
fn gelu_backward_chunk(x: &[f32], grad: &[f32], dx: &mut [f32]) {
    for ((dx, &x), &g) in dx.iter_mut().zip(x).zip(grad) {
        *dx = g * math::gelu_derivative(x);
    }
}
