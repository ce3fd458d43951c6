//! Output buffers written in parallel: each task fills its own chunk, in cache and on its own
//! thread, instead of one thread zeroing the whole buffer before the tasks start (on the
//! training step, `vec![0.0; n]` before a parallel kernel was a serial `memset` of every
//! output). Where a task writes every value of its chunk ([`written`]), the chunk is not
//! zeroed at all: the task proves it wrote the chunk whole ([`Written`]) instead.

use std::mem::MaybeUninit;

use rayon::prelude::*;

/// `len` values, written in chunks of `chunk` (the last one shorter) by `fill(scratch, index,
/// chunk)` on rayon's threads, for a `fill` that may leave values alone: each chunk reads as
/// zeros until `fill` writes it. `scratch` is made by `init` and reused by the chunks one rayon
/// job runs in turn (packing buffers, say).
pub(crate) fn filled_init<T>(
    len: usize,
    chunk: usize,
    init: impl Fn() -> T + Sync + Send,
    fill: impl Fn(&mut T, usize, &mut [f32]) + Sync + Send,
) -> Vec<f32> {
    let (values, _) = written_init(len, chunk, init, |scratch, i, part| {
        let part = zeroed(part);
        fill(scratch, i, part);
        (Written::of(part), ())
    });
    values
}

/// An unwritten chunk set to zeros, for a kernel that takes its output as plain values.
pub(crate) fn zeroed(part: &mut [MaybeUninit<f32>]) -> &mut [f32] {
    part.fill(MaybeUninit::new(0.0));
    // SAFETY: every element of `part` was initialised on the line above.
    unsafe { part.assume_init_mut() }
}

/// `len` values, written in chunks of `chunk` by `fill(index, chunk)` on rayon's threads, for
/// a `fill` that writes every value of its chunk: the chunk comes unwritten, and `fill` hands
/// back the proof that it wrote it whole ([`Written`]) with its result.
pub(crate) fn written<R: Send>(
    len: usize,
    chunk: usize,
    fill: impl Fn(usize, &mut [MaybeUninit<f32>]) -> (Written, R) + Sync + Send,
) -> (Vec<f32>, Vec<R>) {
    written_init(len, chunk, || (), |_, i, part| fill(i, part))
}

/// [`written`] for a `fill` that returns nothing but its proof: the values alone.
pub(crate) fn written_values(
    len: usize,
    chunk: usize,
    fill: impl Fn(usize, &mut [MaybeUninit<f32>]) -> Written + Sync + Send,
) -> Vec<f32> {
    written(len, chunk, |i, part| (fill(i, part), ())).0
}

/// [`written`] with per-thread scratch, as [`filled_init`] has.
pub(crate) fn written_init<T, R: Send>(
    len: usize,
    chunk: usize,
    init: impl Fn() -> T + Sync + Send,
    fill: impl Fn(&mut T, usize, &mut [MaybeUninit<f32>]) -> (Written, R) + Sync + Send,
) -> (Vec<f32>, Vec<R>) {
    let chunks = len.div_ceil(chunk.max(1));
    chunks_written(
        len,
        chunk,
        rayon::iter::repeat_n((), chunks),
        init,
        |s, i, (), part| fill(s, i, part),
    )
}

/// [`written_values`] beside an input that the tasks update in place: `fill(input, output)`
/// gets the matching chunks of `input` and of `input.len()` new values.
pub(crate) fn written_beside(
    input: &mut [f32],
    chunk: usize,
    fill: impl Fn(&mut [f32], &mut [MaybeUninit<f32>]) -> Written + Sync + Send,
) -> Vec<f32> {
    let (len, inputs) = (input.len(), input.par_chunks_mut(chunk.max(1)));
    chunks_written(
        len,
        chunk,
        inputs,
        || (),
        |_, _, input, part| (fill(input, part), ()),
    )
    .0
}

/// The one mechanism behind [`written_init`] and [`written_beside`]: `len` new values in
/// chunks of `chunk`, chunk `i` given unwritten to `fill` with the scratch of its rayon job and
/// item `i` of `inputs`; each chunk's proof checked; `fill`'s results in the chunks' order.
fn chunks_written<I, T, R>(
    len: usize,
    chunk: usize,
    inputs: I,
    init: impl Fn() -> T + Sync + Send,
    fill: impl Fn(&mut T, usize, I::Item, &mut [MaybeUninit<f32>]) -> (Written, R) + Sync + Send,
) -> (Vec<f32>, Vec<R>)
where
    I: IndexedParallelIterator,
    R: Send,
{
    let mut values = Vec::with_capacity(len);
    let parts = values.spare_capacity_mut()[..len].par_chunks_mut(chunk.max(1));
    assert_eq!(inputs.len(), parts.len(), "one input per chunk");
    let results = parts
        .zip(inputs)
        .enumerate()
        .map_init(init, |scratch, (i, (part, input))| {
            let span = Span::of(part);
            let (Written(written), result) = fill(scratch, i, input, part);
            assert_eq!(written, span, "a chunk was not written whole");
            result
        })
        .collect();
    // SAFETY: the chunks cover `0..len`, and each was written whole: `fill` gave back a
    // `Written` made from a `&mut [f32]` at its address and of its length.
    unsafe { values.set_len(len) };
    (values, results)
}

/// Where a chunk of values lies: its first value's address and its length (an address, not a
/// pointer: it is only compared, never read through).
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
pub(crate) struct Span {
    start: usize,
    len: usize,
}

impl Span {
    /// The span of an unwritten chunk (no borrow of it is kept).
    pub(crate) fn of(chunk: &[MaybeUninit<f32>]) -> Self {
        Self {
            start: chunk.as_ptr().addr(),
            len: chunk.len(),
        }
    }

