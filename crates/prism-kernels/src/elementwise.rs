//! GELU on host slices, with its derivative kept for the reverse pass, which scales the
//! gradient by it: one pass each, vectorised, split over threads.

use multiversion::multiversion;
use rayon::prelude::*;

use std::mem::MaybeUninit;

use crate::buffer::{Written, write_each, written_beside, written_values};
use crate::math;

/// Elements per parallel task: large enough to amortise scheduling, small enough to balance.
const CHUNK: usize = 1 << 14;

/// `x = GELU(x)` in place.
pub fn gelu(x: &mut [f32]) {
    x.par_chunks_mut(CHUNK).for_each(gelu_chunk);
}

/// `GELU(x)` into a new buffer, in one parallel pass that reads `x` and writes the result: for
/// an input another tensor still holds, where copying it first and then working in place would
/// be a serial copy and a second pass.
pub fn gelu_of(x: &[f32]) -> Vec<f32> {
    written_values(x.len(), CHUNK, |i, y| {
        Written::of(gelu_chunk_into(&x[i * CHUNK..i * CHUNK + y.len()], y))
    })
}

/// `x = GELU(x)` in place, returning `GELU'(x)` of the values it had, from one pass: what the
/// reverse pass keeps, so that it multiplies by the derivative instead of computing it again
/// from the kept input (an `erf`, two `exp` and a division per value, a third of them in the
/// forward pass already).
pub fn gelu_keeping_derivative(x: &mut [f32]) -> Vec<f32> {
    written_beside(x, CHUNK, |x, d| {
        Written::of(gelu_and_derivative_chunk(x, d))
    })
}

/// `grad *= factor`, in place.
pub fn scale_in_place(grad: &mut [f32], factor: &[f32]) {
    assert_eq!(grad.len(), factor.len(), "scale: sizes differ");
    grad.par_chunks_mut(CHUNK)
        .zip(factor.par_chunks(CHUNK))
        .for_each(|(g, f)| g.iter_mut().zip(f).for_each(|(g, f)| *g *= f));
}

/// `grad * factor` into a new buffer.
pub fn scaled(grad: &[f32], factor: &[f32]) -> Vec<f32> {
    assert_eq!(grad.len(), factor.len(), "scale: sizes differ");
    written_values(grad.len(), CHUNK, |i, out| {
        let (g, f) = (
            &grad[i * CHUNK..][..out.len()],
            &factor[i * CHUNK..][..out.len()],
        );
        for ((o, &g), &f) in out.iter_mut().zip(g).zip(f) {
            o.write(g * f);
        }
        // SAFETY: `g` is as long as `out`, so the loop wrote every value of it.
        Written::of(unsafe { out.assume_init_mut() })
    })
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
fn gelu_and_derivative_chunk<'d>(x: &mut [f32], d: &'d mut [MaybeUninit<f32>]) -> &'d mut [f32] {
    assert_eq!(x.len(), d.len(), "gelu: sizes differ");
    for (x, d) in x.iter_mut().zip(d.iter_mut()) {
        // The same operations as `gelu` and `gelu_derivative` (the compiler shares their `erf`).
        d.write(math::gelu_derivative(*x));
        *x = math::gelu(*x);
    }
    // SAFETY: `d` is as long as `x` (asserted), so the loop wrote every value of it.
    unsafe { d.assume_init_mut() }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_util::bits;

    /// GELU with its derivative kept gives `gelu_of`'s values and `gelu_derivative`'s, bit for
    /// bit, over several chunks and a partial last one; the gradient scaled in place and into
    /// a new buffer agree.
    #[test]
    fn the_kept_derivative_is_the_derivative() {
        let n = 2 * CHUNK + 77;
        let x: Vec<f32> = crate::test_util::values(n, 1)
            .iter()
            .map(|v| 8.0 * v - 4.0)
            .collect();
        let mut y = x.clone();
        let d = gelu_keeping_derivative(&mut y);
        assert_eq!(bits(&y), bits(&gelu_of(&x)));
        let want: Vec<f32> = x.iter().map(|&x| math::gelu_derivative(x)).collect();
        assert_eq!(bits(&d), bits(&want));
        let grad = crate::test_util::values(n, 2);
        let mut got = grad.clone();
        scale_in_place(&mut got, &d);
        let want: Vec<f32> = grad.iter().zip(&d).map(|(g, d)| g * d).collect();
        assert_eq!(bits(&got), bits(&want));
        assert_eq!(bits(&scaled(&grad, &d)), bits(&want));
    }
}
