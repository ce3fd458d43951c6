//! Linear attention (SANA; the student's blocks) on host slices, forward and backward, one head
//! per task:
//!
//! `o_i = phi(q_i) KV / den_i`, with `KV = sum_j phi(k_j)^T v_j` (`d_h x d_h`), `s = sum_j
//! phi(k_j)` and `den_i = phi(q_i) . s + eps`,
//!
//! computed right to left, so no `T x T` matrix is formed, with `gemm` for the two products.
//! Composed from Burn's ops it takes about twelve graph nodes, each a pass over memory; here
//! the feature map, the sums and the division are folded into the products' passes. The
//! forward keeps each row's `den`; the backward recomputes `phi` and `KV` from the inputs.
//!
//! Layout: `q`, `k`, `v`, `o` and their gradients are `[heads, T, d_h]` row-major, where
//! `heads` is batch times heads; `den` is `[heads, T]`.

use burn::tensor::Tensor;
use burn::tensor::activation::relu;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::attention::Dims;
use crate::buffer::{Written, written};
use crate::matrix::{View, matmul, matmul_into};

/// The feature map `phi` of linear attention, applied to queries and keys.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum FeatureMap {
    /// `phi(x) = max(x, 0)`, as in SANA (the default).
    #[default]
    Relu,
    /// `phi(x) = elu(x) + 1`, the feature map the paper names as an example.
    Elu1,
}

impl FeatureMap {
    /// `phi(x)`.
    pub fn value(self, x: f32) -> f32 {
        match self {
            Self::Relu => x.max(0.0),
            Self::Elu1 if x > 0.0 => x + 1.0,
            Self::Elu1 => x.exp(),
        }
    }

    /// `phi'(x)`, as Burn's composition differentiates it (`relu'(0) = 0`; `elu + 1` takes
    /// `exp` at and below 0).
    pub fn derivative(self, x: f32) -> f32 {
        match (self, x > 0.0) {
            (_, true) => 1.0,
            (Self::Relu, false) => 0.0,
            (Self::Elu1, false) => x.exp(),
        }
    }

    /// Applies `phi` element-wise to a tensor, as Burn's ops (what the backends without the
    /// host kernel run).
    pub fn apply<const D: usize>(self, x: Tensor<D>) -> Tensor<D> {
        match self {
            Self::Relu => relu(x),
            // elu(x) + 1 = x + 1 for x > 0 and exp(x) for x <= 0.
            Self::Elu1 => relu(x.clone()) + x.clamp_max(0.0).exp(),
        }
    }

    fn map(self, x: &[f32]) -> Vec<f32> {
        x.iter().map(|&x| self.value(x)).collect()
    }
}

/// One head's `phi(q)`, `phi(k)`, `KV` and `s`.
struct Features {
    q: Vec<f32>,
    k: Vec<f32>,
    kv: Vec<f32>,
    k_sum: Vec<f32>,
}

impl Features {
    fn of(q: &[f32], k: &[f32], v: &[f32], map: FeatureMap, dims: Dims) -> Self {
        let (tokens, d) = (dims.tokens, dims.head_dim);
        let (q, k) = (map.map(q), map.map(k));
        let mut kv = vec![0.0; d * d];
        matmul(
            &mut kv,
            false,
            View::transposed(&k, d, tokens),
            View::rows(v, tokens, d),
            1.0,
        );
        let mut k_sum = vec![0.0; d];
        for row in k.chunks_exact(d) {
            k_sum.iter_mut().zip(row).for_each(|(s, x)| *s += x);
        }
        Self { q, k, kv, k_sum }
    }

    /// `phi(q_i) . s + eps` for query row `i`.
    fn den(&self, i: usize, eps: f32) -> f32 {
        let d = self.k_sum.len();
        let row = &self.q[i * d..][..d];
        row.iter().zip(&self.k_sum).map(|(a, b)| a * b).sum::<f32>() + eps
    }
}

