//! In-cube reductions shared by the tiled kernels (Gaussian compositing, mesh rasterization):
//! stream compaction (each unit of a cube of `len` units says whether it keeps its item, and
//! gets the slot its item takes among the kept ones, in unit order) and the cube's maximum.

use cubecl::prelude::*;

/// An inclusive prefix sum of the `hit` flags over the cube's units (Hillis-Steele in shared
/// memory). Returns this unit's inclusive count: its slot is that minus one when `hit`. After
/// the call (it ends on a barrier) `scan[len - 1]` holds the number kept. Every unit of the cube
/// must call it.
#[cube]
pub fn compact(scan: &mut Shared<[u32]>, hit: bool, #[comptime] len: usize) -> u32 {
    let t = UNIT_POS as usize;
    scan[t] = select(hit, 1u32, 0u32);
    sync_cube();
    let mut offset = 1usize;
    while offset < len {
        let mut add = 0u32;
        if t >= offset {
            add = scan[t - offset];
        }
        sync_cube();
        scan[t] += add;
        sync_cube();
        offset *= 2;
    }
    scan[t]
}

/// The maximum of `value` over the cube's `len` units (an inclusive max-scan in shared memory,
/// as [`compact`]), returned to every unit. Every unit of the cube must call it.
#[cube]
pub fn cube_max(buf: &mut Shared<[u32]>, value: u32, #[comptime] len: usize) -> u32 {
    let t = UNIT_POS as usize;
    buf[t] = value;
    sync_cube();
    let mut offset = 1usize;
    while offset < len {
        let mut other = 0u32;
        if t >= offset {
            other = buf[t - offset];
        }
        sync_cube();
        buf[t] = u32::max(buf[t], other);
        sync_cube();
        offset *= 2;
    }
    // (The maximum of all is at least this unit's value: `max` makes a copy of it.)
    let out = u32::max(buf[len - 1], value);
    sync_cube();
    out
}
