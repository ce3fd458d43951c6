//! The AMX-BF16 kernel: `tdpbf16ps` on 16 x 16 tiles of f32 sums, each from a 16 x 32 tile
//! of `a` and a 32 x 16 tile of `b` in bf16. A block of `c` is 2 x 2 tiles (32 rows by the
//! 32 columns of one packed panel of `b`), so each step loads two tiles of `a` and two of `b`
//! for four products. `b` is packed as the AVX-512 kernel packs it (its rows of pairs are the
//! layout a `b` tile loads); `a` in strips of 32 rows, each row's pairs in a run. Both are
//! padded with zeros to whole tiles, so every tile is full and only the copy into `c` is
//! clipped.
//!
//! Linux gives a process the tile registers only on request ([`enable`]); the tile
//! configuration is per thread, so every task loads it before its first tile.
//!
//! This crate's tests run the kernel on CPUs without AMX too: where the CPU has AVX512-BF16
//! (which the packing needs) but no tiles, a scalar model stands in for the tile instructions
//! of [`block_product`] ([`modelled`]), so that everything around them (the packing, the
//! padding, the clipped copies, the callers' loops) is tested on such hosts as well. The model
//! itself is checked against the tiles where a CPU has them.

use std::arch::asm;
use std::arch::x86_64::__cpuid_count;
use std::marker::PhantomData;
use std::sync::OnceLock;

use super::avx512::{NR, convert, pack_b, pair_rows};
use crate::buffer::filled_init;
use crate::matrix::View;

/// Rows of a tile, and pairs of the inner dimension per tile step.
const TILE: usize = 16;
/// Rows of a block of `c`: two tiles.
const MR: usize = 2 * TILE;
/// Inner values per packed block: a whole number of tile steps.
const KC: usize = 512;
/// The most rows one task takes (whole strips).
const MC: usize = MR * 4;

/// Whether the kernel runs here: on the tiles ([`granted`]), or in this crate's tests on their
/// model ([`modelled`]).
pub(super) fn available() -> bool {
    granted() || modelled()
}

/// Whether the CPU has AMX-TILE and AMX-BF16 and Linux lets this process use the tiles.
fn granted() -> bool {
    static GRANTED: OnceLock<bool> = OnceLock::new();
    *GRANTED.get_or_init(|| {
        let edx = __cpuid_count(7, 0).edx;
        let (tile, bf16) = (edx >> 24 & 1 == 1, edx >> 22 & 1 == 1);
        tile && bf16 && enable()
    })
}

/// Whether [`block_product`] runs on its scalar model ([`model::block_product`]) instead of
/// the tiles: only in this crate's tests, on a CPU with AVX512-BF16 and no AMX tiles.
#[cfg(test)]
fn modelled() -> bool {
    !granted()
        && is_x86_feature_detected!("avx512f")
        && is_x86_feature_detected!("avx512bw")
        && is_x86_feature_detected!("avx512bf16")
}

/// Outside this crate's tests the kernel runs on the tiles only.
#[cfg(not(test))]
fn modelled() -> bool {
    false
}

/// Asks Linux for the tile data state (`arch_prctl(ARCH_REQ_XCOMP_PERM, XTILEDATA)`), once
/// for the process; false where the kernel refuses or is too old.
#[cfg(target_os = "linux")]
fn enable() -> bool {
    const ARCH_REQ_XCOMP_PERM: libc::c_long = 0x1023;
    const XFEATURE_XTILEDATA: libc::c_long = 18;
    // SAFETY: the call only grants a permission; it reads and writes no memory of ours.
    unsafe {
        libc::syscall(
            libc::SYS_arch_prctl,
            ARCH_REQ_XCOMP_PERM,
            XFEATURE_XTILEDATA,
        ) == 0
    }
}

/// Other systems: the tiles are not asked for, and the AVX-512 kernel runs.
#[cfg(not(target_os = "linux"))]
fn enable() -> bool {
    false
}

/// The tile configuration (`ldtilecfg`'s 64 bytes): palette 1, tiles 0 to 7 of 16 rows of
/// 64 bytes (`c`'s four, `a`'s two, `b`'s two).
#[repr(C, align(64))]
struct Config([u8; 64]);

