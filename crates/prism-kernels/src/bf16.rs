//! Matrix products with bf16 operands and f32 accumulation, for `--precision bf16` on the CPU.
//!
//! Both operands are rounded to bf16 (to nearest, ties to even) and their products summed in
//! f32, as AVX512-BF16's `vdpbf16ps` computes them: the product of two bf16 values is exact
//! in f32, so the result differs from the f32 product of the rounded operands only in the
//! order of the f32 sums. Three kernels compute it: AMX's `tdpbf16ps` on tiles where the CPU
//! has AMX-BF16 and Linux grants the tiles, `vdpbf16ps` where it has AVX512-BF16 (two products
//! per f32 lane and instruction, half the bytes per operand), and on every CPU the rounded
//! operands' f32 product through `gemm`, which gives the same values at f32's speed. The
//! fastest of those the CPU runs is timed once per process ([`Bf16Kernel::chosen`]).

use std::sync::OnceLock;
use std::time::{Duration, Instant};

use rayon::prelude::*;

use crate::matrix::{self, View};

/// The code that computes a product of bf16 operands.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Bf16Kernel {
    /// AMX-BF16's `tdpbf16ps` on 16 x 16 tiles of f32 sums (the packing uses AVX512-BF16,
    /// which every AMX-BF16 CPU has).
    Amx,
    /// AVX512-BF16's `vdpbf16ps` (with AVX512-F and -BW for the packing).
    Avx512Bf16,
    /// The operands rounded to bf16 and multiplied as f32 with `gemm`: the same values, at
    /// f32's speed.
    Rounded,
}

impl Bf16Kernel {
    /// Every kernel, in order of preference: the hardware's bf16 products first.
    const ALL: [Self; 3] = [Self::Amx, Self::Avx512Bf16, Self::Rounded];

    /// The kernel this process uses, chosen once: the one `PRISM_BF16_KERNEL` names (`amx`,
    /// `avx512bf16` or `rounded`) if this CPU runs it, else [`Bf16Kernel::fastest`]. When the
    /// choice is [`Bf16Kernel::Rounded`], the first call says on stderr that bf16 products run
    /// no faster than f32 here.
    pub fn chosen() -> Self {
        static CHOSEN: OnceLock<Bf16Kernel> = OnceLock::new();
        *CHOSEN.get_or_init(|| {
            let kernel = std::env::var("PRISM_BF16_KERNEL")
                .ok()
                .and_then(|name| {
                    Self::named(&name)
                        .map_err(|why| eprintln!("prism: {why}; choosing by measurement"))
                        .ok()
                })
                .unwrap_or_else(Self::fastest);
            if kernel == Self::Rounded {
                eprintln!(
                    "prism: bf16 matrix products run here as f32 products of bf16-rounded \
                     operands (the same values, no faster than f32): this CPU has no bf16 \
                     product that beats them"
                );
            }
            kernel
        })
    }

    /// The kernel `name` names, if this CPU runs it; else why not.
    pub fn named(name: &str) -> Result<Self, String> {
        let kernel = match name {
            "amx" => Self::Amx,
            "avx512bf16" => Self::Avx512Bf16,
            "rounded" => Self::Rounded,
            _ => {
                return Err(format!(
                    "PRISM_BF16_KERNEL={name} is not one of amx, avx512bf16, rounded"
                ));
            }
        };
        if kernel.runs_here() {
            Ok(kernel)
        } else {
            Err(format!(
                "PRISM_BF16_KERNEL={name}: this CPU does not run it"
            ))
        }
    }

