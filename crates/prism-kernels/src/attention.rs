//! Softmax attention on host slices, forward and backward, in the manner of FlashAttention:
//! queries are taken in blocks of [`BLOCK`] rows, so the scores of a block (`BLOCK x T`) stay
//! in cache and the `T x T` matrix is never stored. The forward keeps each row's log-sum-exp;
//! the backward recomputes the probabilities from it. Matrix products go through `gemm`;
//! the softmax and its gradient are vectorised row loops.
//!
//! Layout: `q`, `k`, `v`, `o` and their gradients are `[heads, T, d_h]` row-major, where
//! `heads` is batch times heads; `lse` is `[heads, T]`.

use gemm::{Parallelism, gemm};
use multiversion::multiversion;
use rayon::prelude::*;

use crate::math;
use crate::matrix::View;

/// Query rows per block.
const BLOCK: usize = 64;

/// Sizes of an attention call.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Dims {
    /// Independent attention problems (batch x heads).
    pub heads: usize,
    /// Tokens (queries = keys).
    pub tokens: usize,
    /// Width of a head.
    pub head_dim: usize,
}

impl Dims {
    fn per_head(&self) -> usize {
        self.tokens * self.head_dim
    }

    fn check(&self, name: &str, len: usize) {
        assert_eq!(
            len,
            self.heads * self.per_head(),
            "attention: {name} has {len} values, expected {:?}",
            self
        );
    }
}

/// `dst (row-major lhs.rows x rhs.cols) = [dst +] scale * lhs rhs`, single-threaded (the
/// callers parallelise over heads and blocks).
fn matmul(dst: &mut [f32], accumulate: bool, lhs: View<'_>, rhs: View<'_>, scale: f32) {
    assert_eq!(lhs.cols, rhs.rows, "matmul: inner sizes differ");
    assert_eq!(dst.len(), lhs.rows * rhs.cols, "matmul: output size");
    lhs.check();
    rhs.check();
    // SAFETY: the views were checked to lie inside their slices and `dst` holds exactly
    // `m x n` row-major values; gemm reads and writes nothing else.
    unsafe {
        gemm(
            lhs.rows,
            rhs.cols,
            lhs.cols,
            dst.as_mut_ptr(),
            1,
            rhs.cols as isize,
            accumulate,
            lhs.data.as_ptr(),
            lhs.col_stride as isize,
            lhs.row_stride as isize,
            rhs.data.as_ptr(),
            rhs.col_stride as isize,
            rhs.row_stride as isize,
            1.0,
            scale,
            false,
            false,
            false,
            Parallelism::None,
        );
    }
}

/// `(o, lse)`: `o = softmax(scale q k^T) v` and each query row's `log sum_j exp(scale q k_j)`.
pub fn forward(q: &[f32], k: &[f32], v: &[f32], dims: Dims, scale: f32) -> (Vec<f32>, Vec<f32>) {
    for (name, x) in [("q", q), ("k", k), ("v", v)] {
        dims.check(name, x.len());
    }
    let Dims {
        tokens, head_dim, ..
    } = dims;
    let mut o = vec![0.0; q.len()];
    let mut lse = vec![0.0; dims.heads * tokens];
    if o.is_empty() {
        return (o, lse);
    }
    o.par_chunks_mut(dims.per_head())
        .zip(lse.par_chunks_mut(tokens))
        .enumerate()
        .for_each(|(h, (o, lse))| {
            let span = h * dims.per_head()..(h + 1) * dims.per_head();
            let (q, k, v) = (&q[span.clone()], &k[span.clone()], &v[span]);
            // One score buffer per worker thread, reused by its blocks (gemm overwrites it).
            o.par_chunks_mut(BLOCK * head_dim)
                .zip(lse.par_chunks_mut(BLOCK))
                .enumerate()
                .for_each_init(
                    || vec![0.0; BLOCK.min(tokens) * tokens],
                    |p, (b, (o, lse))| {
                        let rows = lse.len();
                        let q = &q[b * BLOCK * head_dim..][..rows * head_dim];
                        let p = &mut p[..rows * tokens];
                        matmul(
                            p,
                            false,
                            View::rows(q, rows, head_dim),
                            View::transposed(k, head_dim, tokens),
                            scale,
                        );
                        softmax_rows(p, tokens, lse);
                        matmul(
                            o,
                            false,
                            View::rows(p, rows, tokens),
                            View::rows(v, tokens, head_dim),
                            1.0,
                        );
                    },
                );
        });
    (o, lse)
}

