//! The flash-attention kernels: softmax attention over `[BH, T, D]` rows without ever writing
//! the `T x T` scores (FlashAttention-2's scheme, plain CubeCL: no cooperative matrices).
//!
//! Every kernel gives one unit one row of the sequence it walks (a query row for the forward
//! pass and for `dQ`, a key row for `dK` / `dV`) and stages tiles of the other sequence in
//! shared memory, where all units of the cube read the same row at once (a broadcast). Rows
//! are held in registers in `f32` whatever the storage type `F` (`f32`, `f16` or `bf16`), and
//! so are every sum and the softmax statistics. The forward pass keeps a running maximum and
//! sum per query (the online softmax) and writes the log-sum-exp `lse_i = m_i + ln(l_i)`; the
//! reverse kernels recompute `P_ij = exp(q_i . k_j s - lse_i)` from it.
//!
//! Loops over the head dimension are unrolled (the rows stay in registers); loops over a tile's
//! rows are not: unrolling both made kernels of `tile x head_dim` straight-line code per
//! barrier, which Mesa's lavapipe (it compiles each barrier into an LLVM coroutine split) did
//! not finish compiling in 13 minutes.

use cubecl::prelude::*;

/// Units (rows) per cube in every kernel.
pub(crate) const ROWS: usize = 64;

/// Rows of the other sequence staged per tile: 32, fewer for wide heads so that two tiles of
/// `f32` stay within 16 KiB of shared memory (the least a Vulkan adapter offers).
pub(crate) fn tile_rows(head_dim: usize) -> usize {
    (2048 / head_dim).clamp(1, 32)
}

/// A score no real one is below: the running maximum's start (its `exp` differences are 0).
const LOWEST: f32 = -1.0e30;

/// Stages rows `first..first + tile` of `src` (`[BH, T, D]`, head `bh`) into `dst` as `f32`,
/// each scaled by `scale`; rows past the end of the sequence are zeros. Every unit of the cube
/// takes part; the caller synchronises before reading.
#[cube]
fn stage_rows<F: Float>(
    src: &Tensor<F>,
    dst: &mut Shared<[f32]>,
    head_base: usize,
    first: usize,
    tokens: usize,
    scale: f32,
    #[comptime] tile: usize,
    #[comptime] head_dim: usize,
) {
    let mut at = UNIT_POS as usize;
    let total = comptime!(tile * head_dim);
    while at < total {
        let row = first + at / head_dim;
        let mut value = 0.0f32;
        if row < tokens {
            value = f32::cast_from(src[head_base + row * head_dim + at % head_dim]) * scale;
        }
        dst[at] = value;
        at += comptime!(ROWS);
    }
}

/// Stages one `f32` per row (`lse` or `delta` of rows `first..first + tile`); zeros past the end.
#[cube]
fn stage_values(
    src: &Tensor<f32>,
    dst: &mut Shared<[f32]>,
    row_base: usize,
    first: usize,
    tokens: usize,
    #[comptime] tile: usize,
) {
    let at = UNIT_POS as usize;
    if at < tile {
        let row = first + at;
        let mut value = 0.0f32;
        if row < tokens {
            value = src[row_base + row];
        }
        dst[at] = value;
    }
}

/// Loads row `row` of head `bh` into registers as `f32`, times `scale` (zeros when out of range).
#[cube]
fn load_row<F: Float>(
    src: &Tensor<F>,
    at: usize,
    valid: bool,
    scale: f32,
    #[comptime] head_dim: usize,
) -> Array<f32> {
    let mut row = Array::<f32>::new(head_dim);
    #[unroll]
    for c in 0..head_dim {
        let mut value = 0.0f32;
        if valid {
            value = f32::cast_from(src[at + c]) * scale;
        }
        row[c] = value;
    }
    row
}

/// A zeroed `f32` row in registers.
#[cube]
fn zero_row(#[comptime] head_dim: usize) -> Array<f32> {
    let mut row = Array::<f32>::new(head_dim);
    #[unroll]
    for c in 0..head_dim {
        row[c] = 0.0;
    }
    row
}

/// `sum_c row[c] * tile[j, c]`.
#[cube]
fn dot_staged(
    row: &Array<f32>,
    staged: &Shared<[f32]>,
    j: usize,
    #[comptime] head_dim: usize,
) -> f32 {
    let mut sum = 0.0f32;
    #[unroll]
    for c in 0..head_dim {
        sum += row[c] * staged[j * head_dim + c];
    }
    sum
}

