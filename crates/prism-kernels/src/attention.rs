//! Softmax attention on host slices, forward and backward, in the manner of FlashAttention:
//! queries are taken in blocks of [`BLOCK`] rows, so the scores of a block (`BLOCK x T`) stay
//! in cache and the `T x T` matrix is never stored. The forward keeps each row's log-sum-exp;
//! the backward recomputes the probabilities from it. Matrix products go through `gemm`;
//! the softmax and its gradient are vectorised row loops.
//!
//! Layout: `q`, `k`, `v`, `o` and their gradients are `[heads, T, d_h]` row-major, where
//! `heads` is batch times heads; `lse` is `[heads, T]`.

use std::mem::MaybeUninit;

use multiversion::multiversion;
use rayon::prelude::*;

use crate::bf16::Bf16Kernel;
use crate::buffer::{Span, Written, written, zeroed};
use crate::math;
use crate::matrix::{View, matmul, matmul_into};

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
    pub(crate) fn per_head(&self) -> usize {
        self.tokens * self.head_dim
    }

    pub(crate) fn check(&self, name: &str, len: usize) {
        assert_eq!(
            len,
            self.heads * self.per_head(),
            "attention: {name} has {len} values, expected {:?}",
            self
        );
    }
}

/// `(o, lse)`: `o = softmax(scale q k^T) v` and each query row's `log sum_j exp(scale q k_j)`.
pub fn forward(q: &[f32], k: &[f32], v: &[f32], dims: Dims, scale: f32) -> (Vec<f32>, Vec<f32>) {
    let (tokens, head_dim) = (dims.tokens, dims.head_dim);
    each_block(
        [q, k, v],
        dims,
        // The head's `k^T`, row-major, shared by its blocks of queries.
        |h| {
            let span = h * dims.per_head()..(h + 1) * dims.per_head();
            let keys = View::transposed(&k[span.clone()], head_dim, tokens).to_rows();
            (span, keys)
        },
        // One score buffer per worker thread, reused by its blocks (gemm overwrites it), and
        // its rows' inverse sums.
        || (vec![0.0; BLOCK.min(tokens) * tokens], [0.0f32; BLOCK]),
        |(span, keys), b, o, lse, (p, inv)| {
            let rows = lse.len();
            let v = &v[span.clone()];
            let q = &q[span.start + b * BLOCK * head_dim..][..rows * head_dim];
            let (p, inv) = (&mut p[..rows * tokens], &mut inv[..rows]);
            matmul(
                p,
                false,
                View::rows(q, rows, head_dim),
                View::rows(keys, head_dim, tokens),
                scale,
            );
            exponentials(p, tokens, 1.0, lse, inv);
            let o = matmul_into(
                o,
                View::rows(p, rows, tokens),
                View::rows(v, tokens, head_dim),
                1.0,
            );
            divide_rows(o, head_dim, inv);
            Written::of(o)
        },
    )
}

/// [`forward`] with the two products taking bf16 operands through `kernel`, the exponentials
/// and their sums in f32: on AMX's tiles ([`forward_amx`]) or with AVX512-BF16's `vdpbf16ps`
/// ([`forward_avx512`]). With [`Bf16Kernel::Rounded`] (no faster than f32) attention stays f32
/// ([`forward`]).
pub fn forward_bf16(
    kernel: Bf16Kernel,
    q: &[f32],
    k: &[f32],
    v: &[f32],
    dims: Dims,
    scale: f32,
) -> (Vec<f32>, Vec<f32>) {
    match kernel {
        #[cfg(target_arch = "x86_64")]
        Bf16Kernel::Amx => forward_amx(q, k, v, dims, scale),
        #[cfg(target_arch = "x86_64")]
        Bf16Kernel::Avx512Bf16 => forward_avx512(q, k, v, dims, scale),
        _ => forward(q, k, v, dims, scale),
    }
}

