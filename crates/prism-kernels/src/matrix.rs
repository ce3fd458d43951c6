//! Strided matrix views over host slices, and the kernels' matrix product on them.

use std::mem::MaybeUninit;

use gemm::{Parallelism, gemm};
use rayon::prelude::*;

/// A strided matrix view over a slice: element `(r, c)` at `r * row_stride + c * col_stride`.
#[derive(Clone, Copy)]
pub(crate) struct View<'a> {
    pub(crate) data: &'a [f32],
    pub(crate) rows: usize,
    pub(crate) cols: usize,
    pub(crate) row_stride: usize,
    pub(crate) col_stride: usize,
}

impl<'a> View<'a> {
    /// Row-major `rows x cols`.
    pub(crate) fn rows(data: &'a [f32], rows: usize, cols: usize) -> Self {
        Self {
            data,
            rows,
            cols,
            row_stride: cols,
            col_stride: 1,
        }
    }

    /// The transpose of a row-major `cols x rows` matrix.
    pub(crate) fn transposed(data: &'a [f32], rows: usize, cols: usize) -> Self {
        Self {
            data,
            rows,
            cols,
            row_stride: 1,
            col_stride: rows,
        }
    }

    /// The transposed view of the same values.
    pub(crate) fn t(self) -> Self {
        Self {
            data: self.data,
            rows: self.cols,
            cols: self.rows,
            row_stride: self.col_stride,
            col_stride: self.row_stride,
        }
    }

    /// Panics unless the view is non-empty and lies inside its slice.
    pub(crate) fn check(&self) {
        let last = (self.rows - 1) * self.row_stride + (self.cols - 1) * self.col_stride;
        assert!(
            self.rows > 0 && self.cols > 0 && last < self.data.len(),
            "matrix view out of bounds"
        );
    }

    /// Element `(r, c)`.
    #[inline(always)]
    pub(crate) fn at(&self, r: usize, c: usize) -> f32 {
        self.data[r * self.row_stride + c * self.col_stride]
    }

    /// Rows `start..end` of the view.
    fn row_range(self, start: usize, end: usize) -> Self {
        Self {
            data: &self.data[start * self.row_stride..],
            rows: end - start,
            ..self
        }
    }

    /// Columns `start..end` of the view.
    fn col_range(self, start: usize, end: usize) -> Self {
        Self {
            data: &self.data[start * self.col_stride..],
            cols: end - start,
            ..self
        }
    }

    /// The view's values copied out row-major (of a transposed view: the transpose).
    ///
    /// `gemm` multiplies fastest with its right operand row-major: given one transposed, it
    /// gathers the operand's columns value by value into its panels, on every call. A
    /// transposed operand that several products share (a head's keys, for each block of its
    /// queries) is cheaper copied out once.
    pub(crate) fn to_rows(self) -> Vec<f32> {
        const TILE: usize = 16;
        self.check();
        let (rows, cols) = (self.rows, self.cols);
        let mut out = vec![0.0; rows * cols];
        // Each tile is read down its columns (contiguous in a transposed view) into a local
        // block, then written out along its rows.
        let mut tile = [[0.0f32; TILE]; TILE];
        for c0 in (0..cols).step_by(TILE) {
            let width = TILE.min(cols - c0);
            for r0 in (0..rows).step_by(TILE) {
                let height = TILE.min(rows - r0);
                for c in 0..width {
                    let column = &self.data[r0 * self.row_stride + (c0 + c) * self.col_stride..];
                    let column = column.iter().step_by(self.row_stride);
                    for (row, &x) in tile.iter_mut().zip(column).take(height) {
                        row[c] = x;
                    }
                }
                for (r, row) in tile.iter().enumerate().take(height) {
                    out[(r0 + r) * cols + c0..][..width].copy_from_slice(&row[..width]);
                }
            }
        }
        out
    }
}

