//! The count of device-to-host reads made at prism's own transfer points.
//!
//! On a GPU every read of a tensor's values is a synchronisation that empties the device's
//! queue, so prism counts them: [`host_reads`] all of them (loss values for the log, the
//! gradient norm for clipping, a frame read back, the geometry operations' reads on the CPU
//! backends), [`geometry_host_reads`] those the geometry operations make. `prism bench` reports
//! both per training step and per frame; on wgpu and CUDA the geometry count is 0.

use std::sync::atomic::{AtomicU64, Ordering};

static ALL: AtomicU64 = AtomicU64::new(0);
static GEOMETRY: AtomicU64 = AtomicU64::new(0);

/// Reads of tensor values to the host since the process started (take differences).
pub fn host_reads() -> u64 {
    ALL.load(Ordering::Relaxed)
}

/// The part of [`host_reads`] made by the geometry operations (rasterizers, triplane
/// sampling, the SMPL-X branch).
pub fn geometry_host_reads() -> u64 {
    GEOMETRY.load(Ordering::Relaxed)
}

/// Counts one read.
pub fn count_host_read() {
    ALL.fetch_add(1, Ordering::Relaxed);
}

/// Counts one read made by a geometry operation (it also counts in [`host_reads`]).
pub fn count_geometry_read() {
    GEOMETRY.fetch_add(1, Ordering::Relaxed);
    count_host_read();
}