/// [`forward`] with `vdpbf16ps` ([`forward_packed`]). Panics unless the CPU runs
/// [`Bf16Kernel::Avx512Bf16`].
#[cfg(target_arch = "x86_64")]
fn forward_avx512(q: &[f32], k: &[f32], v: &[f32], dims: Dims, scale: f32) -> (Vec<f32>, Vec<f32>) {
    use crate::bf16::avx512::{pack, rows_product};
    // Before the packing, which runs AVX512-BF16's instructions too.
    assert!(
        Bf16Kernel::Avx512Bf16.runs_here(),
        "this CPU does not run AVX512-BF16"
    );
    forward_packed(
        [q, k, v],
        dims,
        scale,
        pack,
        Vec::new,
        |a, b, n, packed, c| rows_product(a, 0, n, b, packed, c),
    )
}

/// [`forward`] on AMX's tiles ([`forward_packed`]). Panics unless the CPU runs
/// [`Bf16Kernel::Amx`].
#[cfg(target_arch = "x86_64")]
fn forward_amx(q: &[f32], k: &[f32], v: &[f32], dims: Dims, scale: f32) -> (Vec<f32>, Vec<f32>) {
    use crate::bf16::amx::{PackedA, PackedB, Tiles, product};
    forward_packed(
        [q, k, v],
        dims,
        scale,
        |b| PackedB::new(b, 0, b.rows),
        PackedA::default,
        |a, b, n, packed, c| {
            let tiles = Tiles::configure();
            packed.pack(a, 0, a.rows, 0, a.cols);
            product(&tiles, packed, b, c, n, false);
        },
    )
}