impl Config {
    fn new() -> Self {
        let mut bytes = [0u8; 64];
        bytes[0] = 1;
        for t in 0..8 {
            bytes[16 + 2 * t..18 + 2 * t].copy_from_slice(&64u16.to_le_bytes());
            bytes[48 + t] = TILE as u8;
        }
        Self(bytes)
    }
}

/// This thread's tiles, configured for the kernel's blocks while the value lives and released
/// when it is dropped. The configuration is per thread, so nothing inside its life may hand
/// work to rayon (another task on this thread would release the tiles under it), and the value
/// cannot leave its thread (the raw pointer's marker makes it neither `Send` nor `Sync`).
pub(crate) struct Tiles(PhantomData<*const ()>);

impl Tiles {
    /// Configures this thread's tiles. Panics unless [`available`].
    pub(crate) fn configure() -> Self {
        assert!(available(), "AMX tiles are not available on this CPU");
        if granted() {
            let config = Config::new();
            // SAFETY: `granted` checked the CPU and the permission; the configuration is 64
            // valid bytes.
            unsafe { asm!("ldtilecfg [{}]", in(reg) config.0.as_ptr(), options(nostack)) };
        }
        Self(PhantomData)
    }
}

impl Drop for Tiles {
    fn drop(&mut self) {
        if granted() {
            // SAFETY: releases the tiles this thread configured.
            unsafe { asm!("tilerelease", options(nostack, nomem)) };
        }
    }
}

/// An operand `b` packed for the tiles: rows `k0..k0 + kc` of it as panels of [`NR`] columns,
/// `pairs` (a whole number of tile steps) pairs each.
pub(crate) struct PackedB {
    words: Vec<u32>,
    pairs: usize,
    cols: usize,
}

impl PackedB {
    /// Packs `b[k0..k0 + kc, ..]` (in parallel over its panels). Panics unless [`available`].
    pub(crate) fn new(b: View<'_>, k0: usize, kc: usize) -> Self {
        assert!(available(), "AMX tiles are not available on this CPU");
        let pairs = kc.div_ceil(2).next_multiple_of(TILE);
        Self {
            words: pack_b(b, k0, kc, pairs),
            pairs,
            cols: b.cols,
        }
    }
}

/// An operand `a` packed for the tiles: strips of [`MR`] rows, row `i`'s pair `q` at
/// `i * stride + q`, zero beyond the matrix. The row stride is one tile step longer than the
/// pairs, so that a tile's 16 rows never fall in one cache set. Reused from call to call.
#[derive(Default)]
pub(crate) struct PackedA {
    words: Vec<u32>,
    rows: usize,
    pairs: usize,
    stride: usize,
    /// Scratch for a transposed `a`: one strip's words, pair-major.
    paired: Vec<u32>,
}

impl PackedA {
    /// Packs `a[r0..r0 + rows, k0..k0 + kc]` in place of what it held. Panics unless
    /// [`available`].
    pub(crate) fn pack(&mut self, a: View<'_>, r0: usize, rows: usize, k0: usize, kc: usize) {
        assert!(available(), "AMX tiles are not available on this CPU");
        let used = kc.div_ceil(2);
        self.pairs = used.next_multiple_of(TILE);
        self.stride = self.pairs + TILE;
        self.rows = rows;
        let stride = self.stride;
        // Only the padding is zeroed: the rows' pairs are all written below.
        self.words.resize(rows.div_ceil(MR) * MR * stride, 0);
        for (i, row) in self.words.chunks_mut(stride).enumerate() {
            let pad = if i < rows { used } else { 0 };
            row[pad..].fill(0);
        }
        if a.col_stride == 1 {
            for (i, words) in self.words.chunks_mut(stride).take(rows).enumerate() {
                let row = &a.data[(r0 + i) * a.row_stride + k0..][..kc];
                // SAFETY: `available` checked the CPU, whose AMX implies AVX512-BF16.
                unsafe { convert(row, &mut words[..used]) };
            }
            return;
        }
        // A transposed `a`: its columns are contiguous, so each strip's rows are paired column
        // by column, then the pair-major words are turned row-major.
        self.paired.resize(used * MR, 0);
        for (s, strip) in self.words.chunks_mut(MR * stride).enumerate() {
            let (i0, n) = (r0 + s * MR, MR.min(rows - s * MR));
            pair_rows(a.t(), k0, kc, i0, n, &mut self.paired, MR);
            for (q, words) in self.paired.chunks(MR).enumerate() {
                for (i, &w) in words[..n].iter().enumerate() {
                    strip[i * stride + q] = w;
                }
            }
        }
    }
}