    /// The fastest kernel this CPU runs, timed on one product of the backbone's shape (the
    /// `qkv` projection at 128 px: 512 x 256 x 768), each kernel's best of a few runs. The
    /// hardware's products are not always the fastest: on an Intel Xeon with AVX512-BF16 and
    /// no AMX, `vdpbf16ps` ran the model's products slower than `gemm`'s f32 products of the
    /// rounded operands, where on an AMD Zen 4 it ran them faster (BENCHMARKS.md).
    pub fn fastest() -> Self {
        let candidates: Vec<Self> = Self::ALL.into_iter().filter(|k| k.runs_here()).collect();
        if candidates.len() == 1 {
            return candidates[0];
        }
        let (a, b) = (vec![0.5; 512 * 256], vec![0.25; 256 * 768]);
        let (a, b) = (View::rows(&a, 512, 256), View::rows(&b, 256, 768));
        let timed: Vec<(Self, Duration)> = candidates
            .into_iter()
            .map(|kernel| {
                let best = (0..5)
                    .map(|_| {
                        let start = Instant::now();
                        std::hint::black_box(matmul(kernel, a, b));
                        start.elapsed()
                    })
                    .skip(1)
                    .min()
                    .expect("four timed runs");
                (kernel, best)
            })
            .collect();
        Self::preferred(&timed)
    }

    /// Of timed kernels, in order of preference, the first within 10% of the fastest time:
    /// near-ties go to the hardware's products, so that a noisy measurement rarely changes
    /// the choice (and with it the order of the sums) from one run to the next.
    fn preferred(timed: &[(Self, Duration)]) -> Self {
        let best = timed
            .iter()
            .map(|t| t.1)
            .min()
            .expect("at least one kernel");
        timed
            .iter()
            .find(|t| t.1.as_secs_f64() <= 1.1 * best.as_secs_f64())
            .expect("the fastest is within 10% of itself")
            .0
    }

    /// Whether this CPU (and, for AMX, the operating system) runs the kernel.
    pub fn runs_here(self) -> bool {
        #[cfg(target_arch = "x86_64")]
        let avx512_bf16 = is_x86_feature_detected!("avx512f")
            && is_x86_feature_detected!("avx512bw")
            && is_x86_feature_detected!("avx512bf16");
        #[cfg(not(target_arch = "x86_64"))]
        let avx512_bf16 = false;
        match self {
            #[cfg(target_arch = "x86_64")]
            Self::Amx => avx512_bf16 && amx::available(),
            #[cfg(not(target_arch = "x86_64"))]
            Self::Amx => false,
            Self::Avx512Bf16 => avx512_bf16,
            Self::Rounded => true,
        }
    }
}

/// `x` rounded to the nearest bf16 (ties to even), as its 16 bits.
#[inline(always)]
pub fn bf16_bits(x: f32) -> u16 {
    let b = x.to_bits();
    if x.is_nan() {
        return ((b >> 16) | 0x40) as u16;
    }
    (b.wrapping_add(0x7fff + ((b >> 16) & 1)) >> 16) as u16
}

/// `x` rounded to the nearest bf16, as an f32.
#[inline(always)]
pub fn round_bf16(x: f32) -> f32 {
    f32::from_bits((bf16_bits(x) as u32) << 16)
}

/// `a b` (row-major `a.rows x b.cols`), both operands rounded to bf16, the products summed
/// in f32. Panics if the views disagree or lie outside their slices, or if this CPU does not
/// run `kernel`.
pub(crate) fn matmul(kernel: Bf16Kernel, a: View<'_>, b: View<'_>) -> Vec<f32> {
    product(a, &Packed::new(kernel, b))
}

/// `a b` for an operand `b` packed by [`Packed::new`]: [`matmul`] without packing `b` again.
/// Panics if `a` lies outside its slice or its columns are not `b`'s rows.
pub(crate) fn product(a: View<'_>, b: &Packed) -> Vec<f32> {
    assert_eq!(a.cols, b.rows, "bf16 matmul: inner sizes differ");
    a.check();
    match &b.panels {
        #[cfg(target_arch = "x86_64")]
        Panels::Amx(panels) => amx::matmul(a, b.cols, panels),
        #[cfg(target_arch = "x86_64")]
        Panels::Avx512(panels) => avx512::matmul(a, b.cols, panels),
        Panels::Rounded(rb) => {
            let ra = rounded_span(a);
            matrix::product(View { data: &ra, ..a }, rb.view())
        }
    }
}