/// Each row of `p` (rows of `len`) replaced by its softmax; `lse` gets the rows'
/// log-sum-exp.
#[multiversion(targets("x86_64+avx512f+avx512vl+avx512dq", "x86_64+avx2+fma"))]
fn softmax_rows(p: &mut [f32], len: usize, lse: &mut [f32]) {
    for (row, lse) in p.chunks_exact_mut(len).zip(lse.iter_mut()) {
        let m = math::max(row);
        for x in row.iter_mut() {
            *x = math::exp(*x - m);
        }
        let sum = math::sum_map(row, |x| x);
        let inv = 1.0 / sum;
        for x in row.iter_mut() {
            *x *= inv;
        }
        *lse = m + sum.ln();
    }
}

/// The gradients `(dq, dk, dv)` of [`forward`] given `o`, `lse` and the output's gradient
/// `grad`. With `P` recomputed from `lse`: `dv = P^T grad`, `dP = grad v^T`,
/// `dS = P (dP - rowsum(grad o))`, `dq = scale dS k`, `dk = scale dS^T q`.
#[allow(clippy::too_many_arguments)]
pub fn backward(
    q: &[f32],
    k: &[f32],
    v: &[f32],
    o: &[f32],
    lse: &[f32],
    grad: &[f32],
    dims: Dims,
    scale: f32,
) -> (Vec<f32>, Vec<f32>, Vec<f32>) {
    for (name, x) in [("q", q), ("k", k), ("v", v), ("o", o), ("grad", grad)] {
        dims.check(name, x.len());
    }
    let Dims {
        tokens, head_dim, ..
    } = dims;
    let n = q.len();
    let (mut dq, mut dk, mut dv) = (vec![0.0; n], vec![0.0; n], vec![0.0; n]);
    if n == 0 {
        return (dq, dk, dv);
    }
    let per_head = dims.per_head();
    dq.par_chunks_mut(per_head)
        .zip(dk.par_chunks_mut(per_head).zip(dv.par_chunks_mut(per_head)))
        .enumerate()
        .for_each(|(h, (dq, (dk, dv)))| {
            let span = h * per_head..(h + 1) * per_head;
            let (q, k, v) = (&q[span.clone()], &k[span.clone()], &v[span.clone()]);
            let (o, grad) = (&o[span.clone()], &grad[span]);
            let lse = &lse[h * tokens..(h + 1) * tokens];
            let mut p = vec![0.0; BLOCK.min(tokens) * tokens];
            let mut ds = vec![0.0; p.len()];
            for start in (0..tokens).step_by(BLOCK) {
                let rows = BLOCK.min(tokens - start);
                let block = start * head_dim..(start + rows) * head_dim;
                let (q_b, o_b, g_b) = (&q[block.clone()], &o[block.clone()], &grad[block.clone()]);
                let (p, ds) = (&mut p[..rows * tokens], &mut ds[..rows * tokens]);
                matmul(
                    p,
                    false,
                    View::rows(q_b, rows, head_dim),
                    View::transposed(k, head_dim, tokens),
                    scale,
                );
                probabilities(p, tokens, &lse[start..start + rows]);
                matmul(
                    dv,
                    true,
                    View::transposed(p, tokens, rows),
                    View::rows(g_b, rows, head_dim),
                    1.0,
                );
                matmul(
                    ds,
                    false,
                    View::rows(g_b, rows, head_dim),
                    View::transposed(v, head_dim, tokens),
                    1.0,
                );
                score_gradient(p, ds, o_b, g_b, head_dim, scale);
                matmul(
                    &mut dq[block],
                    false,
                    View::rows(ds, rows, tokens),
                    View::rows(k, tokens, head_dim),
                    1.0,
                );
                matmul(
                    dk,
                    true,
                    View::transposed(ds, tokens, rows),
                    View::rows(q_b, rows, head_dim),
                    1.0,
                );
            }
        });
    (dq, dk, dv)
}

/// Scores to probabilities in place: `p = exp(s - lse)` row by row.
#[multiversion(targets("x86_64+avx512f+avx512vl+avx512dq", "x86_64+avx2+fma"))]
fn probabilities(p: &mut [f32], len: usize, lse: &[f32]) {
    for (row, &lse) in p.chunks_exact_mut(len).zip(lse) {
        for x in row.iter_mut() {
            *x = math::exp(*x - lse);
        }
    }
}

/// `ds = scale * p * (dp - rowsum(grad o))` in place of `dp` (held in `ds`), row by row.
#[multiversion(targets("x86_64+avx512f+avx512vl+avx512dq", "x86_64+avx2+fma"))]
fn score_gradient(p: &[f32], ds: &mut [f32], o: &[f32], grad: &[f32], head_dim: usize, scale: f32) {
    let len = p.len() / (o.len() / head_dim);
    for (((p, ds), o), g) in p
        .chunks_exact(len)
        .zip(ds.chunks_exact_mut(len))
        .zip(o.chunks_exact(head_dim))
        .zip(grad.chunks_exact(head_dim))
    {
        let d = math::sum_zip(g, o, |g, o| g * o);
        for (ds, &p) in ds.iter_mut().zip(p) {
            *ds = scale * p * (*ds - d);
        }
    }
}