/// `c[..a.rows, ..b.cols] = a b`, or `+=` when `accumulate`, with `c` row-major of row stride
/// `ldc`. Whole tiles are stored straight into `c`; the clipped edges and sums go through a
/// scratch block. Panics if the operands disagree or `c` is too short.
pub(crate) fn product(
    _tiles: &Tiles,
    a: &PackedA,
    b: &PackedB,
    c: &mut [f32],
    ldc: usize,
    accumulate: bool,
) {
    assert_eq!(a.pairs, b.pairs, "amx product: inner sizes differ");
    assert!(
        ldc >= b.cols,
        "amx product: row stride {ldc} under {} columns",
        b.cols
    );
    if a.rows == 0 || b.cols == 0 {
        return;
    }
    assert!(
        c.len() >= (a.rows - 1) * ldc + b.cols,
        "amx product: output too short"
    );
    let pairs = a.pairs;
    let mut scratch = [0.0f32; MR * NR];
    for p in 0..b.cols.div_ceil(NR) {
        let cols = NR.min(b.cols - p * NR);
        let panel = &b.words[p * pairs * NR..][..pairs * NR];
        for s in 0..a.rows.div_ceil(MR) {
            let strip = &a.words[s * MR * a.stride..][..MR * a.stride];
            let rows = MR.min(a.rows - s * MR);
            let out = &mut c[s * MR * ldc + p * NR..];
            if !accumulate && rows == MR && cols == NR {
                // SAFETY: the tiles are configured (`_tiles`); the strip and panel hold
                // `pairs` pairs at their strides; `c` holds 32 rows of 32 values from `out`
                // at stride `ldc` (checked above).
                unsafe { block_product(strip, a.stride, panel, pairs, out.as_mut_ptr(), ldc) };
                continue;
            }
            // SAFETY: as above, into the scratch block of 32 rows of `NR`.
            unsafe { block_product(strip, a.stride, panel, pairs, scratch.as_mut_ptr(), NR) };
            for (i, sums) in scratch.chunks(NR).take(rows).enumerate() {
                let out = &mut out[i * ldc..][..cols];
                if accumulate {
                    out.iter_mut().zip(sums).for_each(|(o, s)| *o += s);
                } else {
                    out.copy_from_slice(&sums[..cols]);
                }
            }
        }
    }
}

/// `b` packed whole for the tiles, block by block of the inner dimension (each block's first
/// row, size and panels), the caller having checked the view and [`available`].
pub(super) fn pack(b: View<'_>) -> Vec<(usize, usize, PackedB)> {
    (0..b.rows)
        .step_by(KC)
        .map(|k0| {
            let kc = KC.min(b.rows - k0);
            (k0, kc, PackedB::new(b, k0, kc))
        })
        .collect()
}

/// `a b` for `b` of `n` columns packed by [`pack`], the caller having checked the views and
/// [`available`]. Each task zeroes and fills its block of rows of `c` in one pass over the
/// inner dimension.
pub(super) fn matmul(a: View<'_>, n: usize, panels: &[(usize, usize, PackedB)]) -> Vec<f32> {
    let m = a.rows;
    let mc = super::rows_per_task(m, MR, MC);
    filled_init(m * n, mc * n, PackedA::default, |ap, t, block| {
        let tiles = Tiles::configure();
        for (k0, kc, bp) in panels {
            ap.pack(a, t * mc, block.len() / n, *k0, *kc);
            product(&tiles, ap, bp, block, n, *k0 > 0);
        }
    })
}