/// `(o, den)` of linear attention with feature map `map` and `eps` in the normaliser.
pub fn forward(
    q: &[f32],
    k: &[f32],
    v: &[f32],
    dims: Dims,
    map: FeatureMap,
    eps: f32,
) -> (Vec<f32>, Vec<f32>) {
    for (name, x) in [("q", q), ("k", k), ("v", v)] {
        dims.check(name, x.len());
    }
    let per_head = dims.per_head();
    let (o, den) = written(dims.heads * per_head, per_head.max(1), |h, o| {
        let span = h * per_head..(h + 1) * per_head;
        let (q, k, v) = (&q[span.clone()], &k[span.clone()], &v[span]);
        let f = Features::of(q, k, v, map, dims);
        let d = dims.head_dim;
        let o = matmul_into(
            o,
            View::rows(&f.q, dims.tokens, d),
            View::rows(&f.kv, d, d),
            1.0,
        );
        let mut den = vec![0.0; dims.tokens];
        for (i, (row, den)) in o.chunks_exact_mut(d).zip(&mut den).enumerate() {
            *den = f.den(i, eps);
            row.iter_mut().for_each(|x| *x /= *den);
        }
        (Written::of(o), den)
    });
    (o, den.concat())
}

/// The gradients `(dq, dk, dv)` of [`forward`] given `o`, `den` and the output's gradient
/// `grad`: with `dn = grad / den` and `dden_i = -(grad_i . o_i) / den_i`,
/// `d phi(q) = dn KV^T + dden s^T`, `dKV = phi(q)^T dn`, `ds = phi(q)^T dden`,
/// `d phi(k) = v dKV^T + 1 ds^T`, `dv = phi(k) dKV`, and `phi'` on the way back to `q`, `k`.
#[allow(clippy::too_many_arguments)]
pub fn backward(
    q: &[f32],
    k: &[f32],
    v: &[f32],
    o: &[f32],
    den: &[f32],
    grad: &[f32],
    dims: Dims,
    map: FeatureMap,
) -> (Vec<f32>, Vec<f32>, Vec<f32>) {
    for (name, x) in [("q", q), ("k", k), ("v", v), ("o", o), ("grad", grad)] {
        dims.check(name, x.len());
    }
    let (tokens, d) = (dims.tokens, dims.head_dim);
    let n = q.len();
    let (mut dq, mut dk, mut dv) = (vec![0.0; n], vec![0.0; n], vec![0.0; n]);
    let per_head = dims.per_head();
    if n == 0 {
        return (dq, dk, dv);
    }
    dq.par_chunks_mut(per_head)
        .zip(dk.par_chunks_mut(per_head).zip(dv.par_chunks_mut(per_head)))
        .enumerate()
        .for_each(|(h, (dq, (dk, dv)))| {
            let span = h * per_head..(h + 1) * per_head;
            let (q, k, v) = (&q[span.clone()], &k[span.clone()], &v[span.clone()]);
            let (o, grad) = (&o[span.clone()], &grad[span]);
            let den = &den[h * tokens..(h + 1) * tokens];
            let f = Features::of(q, k, v, map, dims);
            // dn = grad / den, and dden per row.
            let mut dn = grad.to_vec();
            let mut dden = vec![0.0; tokens];
            for (i, row) in dn.chunks_exact_mut(d).enumerate() {
                let o_i = &o[i * d..][..d];
                dden[i] = -row.iter().zip(o_i).map(|(g, o)| g * o).sum::<f32>() / den[i];
                row.iter_mut().for_each(|g| *g /= den[i]);
            }
            // d phi(q) in dq, then times phi'(q).
            matmul(
                dq,
                false,
                View::rows(&dn, tokens, d),
                View::transposed(&f.kv, d, d),
                1.0,
            );
            for ((row, &dd), q) in dq.chunks_exact_mut(d).zip(&dden).zip(q.chunks_exact(d)) {
                for ((x, &s), &q) in row.iter_mut().zip(&f.k_sum).zip(q) {
                    *x = (*x + dd * s) * map.derivative(q);
                }
            }
            let mut dkv = vec![0.0; d * d];
            matmul(
                &mut dkv,
                false,
                View::transposed(&f.q, d, tokens),
                View::rows(&dn, tokens, d),
                1.0,
            );
            let mut ds = vec![0.0; d];
            for (row, &dd) in f.q.chunks_exact(d).zip(&dden) {
                ds.iter_mut().zip(row).for_each(|(s, x)| *s += dd * x);
            }
            // d phi(k) in dk, then times phi'(k).
            matmul(
                dk,
                false,
                View::rows(v, tokens, d),
                View::transposed(&dkv, d, d),
                1.0,
            );
            for (row, k) in dk.chunks_exact_mut(d).zip(k.chunks_exact(d)) {
                for ((x, &s), &k) in row.iter_mut().zip(&ds).zip(k) {
                    *x = (*x + s) * map.derivative(k);
                }
            }
            matmul(
                dv,
                false,
                View::rows(&f.k, tokens, d),
                View::rows(&dkv, d, d),
                1.0,
            );
        });
    (dq, dk, dv)
}