/// An operand `b` in the layout its kernel reads, packed once so that products with a matrix
/// used again and again (a layer's weight, in inference: [`crate::packed`]) skip the
/// packing, which costs about as much as a small product on AMX.
pub(crate) struct Packed {
    /// `b`'s rows (the product's inner size) and columns.
    rows: usize,
    cols: usize,
    panels: Panels,
}

/// The packed values, per kernel.
enum Panels {
    /// [`amx::PackedB`] per block of the inner dimension (its first row and size).
    #[cfg(target_arch = "x86_64")]
    Amx(Vec<(usize, usize, amx::PackedB)>),
    /// The AVX-512 kernel's panels per block of the inner dimension (its first row and size).
    #[cfg(target_arch = "x86_64")]
    Avx512(Vec<(usize, usize, Vec<u32>)>),
    /// `b` rounded to bf16 values, in its own layout, for `gemm`.
    Rounded(RoundedB),
}

/// An operand rounded in its own layout: the span of values its view covers, and its strides.
struct RoundedB {
    values: Vec<f32>,
    rows: usize,
    cols: usize,
    row_stride: usize,
    col_stride: usize,
}

impl RoundedB {
    fn view(&self) -> View<'_> {
        View {
            data: &self.values,
            rows: self.rows,
            cols: self.cols,
            row_stride: self.row_stride,
            col_stride: self.col_stride,
        }
    }
}

impl Packed {
    /// `b` packed for `kernel`. Panics if `b` lies outside its slice, or if this CPU does not
    /// run `kernel`.
    pub(crate) fn new(kernel: Bf16Kernel, b: View<'_>) -> Self {
        b.check();
        assert!(
            kernel.runs_here(),
            "this CPU does not run the {kernel:?} kernel"
        );
        let panels = match kernel {
            #[cfg(target_arch = "x86_64")]
            Bf16Kernel::Amx => Panels::Amx(amx::pack(b)),
            #[cfg(target_arch = "x86_64")]
            Bf16Kernel::Avx512Bf16 => Panels::Avx512(avx512::pack(b)),
            #[cfg(not(target_arch = "x86_64"))]
            Bf16Kernel::Amx | Bf16Kernel::Avx512Bf16 => unreachable!("runs on x86_64 only"),
            Bf16Kernel::Rounded => Panels::Rounded(RoundedB {
                values: rounded_span(b),
                rows: b.rows,
                cols: b.cols,
                row_stride: b.row_stride,
                col_stride: b.col_stride,
            }),
        };
        Self {
            rows: b.rows,
            cols: b.cols,
            panels,
        }
    }
}

/// Rows of `c` per task of a blocked kernel: enough tasks for every thread twice over, in whole
/// strips of `strip` rows, at most `most` rows.
#[cfg(target_arch = "x86_64")]
fn rows_per_task(m: usize, strip: usize, most: usize) -> usize {
    m.div_ceil(2 * rayon::current_num_threads())
        .next_multiple_of(strip)
        .min(most)
}

/// Values per task of [`rounded_span`]'s pass: at least enough that a task costs more than
/// handing it to another thread.
const ROUND_TASK: usize = 1 << 14;

/// The span of values `v` covers, rounded to bf16 values in its own layout (one pass over
/// contiguous memory on both threads, into memory not zeroed first), so that a transposed
/// operand stays transposed for `gemm`.
fn rounded_span(v: View<'_>) -> Vec<f32> {
    let span = &v.data[..=(v.rows - 1) * v.row_stride + (v.cols - 1) * v.col_stride];
    let mut out = Vec::new();
    span.par_iter()
        .with_min_len(ROUND_TASK)
        .map(|&x| round_bf16(x))
        .collect_into_vec(&mut out);
    out
}

#[cfg(target_arch = "x86_64")]
pub(crate) mod amx;

