//! Multi-head self-attention from the joint projection as it lies, on host slices, forward and
//! backward: `qkv` `[B, T, 3, H, d_h]` in, the heads' outputs `[B, T, H, d_h]` out, with
//! RMSNorm on the queries and keys (QK-norm) on the way, and softmax or linear attention
//! ([`Mixing`]) in each head.
//!
//! Composed from Burn's ops, a block's attention permutes `qkv` into head-major order, narrows
//! out `q`, `k` and `v`, normalises two of them and merges the heads back: two copies on one
//! thread forward, and backward a zeroed `qkv`-sized gradient per narrow, two sums of them and
//! two more copies. Here each layout change is part of a parallel pass that is made anyway (the
//! norms, the gathering of a head's rows), and the gradient of `qkv` is written once, in its
//! own layout.

use std::mem::MaybeUninit;

use crate::attention::{self, Dims};
use crate::bf16::Bf16Kernel;
use crate::buffer::{Written, write_parts, written, written_values};
use crate::linear_attention::{self, FeatureMap};
use crate::norm::{self, NormKind, rows_per_task};

/// What each head computes from its normalised queries and keys and its values.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Mixing {
    /// `softmax(q k^T / sqrt(d_h)) v` (the teacher's blocks). With `bf16`, its two products
    /// take bf16 operands where the CPU's bf16 kernel has an attention path and no gradient is
    /// needed (see [`attention::forward_bf16`]).
    Softmax {
        /// bf16 products when no gradient is needed.
        bf16: bool,
    },
    /// Linear attention with `feature_map` and `eps` in its normaliser (the student's
    /// stitched blocks; see [`linear_attention`]).
    Linear {
        /// `phi`, on the queries and keys.
        feature_map: FeatureMap,
        /// Added to each row's normaliser.
        eps: f64,
    },
}

impl Mixing {
    /// The same mixing with its products in f32: what runs under a gradient.
    pub(crate) fn in_f32(self) -> Self {
        match self {
            Self::Softmax { .. } => Self::Softmax { bf16: false },
            linear => linear,
        }
    }
}

/// Sizes of a multi-head self-attention.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Heads {
    /// Batch items.
    pub batch: usize,
    /// Tokens per item.
    pub tokens: usize,
    /// Heads.
    pub heads: usize,
    /// Width of a head.
    pub head_dim: usize,
}

impl Heads {
    /// The attention problems, one per batch item and head.
    pub fn attention(&self) -> Dims {
        Dims {
            heads: self.batch * self.heads,
            tokens: self.tokens,
            head_dim: self.head_dim,
        }
    }

    /// Values per token of the output (`H d_h`).
    fn width(&self) -> usize {
        self.heads * self.head_dim
    }

    /// Values of one head-major tensor (`B H T d_h`).
    fn len(&self) -> usize {
        self.batch * self.tokens * self.width()
    }

    /// Where the `d_h` values of head `h` of part `part` (0 `q`, 1 `k`, 2 `v`) of token `t` of
    /// item `b` start in `qkv`.
    fn joint(&self, b: usize, t: usize, part: usize, h: usize) -> usize {
        ((b * self.tokens + t) * 3 + part) * self.width() + h * self.head_dim
    }

    /// Where token `t` of head `bh` (item times heads plus head) starts in a head-major tensor.
    fn head_major(&self, bh: usize, t: usize) -> usize {
        (bh * self.tokens + t) * self.head_dim
    }

    /// Where head `h` of token `t` of item `b` starts in a token-major `[B, T, H, d_h]` tensor.
    fn token_major(&self, b: usize, t: usize, h: usize) -> usize {
        (b * self.tokens + t) * self.width() + h * self.head_dim
    }

    fn check(&self, qkv: &[f32], q_gain: &[f32], k_gain: &[f32]) {
        assert_eq!(
            qkv.len(),
            3 * self.len(),
            "self-attention: qkv has {} values, expected {self:?} x 3",
            qkv.len()
        );
        for (name, gain) in [("query", q_gain), ("key", k_gain)] {
            assert_eq!(
                gain.len(),
                self.head_dim,
                "self-attention: the {name} gain has {} values, expected d_h = {}",
                gain.len(),
                self.head_dim
            );
        }
    }
}

/// What the backward pass reads of the forward's: the normalised queries and keys, the values,
/// the heads' outputs (all head-major, `[B H, T, d_h]`), and one value per query row: its
/// log-sum-exp (softmax) or its normaliser (linear).
#[derive(Clone, Debug)]
pub struct Saved {
    q: Vec<f32>,
    k: Vec<f32>,
    v: Vec<f32>,
    o: Vec<f32>,
    rows: Vec<f32>,
}

