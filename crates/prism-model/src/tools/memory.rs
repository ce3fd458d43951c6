//! Peak memory of a stretch of work ([`MemoryProbe`]), for the benchmarks.
//!
//! GPU backends report their memory pools; the CPU backends (ndarray, flex) allocate tensors
//! on the heap, so their peak is measured by counting the heap: a binary that installs
//! [`PeakAllocator`] as its global allocator (as `prism` does) gets the exact peak of live heap
//! bytes; otherwise the probe falls back to the process's resident-set high-water mark
//! (Linux).

use std::alloc::{GlobalAlloc, Layout};
use std::sync::atomic::{AtomicU64, Ordering};

use burn::tensor::Device;

static LIVE: AtomicU64 = AtomicU64::new(0);
static PEAK: AtomicU64 = AtomicU64::new(0);

/// An allocator (`A`: the system's, or a faster one) counting the live heap bytes and their
/// peak, so that [`MemoryProbe`] can report the peak heap use of the CPU backends. Install it
/// in a binary with `#[global_allocator] static ALLOC: PeakAllocator<System> =
/// PeakAllocator(System);` (the cost is two atomic additions per allocation).
#[derive(Debug, Default, Clone, Copy)]
pub struct PeakAllocator<A>(pub A);

/// Live heap bytes now, as counted by [`PeakAllocator`] (0 when it is not installed).
pub(crate) fn live_heap_bytes() -> u64 {
    LIVE.load(Ordering::Relaxed)
}

fn added(size: usize) {
    let live = LIVE.fetch_add(size as u64, Ordering::Relaxed) + size as u64;
    PEAK.fetch_max(live, Ordering::Relaxed);
}

fn removed(size: usize) {
    LIVE.fetch_sub(size as u64, Ordering::Relaxed);
}

// SAFETY: every call is forwarded unchanged to the inner allocator; the counters only observe.
unsafe impl<A: GlobalAlloc> GlobalAlloc for PeakAllocator<A> {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        // SAFETY: same contract as the caller's.
        let ptr = unsafe { self.0.alloc(layout) };
        if !ptr.is_null() {
            added(layout.size());
        }
        ptr
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        // SAFETY: same contract as the caller's.
        let ptr = unsafe { self.0.alloc_zeroed(layout) };
        if !ptr.is_null() {
            added(layout.size());
        }
        ptr
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: same contract as the caller's.
        unsafe { self.0.dealloc(ptr, layout) };
        removed(layout.size());
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        // SAFETY: same contract as the caller's.
        let new = unsafe { self.0.realloc(ptr, layout, new_size) };
        if !new.is_null() {
            removed(layout.size());
            added(new_size);
        }
        new
    }
}

/// How a [`MemoryProbe`] measures.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Source {
    /// The device's memory pools: the largest reservation seen.
    Pool { peak: u64 },
    /// [`PeakAllocator`]: peak live heap bytes above the live bytes at the start.
    Heap { start: u64 },
    /// Linux `VmHWM` (reset at the start) above `VmRSS` at the start.
    Rss { start: u64 },
    /// Nothing to measure with.
    None,
}

/// Measures the peak memory of a stretch of work on a device: what the work needed on top of
/// what was allocated before it started (weights and inputs made before the start are not
/// counted on the CPU).
///
/// - Backends with memory pools (the CubeCL ones: wgpu, cuda) report the bytes their
///   allocator holds ([`Device::memory_pool_usage`]); the probe reports the largest value seen
///   at [`MemoryProbe::sample`] calls and at the end: an upper bound of the peak in use, as
///   pools keep freed pages.
/// - CPU backends: with [`PeakAllocator`] installed, the peak of live heap bytes minus the
///   live bytes at the start (exact; probes must not overlap, as the peak is global);
///   otherwise the growth of the resident set above its size at the start (Linux only; it
///   under-counts when the allocator reuses memory freed before the start).
#[derive(Debug)]
pub struct MemoryProbe {
    device: Device,
    source: Source,
}

impl MemoryProbe {
    /// Starts measuring on `device`.
    pub fn start(device: &Device) -> Self {
        let source = if let Some(usage) = device.memory_pool_usage() {
            Source::Pool {
                peak: usage.bytes_reserved,
            }
        } else if live_heap_bytes() > 0 {
            let start = live_heap_bytes();
            PEAK.store(start, Ordering::Relaxed);
            Source::Heap { start }
        } else {
            match (reset_peak_rss(), proc_status_bytes("VmRSS:")) {
                (true, Some(start)) => Source::Rss { start },
                _ => Source::None,
            }
        };
        Self {
            device: device.clone(),
            source,
        }
    }

    /// Records the device pool's current reservation (the other sources keep their own peak).
    pub fn sample(&mut self) {
        if let Source::Pool { peak } = &mut self.source
            && let Some(now) = self.device.memory_pool_usage()
        {
            *peak = (*peak).max(now.bytes_reserved);
        }
    }

    /// The peak in bytes since [`MemoryProbe::start`], or `None` when it cannot be measured.
    pub fn peak_bytes(mut self) -> Option<u64> {
        self.sample();
        match self.source {
            Source::Pool { peak } => Some(peak),
            Source::Heap { start } => Some(PEAK.load(Ordering::Relaxed).saturating_sub(start)),
            Source::Rss { start } => Some(proc_status_bytes("VmHWM:")?.saturating_sub(start)),
            Source::None => None,
        }
    }

    /// What the probe measures: `pool`, `heap`, `rss` or `none`.
    pub fn method(&self) -> &'static str {
        match self.source {
            Source::Pool { .. } => "pool",
            Source::Heap { .. } => "heap",
            Source::Rss { .. } => "rss",
            Source::None => "none",
        }
    }
}

/// Resets this process's resident-set high-water mark (Linux `clear_refs` value 5).
fn reset_peak_rss() -> bool {
    std::fs::write("/proc/self/clear_refs", "5").is_ok()
}

/// A `kB` line of `/proc/self/status` in bytes.
fn proc_status_bytes(key: &str) -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with(key))?;
    let kb: u64 = line[key.len()..]
        .trim()
        .trim_end_matches("kB")
        .trim()
        .parse()
        .ok()?;
    Some(kb * 1024)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Without the counting allocator (the test binary uses the system one), the probe falls
    /// back to the resident set on Linux and sees a buffer that is touched page by page.
    #[test]
    fn rss_probe_sees_a_large_buffer() {
        let device = Device::flex();
        let probe = MemoryProbe::start(&device);
        if probe.method() != "rss" {
            eprintln!(
                "skipped: no /proc/self/clear_refs here ({})",
                probe.method()
            );
            return;
        }
        drop(probe);
        let size = 64 << 20;
        // The probe measures the whole process, and the other tests of this process allocate
        // and free memory on their threads meanwhile (a test's memory freed after this probe
        // started lowers what it sees): the best of three attempts.
        let peaks: Vec<u64> = (0..3)
            .map(|_| {
                let probe = MemoryProbe::start(&device);
                let buffer = vec![1u8; size];
                std::hint::black_box(&buffer);
                probe.peak_bytes().expect("rss")
            })
            .collect();
        let peak = peaks.iter().copied().max().unwrap_or(0);
        // Three quarters: the kernel's resident-set counters are batched per CPU and were
        // seen 10 % short under load (a probe that missed the buffer reports the process's
        // few megabytes).
        assert!(peak >= (size as u64) * 3 / 4, "peaks {peaks:?}");
        assert!(peak < 4 * size as u64, "peaks {peaks:?}");
    }
}