#[cfg(target_arch = "x86_64")]
pub(crate) mod avx512 {
    //! The `vdpbf16ps` kernel, blocked in the manner of GotoBLAS: `b` is packed in panels of
    //! `NR` columns per block of `KC` inner values, `a` in strips of `MR` rows per task, and
    //! each `MR x NR` tile of `c` accumulates in 24 vector registers.
    use std::arch::x86_64::*;

    use rayon::prelude::*;

    use super::bf16_bits;
    use crate::buffer::filled_init;
    use crate::matrix::View;

    /// Rows of a register tile.
    const MR: usize = 12;
    /// Columns of a register tile: two vectors of 16 f32.
    pub(super) const NR: usize = 32;
    /// Inner-dimension values per packed block (even, so pairs never straddle two blocks).
    const KC: usize = 384;
    /// The most rows one task takes (a multiple of `MR`).
    const MC: usize = MR * 8;

    /// Two bf16 values in one 32-bit word, the first in the low half (`vdpbf16ps`' order).
    #[inline(always)]
    pub(super) fn pair(lo: f32, hi: f32) -> u32 {
        bf16_bits(lo) as u32 | (bf16_bits(hi) as u32) << 16
    }

    /// Lanes `0..n` of a 16-lane vector.
    #[inline(always)]
    fn lanes(n: usize) -> u16 {
        if n >= 16 { u16::MAX } else { (1u16 << n) - 1 }
    }

    /// `out[j] = pair(lo[j], hi[j])` for `j < out.len() <= 32`, `hi` absent reading as zeros:
    /// two source rows interleaved into the words of their pairs.
    #[target_feature(enable = "avx512f,avx512bw,avx512bf16")]
    fn interleave(lo: &[f32], hi: Option<&[f32]>, out: &mut [u32]) {
        const IDX: [u16; 32] = {
            let mut idx = [0u16; 32];
            let mut j = 0;
            while j < 16 {
                idx[2 * j] = j as u16;
                idx[2 * j + 1] = j as u16 + 16;
                j += 1;
            }
            idx
        };
        assert!(out.len() <= 32 && lo.len() >= out.len());
        assert!(hi.is_none_or(|hi| hi.len() >= out.len()));
        // SAFETY: every load and store is masked to the lanes below `out.len()`, which the
        // slices were checked to hold.
        unsafe {
            let idx = _mm512_loadu_si512(IDX.as_ptr().cast());
            for h in 0..out.len().div_ceil(16) {
                let mask = lanes(out.len() - 16 * h);
                let l = _mm512_maskz_loadu_ps(mask, lo.as_ptr().add(16 * h));
                let u = match hi {
                    Some(hi) => _mm512_maskz_loadu_ps(mask, hi.as_ptr().add(16 * h)),
                    None => _mm512_setzero_ps(),
                };
                let halves: __m512i = std::mem::transmute(_mm512_cvtne2ps_pbh(u, l));
                let words = _mm512_permutexvar_epi16(idx, halves);
                _mm512_mask_storeu_epi32(out.as_mut_ptr().add(16 * h).cast(), mask, words);
            }
        }
    }

    /// `out[q] = pair(row[2q], row[2q + 1])`: a contiguous run as the words of its pairs (an
    /// odd length's last word has a zero high half).
    #[target_feature(enable = "avx512f,avx512bw,avx512bf16")]
    pub(super) fn convert(row: &[f32], out: &mut [u32]) {
        assert_eq!(out.len(), row.len().div_ceil(2));
        // SAFETY: the loads are masked to `row`'s values, the stores to `out`'s words.
        unsafe {
            for (t, words) in out.chunks_mut(16).enumerate() {
                let n = row.len() - 32 * t;
                let l = _mm512_maskz_loadu_ps(lanes(n), row.as_ptr().add(32 * t));
                let u = if n > 16 {
                    _mm512_maskz_loadu_ps(lanes(n - 16), row.as_ptr().add(32 * t + 16))
                } else {
                    _mm512_setzero_ps()
                };
                let halves: __m512i = std::mem::transmute(_mm512_cvtne2ps_pbh(u, l));
                _mm512_mask_storeu_epi32(words.as_mut_ptr().cast(), lanes(words.len()), halves);
            }
        }
    }