    /// The address just past the span.
    fn end(self) -> usize {
        self.start + self.len * size_of::<f32>()
    }
}

/// A chunk of [`written`] as `fill` left it. Made only from the `&mut [f32]` that writing the
/// chunk gave (`write_copy_of_slice`, [`write_each`], a product written through it), or from
/// such proofs of its parts ([`Written::joined`]): a `Written` with the chunk's span proves
/// every value of it was set.
pub(crate) struct Written(Span);

impl Written {
    /// The proof that `values` are written.
    pub(crate) fn of(values: &mut [f32]) -> Self {
        Self(Span {
            start: values.as_ptr().addr(),
            len: values.len(),
        })
    }

    /// The proof for `whole` from the proofs of its parts, written side by side in order.
    /// Panics unless they cover it exactly.
    pub(crate) fn joined(whole: Span, parts: impl IntoIterator<Item = Written>) -> Self {
        let mut next = whole.start;
        for Written(part) in parts {
            assert!(part.start == next, "the written parts are not side by side");
            next = part.end();
        }
        assert!(
            next == whole.end(),
            "the written parts do not cover the chunk"
        );
        Self(whole)
    }
}

/// `out` written a part of `len` values at a time, in order, by `write(index, part)`: the
/// proof for all of it. Panics unless the parts cover it.
pub(crate) fn write_parts(
    out: &mut [MaybeUninit<f32>],
    len: usize,
    mut write: impl FnMut(usize, &mut [MaybeUninit<f32>]) -> Written,
) -> Written {
    let span = Span::of(out);
    let parts = out.chunks_exact_mut(len).enumerate();
    Written::joined(span, parts.map(|(i, part)| write(i, part)))
}

/// Each `dst[i] = f(src[i])`: the values written, as a plain slice.
#[inline(always)]
pub(crate) fn write_each<'a>(
    dst: &'a mut [MaybeUninit<f32>],
    src: &[f32],
    f: impl Fn(f32) -> f32,
) -> &'a mut [f32] {
    assert_eq!(dst.len(), src.len(), "write_each: sizes differ");
    for (d, &x) in dst.iter_mut().zip(src) {
        d.write(f(x));
    }
    // SAFETY: every element of `dst` was written on the lines above.
    unsafe { dst.assume_init_mut() }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every value is written once, by the chunk that holds it, whatever the split; with
    /// [`filled_init`], values `fill` leaves alone read as zeros.
    #[test]
    fn chunks_cover_the_buffer_once() {
        for (len, chunk) in [(0, 4), (1, 4), (10, 3), (4096, 100), (7, 7), (5, 0)] {
            let value = |k: usize| k as f32 + 0.5;
            let (v, firsts) = written(len, chunk, |i, part| {
                let first = i * chunk.max(1);
                let part = write_parts(part, 1, |j, x| {
                    Written::of(x.write_copy_of_slice(&[value(first + j)]))
                });
                (part, first)
            });
            assert_eq!(
                v,
                (0..len).map(value).collect::<Vec<_>>(),
                "len {len}, chunk {chunk}"
            );
            let starts: Vec<usize> = (0..len).step_by(chunk.max(1)).collect();
            assert_eq!(firsts, starts);
            let v = filled_init(
                len,
                chunk,
                || (),
                |_, i, part| {
                    for (j, x) in part.iter_mut().enumerate().skip(1) {
                        *x += (i * chunk.max(1) + j) as f32;
                    }
                },
            );
            let want: Vec<f32> = (0..len)
                .map(|k| if k % chunk.max(1) == 0 { 0.0 } else { k as f32 })
                .collect();
            assert_eq!(v, want, "len {len}, chunk {chunk}");
        }
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

    /// A chunk's proof must be of the whole chunk: a part of it, or another buffer of its
    /// length, is refused before any unwritten value could be read.
    #[test]
    fn a_chunk_written_in_part_is_refused() {
        let run = |fill: fn(&mut [MaybeUninit<f32>]) -> Written| {
            std::panic::catch_unwind(|| written(8, 4, |_, part| (fill(part), ()))).is_err()
        };
        assert!(!run(|part| Written::of(
            part.write_copy_of_slice(&[1.0; 4])
        )));
        assert!(run(|part| Written::of(
            part[..3].write_copy_of_slice(&[1.0; 3])
        )));
        assert!(run(|part| Written::of(
            part[1..].write_copy_of_slice(&[1.0; 3])
        )));
        assert!(run(|_| Written::of(Vec::from([1.0; 4]).leak())));
        // Parts joined must lie side by side and cover the chunk.
        assert!(!run(|part| write_parts(part, 2, |_, x| Written::of(
            x.write_copy_of_slice(&[1.0; 2])
        ))));
        assert!(run(|part| write_parts(part, 3, |_, x| Written::of(
            x.write_copy_of_slice(&[1.0; 3])
        ))));
        assert!(run(|part| {
            let span = Span::of(part);
            let (a, b) = part.split_at_mut(2);
            let (b, a) = (
                Written::of(b.write_copy_of_slice(&[1.0; 2])),
                Written::of(a.write_copy_of_slice(&[1.0; 2])),
            );
            Written::joined(span, [b, a])
        }));
    }

    /// `write_each` writes `f` of each value.
    #[test]
    fn write_each_maps_every_value() {
        let src = [1.0, -2.0, 3.5];
        let mut dst = [MaybeUninit::uninit(); 3];
        assert_eq!(
            write_each(&mut dst, &src, |x| 2.0 * x + 1.0),
            [3.0, -3.0, 8.0]
        );
    }
}