/// The bf16 forward passes: `q`, `k`, `v` and each row's exponentials `exp(scale (s - max s))`
/// rounded to bf16, the products summed in f32, and the output rows divided by the
/// exponentials' f32 sums. `pack` packs an operand `b` for a kernel's products, once per head
/// for its `k^T` and `v`; `product(a, b, n, scratch, c)` writes `c = a b` (`n` columns) on the
/// calling thread, with a worker thread's `scratch` made by `scratch()`.
#[cfg(target_arch = "x86_64")]
fn forward_packed<P: Sync, S: Send>(
    [q, k, v]: [&[f32]; 3],
    dims: Dims,
    scale: f32,
    pack: impl Fn(View<'_>) -> P + Sync + Send,
    scratch: impl Fn() -> S + Sync + Send,
    product: impl Fn(View<'_>, &P, usize, &mut S, &mut [f32]) + Sync + Send,
) -> (Vec<f32>, Vec<f32>) {
    let (tokens, head_dim) = (dims.tokens, dims.head_dim);
    each_block(
        [q, k, v],
        dims,
        |h| {
            let span = h * dims.per_head()..(h + 1) * dims.per_head();
            let (k, v) = (&k[span.clone()], &v[span.clone()]);
            let keys = pack(View::transposed(k, head_dim, tokens));
            let values = pack(View::rows(v, tokens, head_dim));
            (span.start, keys, values)
        },
        || {
            let scores = vec![0.0; BLOCK.min(tokens) * tokens];
            (scores, scratch(), [0.0f32; BLOCK])
        },
        |(start, keys, values), b, o, lse, (p, s, inv)| {
            let rows = lse.len();
            let q = &q[start + b * BLOCK * head_dim..][..rows * head_dim];
            let (p, inv) = (&mut p[..rows * tokens], &mut inv[..rows]);
            product(View::rows(q, rows, head_dim), keys, tokens, s, p);
            exponentials(p, tokens, scale, lse, inv);
            let o = zeroed(o);
            product(View::rows(p, rows, tokens), values, head_dim, s, o);
            divide_rows(o, head_dim, inv);
            Written::of(o)
        },
    )
}

/// The skeleton of the forward passes: checks the sizes, allocates `(o, lse)`, and runs
/// `block(head's, b, o, lse, scratch)` on every block `b` of [`BLOCK`] query rows of every
/// head in parallel, where `o` (unwritten: `block` writes it whole) and `lse` are the block's
/// rows, `head's` what `prepare(h)` made once for the head's blocks, and `scratch` a worker
/// thread's, made by `scratch()`.
fn each_block<H, S>(
    inputs: [&[f32]; 3],
    dims: Dims,
    prepare: impl Fn(usize) -> H + Sync + Send,
    scratch: impl Fn() -> S + Sync + Send,
    block: impl Fn(&H, usize, &mut [MaybeUninit<f32>], &mut [f32], &mut S) -> Written + Sync + Send,
) -> (Vec<f32>, Vec<f32>)
where
    H: Sync,
{
    for (name, x) in ["q", "k", "v"].into_iter().zip(inputs) {
        dims.check(name, x.len());
    }
    let Dims {
        tokens, head_dim, ..
    } = dims;
    if dims.heads * dims.per_head() == 0 {
        return (Vec::new(), vec![0.0; dims.heads * tokens]);
    }
    let (o, lse) = written(dims.heads * dims.per_head(), dims.per_head(), |h, o| {
        let head = prepare(h);
        let mut lse = vec![0.0; tokens];
        let span = Span::of(o);
        let blocks: Vec<Written> = o
            .par_chunks_mut(BLOCK * head_dim)
            .zip(lse.par_chunks_mut(BLOCK))
            .enumerate()
            .map_init(&scratch, |s, (b, (o, lse))| block(&head, b, o, lse, s))
            .collect();
        (Written::joined(span, blocks), lse)
    });
    (o, lse.concat())
}

/// Each row of `o` (rows of `len`) multiplied by its entry of `inv`: the exponentials'
/// weighted sums divided by the exponentials' sums after the product, on `len` values a row
/// rather than on the block's scores.
fn divide_rows(o: &mut [f32], len: usize, inv: &[f32]) {
    for (row, &inv) in o.chunks_exact_mut(len).zip(inv) {
        row.iter_mut().for_each(|x| *x *= inv);
    }
}

/// Each row `s` of `p` (rows of `len`) replaced by `exp(scale (s - max s))`; `lse` gets the
/// rows' `log sum exp(scale s)` and `inv` one over the sums of the new rows (`scale > 0`).
#[multiversion(targets("x86_64+avx512f+avx512vl+avx512dq", "x86_64+avx2+fma"))]
fn exponentials(p: &mut [f32], len: usize, scale: f32, lse: &mut [f32], inv: &mut [f32]) {
    for ((row, lse), inv) in p.chunks_exact_mut(len).zip(lse.iter_mut()).zip(inv) {
        let m = math::max(row);
        let shift = -scale * m;
        let sum = math::map_sum(row, |x| math::exp(x.mul_add(scale, shift)));
        *inv = 1.0 / sum;
        *lse = scale * m + sum.ln();
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
    // One pair of score buffers per worker thread, reused by its heads (gemm overwrites them).
    let scratch = || {
        let len = BLOCK.min(tokens) * tokens;
        (vec![0.0; len], vec![0.0; len])
    };
    dq.par_chunks_mut(per_head)
        .zip(dk.par_chunks_mut(per_head).zip(dv.par_chunks_mut(per_head)))
        .enumerate()
        .for_each_init(scratch, |(p, ds), (h, (dq, (dk, dv)))| {
            let span = h * per_head..(h + 1) * per_head;
            let (q, k, v) = (&q[span.clone()], &k[span.clone()], &v[span.clone()]);
            let (o, grad) = (&o[span.clone()], &grad[span]);
            let lse = &lse[h * tokens..(h + 1) * tokens];
            // `k^T` and `v^T` row-major, shared by the head's blocks.
            let keys = View::transposed(k, head_dim, tokens).to_rows();
            let values = View::transposed(v, head_dim, tokens).to_rows();
            for start in (0..tokens).step_by(BLOCK) {
                let rows = BLOCK.min(tokens - start);
                let block = start * head_dim..(start + rows) * head_dim;
                let (q_b, o_b, g_b) = (&q[block.clone()], &o[block.clone()], &grad[block.clone()]);
                let (p, ds) = (&mut p[..rows * tokens], &mut ds[..rows * tokens]);
                matmul(
                    p,
                    false,
                    View::rows(q_b, rows, head_dim),
                    View::rows(&keys, head_dim, tokens),
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
                    View::rows(&values, head_dim, tokens),
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_util::bits;

    /// Values in [-2, 2).
    fn values(n: usize, seed: u64) -> Vec<f32> {
        crate::test_util::values(n, seed)
            .into_iter()
            .map(|x| 2.0 * x)
            .collect()
    }

    /// `(o, lse)` in f64 with bf16's roundings where the bf16 path makes them: `q`, `k`, `v`
    /// and each row's exponentials `exp(scale (s - max s))` rounded, the rest exact.
    fn reference_bf16(q: &[f32], k: &[f32], v: &[f32], dims: Dims, scale: f32) -> Vec<f64> {
        let r = |x: f32| crate::bf16::round_bf16(x) as f64;
        let Dims {
            heads,
            tokens,
            head_dim,
        } = dims;
        let mut out = Vec::new();
        for h in 0..heads {
            let at = |x: &[f32], t: usize, d: usize| r(x[(h * tokens + t) * head_dim + d]);
            for i in 0..tokens {
                let s: Vec<f64> = (0..tokens)
                    .map(|j| (0..head_dim).map(|d| at(q, i, d) * at(k, j, d)).sum())
                    .collect();
                let m = s.iter().cloned().fold(f64::MIN, f64::max);
                let e: Vec<f64> = s.iter().map(|s| (scale as f64 * (s - m)).exp()).collect();
                let sum: f64 = e.iter().sum();
                for d in 0..head_dim {
                    let num: f64 = (0..tokens).map(|j| r(e[j] as f32) * at(v, j, d)).sum();
                    out.push(num / sum);
                }
                out.push(scale as f64 * m + sum.ln());
            }
        }
        out
    }

    /// The bf16 forward on every kernel this CPU runs (AMX on its tiles, or on their model
    /// where the CPU has AVX512-BF16 and no tiles: see `bf16::amx`): AMX and `vdpbf16ps`
    /// against the rounded reference (to within one bf16 step of an exponential that rounds
    /// the other way), on sizes that leave partial tiles, strips, panels, blocks of the inner
    /// dimension and blocks of queries; the rounded kernel's f32 path against the f32 forward
    /// exactly. Each kernel gives the same bits on one thread, where a worker's scratch serves
    /// several blocks in turn, as on the shared pool, where most blocks get fresh scratch: a
    /// block that reads what the one before it left would differ.
    #[test]
    fn bf16_forward_matches_its_rounded_reference() {
        let one_thread = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap();
        let sizes = [
            (1, 1, 1),
            (2, 45, 24),
            (1, 100, 64),
            (3, 130, 40),
            (1, 400, 33),
        ];
        for (heads, tokens, head_dim) in sizes {
            let dims = Dims {
                heads,
                tokens,
                head_dim,
            };
            let n = heads * tokens * head_dim;
            let (q, k, v) = (values(n, 1), values(n, 2), values(n, 3));
            let scale = 1.0 / (head_dim as f32).sqrt();
            let f32_out = forward(&q, &k, &v, dims, scale);
            for kernel in [Bf16Kernel::Amx, Bf16Kernel::Avx512Bf16, Bf16Kernel::Rounded] {
                if !kernel.runs_here() {
                    eprintln!("{kernel:?} does not run here");
                    continue;
                }
                let (o, lse) = forward_bf16(kernel, &q, &k, &v, dims, scale);
                let serial = one_thread.install(|| forward_bf16(kernel, &q, &k, &v, dims, scale));
                assert_eq!(
                    (bits(&serial.0), bits(&serial.1)),
                    (bits(&o), bits(&lse)),
                    "{kernel:?} {heads} x {tokens} x {head_dim}: one thread differs"
                );
                if kernel == Bf16Kernel::Rounded {
                    assert_eq!((o, lse), f32_out, "{kernel:?} takes the f32 path");
                    continue;
                }
                let want = reference_bf16(&q, &k, &v, dims, scale);
                let got = o
                    .chunks(head_dim)
                    .zip(&lse)
                    .flat_map(|(o, l)| o.iter().chain(std::iter::once(l)).map(|&x| x as f64));
                let err = got
                    .zip(&want)
                    .map(|(g, w)| (g - w).abs())
                    .fold(0.0, f64::max);
                assert!(
                    err < 2e-3,
                    "{kernel:?} attention {heads} x {tokens} x {head_dim}: error {err}"
                );
                let f32_err = o
                    .iter()
                    .zip(&f32_out.0)
                    .map(|(a, b)| (a - b).abs())
                    .fold(0.0, f32::max);
                eprintln!(
                    "{kernel:?} {heads} x {tokens} x {head_dim}: {err:e} from the reference, \
                     {f32_err:e} from f32"
                );
            }
        }
    }
}
