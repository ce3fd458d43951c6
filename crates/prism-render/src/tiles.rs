//! What the tiled kernels share (Gaussian compositing, mesh rasterization): the pixel a unit
//! shades when a cube covers one 16x16 tile of one camera, and in-cube reductions: stream
//! compaction (each unit of a cube of `len` units says whether it keeps its item, and gets the
//! slot its item takes among the kept ones, in unit order) and the cube's maximum.

use cubecl::prelude::*;

use crate::splat::TILE_SIZE;

/// The pixel of one unit of a tile's cube (cube `(tile x, tile y, camera)`, unit `(x, y)` in
/// the tile).
#[derive(CubeType, Clone, Copy)]
pub struct TilePixel {
    /// The camera (batch element).
    pub b: usize,
    /// Whether the pixel is inside the image (a partial tile's other units only help).
    pub inside: bool,
    /// The column and row as floats.
    pub px: f32,
    pub py: f32,
    /// `y * width + x`, and `width * height`.
    pub pix: usize,
    pub hw: usize,
}

/// This unit's pixel in an image of `width x height`.
#[cube]
pub fn tile_pixel(width: u32, height: u32) -> TilePixel {
    let x = CUBE_POS_X * TILE_SIZE as u32 + UNIT_POS_X;
    let y = CUBE_POS_Y * TILE_SIZE as u32 + UNIT_POS_Y;
    TilePixel {
        b: CUBE_POS_Z as usize,
        inside: x < width && y < height,
        px: f32::cast_from(x),
        py: f32::cast_from(y),
        pix: (y * width + x) as usize,
        hw: (width * height) as usize,
    }
}

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
