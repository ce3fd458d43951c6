//! Operands packed for the bf16 kernels, kept from one product to the next while their values
//! live: in inference a layer's weight is the same matrix at every call, and on AMX packing it
//! cost about as much as the product (an eighth of the bf16 student's time at 128 px).
//!
//! An operand is known by the buffer that holds its values ([`SharedBuffer`]), and the cache
//! keeps a weak handle to that buffer. That makes a stale entry impossible, with no
//! cooperation from the code that owns the tensor:
//! - the buffer's allocation is not freed while the handle lives, so no other tensor's values
//!   can come to live at the same address;
//! - a shared buffer (one with a weak handle too) is never written in place: flex writes a
//!   buffer only when no other handle to it exists, and otherwise writes a new one (so an
//!   optimizer's step gives a weight a new buffer, and the old entry dies with the old one).
//!
//! An entry whose buffer has been freed is dropped at the next insertion.

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex, PoisonError, Weak};

use burn::tensor::Bytes;

use crate::bf16::{Bf16Kernel, Packed};
use crate::matrix::View;

/// The buffer an operand's values are read from, where the backend shares buffers between
/// tensors (flex): its address, where the operand starts in it, and a weak handle to it.
pub struct SharedBuffer {
    pub(crate) address: usize,
    pub(crate) start: usize,
    pub(crate) alive: Weak<Bytes>,
}

/// A packed operand: its buffer's address, its first value and its shape.
type Key = (usize, usize, usize, usize);

/// A kept packing and the buffer it was packed from.
struct Entry {
    alive: Weak<Bytes>,
    packed: Arc<Packed>,
}

static CACHE: Mutex<BTreeMap<Key, Entry>> = Mutex::new(BTreeMap::new());

/// `b`, whose values `buffer` holds from its first value on, packed for the chosen bf16
/// kernel ([`Bf16Kernel::chosen`]): the packing kept from an earlier call while the buffer
/// lives, else packed now and kept.
pub(crate) fn packed(buffer: SharedBuffer, b: View<'_>) -> Arc<Packed> {
    let key = (buffer.address, buffer.start, b.rows, b.cols);
    let lock = || CACHE.lock().unwrap_or_else(PoisonError::into_inner);
    if let Some(entry) = lock().get(&key)
        && entry.alive.strong_count() > 0
    {
        return Arc::clone(&entry.packed);
    }
    // Packed without the lock held: the packing runs on rayon's threads, one of which may be
    // running another product that wants the cache.
    let packed = Arc::new(Packed::new(Bf16Kernel::chosen(), b));
    let mut cache = lock();
    cache.retain(|_, entry| entry.alive.strong_count() > 0);
    cache.insert(
        key,
        Entry {
            alive: buffer.alive,
            packed: Arc::clone(&packed),
        },
    );
    packed
}

#[cfg(test)]
mod tests {
    use burn::backend::Flex;
    use burn::backend::tensor::FloatTensor;
    use burn::tensor::Shape;

    use super::*;
    use crate::bf16;
    use crate::extension::FusedOps;
    use crate::host::HostTensors;
    use crate::test_util::values;

    /// Whether the cache holds an entry for `rows x cols` values at `start` of the buffer at
    /// `address`, live or not.
    fn holds(address: usize, start: usize, rows: usize, cols: usize) -> bool {
        CACHE
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .contains_key(&(address, start, rows, cols))
    }

    /// A weight's packing is kept and read again with the same bits as packing it anew; when
    /// the weight is updated (as an optimizer's step does, in place where flex can) the product
    /// reads the new values, not the kept packing; the old buffer's entry goes. The test keeps
    /// no handle to the buffer itself, so only the cache's own handle stops the in-place write.
    #[test]
    fn a_kept_packing_follows_its_weight() {
        let device = Default::default();
        let (m, k, n) = (37, 70, 45);
        let (xv, wv) = (values(m * k, 1), values(k * n, 2));
        let x = || Flex::tensor(xv.clone(), Shape::new([m, k]), &device);
        let product = |w: &FloatTensor<Flex>| {
            Flex::values(<Flex as FusedOps>::fused_matmul(x(), w.clone(), true)).to_vec()
        };
        let want = |w: &[f32]| {
            bf16::matmul(
                Bf16Kernel::chosen(),
                View::rows(&xv, m, k),
                View::rows(w, k, n),
            )
        };
        let w = Flex::tensor(wv.clone(), Shape::new([k, n]), &device);
        let (address, start) = {
            let buffer = Flex::shared_buffer(&w).expect("a contiguous flex tensor");
            (buffer.address, buffer.start)
        };
        assert!(!holds(address, start, k, n));
        assert_eq!(product(&w), want(&wv), "packed and kept");
        assert!(holds(address, start, k, n));
        assert_eq!(product(&w), want(&wv), "read from the cache");

        let w = Flex::update(w, |v| v.iter_mut().for_each(|x| *x = 0.25 - 2.0 * *x));
        let new = Flex::shared_buffer(&w).expect("a contiguous flex tensor");
        assert_ne!(
            new.address, address,
            "a kept buffer is not written in place"
        );
        let updated = Flex::values(w.clone()).to_vec();
        assert_ne!(updated, wv);
        assert_eq!(product(&w), want(&updated), "the updated weight");
        assert!(
            !holds(address, start, k, n),
            "the old buffer's entry is gone"
        );
        assert!(holds(new.address, new.start, k, n));
    }
}