/// `c (MR x NR at row stride ldc) = strip panel` over `pairs` pairs, with the tiles configured.
///
/// # Safety
/// The CPU runs AMX-BF16, this thread's tiles are configured by [`Config`], `strip` holds
/// `MR` rows of `pairs` pairs at row stride `stride` words, `panel` holds `pairs * NR` words,
/// `pairs` is a multiple of [`TILE`], and `c` points at 32 writable rows of 32 values at
/// row stride `ldc`.
unsafe fn block_product(
    strip: &[u32],
    stride: usize,
    panel: &[u32],
    pairs: usize,
    c: *mut f32,
    ldc: usize,
) {
    debug_assert!(strip.len() >= (MR - 1) * stride + pairs && panel.len() >= pairs * NR);
    debug_assert_eq!(pairs % TILE, 0);
    #[cfg(test)]
    if modelled() {
        // SAFETY: as for the tiles, which the model reads and writes alike.
        unsafe { model::block_product(strip, stride, panel, pairs, c, ldc) };
        return;
    }
    let (a_stride, b_stride, c_stride) = (4 * stride, 4 * NR, 4 * ldc);
    // SAFETY: tile step `s` reads strip words `i * stride + 16 s .. + 16` for rows `i < 32`
    // and panel words `(16 s + q) * NR .. + 32` for `q < 16`, all inside the slices; the
    // stores write 32 rows of 32 values from `c` at stride `ldc`, which the caller provides.
    unsafe {
        asm!(
            "tilezero tmm0",
            "tilezero tmm1",
            "tilezero tmm2",
            "tilezero tmm3",
            options(nostack, nomem)
        );
        let (a0, a1, b) = (
            strip.as_ptr(),
            strip.as_ptr().add(TILE * stride),
            panel.as_ptr(),
        );
        for s in 0..pairs / TILE {
            asm!(
                "tileloadd tmm4, [{a0} + {sa}*1]",
                "tileloadd tmm5, [{a1} + {sa}*1]",
                "tileloadd tmm6, [{b} + {sb}*1]",
                "tileloadd tmm7, [{b} + {sb}*1 + 64]",
                "tdpbf16ps tmm0, tmm4, tmm6",
                "tdpbf16ps tmm1, tmm4, tmm7",
                "tdpbf16ps tmm2, tmm5, tmm6",
                "tdpbf16ps tmm3, tmm5, tmm7",
                a0 = in(reg) a0.add(TILE * s),
                a1 = in(reg) a1.add(TILE * s),
                b = in(reg) b.add(TILE * s * NR),
                sa = in(reg) a_stride,
                sb = in(reg) b_stride,
                options(nostack, readonly)
            );
        }
        asm!(
            "tilestored [{c} + {sc}*1], tmm0",
            "tilestored [{c} + {sc}*1 + 64], tmm1",
            "tilestored [{c2} + {sc}*1], tmm2",
            "tilestored [{c2} + {sc}*1 + 64], tmm3",
            c = in(reg) c,
            c2 = in(reg) c.add(TILE * ldc),
            sc = in(reg) c_stride,
            options(nostack)
        );
    }
}

/// A scalar model of [`block_product`]'s tiles, for this crate's tests on CPUs without them.
#[cfg(test)]
mod model {
    use super::{MR, NR};

    /// The bf16 value in the low (`0`) or high (`1`) half of a word, as an f32.
    pub(super) fn half(word: u32, h: usize) -> f32 {
        f32::from_bits(if h == 0 {
            word << 16
        } else {
            word & 0xffff_0000
        })
    }