/// `dst (row-major lhs.rows x rhs.cols) = [dst +] scale * lhs rhs`, single-threaded (the
/// callers parallelise: attention over heads and blocks, convolutions over images).
pub(crate) fn matmul(dst: &mut [f32], accumulate: bool, lhs: View<'_>, rhs: View<'_>, scale: f32) {
    assert_eq!(dst.len(), lhs.rows * rhs.cols, "matmul: output size");
    // SAFETY: `dst` holds exactly `m x n` initialised values, row-major.
    unsafe { gemm_call(dst.as_mut_ptr(), rhs.cols, accumulate, lhs, rhs, scale) };
}

/// `dst = scale * lhs rhs` into an unwritten `dst` (row-major `lhs.rows x rhs.cols`),
/// single-threaded as [`matmul`]: every value written, handed back as a plain slice.
pub(crate) fn matmul_into<'a>(
    dst: &'a mut [MaybeUninit<f32>],
    lhs: View<'_>,
    rhs: View<'_>,
    scale: f32,
) -> &'a mut [f32] {
    assert_eq!(dst.len(), lhs.rows * rhs.cols, "matmul: output size");
    // SAFETY: `dst` holds exactly `m x n` values, row-major; without accumulation `gemm` reads
    // none of them.
    unsafe { gemm_call(dst.as_mut_ptr().cast(), rhs.cols, false, lhs, rhs, scale) };
    // SAFETY: `gemm` without accumulation wrote every one of the `m x n` values.
    unsafe { dst.assume_init_mut() }
}

/// The row-major `a b` through `gemm`, on all of rayon's threads when the product is large
/// enough to pay for them. The output is written once: it is not zeroed first (`gemm` without
/// accumulation reads none of it), which on the training step was a serial `memset` of every
/// product's output.
///
/// The threads do not share one `gemm` call: the output is cut into one band per thread, along
/// its longer side, and each band is its own single-threaded product. On the backbone's shapes
/// (512 rows, widths 256 to 1024) this ran at 1.0x to 1.24x `gemm`'s own two-thread speed on a
/// 2-core Xeon, most for the backward pass's transposed operands (BENCHMARKS.md, issue 43's
/// "Each thread its own product band, and the workers kept awake"). A band is at least
/// [`MIN_BAND`] wide; a product too small for two bands runs on one thread.
pub(crate) fn product(a: View<'_>, b: View<'_>) -> Vec<f32> {
    let (m, n) = (a.rows, b.cols);
    let len = m * n;
    let mut c: Vec<f32> = Vec::with_capacity(len);
    let bands = if m * a.cols * n >= PARALLEL_FLOPS {
        rayon::current_num_threads().min(m.max(n) / MIN_BAND).max(1)
    } else {
        1
    };
    let dst = Destination(c.as_mut_ptr());
    let along = m.max(n);
    // Where band `i` starts: an equal share, on a multiple of 16 (a vector of the kernel).
    let cut = |i: usize| {
        if i == bands {
            along
        } else {
            i * along / bands / 16 * 16
        }
    };
    let band = |i: usize| {
        // Band `i` of `bands`: rows (or columns) `start..end` of the output.
        let (start, end) = (cut(i), cut(i + 1));
        // SAFETY: the bands cover disjoint parts of `c`'s `m x n` values (rows `start..end`, or
        // columns `start..end` of every row), each written by one call only, at the full row
        // stride `n`.
        unsafe {
            if m >= n {
                let a = a.row_range(start, end);
                gemm_call(dst.at(start * n), n, false, a, b, 1.0);
            } else {
                gemm_call(dst.at(start), n, false, a, b.col_range(start, end), 1.0);
            }
        }
    };
    if bands == 1 {
        band(0);
    } else {
        (0..bands).into_par_iter().for_each(band);
    }
    // SAFETY: the bands together wrote all `len` values (`gemm` without accumulation writes
    // every value of its output and reads none).
    unsafe { c.set_len(len) };
    c
}

/// Multiply-adds below which [`product`] stays on one thread.
const PARALLEL_FLOPS: usize = 1 << 16;

/// The fewest rows (or columns) of a product's output that [`product`] gives a thread.
const MIN_BAND: usize = 64;