/// The heads' outputs `[B, T, H, d_h]` of `mixing` per head on `q = RMSNorm(q_raw) q_gain`,
/// `k = RMSNorm(k_raw) k_gain` and `v`, where `q_raw`, `k_raw`, `v` are the three parts of
/// `qkv` `[B, T, 3, H, d_h]`; and what [`backward`] needs.
pub fn forward(
    qkv: &[f32],
    q_gain: &[f32],
    k_gain: &[f32],
    eps: f32,
    l: Heads,
    mixing: Mixing,
) -> (Vec<f32>, Saved) {
    l.check(qkv, q_gain, k_gain);
    let q = split(qkv, 0, Some(q_gain), eps, l);
    let k = split(qkv, 1, Some(k_gain), eps, l);
    let v = split(qkv, 2, None, eps, l);
    let (dims, scale) = (l.attention(), 1.0 / (l.head_dim as f32).sqrt());
    let (o, rows) = match mixing {
        Mixing::Softmax { bf16: true } => {
            attention::forward_bf16(Bf16Kernel::chosen(), &q, &k, &v, dims, scale)
        }
        Mixing::Softmax { bf16: false } => attention::forward(&q, &k, &v, dims, scale),
        Mixing::Linear { feature_map, eps } => {
            linear_attention::forward(&q, &k, &v, dims, feature_map, eps as f32)
        }
    };
    let out = merge(&o, l);
    (out, Saved { q, k, v, o, rows })
}

/// The gradients `(d qkv, d q_gain, d k_gain)` of [`forward`] with `mixing` (in f32) given its
/// output's gradient `grad` (`[B, T, H, d_h]`).
#[allow(clippy::too_many_arguments)]
pub fn backward(
    qkv: &[f32],
    q_gain: &[f32],
    k_gain: &[f32],
    eps: f32,
    l: Heads,
    mixing: Mixing,
    saved: &Saved,
    grad: &[f32],
) -> (Vec<f32>, Vec<f32>, Vec<f32>) {
    l.check(qkv, q_gain, k_gain);
    assert_eq!(
        grad.len(),
        l.len(),
        "self-attention: the output's gradient has {} values, expected {l:?}",
        grad.len()
    );
    let Saved { q, k, v, o, rows } = saved;
    let (dims, scale) = (l.attention(), 1.0 / (l.head_dim as f32).sqrt());
    let grad = unmerge(grad, l);
    let (dq, dk, dv) = match mixing {
        Mixing::Softmax { .. } => attention::backward(q, k, v, o, rows, &grad, dims, scale),
        Mixing::Linear { feature_map, .. } => {
            linear_attention::backward(q, k, v, o, rows, &grad, dims, feature_map)
        }
    };
    join(qkv, [q_gain, k_gain], eps, [&dq, &dk, &dv], l)
}

/// Part `part` (0 `q`, 1 `k`, 2 `v`) of `qkv` in head-major order, each row normalised by
/// RMSNorm times `gain` when there is one.
fn split(qkv: &[f32], part: usize, gain: Option<&[f32]>, eps: f32, l: Heads) -> Vec<f32> {
    let d = l.head_dim;
    head_major(l, |b, h, out| {
        write_parts(out, d, |t, dst| {
            let x = &qkv[l.joint(b, t, part, h)..][..d];
            Written::of(match gain {
                Some(gain) => norm::forward_rows(NormKind::Rms, x, gain, eps, dst),
                None => dst.write_copy_of_slice(x),
            })
        })
    })
}

/// A head-major `[B H, T, d_h]` buffer, each head's `T x d_h` values written by
/// `write(b, h, head)` on rayon's threads.
fn head_major(
    l: Heads,
    write: impl Fn(usize, usize, &mut [MaybeUninit<f32>]) -> Written + Sync + Send,
) -> Vec<f32> {
    written_values(l.len(), l.tokens * l.head_dim, |bh, out| {
        write(bh / l.heads, bh % l.heads, out)
    })
}

/// The heads' outputs from head-major order `[B H, T, d_h]` to token-major `[B, T, H, d_h]`.
fn merge(o: &[f32], l: Heads) -> Vec<f32> {
    let (width, d) = (l.width(), l.head_dim);
    let rows = rows_per_task(width);
    written_values(l.len(), rows * width, |task, out| {
        write_parts(out, d, |i, dst| {
            let (bt, h) = (task * rows + i / l.heads, i % l.heads);
            let (b, t) = (bt / l.tokens, bt % l.tokens);
            Written::of(dst.write_copy_of_slice(&o[l.head_major(b * l.heads + h, t)..][..d]))
        })
    })
}

/// A token-major `[B, T, H, d_h]` tensor in head-major order `[B H, T, d_h]`.
fn unmerge(x: &[f32], l: Heads) -> Vec<f32> {
    let d = l.head_dim;
    head_major(l, |b, h, out| {
        write_parts(out, d, |t, dst| {
            Written::of(dst.write_copy_of_slice(&x[l.token_major(b, t, h)..][..d]))
        })
    })
}

