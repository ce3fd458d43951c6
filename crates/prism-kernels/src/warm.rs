//! Rayon's other workers kept awake while a pass runs on a CPU backend.
//!
//! Between two parallel kernels a rayon worker with nothing to steal sleeps on a futex after a
//! few rounds of yielding, and the next kernel wakes it with a system call; under a hypervisor
//! the wake-up also waits for the host to run the worker's virtual CPU again. A forward pass of
//! the backbone at 128 px runs about sixty parallel kernels, each a fraction of a millisecond.
//! [`warm`] runs a closure while every other worker of the current pool loops in
//! [`rayon::yield_now`], which runs any job that appears (stolen or its own) and otherwise
//! returns at once, so the worker never reaches its sleep. Between jobs it yields its core to
//! any other thread that wants it (the data loader's), so it keeps the core only from the idle
//! task. On a 2-core Xeon this took the backbone's forward passes at 128 px to 0.95x to 0.96x of
//! their time and the training step to 0.92x (BENCHMARKS.md, issue 43's "Each thread its own
//! product band, and the workers kept awake").

use std::cell::Cell;
use std::sync::atomic::{AtomicBool, Ordering};

use burn::tensor::Device;

use crate::{HostIsa, is_host};

/// Runs `f` with the current rayon pool's other workers spinning for work instead of sleeping
/// (see the module docs) when `device` is one of the CPU backends the host kernels run on;
/// `f`'s result. On other devices `f` just runs: the threads would only wait for the device.
/// Inside another warm closure on the same thread (a training step's forward passes) `f` just
/// runs too: the workers are awake already.
///
/// The first call on a CPU backend also settles [`HostIsa::chosen`], which says on stderr when
/// the kernels run narrower code than the CPU has.
pub fn warm<R>(device: &Device, f: impl FnOnce() -> R) -> R {
    let host = is_host(device);
    if host {
        HostIsa::chosen();
    }
    let others = rayon::current_num_threads().saturating_sub(1);
    if others == 0 || !host || WARM.get() {
        return f();
    }
    let done = AtomicBool::new(false);
    // In place: `f` runs on this thread (it need not be `Send`), the spinners on the others.
    rayon::in_place_scope(|scope| {
        for _ in 0..others {
            scope.spawn(|_| {
                while !done.load(Ordering::Acquire) {
                    if rayon::yield_now() != Some(rayon::Yield::Executed) {
                        std::thread::yield_now();
                    }
                }
            });
        }
        // Stops the spinners when `f` returns or panics: the scope waits for them either way.
        let _stop = Stop(&done);
        WARM.set(true);
        f()
    })
}

thread_local! {
    /// Whether this thread runs a warm closure now.
    static WARM: Cell<bool> = const { Cell::new(false) };
}

/// Sets the spinners' flag, and clears this thread's [`WARM`], when dropped: on return or
/// unwinding.
struct Stop<'a>(&'a AtomicBool);

impl Drop for Stop<'_> {
    fn drop(&mut self) {
        self.0.store(true, Ordering::Release);
        WARM.set(false);
    }
}

#[cfg(test)]
mod tests {
    // burn-ndarray is deprecated upstream, but the project's tests run on it.
    #![allow(deprecated)]

    use super::*;
    use rayon::prelude::*;

    /// A pool of `threads` workers of its own.
    fn pool(threads: usize) -> rayon::ThreadPool {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
    }

    /// Parallel work inside a warm closure, and a warm closure inside another, runs to its
    /// result and returns: the spinners take jobs and stop when the closure is done.
    #[test]
    fn warm_closures_run_parallel_work_and_return() {
        let device = Device::ndarray();
        let sum = |n: u64| (0..n).into_par_iter().map(|i| i * i).sum::<u64>();
        let expected = sum(100_000);
        let got = pool(3).install(|| {
            warm(&device, || {
                let inner = warm(&device, || sum(100_000));
                (0..20).map(|_| sum(100_000)).all(|s| s == expected) && inner == expected
            })
        });
        assert!(got);
        // Outside any pool, on the global one.
        assert_eq!(warm(&device, || sum(100_000)), expected);
    }

    /// A panic in the closure reaches the caller: the spinners stop and the scope ends.
    #[test]
    fn a_panic_in_a_warm_closure_reaches_the_caller() {
        let device = Device::ndarray();
        let caught = pool(2)
            .install(|| std::panic::catch_unwind(|| warm(&device, || panic!("in the pass"))));
        assert!(caught.is_err());
    }
}