/// `acc += weight * tile[j, :]`.
#[cube]
fn add_staged(
    acc: &mut Array<f32>,
    staged: &Shared<[f32]>,
    j: usize,
    weight: f32,
    #[comptime] head_dim: usize,
) {
    #[unroll]
    for c in 0..head_dim {
        acc[c] += weight * staged[j * head_dim + c];
    }
}

/// Writes `row * scale` to `dst[at..at + D]` in the storage type.
#[cube]
fn store_row<F: Float>(
    dst: &mut Tensor<F>,
    row: &Array<f32>,
    at: usize,
    scale: f32,
    #[comptime] head_dim: usize,
) {
    #[unroll]
    for c in 0..head_dim {
        dst[at + c] = F::cast_from(row[c] * scale);
    }
}

/// Where a unit's row lies: the sequence length, the head's first element, the row's first
/// element and whether the row exists (the last block of a head has units past its end).
#[derive(CubeType, Clone, Copy)]
struct RowPlace {
    tokens: usize,
    head_base: usize,
    at: usize,
    valid: bool,
}

/// This unit's row of head `CUBE_POS_Y`, block `CUBE_POS_X` of [`ROWS`] rows.
#[cube]
fn row_place(tokens: u32, #[comptime] head_dim: usize) -> RowPlace {
    let t = tokens as usize;
    let head_base = CUBE_POS_Y as usize * t * head_dim;
    let row = CUBE_POS_X as usize * comptime!(ROWS) + UNIT_POS as usize;
    RowPlace {
        tokens: t,
        head_base,
        at: head_base + row * head_dim,
        valid: row < t,
    }
}

/// The forward pass: `out_i = sum_j softmax_j(q_i . k_j scale) v_j` and `lse_i`, one unit per
/// query row, cubes `(query block, bh)`.
#[cube(launch_unchecked)]
pub(crate) fn forward_kernel<F: Float>(
    q: &Tensor<F>,
    k: &Tensor<F>,
    v: &Tensor<F>,
    out: &mut Tensor<F>,
    lse: &mut Tensor<f32>,
    tokens: u32,
    scale: f32,
    #[comptime] head_dim: usize,
    #[comptime] tile: usize,
    #[define(F)] _dtype: ElemType,
) {
    let place = row_place(tokens, head_dim);
    let t = place.tokens;
    let head_base = place.head_base;
    let at = place.at;
    let valid = place.valid;
    let q_row = load_row::<F>(q, at, valid, scale, head_dim);
    let mut acc = zero_row(head_dim);
    let mut scores = Array::<f32>::new(tile);
    let mut running_max = f32::new(LOWEST);
    let mut running_sum = 0.0f32;
    let mut keys = Shared::<[f32]>::new_slice(comptime!(tile * head_dim));
    let mut values = Shared::<[f32]>::new_slice(comptime!(tile * head_dim));
    let mut first = 0usize;
    while first < t {
        stage_rows::<F>(k, &mut keys, head_base, first, t, 1.0, tile, head_dim);
        stage_rows::<F>(v, &mut values, head_base, first, t, 1.0, tile, head_dim);
        sync_cube();
        let count = min(t - first, tile);
        let mut tile_max = running_max;
        for j in 0..count {
            let s = dot_staged(&q_row, &keys, j, head_dim);
            scores[j] = s;
            tile_max = f32::max(tile_max, s);
        }
        let correction = f32::exp(running_max - tile_max);
        running_sum *= correction;
        #[unroll]
        for c in 0..head_dim {
            acc[c] *= correction;
        }
        for j in 0..count {
            let p = f32::exp(scores[j] - tile_max);
            running_sum += p;
            add_staged(&mut acc, &values, j, p, head_dim);
        }
        running_max = tile_max;
        sync_cube();
        first += tile;
    }
    if valid {
        store_row::<F>(out, &acc, at, 1.0 / running_sum, head_dim);
        lse[at / head_dim] = running_max + f32::ln(running_sum);
    }
}