    /// How a packed strip of `a` lays out its words.
    #[derive(Clone, Copy, PartialEq, Eq)]
    enum Strip {
        /// Word `(i, q)` at `q * MR + i`: the pairs of one inner step side by side.
        PairMajor,
        /// Word `(i, q)` at `i * pairs + q`: each row's pairs in a run.
        RowMajor,
    }

    /// `b[k0..k0 + kc, ..]` as panels of `NR` columns and `pairs >= kc / 2` pairs: panel `p`,
    /// pair `q`, column `j` at `(p * pairs + q) * NR + j`, zero beyond the matrix.
    pub(super) fn pack_b(b: View<'_>, k0: usize, kc: usize, pairs: usize) -> Vec<u32> {
        let used = kc.div_ceil(2);
        assert!(
            pairs >= used,
            "pack_b: {pairs} pairs cannot hold {kc} values"
        );
        let mut out = vec![0u32; b.cols.div_ceil(NR) * pairs * NR];
        out.par_chunks_mut(pairs * NR)
            .enumerate()
            .for_each_init(Vec::new, |column, (p, panel)| {
                let panel = &mut panel[..used * NR];
                let (c0, cols) = (p * NR, NR.min(b.cols - p * NR));
                if b.row_stride == 1 {
                    // Contiguous columns (a transposed row-major matrix): each column's pairs
                    // converted in a run, then set into the panel's rows.
                    column.resize(used, 0);
                    for j in 0..cols {
                        let run = &b.data[(c0 + j) * b.col_stride + k0..][..kc];
                        // SAFETY: `matmul`'s caller checked the CPU's features.
                        unsafe { convert(run, column) };
                        for (q, &w) in column.iter().enumerate() {
                            panel[q * NR + j] = w;
                        }
                    }
                    return;
                }
                pair_rows(b, k0, kc, c0, cols, panel, NR);
            });
        out
    }

    /// Word `(q, j)` at `q * stride + j` of `out`, for `j < width`: rows `k0 + 2q` and
    /// `k0 + 2q + 1` of `m` (the second zero past `k0 + kc`) at column `c0 + j`, as a pair.
    pub(super) fn pair_rows(
        m: View<'_>,
        k0: usize,
        kc: usize,
        c0: usize,
        width: usize,
        out: &mut [u32],
        stride: usize,
    ) {
        for (q, words) in out.chunks_mut(stride).enumerate() {
            let r0 = k0 + 2 * q;
            let r1 = (2 * q + 1 < kc).then_some(r0 + 1);
            let words = &mut words[..width];
            if m.col_stride == 1 {
                let row = |r: usize| &m.data[r * m.row_stride + c0..][..width];
                // SAFETY: `matmul`'s caller checked the CPU's features.
                unsafe { interleave(row(r0), r1.map(row), words) };
            } else {
                for (j, w) in words.iter_mut().enumerate() {
                    let hi = r1.map_or(0.0, |r1| m.at(r1, c0 + j));
                    *w = pair(m.at(r0, c0 + j), hi);
                }
            }
        }
    }

    /// `a[r0..r0 + rows, k0..k0 + kc]` as strips of `MR` rows (zero beyond the matrix), each of
    /// `pairs * MR` words in the layout returned.
    fn pack_a(
        a: View<'_>,
        r0: usize,
        rows: usize,
        k0: usize,
        kc: usize,
        out: &mut Vec<u32>,
    ) -> Strip {
        let pairs = kc.div_ceil(2);
        out.clear();
        out.resize(rows.div_ceil(MR) * pairs * MR, 0);
        if a.col_stride == 1 {
            for (i, words) in out.chunks_mut(pairs).take(rows).enumerate() {
                let row = &a.data[(r0 + i) * a.row_stride + k0..][..kc];
                // SAFETY: `matmul`'s caller checked the CPU's features.
                unsafe { convert(row, words) };
            }
            return Strip::RowMajor;
        }
        for (s, strip) in out.chunks_mut(pairs * MR).enumerate() {
            let (i0, n) = (r0 + s * MR, MR.min(rows - s * MR));
            pair_rows(a.t(), k0, kc, i0, n, strip, MR);
        }
        Strip::PairMajor
    }