    /// [`super::block_product`] as its tiles compute it: each sum starts at zero, and the tile
    /// steps' `tdpbf16ps` add to it, pair by pair in order, the pair's two exact products (the
    /// high halves' first), rounding to f32 after each.
    ///
    /// # Safety
    /// As [`super::block_product`]'s, but for the CPU: `c` points at 32 writable rows of 32
    /// values at row stride `ldc`.
    pub(super) unsafe fn block_product(
        strip: &[u32],
        stride: usize,
        panel: &[u32],
        pairs: usize,
        c: *mut f32,
        ldc: usize,
    ) {
        let mut sums = [[0.0f32; NR]; MR];
        for (i, row) in sums.iter_mut().enumerate() {
            for (j, sum) in row.iter_mut().enumerate() {
                for q in 0..pairs {
                    let (a, b) = (strip[i * stride + q], panel[q * NR + j]);
                    *sum += half(a, 1) * half(b, 1);
                    *sum += half(a, 0) * half(b, 0);
                }
            }
        }
        for (i, row) in sums.iter().enumerate() {
            // SAFETY: row `i < 32` of `c` holds 32 writable values (the caller's promise).
            let out = unsafe { std::slice::from_raw_parts_mut(c.add(i * ldc), NR) };
            out.copy_from_slice(row);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bf16::avx512::pair;
    use crate::test_util::values;

    /// Words of two bf16 values each, from uniform values in [-1, 1).
    fn words(n: usize, seed: u64) -> Vec<u32> {
        values(2 * n, seed)
            .chunks(2)
            .map(|p| pair(p[0], p[1]))
            .collect()
    }

    /// A `PackedA` used again (as a task's or a worker's is) holds nothing of what it held:
    /// infinities packed first, beyond the second matrix's pairs and rows, would meet `b`'s
    /// zero padding and make NaNs. The second product matches the rounded operands' sums.
    #[test]
    fn a_packing_used_again_keeps_nothing_of_the_last() {
        if !available() {
            eprintln!("no AMX tiles or model here");
            return;
        }
        let infinities = vec![f32::INFINITY; 40 * 70];
        let mut packed = PackedA::default();
        packed.pack(View::rows(&infinities, 40, 70), 0, 40, 0, 70);
        let (m, k, n) = (33, 21, 5);
        let (a, b) = (values(m * k, 1), values(k * n, 2));
        packed.pack(View::rows(&a, m, k), 0, m, 0, k);
        let panels = PackedB::new(View::rows(&b, k, n), 0, k);
        let mut c = vec![f32::NAN; m * n];
        let tiles = Tiles::configure();
        product(&tiles, &packed, &panels, &mut c, n, false);
        drop(tiles);
        let r = |x: f32| crate::bf16::round_bf16(x) as f64;
        for i in 0..m {
            for j in 0..n {
                let want: f64 = (0..k).map(|p| r(a[i * k + p]) * r(b[p * n + j])).sum();
                let got = c[i * n + j] as f64;
                assert!(
                    (got - want).abs() < 1e-5,
                    "({i}, {j}): {got} against {want}"
                );
            }
        }
    }

    /// The model against the tiles, on a block of three tile steps written at a row stride
    /// wider than the block: the same sums, to within f32's rounding of their order (the
    /// hardware's order inside a `tdpbf16ps` is not documented), and nothing written between
    /// the rows. Runs where the CPU grants the tiles; elsewhere it says so and checks nothing.
    #[test]
    fn the_model_computes_what_the_tiles_compute() {
        if !granted() {
            eprintln!("no AMX tiles here: the model stands in for them, unchecked");
            return;
        }
        let (pairs, ldc) = (3 * TILE, NR + 5);
        let stride = pairs + TILE;
        let (strip, panel) = (words(MR * stride, 1), words(pairs * NR, 2));
        let mut tiles = vec![-7.0f32; MR * ldc];
        let mut modelled = tiles.clone();
        let configured = Tiles::configure();
        // SAFETY: the tiles are configured; the strip holds 32 rows at `stride` of `pairs`
        // pairs, the panel `pairs` rows of `NR`, and each output 32 rows at `ldc`.
        unsafe {
            block_product(&strip, stride, &panel, pairs, tiles.as_mut_ptr(), ldc);
            model::block_product(&strip, stride, &panel, pairs, modelled.as_mut_ptr(), ldc);
        }
        drop(configured);
        for i in 0..MR {
            for j in 0..ldc {
                let (t, m) = (tiles[i * ldc + j], modelled[i * ldc + j]);
                if j >= NR {
                    assert_eq!((t, m), (-7.0, -7.0), "row {i} column {j} was written");
                    continue;
                }
                let magnitude: f32 = (0..pairs)
                    .flat_map(|q| {
                        let (a, b) = (strip[i * stride + q], panel[q * NR + j]);
                        [0, 1].map(|h| (model::half(a, h) * model::half(b, h)).abs())
                    })
                    .sum();
                let bound = 2.0 * (2 * pairs) as f32 * f32::EPSILON * magnitude;
                assert!(
                    (t - m).abs() <= bound,
                    "row {i} column {j}: tiles {t}, model {m}"
                );
            }
        }
    }
}
