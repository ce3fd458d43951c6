//! Strided matrix views over host slices, and the kernels' matrix product on them.

use gemm::{Parallelism, gemm};

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
    gemm_into(dst, accumulate, lhs, rhs, scale, Parallelism::None);
}

/// The row-major `a b` through `gemm`, parallel over the threads when the product is large
/// enough to pay for them. The output is written once: it is not zeroed first (`gemm` without
/// accumulation reads none of it), which on the training step was a serial `memset` of every
/// product's output.
pub(crate) fn product(a: View<'_>, b: View<'_>) -> Vec<f32> {
    let len = a.rows * b.cols;
    let parallelism = if a.rows * a.cols * b.cols >= PARALLEL_FLOPS {
        Parallelism::Rayon(0)
    } else {
        Parallelism::None
    };
    let mut c = Vec::with_capacity(len);
    // SAFETY: `c` has room for the `m x n` values; `gemm` without accumulation writes every one
    // of them and reads none, so all `len` are initialised when the length is set.
    unsafe {
        gemm_raw(c.as_mut_ptr(), false, a, b, 1.0, parallelism);
        c.set_len(len);
    }
    c
}

/// Multiply-adds below which [`product`] stays on one thread.
const PARALLEL_FLOPS: usize = 1 << 16;

/// `dst = [dst +] scale * lhs rhs` through `gemm`, on `parallelism`'s threads.
fn gemm_into(
    dst: &mut [f32],
    accumulate: bool,
    lhs: View<'_>,
    rhs: View<'_>,
    scale: f32,
    parallelism: Parallelism,
) {
    assert_eq!(dst.len(), lhs.rows * rhs.cols, "matmul: output size");
    // SAFETY: `dst` holds exactly `m x n` initialised values.
    unsafe { gemm_raw(dst.as_mut_ptr(), accumulate, lhs, rhs, scale, parallelism) }
}

/// [`gemm_into`] on a raw destination.
///
/// # Safety
/// `dst` is valid for writes of `lhs.rows x rhs.cols` values (row-major), and for reads of as
/// many initialised ones when `accumulate`.
unsafe fn gemm_raw(
    dst: *mut f32,
    accumulate: bool,
    lhs: View<'_>,
    rhs: View<'_>,
    scale: f32,
    parallelism: Parallelism,
) {
    assert_eq!(lhs.cols, rhs.rows, "matmul: inner sizes differ");
    lhs.check();
    rhs.check();
    // SAFETY: the views were checked to lie inside their slices, and the caller vouches for
    // `dst`'s `m x n` row-major values; gemm reads and writes nothing else, and reads `dst`
    // only when `accumulate`.
    unsafe {
        gemm(
            lhs.rows,
            rhs.cols,
            lhs.cols,
            dst,
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
            parallelism,
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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