    /// `b` packed whole, block by block of the inner dimension (each block's first row, size
    /// and panels), the caller having checked the CPU's features and the view.
    pub(crate) fn pack(b: View<'_>) -> Vec<(usize, usize, Vec<u32>)> {
        (0..b.rows)
            .step_by(KC)
            .map(|k0| {
                let kc = KC.min(b.rows - k0);
                (k0, kc, pack_b(b, k0, kc, kc.div_ceil(2)))
            })
            .collect()
    }

    /// `a b` for `b` of `n` columns packed by [`pack`], the caller having checked the CPU's
    /// features and the views. Each task fills its block of rows of `c` ([`rows_product`]).
    pub(super) fn matmul(a: View<'_>, n: usize, panels: &[(usize, usize, Vec<u32>)]) -> Vec<f32> {
        let m = a.rows;
        let mc = super::rows_per_task(m, MR, MC);
        filled_init(m * n, mc * n, Vec::new, |ap, t, block| {
            rows_product(a, t * mc, n, panels, ap, block);
        })
    }

    /// `c = a[r0..r0 + rows] b` on the calling thread, for `b` of `n` columns packed by
    /// [`pack`] and `c` of `rows = c.len() / n` rows of `n`, in one pass over the inner
    /// dimension: `c`'s values are overwritten, never read first (where `b` has no rows, `c`
    /// is left as it was); `ap` holds the packed strips of `a`. Panics unless this CPU runs
    /// AVX512-BF16 (with AVX512-F and -BW).
    pub(crate) fn rows_product(
        a: View<'_>,
        r0: usize,
        n: usize,
        panels: &[(usize, usize, Vec<u32>)],
        ap: &mut Vec<u32>,
        c: &mut [f32],
    ) {
        assert!(
            super::Bf16Kernel::Avx512Bf16.runs_here(),
            "this CPU does not run AVX512-BF16"
        );
        let rows = c.len() / n;
        assert!(r0 + rows <= a.rows && c.len() == rows * n);
        for (k0, kc, bp) in panels {
            let pairs = kc.div_ceil(2);
            let layout = pack_a(a, r0, rows, *k0, *kc, ap);
            for p in 0..n.div_ceil(NR) {
                let cols = NR.min(n - p * NR);
                let panel = &bp[p * pairs * NR..][..pairs * NR];
                for s in 0..rows.div_ceil(MR) {
                    let strip = &ap[s * pairs * MR..][..pairs * MR];
                    let tile = Tile {
                        pairs,
                        rows: MR.min(rows - s * MR),
                        cols,
                        ldc: n,
                        accumulate: *k0 > 0,
                    };
                    let out = &mut c[s * MR * n + p * NR..];
                    // SAFETY: the CPU's features were checked above.
                    unsafe {
                        match layout {
                            Strip::PairMajor => tile.run::<false>(strip, panel, out),
                            Strip::RowMajor => tile.run::<true>(strip, panel, out),
                        }
                    }
                }
            }
        }
    }

    /// One `MR x NR` register tile of `c`.
    struct Tile {
        /// Packed pairs of the inner dimension.
        pairs: usize,
        /// Rows and columns of the tile inside `c`.
        rows: usize,
        cols: usize,
        /// `c`'s row stride.
        ldc: usize,
        /// Add to `c` instead of overwriting it.
        accumulate: bool,
    }

