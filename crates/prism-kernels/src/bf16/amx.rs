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

use std::arch::asm;
use std::arch::x86_64::__cpuid_count;
use std::sync::OnceLock;

use rayon::prelude::*;

use super::avx512::{NR, convert, pack_b, pair_rows};
use crate::matrix::View;

/// Rows of a tile, and pairs of the inner dimension per tile step.
const TILE: usize = 16;
/// Rows of a block of `c`: two tiles.
const MR: usize = 2 * TILE;
/// Inner values per packed block: a whole number of tile steps.
const KC: usize = 512;
/// The most rows one task takes (whole strips).
const MC: usize = MR * 4;

/// Whether the CPU has AMX-TILE and AMX-BF16 and Linux lets this process use the tiles.
pub(super) fn available() -> bool {
    static AVAILABLE: OnceLock<bool> = OnceLock::new();
    *AVAILABLE.get_or_init(|| {
        let edx = __cpuid_count(7, 0).edx;
        let (tile, bf16) = (edx >> 24 & 1 == 1, edx >> 22 & 1 == 1);
        tile && bf16 && enable()
    })
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

/// `a[r0..r0 + rows, k0..k0 + kc]` as strips of `MR` rows, row `i`'s pair `q` at
/// `i * pairs + q`, zero beyond the matrix (`pairs` a whole number of tile steps).
fn pack_a(a: View<'_>, r0: usize, rows: usize, k0: usize, kc: usize, out: &mut Vec<u32>) {
    let pairs = kc.div_ceil(2).next_multiple_of(TILE);
    out.clear();
    out.resize(rows.div_ceil(MR) * MR * pairs, 0);
    if a.col_stride == 1 {
        for (i, words) in out.chunks_mut(pairs).take(rows).enumerate() {
            let row = &a.data[(r0 + i) * a.row_stride + k0..][..kc];
            // SAFETY: `available` checked the CPU, whose AMX implies AVX512-BF16.
            unsafe { convert(row, &mut words[..kc.div_ceil(2)]) };
        }
        return;
    }
    // A transposed `a`: its columns are contiguous, so each strip's rows are paired column
    // by column, then the pair-major words are turned row-major.
    let mut paired = vec![0u32; kc.div_ceil(2) * MR];
    for (s, strip) in out.chunks_mut(MR * pairs).enumerate() {
        let (i0, n) = (r0 + s * MR, MR.min(rows - s * MR));
        pair_rows(a.t(), k0, kc, i0, n, &mut paired, MR);
        for (q, words) in paired.chunks(MR).enumerate() {
            for (i, &w) in words[..n].iter().enumerate() {
                strip[i * pairs + q] = w;
            }
        }
    }
}

/// `a b`, the caller having checked the views and [`available`].
pub(super) fn matmul(a: View<'_>, b: View<'_>) -> Vec<f32> {
    let (m, k, n) = (a.rows, a.cols, b.cols);
    let mut c = vec![0.0f32; m * n];
    let panels = n.div_ceil(NR);
    let mc = super::rows_per_task(m, MR, MC);
    for k0 in (0..k).step_by(KC) {
        let kc = KC.min(k - k0);
        let pairs = kc.div_ceil(2).next_multiple_of(TILE);
        let bp = pack_b(b, k0, kc, pairs);
        c.par_chunks_mut(mc * n)
            .enumerate()
            .for_each_init(Vec::new, |ap, (t, block)| {
                let rows = block.len() / n;
                pack_a(a, t * mc, rows, k0, kc, ap);
                let config = Config::new();
                // SAFETY: `available` checked the CPU and the permission; the configuration
                // is 64 valid bytes.
                unsafe { asm!("ldtilecfg [{}]", in(reg) config.0.as_ptr(), options(nostack)) };
                let mut tile = [0.0f32; MR * NR];
                for p in 0..panels {
                    let cols = NR.min(n - p * NR);
                    let panel = &bp[p * pairs * NR..][..pairs * NR];
                    for s in 0..rows.div_ceil(MR) {
                        let strip = &ap[s * MR * pairs..][..MR * pairs];
                        // SAFETY: as above; the strip and panel hold `pairs` pairs.
                        unsafe { block_product(strip, panel, pairs, &mut tile) };
                        let tile_rows = MR.min(rows - s * MR);
                        for (i, sums) in tile.chunks(NR).take(tile_rows).enumerate() {
                            let out = &mut block[(s * MR + i) * n + p * NR..][..cols];
                            if k0 > 0 {
                                out.iter_mut().zip(sums).for_each(|(o, s)| *o += s);
                            } else {
                                out.copy_from_slice(&sums[..cols]);
                            }
                        }
                    }
                }
                // SAFETY: releases the tiles this thread configured.
                unsafe { asm!("tilerelease", options(nostack, nomem)) };
            });
    }
    c
}

/// `tile (MR x NR, row-major) = strip panel` over `pairs` pairs, with the tiles configured.
///
/// # Safety
/// The CPU runs AMX-BF16, this thread's tiles are configured by [`Config`], and `strip` and
/// `panel` hold `MR * pairs` and `pairs * NR` words, `pairs` a multiple of [`TILE`].
unsafe fn block_product(strip: &[u32], panel: &[u32], pairs: usize, tile: &mut [f32; MR * NR]) {
    debug_assert!(strip.len() >= MR * pairs && panel.len() >= pairs * NR);
    debug_assert_eq!(pairs % TILE, 0);
    let (a_stride, b_stride, c_stride) = (4 * pairs, 4 * NR, 4 * NR);
    // SAFETY: tile step `s` reads strip words `i * pairs + 16 s .. + 16` for rows `i < 32`
    // and panel words `(16 s + q) * NR .. + 32` for `q < 16`, all inside the slices; the
    // stores write `tile`'s 32 rows of 32 values.
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
            strip.as_ptr().add(TILE * pairs),
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
        let c = tile.as_mut_ptr();
        asm!(
            "tilestored [{c} + {sc}*1], tmm0",
            "tilestored [{c} + {sc}*1 + 64], tmm1",
            "tilestored [{c2} + {sc}*1], tmm2",
            "tilestored [{c2} + {sc}*1 + 64], tmm3",
            c = in(reg) c,
            c2 = in(reg) c.add(TILE * NR),
            sc = in(reg) c_stride,
            options(nostack)
        );
    }
}