/// The output of [`product`], shared by its bands (each writes its own values).
#[derive(Clone, Copy)]
struct Destination(*mut f32);
// SAFETY: the bands write disjoint values (see `product`).
unsafe impl Send for Destination {}
// SAFETY: as above; no band reads another's values.
unsafe impl Sync for Destination {}

impl Destination {
    /// The value `offset` places on.
    ///
    /// # Safety
    /// `offset` lies within the output.
    unsafe fn at(self, offset: usize) -> *mut f32 {
        // SAFETY: passed on from the caller.
        unsafe { self.0.add(offset) }
    }
}

/// The single-threaded `gemm` call behind [`matmul`] and [`product`]'s bands.
///
/// # Safety
/// `dst` is valid for writes of `lhs.rows x rhs.cols` values at row stride `dst_row_stride`,
/// and for reads of as many initialised ones when `accumulate`.
unsafe fn gemm_call(
    dst: *mut f32,
    dst_row_stride: usize,
    accumulate: bool,
    lhs: View<'_>,
    rhs: View<'_>,
    scale: f32,
) {
    assert_eq!(lhs.cols, rhs.rows, "matmul: inner sizes differ");
    lhs.check();
    rhs.check();
    // SAFETY: the views were checked to lie inside their slices, and the caller vouches for
    // `dst`'s `m x n` values; gemm reads and writes nothing else, and reads `dst` only when
    // `accumulate`.
    unsafe {
        gemm(
            lhs.rows,
            rhs.cols,
            lhs.cols,
            dst,
            1,
            dst_row_stride as isize,
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

#[cfg(test)]
mod tests {
    use super::*;

    /// [`product`] against the sums written out, on one band and on several, cut along rows
    /// and along columns, with each operand row-major or transposed, on sizes that leave
    /// partial vectors and uneven bands.
    #[test]
    fn product_matches_the_sums_in_every_band() {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(3)
            .build()
            .unwrap();
        let value = |i: usize| ((i * 7919) % 97) as f32 / 97.0 - 0.5;
        for (m, k, n) in [(5, 3, 7), (300, 17, 70), (70, 9, 333), (200, 40, 200)] {
            let a: Vec<f32> = (0..m * k).map(value).collect();
            let b: Vec<f32> = (0..k * n).map(|i| value(i + 11)).collect();
            let expected: Vec<f32> = (0..m * n)
                .map(|i| (0..k).map(|j| a[i / n * k + j] * b[j * n + i % n]).sum())
                .collect();
            let a_t = View::rows(&a, m, k).t().to_rows();
            let b_t = View::rows(&b, k, n).t().to_rows();
            for (lhs, rhs) in [
                (View::rows(&a, m, k), View::rows(&b, k, n)),
                (View::transposed(&a_t, m, k), View::rows(&b, k, n)),
                (View::rows(&a, m, k), View::transposed(&b_t, k, n)),
            ] {
                for got in [product(lhs, rhs), pool.install(|| product(lhs, rhs))] {
                    for (i, (g, e)) in got.iter().zip(&expected).enumerate() {
                        assert!(
                            (g - e).abs() < 1e-4,
                            "{m}x{k}x{n}, value {i}: {g} against {e}"
                        );
                    }
                }
            }
        }
    }

    /// A row-major view copies out as itself, a transposed one as its transpose, on sizes
    /// that leave partial tiles.
    #[test]
    fn to_rows_copies_the_values_row_major() {
        for (rows, cols) in [(1, 1), (3, 40), (17, 35), (32, 16)] {
            let data: Vec<f32> = (0..rows * cols).map(|i| i as f32).collect();
            assert_eq!(View::rows(&data, rows, cols).to_rows(), data);
            let t = View::transposed(&data, cols, rows).to_rows();
            // `t` is `cols x rows`: its element (i, j) is the data's (j, i).
            for (i, j) in (0..cols).flat_map(|i| (0..rows).map(move |j| (i, j))) {
                assert_eq!(
                    t[i * rows + j],
                    data[j * cols + i],
                    "({i}, {j}) of the transpose of {rows} x {cols}"
                );
            }
        }
    }
}
