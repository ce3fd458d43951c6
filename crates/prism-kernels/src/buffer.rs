//! Output buffers written in parallel: each task zeroes and fills its own chunk, in cache and on
//! its own thread, instead of one thread zeroing the whole buffer before the tasks start (on the
//! training step, `vec![0.0; n]` before a parallel kernel was a serial `memset` of every
//! output).

use std::mem::MaybeUninit;

use rayon::prelude::*;

/// `len` values, written in chunks of `chunk` (the last one shorter) by `fill(index, chunk)`
/// on rayon's threads. Each chunk reads as zeros until `fill` writes it.
pub(crate) fn filled(
    len: usize,
    chunk: usize,
    fill: impl Fn(usize, &mut [f32]) + Sync + Send,
) -> Vec<f32> {
    filled_with(len, chunk, fill).0
}

/// [`filled`], also returning what `fill` returned for each chunk, in the chunks' order (a
/// reduction summed in that order gives the same bits on any number of threads).
pub(crate) fn filled_with<R: Send>(
    len: usize,
    chunk: usize,
    fill: impl Fn(usize, &mut [f32]) -> R + Sync + Send,
) -> (Vec<f32>, Vec<R>) {
    chunks_filled(len, chunk, || (), |_, i, part| fill(i, part))
}

/// [`filled`] with per-thread scratch: `fill(scratch, index, chunk)` gets a value made by
/// `init` and reused by the chunks one rayon job runs in turn (packing buffers, say).
pub(crate) fn filled_init<T>(
    len: usize,
    chunk: usize,
    init: impl Fn() -> T + Sync + Send,
    fill: impl Fn(&mut T, usize, &mut [f32]) + Sync + Send,
) -> Vec<f32> {
    chunks_filled(len, chunk, init, fill).0
}

/// The one mechanism behind the functions above: each chunk zeroed, then given to `fill` with
/// the scratch of its rayon job; `fill`'s results in the chunks' order.
fn chunks_filled<T, R: Send>(
    len: usize,
    chunk: usize,
    init: impl Fn() -> T + Sync + Send,
    fill: impl Fn(&mut T, usize, &mut [f32]) -> R + Sync + Send,
) -> (Vec<f32>, Vec<R>) {
    let mut values = Vec::with_capacity(len);
    let results = values.spare_capacity_mut()[..len]
        .par_chunks_mut(chunk.max(1))
        .enumerate()
        .map_init(init, |scratch, (i, part)| {
            part.fill(MaybeUninit::new(0.0));
            // SAFETY: every element of `part` was initialised on the line above, and
            // `MaybeUninit<f32>` has the layout of `f32`.
            let part = unsafe { &mut *(part as *mut [MaybeUninit<f32>] as *mut [f32]) };
            fill(scratch, i, part)
        })
        .collect();
    // SAFETY: the chunks cover `0..len`, and each was initialised above.
    unsafe { values.set_len(len) };
    (values, results)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every value is written once, by the chunk that holds it, whatever the split, and
    /// values `fill` leaves alone read as zeros.
    #[test]
    fn chunks_cover_the_buffer_once() {
        for (len, chunk) in [(0, 4), (1, 4), (10, 3), (4096, 100), (7, 7), (5, 0)] {
            let v = filled(len, chunk, |i, part| {
                for (j, x) in part.iter_mut().enumerate().skip(1) {
                    *x += (i * chunk.max(1) + j) as f32;
                }
            });
            let want: Vec<f32> = (0..len)
                .map(|k| if k % chunk.max(1) == 0 { 0.0 } else { k as f32 })
                .collect();
            assert_eq!(v, want, "len {len}, chunk {chunk}");
        }
        let (_, firsts) = filled_with(10, 3, |i, part| (i, part.len()));
        assert_eq!(firsts, [(0, 3), (1, 3), (2, 3), (3, 1)]);
        // Each chunk gets its index and a scratch made by `init`, which counts the chunks that
        // have used it (one job may run several in turn).
        let v = filled_init(
            10,
            3,
            || 0.0,
            |seen: &mut f32, i, part| {
                *seen += 1.0;
                part.fill(i as f32 + 10.0 * *seen);
            },
        );
        for (k, &x) in v.iter().enumerate() {
            let (chunk, seen) = ((k / 3) as f32, (x / 10.0).floor());
            assert_eq!(x, chunk + 10.0 * seen, "value {k}");
            assert!(
                (1.0..=4.0).contains(&seen),
                "value {k}: scratch seen {seen} times"
            );
        }
    }
}