    impl Tile {
        /// `c[..rows, ..cols] [+]= a b` from a strip of `a` (row-major layout when `ROWS`) and a
        /// panel of `b`.
        #[target_feature(enable = "avx512f,avx512bf16")]
        fn run<const ROWS: bool>(&self, a: &[u32], b: &[u32], c: &mut [f32]) {
            let pairs = self.pairs;
            assert!(a.len() >= pairs * MR && b.len() >= pairs * NR);
            assert!(self.rows <= MR && self.cols <= NR && self.rows > 0);
            assert!(c.len() >= (self.rows - 1) * self.ldc + self.cols);
            let (row_step, pair_step) = if ROWS { (pairs, 1) } else { (1, MR) };
            let mut acc = [[_mm512_setzero_ps(); 2]; MR];
            // SAFETY: word (i, q) of the strip is at i * row_step + q * pair_step <
            // pairs * MR, and word (q, j) of the panel at q * NR + j < pairs * NR.
            unsafe {
                let (mut ap, mut bp) = (a.as_ptr(), b.as_ptr());
                for _ in 0..pairs {
                    let b0: __m512bh = std::mem::transmute(_mm512_loadu_si512(bp.cast()));
                    let b1: __m512bh = std::mem::transmute(_mm512_loadu_si512(bp.add(16).cast()));
                    for (i, acc) in acc.iter_mut().enumerate() {
                        let ai = _mm512_set1_epi32(*ap.add(i * row_step) as i32);
                        let ai: __m512bh = std::mem::transmute(ai);
                        acc[0] = _mm512_dpbf16_ps(acc[0], ai, b0);
                        acc[1] = _mm512_dpbf16_ps(acc[1], ai, b1);
                    }
                    ap = ap.add(pair_step);
                    bp = bp.add(NR);
                }
            }
            let masks = [lanes(self.cols), lanes(self.cols.saturating_sub(16))];
            for (i, acc) in acc.iter().enumerate().take(self.rows) {
                for (h, (&v, &mask)) in acc.iter().zip(&masks).enumerate() {
                    // SAFETY: the masked lanes lie below (rows - 1) * ldc + cols.
                    unsafe {
                        let dst = c.as_mut_ptr().add(i * self.ldc + 16 * h);
                        let v = if self.accumulate {
                            _mm512_add_ps(v, _mm512_maskz_loadu_ps(mask, dst))
                        } else {
                            v
                        };
                        _mm512_mask_storeu_ps(dst, mask, v);
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_util::values;

    /// The product of the rounded operands in f64.
    fn reference(a: View<'_>, b: View<'_>) -> Vec<f64> {
        let mut c = vec![0.0; a.rows * b.cols];
        for i in 0..a.rows {
            for j in 0..b.cols {
                c[i * b.cols + j] = (0..a.cols)
                    .map(|p| round_bf16(a.at(i, p)) as f64 * round_bf16(b.at(p, j)) as f64)
                    .sum();
            }
        }
        c
    }

    /// The fastest kernel wins unless one earlier in the order of preference is within 10%
    /// of it.
    #[test]
    fn the_choice_is_the_fastest_or_a_preferred_near_tie() {
        let ms = Duration::from_micros;
        use Bf16Kernel::{Amx, Avx512Bf16, Rounded};
        let cases = [
            (vec![(Avx512Bf16, ms(1300)), (Rounded, ms(1000))], Rounded),
            (
                vec![(Avx512Bf16, ms(1090)), (Rounded, ms(1000))],
                Avx512Bf16,
            ),
            (vec![(Avx512Bf16, ms(700)), (Rounded, ms(1000))], Avx512Bf16),
            (
                vec![(Amx, ms(1200)), (Avx512Bf16, ms(1050)), (Rounded, ms(1000))],
                Avx512Bf16,
            ),
            (vec![(Rounded, ms(1000))], Rounded),
        ];
        for (timed, want) in cases {
            assert_eq!(Bf16Kernel::preferred(&timed), want, "{timed:?}");
        }
    }

    /// The measured choice is a kernel this CPU runs, and `PRISM_BF16_KERNEL`'s names map to
    /// the kernels this CPU runs; other names, and kernels it does not run, are refused.
    #[test]
    fn the_measured_and_the_named_kernels_run_here() {
        let fastest = Bf16Kernel::fastest();
        eprintln!("fastest bf16 kernel here: {fastest:?}");
        assert!(fastest.runs_here());
        for (name, kernel) in [
            ("amx", Bf16Kernel::Amx),
            ("avx512bf16", Bf16Kernel::Avx512Bf16),
            ("rounded", Bf16Kernel::Rounded),
        ] {
            match Bf16Kernel::named(name) {
                Ok(named) => assert_eq!(named, kernel),
                Err(why) => {
                    assert!(!kernel.runs_here(), "{name}: {why}");
                    assert!(why.contains("does not run"), "{why}");
                }
            }
        }
        let err = Bf16Kernel::named("fp8").unwrap_err();
        assert!(err.contains("not one of amx, avx512bf16, rounded"), "{err}");
    }

    /// Every kernel this CPU runs (AMX on the tiles' model where the CPU has AVX512-BF16 and
    /// no tiles), on sizes that leave partial tiles, strips and panels, more than one block of
    /// the inner dimension (odd and even) and of rows, and each operand row-major or
    /// transposed: within f32's rounding of the sums of the rounded operands' exact products.
    #[test]
    fn kernels_match_the_rounded_product() {
        let kernels: Vec<Bf16Kernel> =
            [Bf16Kernel::Amx, Bf16Kernel::Avx512Bf16, Bf16Kernel::Rounded]
                .into_iter()
                .filter(|k| k.runs_here())
                .collect();
        eprintln!("kernels run here: {kernels:?}");
        for (m, k, n) in [
            (1, 1, 1),
            (13, 7, 33),
            (12, 2, 32),
            (130, 801, 70),
            (200, 384, 31),
        ] {
            let (ad, bd) = (values(m * k, 1), values(k * n, 2));
            for (a_t, b_t) in [(false, false), (true, false), (false, true), (true, true)] {
                let a = if a_t {
                    View::transposed(&ad, m, k)
                } else {
                    View::rows(&ad, m, k)
                };
                let b = if b_t {
                    View::transposed(&bd, k, n)
                } else {
                    View::rows(&bd, k, n)
                };
                let want = reference(a, b);
                for &kernel in &kernels {
                    let got = matmul(kernel, a, b);
                    let err = got
                        .iter()
                        .zip(&want)
                        .map(|(x, y)| (*x as f64 - y).abs())
                        .fold(0.0, f64::max);
                    let bound = 1e-6 * (k as f64).sqrt().max(1.0) * 4.0;
                    assert!(
                        err < bound,
                        "{kernel:?} {m}x{k}x{n} (a transposed {a_t}, b {b_t}): error {err}"
                    );
                }
            }
        }
    }

    /// Rounding to nearest with ties to even, infinities kept, NaN kept a NaN.
    #[test]
    fn rounding_is_to_nearest_even() {
        assert_eq!(round_bf16(1.0), 1.0);
        // 1 + 2^-8 lies halfway between 1 and 1 + 2^-7: the tie goes to the even 1.
        assert_eq!(round_bf16(1.0 + 2f32.powi(-8)), 1.0);
        // 1 + 3 * 2^-8 lies halfway between 1 + 2^-7 and 1 + 2^-6: to the even 1 + 2^-6.
        assert_eq!(round_bf16(1.0 + 3.0 * 2f32.powi(-8)), 1.0 + 2f32.powi(-6));
        assert_eq!(
            round_bf16(1.0 + 2f32.powi(-8) + 2f32.powi(-12)),
            1.0 + 2f32.powi(-7)
        );
        assert_eq!(round_bf16(-3.0), -3.0);
        assert_eq!(round_bf16(f32::INFINITY), f32::INFINITY);
        assert!(round_bf16(f32::NAN).is_nan());
        let x = 0.1f32;
        assert!((round_bf16(x) - x).abs() <= x * 2f32.powi(-9));
    }
}