/// The gradient of `qkv` in its own layout from the head-major gradients of the normalised
/// queries and keys and of the values (the norms' backward on the way), and the gains'.
fn join(
    qkv: &[f32],
    gains: [&[f32]; 2],
    eps: f32,
    grads: [&[f32]; 3],
    l: Heads,
) -> (Vec<f32>, Vec<f32>, Vec<f32>) {
    let (width, d) = (l.width(), l.head_dim);
    let rows = rows_per_task(3 * width);
    let (dqkv, parts) = written(3 * l.len(), rows * 3 * width, |task, out| {
        let mut dgains = [vec![0.0; d], vec![0.0; d]];
        // Each row is `q`, `k`, `v`, each of them `heads` parts of `d` values.
        let written = write_parts(out, d, |i, dst| {
            let (bt, part, h) = (
                task * rows + i / (3 * l.heads),
                i / l.heads % 3,
                i % l.heads,
            );
            let (b, t) = (bt / l.tokens, bt % l.tokens);
            let grad = &grads[part][l.head_major(b * l.heads + h, t)..][..d];
            Written::of(match part {
                2 => dst.write_copy_of_slice(grad),
                _ => {
                    let x = &qkv[l.joint(b, t, part, h)..][..d];
                    norm::backward_rows(
                        NormKind::Rms,
                        x,
                        gains[part],
                        grad,
                        eps,
                        dst,
                        &mut dgains[part],
                    )
                }
            })
        });
        (written, dgains)
    });
    // Summed in the tasks' order: the same bits on any number of threads.
    let (mut dq_gain, mut dk_gain) = (vec![0.0; d], vec![0.0; d]);
    for [q, k] in parts {
        dq_gain.iter_mut().zip(&q).for_each(|(a, b)| *a += b);
        dk_gain.iter_mut().zip(&k).for_each(|(a, b)| *a += b);
    }
    (dqkv, dq_gain, dk_gain)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_util::values;

    const L: Heads = Heads {
        batch: 2,
        tokens: 5,
        heads: 2,
        head_dim: 4,
    };

    /// `sum(forward(qkv, gains) * w)` in f64 from the f32 kernel.
    fn loss(qkv: &[f32], q_gain: &[f32], k_gain: &[f32], w: &[f32], mixing: Mixing) -> f64 {
        let (out, _) = forward(qkv, q_gain, k_gain, 1e-5, L, mixing);
        out.iter().zip(w).map(|(o, w)| *o as f64 * *w as f64).sum()
    }

    /// The backward pass against central finite differences of the forward, for every value
    /// of `qkv` and of both gains, with each mixing and feature map. ReLU's kink at 0 would
    /// spoil the differences of the values near it, so its inputs are all positive there (its
    /// zero branch is checked against Burn's ops in `tests/fused.rs`).
    #[test]
    fn gradients_match_finite_differences() {
        let signed = values(3 * L.len(), 1);
        let (q_gain, k_gain) = (values(4, 2), values(4, 3));
        let q_gain: Vec<f32> = q_gain.iter().map(|g| g + 1.5).collect();
        let k_gain: Vec<f32> = k_gain.iter().map(|g| g + 1.5).collect();
        let w = values(L.len(), 4);
        let linear = |feature_map| Mixing::Linear {
            feature_map,
            eps: 1e-6,
        };
        let mixings = [
            Mixing::Softmax { bf16: false },
            linear(FeatureMap::Relu),
            linear(FeatureMap::Elu1),
        ];
        for mixing in mixings {
            let qkv: Vec<f32> = match mixing {
                Mixing::Linear {
                    feature_map: FeatureMap::Relu,
                    ..
                } => signed.iter().map(|x| x + 1.5).collect(),
                _ => signed.clone(),
            };
            let (_, saved) = forward(&qkv, &q_gain, &k_gain, 1e-5, L, mixing);
            let (dqkv, dq_gain, dk_gain) =
                backward(&qkv, &q_gain, &k_gain, 1e-5, L, mixing, &saved, &w);
            let h = 1e-2;
            let numeric = |which: usize, i: usize| {
                let at = |delta: f32| {
                    let mut inputs = [qkv.clone(), q_gain.clone(), k_gain.clone()];
                    inputs[which][i] += delta;
                    let [x, g, k] = &inputs;
                    loss(x, g, k, &w, mixing)
                };
                (at(h) - at(-h)) / (2.0 * h as f64)
            };
            for (which, analytic) in [dqkv, dq_gain, dk_gain].iter().enumerate() {
                for (i, &a) in analytic.iter().enumerate() {
                    let n = numeric(which, i);
                    assert!(
                        (a as f64 - n).abs() < 2e-3 + 2e-2 * n.abs(),
                        "{mixing:?}, input {which}, value {i}: backward {a}, finite difference {n}"
                    );
                }
            }
        }
    }

    /// The layout changes undo each other, and `merge` puts head `h`'s row of token `t` where
    /// the output projection reads it.
    #[test]
    fn merge_and_unmerge_are_inverse_transposes() {
        let o = values(L.len(), 5);
        let merged = merge(&o, L);
        assert_eq!(unmerge(&merged, L), o);
        let (b, t, h) = (1, 3, 1);
        let d = L.head_dim;
        assert_eq!(
            merged[L.token_major(b, t, h)..][..d],
            o[L.head_major(b * L.heads + h, t)..][..d]
        );
    }
}