/// The reverse pass for the queries, one unit per query row `i`:
/// `delta_i = dO_i . O_i` (written for [`key_grad_kernel`]) and
/// `dQ_i = scale sum_j P_ij (dO_i . v_j - delta_i) k_j`.
#[cube(launch_unchecked)]
pub(crate) fn query_grad_kernel<F: Float>(
    q: &Tensor<F>,
    k: &Tensor<F>,
    v: &Tensor<F>,
    out: &Tensor<F>,
    grad_out: &Tensor<F>,
    lse: &Tensor<f32>,
    delta: &mut Tensor<f32>,
    grad_q: &mut Tensor<F>,
    tokens: u32,
    scale: f32,
    #[comptime] head_dim: usize,
    #[comptime] tile: usize,
    #[define(F)] _dtype: ElemType,
) {
    let place = row_place(tokens, head_dim);
    let t = place.tokens;
    let head_base = place.head_base;
    let at = place.at;
    let valid = place.valid;
    let q_row = load_row::<F>(q, at, valid, scale, head_dim);
    let do_row = load_row::<F>(grad_out, at, valid, 1.0, head_dim);
    let o_row = load_row::<F>(out, at, valid, 1.0, head_dim);
    let mut d = 0.0f32;
    #[unroll]
    for c in 0..head_dim {
        d += do_row[c] * o_row[c];
    }
    let mut row_lse = 0.0f32;
    if valid {
        delta[at / head_dim] = d;
        row_lse = lse[at / head_dim];
    }
    let mut acc = zero_row(head_dim);
    let mut keys = Shared::<[f32]>::new_slice(comptime!(tile * head_dim));
    let mut values = Shared::<[f32]>::new_slice(comptime!(tile * head_dim));
    let mut first = 0usize;
    while first < t {
        stage_rows::<F>(k, &mut keys, head_base, first, t, 1.0, tile, head_dim);
        stage_rows::<F>(v, &mut values, head_base, first, t, 1.0, tile, head_dim);
        sync_cube();
        let count = min(t - first, tile);
        for j in 0..count {
            let p = f32::exp(dot_staged(&q_row, &keys, j, head_dim) - row_lse);
            let dp = dot_staged(&do_row, &values, j, head_dim);
            add_staged(&mut acc, &keys, j, p * (dp - d), head_dim);
        }
        sync_cube();
        first += tile;
    }
    if valid {
        store_row::<F>(grad_q, &acc, at, scale, head_dim);
    }
}

/// The reverse pass for the keys and values, one unit per key row `j`:
/// `dV_j = sum_i P_ij dO_i` and `dK_j = scale sum_i P_ij (dO_i . v_j - delta_i) q_i`.
#[cube(launch_unchecked)]
pub(crate) fn key_grad_kernel<F: Float>(
    q: &Tensor<F>,
    k: &Tensor<F>,
    v: &Tensor<F>,
    grad_out: &Tensor<F>,
    lse: &Tensor<f32>,
    delta: &Tensor<f32>,
    grad_k: &mut Tensor<F>,
    grad_v: &mut Tensor<F>,
    tokens: u32,
    scale: f32,
    #[comptime] head_dim: usize,
    #[comptime] tile: usize,
    #[define(F)] _dtype: ElemType,
) {
    let place = row_place(tokens, head_dim);
    let t = place.tokens;
    let head_base = place.head_base;
    let at = place.at;
    let valid = place.valid;
    let k_row = load_row::<F>(k, at, valid, 1.0, head_dim);
    let v_row = load_row::<F>(v, at, valid, 1.0, head_dim);
    let mut acc_k = zero_row(head_dim);
    let mut acc_v = zero_row(head_dim);
    // Queries staged already scaled: q_i . k_j scale, and dK_j sums (scale q_i) terms.
    let mut queries = Shared::<[f32]>::new_slice(comptime!(tile * head_dim));
    let mut grads = Shared::<[f32]>::new_slice(comptime!(tile * head_dim));
    let mut lses = Shared::<[f32]>::new_slice(tile);
    let mut deltas = Shared::<[f32]>::new_slice(tile);
    let mut first = 0usize;
    while first < t {
        stage_rows::<F>(q, &mut queries, head_base, first, t, scale, tile, head_dim);
        stage_rows::<F>(
            grad_out, &mut grads, head_base, first, t, 1.0, tile, head_dim,
        );
        stage_values(lse, &mut lses, head_base / head_dim, first, t, tile);
        stage_values(delta, &mut deltas, head_base / head_dim, first, t, tile);
        sync_cube();
        let count = min(t - first, tile);
        for i in 0..count {
            let p = f32::exp(dot_staged(&k_row, &queries, i, head_dim) - lses[i]);
            add_staged(&mut acc_v, &grads, i, p, head_dim);
            let dp = dot_staged(&v_row, &grads, i, head_dim);
            add_staged(&mut acc_k, &queries, i, p * (dp - deltas[i]), head_dim);
        }
        sync_cube();
        first += tile;
    }
    if valid {
        store_row::<F>(grad_k, &acc_k, at, 1.0, head_dim);
        store_row::<F>(grad_v, &acc_v, at, 1.0, head_dim);
    }
}
