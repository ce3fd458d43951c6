//! The count of device-to-host reads made at prism's own transfer points.
//!
//! On a GPU every read of a tensor's values is a synchronisation that empties the device's
//! queue, so prism counts them: [`host_reads`] all of them (loss values for the log, the
//! gradient norm for clipping, a frame read back, the geometry operations' reads on the CPU
//! backends), [`geometry_host_reads`] those the geometry operations make. `prism bench` reports
//! both per training step and per frame; on wgpu and CUDA the geometry count is 0.
//!
//! The counts are per thread: a read is made by the thread that runs the operation, so a
//! difference taken around a step counts that step's reads alone, whatever other threads of
//! the process (tests side by side, a server's other sessions) compute meanwhile.

use std::cell::Cell;

thread_local! {
    static ALL: Cell<u64> = const { Cell::new(0) };
    static GEOMETRY: Cell<u64> = const { Cell::new(0) };
}

/// Reads of tensor values to the host made by this thread since it started (take
/// differences).
pub fn host_reads() -> u64 {
    ALL.get()
}

/// The part of [`host_reads`] made by the geometry operations (rasterizers, triplane
/// sampling, the SMPL-X branch).
pub fn geometry_host_reads() -> u64 {
    GEOMETRY.get()
}

/// Counts one read.
pub fn count_host_read() {
    ALL.set(ALL.get() + 1);
}

/// Counts one read made by a geometry operation (it also counts in [`host_reads`]).
pub fn count_geometry_read() {
    GEOMETRY.set(GEOMETRY.get() + 1);
    count_host_read();
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn another_threads_reads_do_not_count_here() {
        let (all, geometry) = (host_reads(), geometry_host_reads());
        count_geometry_read();
        count_host_read();
        std::thread::spawn(|| {
            count_geometry_read();
            assert_eq!((host_reads(), geometry_host_reads()), (1, 1));
        })
        .join()
        .unwrap();
        assert_eq!(host_reads() - all, 2);
        assert_eq!(geometry_host_reads() - geometry, 1);
    }
}
