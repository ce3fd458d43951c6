//! The rasterizer's CubeCL kernels: projection, depth sort, tiled compositing and their reverse
//! passes. They compute what the host rasterizer (`super::super::host`) computes, with its
//! constants and tile size; the comments name the host function each one mirrors.
//!
//! Buffers are flat `f32` / `u32` arrays. A projected Gaussian takes [`PROJECTED`] floats:
//! `u, v, depth, conic a, b, c, opacity, pixel rect x0, y0, x1, y1, valid` (`valid` is 1 for a
//! Gaussian in front of the camera whose pixel rect is not empty, else 0). A camera takes
//! [`VIEW`] floats: the world-to-camera rotation row-major, the translation, `fx fy cx cy`, and
//! the `x/z` and `y/z` limits of the projection Jacobian (`View::ratio_limits`).

use cubecl::prelude::*;

use crate::tiles::{compact, cube_max, tile_pixel};

use crate::splat::host::{
    DILATION, EXTENT_SIGMAS, MAX_ALPHA, MAX_POWER, MIN_ALPHA, MIN_TRANSMITTANCE, NEAR_PLANE,
    TILE_SIZE,
};

/// Floats per projected Gaussian.
pub const PROJECTED: usize = 12;
/// Floats per camera: the pinhole of `crate::launch::cameras_tensor`, then 4 ratio limits.
pub const VIEW: usize = crate::launch::PINHOLE + 4;
/// The gradient slots per Gaussian ahead of its features: `u, v, depth, conic a, b, c,
/// opacity` (the host's `GRAD_HEAD`).
pub const GRAD_HEAD: usize = 7;
/// Pixels per tile, and the Gaussians one cube stages in shared memory at a time.
pub const BLOCK: usize = TILE_SIZE * TILE_SIZE;
/// The sort key and index of a padding slot, and the key of a Gaussian that is not drawn.
pub const NONE: u32 = 0xFFFF_FFFF;

/// Floats of one Gaussian staged in shared memory: `u v depth a b c opacity x0 y0 x1 y1`.
const STAGED: usize = 11;

/// Everything the projection derives from one Gaussian in one camera (host `intermediates`).
#[derive(CubeType, Clone, Copy)]
pub struct Projection {
    valid: bool,
    /// Normalised quaternion `w x y z` and the norm it was divided by.
    qw: f32,
    qx: f32,
    qy: f32,
    qz: f32,
    qn: f32,
    /// Axis scales.
    sx: f32,
    sy: f32,
    sz: f32,
    /// Camera-space centre.
    cx: f32,
    cy: f32,
    cz: f32,
    /// Clamped `x/z`, `y/z` and whether each was clamped.
    ratio_x: f32,
    ratio_y: f32,
    clamped_x: bool,
    clamped_y: bool,
    /// World-space rows of the projection Jacobian, `m0 = W^T j0`, `m1 = W^T j1`.
    m0x: f32,
    m0y: f32,
    m0z: f32,
    m1x: f32,
    m1y: f32,
    m1z: f32,
    /// 3D covariance (symmetric): `xx xy xz yy yz zz`.
    s_xx: f32,
    s_xy: f32,
    s_xz: f32,
    s_yy: f32,
    s_yz: f32,
    s_zz: f32,
    /// 2D covariance with the low-pass dilation, and its inverse (the conic).
    cov_a: f32,
    cov_c: f32,
    con_a: f32,
    con_b: f32,
    con_c: f32,
}

/// A rotation matrix, `m{row}{col}`.
#[derive(CubeType, Clone, Copy)]
pub struct Rot {
    m00: f32,
    m01: f32,
    m02: f32,
    m10: f32,
    m11: f32,
    m12: f32,
    m20: f32,
    m21: f32,
    m22: f32,
}

/// The rotation matrix of the unit quaternion `w x y z` (host `rotation_matrix`).
#[cube]
fn rotation(w: f32, x: f32, y: f32, z: f32) -> Rot {
    Rot {
        m00: 1.0 - 2.0 * (y * y + z * z),
        m01: 2.0 * (x * y - w * z),
        m02: 2.0 * (x * z + w * y),
        m10: 2.0 * (x * y + w * z),
        m11: 1.0 - 2.0 * (x * x + z * z),
        m12: 2.0 * (y * z - w * x),
        m20: 2.0 * (x * z - w * y),
        m21: 2.0 * (y * z + w * x),
        m22: 1.0 - 2.0 * (x * x + y * y),
    }
}

/// Projects Gaussian `g` (flat index `b * N + i`) into camera `b` (host `intermediates`).
#[cube]
fn project_one(
    means: &Tensor<f32>,
    log_scales: &Tensor<f32>,
    rotations: &Tensor<f32>,
    views: &Tensor<f32>,
    g: usize,
    b: usize,
) -> Projection {
    let vb = b * VIEW;
    let (px, py, pz) = (means[3 * g], means[3 * g + 1], means[3 * g + 2]);
    let cx = views[vb] * px + views[vb + 1] * py + views[vb + 2] * pz + views[vb + 9];
    let cy = views[vb + 3] * px + views[vb + 4] * py + views[vb + 5] * pz + views[vb + 10];
    let cz = views[vb + 6] * px + views[vb + 7] * py + views[vb + 8] * pz + views[vb + 11];
    let (w0, x0, y0, z0) = (
        rotations[4 * g],
        rotations[4 * g + 1],
        rotations[4 * g + 2],
        rotations[4 * g + 3],
    );
    let qn = f32::sqrt(w0 * w0 + x0 * x0 + y0 * y0 + z0 * z0);
    let mut valid = !f32::is_nan(cz) && cz >= NEAR_PLANE && !f32::is_nan(qn) && qn > 1e-12;
    let inv = 1.0 / f32::max(qn, 1e-12);
    let (qw, qx, qy, qz) = (w0 * inv, x0 * inv, y0 * inv, z0 * inv);
    let sx = f32::exp(log_scales[3 * g]);
    let sy = f32::exp(log_scales[3 * g + 1]);
    let sz = f32::exp(log_scales[3 * g + 2]);
    // RS = R diag(s); Sigma = RS RS^T.
    let r = rotation(qw, qx, qy, qz);
    let a00 = r.m00 * sx;
    let a01 = r.m01 * sy;
    let a02 = r.m02 * sz;
    let a10 = r.m10 * sx;
    let a11 = r.m11 * sy;
    let a12 = r.m12 * sz;
    let a20 = r.m20 * sx;
    let a21 = r.m21 * sy;
    let a22 = r.m22 * sz;
    let s_xx = a00 * a00 + a01 * a01 + a02 * a02;
    let s_xy = a00 * a10 + a01 * a11 + a02 * a12;
    let s_xz = a00 * a20 + a01 * a21 + a02 * a22;
    let s_yy = a10 * a10 + a11 * a11 + a12 * a12;
    let s_yz = a10 * a20 + a11 * a21 + a12 * a22;
    let s_zz = a20 * a20 + a21 * a21 + a22 * a22;

    let (fx, fy) = (views[vb + 12], views[vb + 13]);
    let rz = 1.0 / cz;
    let raw_x = cx * rz;
    let raw_y = cy * rz;
    let ratio_x = f32::min(f32::max(raw_x, views[vb + 16]), views[vb + 17]);
    let ratio_y = f32::min(f32::max(raw_y, views[vb + 18]), views[vb + 19]);
    // j0 = (fx rz, 0, -fx ratio_x rz), j1 = (0, fy rz, -fy ratio_y rz); m = W^T j.
    let j0x = fx * rz;
    let j0z = -fx * ratio_x * rz;
    let j1y = fy * rz;
    let j1z = -fy * ratio_y * rz;
    let m0x = views[vb] * j0x + views[vb + 6] * j0z;
    let m0y = views[vb + 1] * j0x + views[vb + 7] * j0z;
    let m0z = views[vb + 2] * j0x + views[vb + 8] * j0z;
    let m1x = views[vb + 3] * j1y + views[vb + 6] * j1z;
    let m1y = views[vb + 4] * j1y + views[vb + 7] * j1z;
    let m1z = views[vb + 5] * j1y + views[vb + 8] * j1z;
    let s0x = s_xx * m0x + s_xy * m0y + s_xz * m0z;
    let s0y = s_xy * m0x + s_yy * m0y + s_yz * m0z;
    let s0z = s_xz * m0x + s_yz * m0y + s_zz * m0z;
    let s1x = s_xx * m1x + s_xy * m1y + s_xz * m1z;
    let s1y = s_xy * m1x + s_yy * m1y + s_yz * m1z;
    let s1z = s_xz * m1x + s_yz * m1y + s_zz * m1z;
    let cov_a = m0x * s0x + m0y * s0y + m0z * s0z + DILATION;
    let cov_b = m0x * s1x + m0y * s1y + m0z * s1z;
    let cov_c = m1x * s1x + m1y * s1y + m1z * s1z + DILATION;
    let det = cov_a * cov_c - cov_b * cov_b;
    valid = valid && !f32::is_nan(det) && det > 0.0;
    Projection {
        valid,
        qw,
        qx,
        qy,
        qz,
        qn,
        sx,
        sy,
        sz,
        cx,
        cy,
        cz,
        ratio_x,
        ratio_y,
        clamped_x: ratio_x != raw_x,
        clamped_y: ratio_y != raw_y,
        m0x,
        m0y,
        m0z,
        m1x,
        m1y,
        m1z,
        s_xx,
        s_xy,
        s_xz,
        s_yy,
        s_yz,
        s_zz,
        cov_a,
        cov_c,
        con_a: cov_c / det,
        con_b: -cov_b / det,
        con_c: cov_a / det,
    }
}

/// Projects every Gaussian and writes its depth sort key: one unit per slot of the padded
/// `[B, n_pad]` key array (host `project` and the first half of `bin`).
#[cube(launch)]
pub fn project_kernel(
    means: &Tensor<f32>,
    log_scales: &Tensor<f32>,
    rotations: &Tensor<f32>,
    opacity_logits: &Tensor<f32>,
    views: &Tensor<f32>,
    projected: &mut Tensor<f32>,
    keys: &mut Tensor<u32>,
    values: &mut Tensor<u32>,
    count: u32,
    n_pad: u32,
    width: u32,
    height: u32,
) {
    let pos = ABSOLUTE_POS;
    if pos >= keys.len() {
        terminate!();
    }
    let b = pos / n_pad as usize;
    let i = pos % n_pad as usize;
    if i >= count as usize {
        keys[pos] = NONE;
        values[pos] = NONE;
        terminate!();
    }
    let g = b * count as usize + i;
    let p = project_one(means, log_scales, rotations, views, g, b);
    let vb = b * VIEW;
    let rz = 1.0 / p.cz;
    let u = views[vb + 12] * p.cx * rz + views[vb + 14];
    let v = views[vb + 13] * p.cy * rz + views[vb + 15];
    let ext_x = EXTENT_SIGMAS * f32::sqrt(p.cov_a);
    let ext_y = EXTENT_SIGMAS * f32::sqrt(p.cov_c);
    // Projected::pixel_rect.
    let x0 = f32::max(f32::ceil(u - ext_x - 0.5), 0.0);
    let y0 = f32::max(f32::ceil(v - ext_y - 0.5), 0.0);
    let x1 = f32::min(f32::floor(u + ext_x - 0.5), f32::cast_from(width) - 1.0);
    let y1 = f32::min(f32::floor(v + ext_y - 0.5), f32::cast_from(height) - 1.0);
    let drawn = p.valid && x0 <= x1 && y0 <= y1;
    let o = g * PROJECTED;
    projected[o] = u;
    projected[o + 1] = v;
    projected[o + 2] = p.cz;
    projected[o + 3] = p.con_a;
    projected[o + 4] = p.con_b;
    projected[o + 5] = p.con_c;
    projected[o + 6] = 1.0 / (1.0 + f32::exp(-opacity_logits[g]));
    projected[o + 7] = x0;
    projected[o + 8] = y0;
    projected[o + 9] = x1;
    projected[o + 10] = y1;
    projected[o + 11] = select(drawn, 1.0f32, 0.0f32);
    // Depths are positive here, so their bit patterns sort like the numbers; ties go by index
    // (the host sorts by `(depth, index)`).
    keys[pos] = select(drawn, u32::reinterpret(p.cz), NONE);
    values[pos] = i as u32;
}

/// Whether the pair `(ki, vi)` at flat index `i` and `(kl, vl)` at its partner (further on) must
/// swap in a merge of size `k`: ascending or descending by `(key, value)`, the direction from
/// the index within its `n_pad` segment so that every segment ends ascending.
#[cube]
fn out_of_order(ki: u32, vi: u32, kl: u32, vl: u32, i: u32, k: u32, n_pad: u32) -> bool {
    let greater = ki > kl || (ki == kl && vi > vl);
    let less = ki < kl || (ki == kl && vi < vl);
    let ascending = (i & (n_pad - 1) & k) == 0;
    (ascending && greater) || (!ascending && less)
}

/// One compare-and-swap pass of a bitonic sort of `(key, value)` pairs, ascending within each
/// power-of-two segment (`k` and `j` of the classic network: `k` the size of the bitonic
/// sequences being merged, `j` the distance of the compared pairs).
#[cube(launch)]
pub fn bitonic_step_kernel(
    keys: &mut Tensor<u32>,
    values: &mut Tensor<u32>,
    j: u32,
    k: u32,
    n_pad: u32,
) {
    let i = ABSOLUTE_POS;
    if i >= keys.len() {
        terminate!();
    }
    let l = (i as u32 ^ j) as usize;
    if l > i {
        let (ki, kl) = (keys[i], keys[l]);
        let (vi, vl) = (values[i], values[l]);
        if out_of_order(ki, vi, kl, vl, i as u32, k, n_pad) {
            keys[i] = kl;
            keys[l] = ki;
            values[i] = vl;
            values[l] = vi;
        }
    }
}

/// The passes of a bitonic sort whose compared pairs lie within one aligned block of [`BLOCK`]
/// entries (`j < BLOCK`), done in shared memory by one cube per block: the merges of sizes
/// `k_first..=k_last` (doubling), the first starting at distance `j_first`, the others at `k / 2`.
/// Directions as in [`bitonic_step_kernel`].
#[cube(launch)]
pub fn bitonic_local_kernel(
    keys: &mut Tensor<u32>,
    values: &mut Tensor<u32>,
    k_first: u32,
    k_last: u32,
    j_first: u32,
    n_pad: u32,
) {
    let t = UNIT_POS as usize;
    let i = CUBE_POS * BLOCK + t;
    let mut sk = Shared::<[u32]>::new_slice(BLOCK);
    let mut sv = Shared::<[u32]>::new_slice(BLOCK);
    sk[t] = keys[i];
    sv[t] = values[i];
    sync_cube();
    let mut k = k_first;
    while k <= k_last {
        let mut j = k / 2;
        if k == k_first {
            j = j_first;
        }
        while j > 0 {
            let l = t ^ j as usize;
            if l > t {
                let (ki, kl) = (sk[t], sk[l]);
                let (vi, vl) = (sv[t], sv[l]);
                if out_of_order(ki, vi, kl, vl, i as u32, k, n_pad) {
                    sk[t] = kl;
                    sk[l] = ki;
                    sv[t] = vl;
                    sv[l] = vi;
                }
            }
            sync_cube();
            j /= 2;
        }
        k *= 2;
    }
    keys[i] = sk[t];
    values[i] = sv[t];
}

/// Shared memory of one tile's cube: the Gaussians of the current chunk that meet the tile,
/// compacted in depth order.
#[derive(CubeType)]
pub struct Stage {
    /// Index of each staged Gaussian.
    ids: Shared<[u32]>,
    /// Its rank in the camera's depth order.
    ranks: Shared<[u32]>,
    /// `u v depth a b c opacity x0 y0 x1 y1` of each.
    staged: Shared<[f32]>,
    /// Prefix sums of the hit flags (the compaction's write positions).
    scan: Shared<[u32]>,
}

#[cube]
fn new_stage() -> Stage {
    Stage {
        ids: Shared::<[u32]>::new_slice(BLOCK),
        ranks: Shared::<[u32]>::new_slice(BLOCK),
        staged: Shared::<[f32]>::new_slice(BLOCK * STAGED),
        scan: Shared::<[u32]>::new_slice(BLOCK),
    }
}

/// Stages chunk `chunk` of camera `b`'s depth order: each unit reads one entry, keeps it when
/// the Gaussian is drawn and its pixel rect meets this cube's tile, and the kept ones are
/// compacted in order ([`compact`]). Returns how many were kept; every
/// unit of the cube must call it.
#[cube]
fn stage_chunk(
    projected: &Tensor<f32>,
    order: &Tensor<u32>,
    stage: &mut Stage,
    chunk: usize,
    b: usize,
    count: u32,
    n_pad: u32,
) -> usize {
    let t = UNIT_POS as usize;
    let tile_x0 = f32::cast_from(CUBE_POS_X * TILE_SIZE as u32);
    let tile_y0 = f32::cast_from(CUBE_POS_Y * TILE_SIZE as u32);
    let last = (TILE_SIZE - 1) as f32;
    let g = order[b * n_pad as usize + chunk * BLOCK + t];
    let mut hit = false;
    let mut o = 0usize;
    if g < count {
        o = (b * count as usize + g as usize) * PROJECTED;
        hit = projected[o + 11] > 0.5
            && projected[o + 7] <= tile_x0 + last
            && projected[o + 9] >= tile_x0
            && projected[o + 8] <= tile_y0 + last
            && projected[o + 10] >= tile_y0;
    }
    let slot = compact(&mut stage.scan, hit, BLOCK);
    if hit {
        let at = (slot - 1) as usize;
        stage.ids[at] = g;
        stage.ranks[at] = (chunk * BLOCK + t) as u32;
        #[unroll]
        for k in 0..STAGED {
            stage.staged[at * STAGED + k] = projected[o + k];
        }
    }
    sync_cube();
    stage.scan[BLOCK - 1] as usize
}

/// The Gaussian staged in slot `s` at pixel `(px, py)`: the offset of the pixel centre from
/// its mean and `(alpha, gauss, raw)` where it contributes, `alpha = 0` where it does not (host
/// `overlap` and `alpha_at`).
#[cube]
fn alpha_at(staged: &Shared<[f32]>, s: usize, px: f32, py: f32) -> Sample {
    let o = s * STAGED;
    let dx = px + 0.5 - staged[o];
    let dy = py + 0.5 - staged[o + 1];
    let mut out = Sample {
        dx,
        dy,
        alpha: 0.0,
        gauss: 0.0,
        raw: 0.0,
    };
    if px >= staged[o + 7] && px <= staged[o + 9] && py >= staged[o + 8] && py <= staged[o + 10] {
        let (a, b, c) = (staged[o + 3], staged[o + 4], staged[o + 5]);
        let power = 0.5 * (a * dx * dx + c * dy * dy) + b * dx * dy;
        if !f32::is_nan(power) && power <= MAX_POWER {
            let gauss = f32::exp(-power);
            let raw = staged[o + 6] * gauss;
            let alpha = f32::min(raw, MAX_ALPHA);
            if alpha >= MIN_ALPHA {
                out.alpha = alpha;
                out.gauss = gauss;
                out.raw = raw;
            }
        }
    }
    out
}

/// A Gaussian's alpha at one pixel, its Gaussian falloff and the alpha before the clamp.
#[derive(CubeType, Clone, Copy)]
pub struct Sample {
    dx: f32,
    dy: f32,
    alpha: f32,
    gauss: f32,
    raw: f32,
}

/// Front-to-back compositing, one cube per tile and one unit per pixel (host `composite`).
/// `image` must be zeroed; `contributors` receives `1 +` the depth rank of the last
/// Gaussian composited into each pixel.
#[cube(launch)]
pub fn rasterize_kernel(
    projected: &Tensor<f32>,
    features: &Tensor<f32>,
    order: &Tensor<u32>,
    image: &mut Tensor<f32>,
    transmittance: &mut Tensor<f32>,
    contributors: &mut Tensor<u32>,
    count: u32,
    n_pad: u32,
    width: u32,
    height: u32,
    channels: u32,
) {
    let here = tile_pixel(width, height);
    let (b, inside, px, py, pix, hw) = (here.b, here.inside, here.px, here.py, here.pix, here.hw);
    let ch = channels as usize;
    let mut stage = new_stage();
    let mut t = 1.0f32;
    let mut last = 0u32;
    let mut done = !inside;
    let chunks = n_pad as usize / BLOCK;
    // Whether every pixel of the tile is done (the same for every unit: the rest is skipped).
    let mut saturated = false;
    for chunk in 0..chunks {
        if !saturated {
            let hits = stage_chunk(projected, order, &mut stage, chunk, b, count, n_pad);
            for s in 0..hits {
                if !done {
                    let g = stage.ids[s];
                    let o = s * STAGED;
                    let a = alpha_at(&stage.staged, s, px, py);
                    if a.alpha > 0.0 {
                        let next = t * (1.0 - a.alpha);
                        if next < MIN_TRANSMITTANCE {
                            done = true;
                        } else {
                            let w = a.alpha * t;
                            let f = (b * count as usize + g as usize) * ch;
                            let out = b * (ch + 2) * hw + pix;
                            for c in 0..ch {
                                image[out + c * hw] += w * features[f + c];
                            }
                            image[out + ch * hw] += w;
                            image[out + (ch + 1) * hw] += w * stage.staged[o + 2];
                            t = next;
                            last = stage.ranks[s] + 1;
                        }
                    }
                }
            }
            sync_cube();
            saturated = cube_max(&mut stage.scan, select(done, 0u32, 1u32), BLOCK) == 0;
        }
    }
    if inside {
        transmittance[b * hw + pix] = t;
        contributors[b * hw + pix] = last;
    }
}

/// The reverse of [`rasterize_kernel`]: each pixel walks its Gaussians back to front and adds
/// its share of `dL/d(u, v, depth, conic, opacity, features)` to `grads` (`[B * N,
/// GRAD_HEAD + C]`) with atomic adds (host `composite_backward`). `behind` is zeroed scratch of
/// the image's shape.
#[cube(launch)]
pub fn rasterize_backward_kernel(
    projected: &Tensor<f32>,
    features: &Tensor<f32>,
    order: &Tensor<u32>,
    transmittance: &Tensor<f32>,
    contributors: &Tensor<u32>,
    grad_image: &Tensor<f32>,
    behind: &mut Tensor<f32>,
    grads: &mut Tensor<Atomic<f32>>,
    count: u32,
    n_pad: u32,
    width: u32,
    height: u32,
    channels: u32,
) {
    let here = tile_pixel(width, height);
    let (b, inside, px, py, pix, hw) = (here.b, here.inside, here.px, here.py, here.pix, here.hw);
    let ch = channels as usize;
    let stride = GRAD_HEAD + ch;
    let mut stage = new_stage();
    let mut t = 1.0f32;
    let mut n = 0u32;
    if inside {
        t = transmittance[b * hw + pix];
        n = contributors[b * hw + pix];
    }
    let chunks = n_pad as usize / BLOCK;
    // Chunks at or past the tile's largest contributor count hold nothing to undo.
    let needed = cube_max(&mut stage.scan, n, BLOCK) as usize;
    for back in 0..chunks {
        let chunk = chunks - 1 - back;
        if chunk * BLOCK < needed {
            let hits = stage_chunk(projected, order, &mut stage, chunk, b, count, n_pad);
            for back_s in 0..hits {
                let s = hits - 1 - back_s;
                let g = stage.ids[s];
                if inside && stage.ranks[s] < n {
                    let o = s * STAGED;
                    let a = alpha_at(&stage.staged, s, px, py);
                    let (dx, dy) = (a.dx, a.dy);
                    if a.alpha > 0.0 {
                        let tk = t / (1.0 - a.alpha);
                        t = tk;
                        let wk = a.alpha * tk;
                        let f = (b * count as usize + g as usize) * ch;
                        let slot = (b * count as usize + g as usize) * stride;
                        let depth = stage.staged[o + 2];
                        let mut d_alpha = 0.0f32;
                        for c in 0..ch + 2 {
                            let mut fc = 1.0f32;
                            if c < ch {
                                fc = features[f + c];
                            } else if c == ch + 1 {
                                fc = depth;
                            }
                            let at = (b * (ch + 2) + c) * hw + pix;
                            let gc = grad_image[at];
                            let bc = behind[at];
                            d_alpha += (fc - bc) * gc;
                            behind[at] = a.alpha * fc + (1.0 - a.alpha) * bc;
                            if c < ch {
                                grads[slot + GRAD_HEAD + c].fetch_add(wk * gc);
                            } else if c == ch + 1 {
                                grads[slot + 2].fetch_add(wk * gc);
                            }
                        }
                        d_alpha *= tk;
                        if a.raw < MAX_ALPHA {
                            let (ca, cb, cc) = (
                                stage.staged[o + 3],
                                stage.staged[o + 4],
                                stage.staged[o + 5],
                            );
                            let d_power = -a.alpha * d_alpha;
                            grads[slot + 6].fetch_add(a.gauss * d_alpha);
                            grads[slot].fetch_add(-d_power * (ca * dx + cb * dy));
                            grads[slot + 1].fetch_add(-d_power * (cb * dx + cc * dy));
                            grads[slot + 3].fetch_add(0.5 * dx * dx * d_power);
                            grads[slot + 4].fetch_add(dx * dy * d_power);
                            grads[slot + 5].fetch_add(0.5 * dy * dy * d_power);
                        }
                    }
                }
            }
            sync_cube();
        }
    }
}

/// The chain rule from the projected gradients back to the Gaussian parameters, one unit per
/// Gaussian (host `project_backward`, and the feature gradients copied out of `grads`).
#[cube(launch)]
pub fn project_backward_kernel(
    means: &Tensor<f32>,
    log_scales: &Tensor<f32>,
    rotations: &Tensor<f32>,
    opacity_logits: &Tensor<f32>,
    views: &Tensor<f32>,
    grads: &Tensor<f32>,
    g_means: &mut Tensor<f32>,
    g_log_scales: &mut Tensor<f32>,
    g_rotations: &mut Tensor<f32>,
    g_opacity_logits: &mut Tensor<f32>,
    g_features: &mut Tensor<f32>,
    count: u32,
    channels: u32,
) {
    let g = ABSOLUTE_POS;
    if g >= opacity_logits.len() {
        terminate!();
    }
    let b = g / count as usize;
    let ch = channels as usize;
    let slot = g * (GRAD_HEAD + ch);
    for c in 0..ch {
        g_features[g * ch + c] = grads[slot + GRAD_HEAD + c];
    }
    let p = project_one(means, log_scales, rotations, views, g, b);
    if !p.valid {
        for k in 0..3 {
            g_means[3 * g + k] = 0.0f32;
            g_log_scales[3 * g + k] = 0.0f32;
        }
        for k in 0..4 {
            g_rotations[4 * g + k] = 0.0f32;
        }
        g_opacity_logits[g] = 0.0f32;
        terminate!();
    }
    let vb = b * VIEW;
    let (fx, fy) = (views[vb + 12], views[vb + 13]);
    let rz = 1.0 / p.cz;
    let rz2 = rz * rz;
    let (gu, gv, gdepth) = (grads[slot], grads[slot + 1], grads[slot + 2]);
    let (a, bb, c) = (p.con_a, p.con_b, p.con_c);
    let (ga, gb, gc) = (grads[slot + 3], grads[slot + 4] * 0.5, grads[slot + 5]);
    // d conic / d cov2 = -conic dconic conic.
    let q0 = a * ga + bb * gb;
    let q1 = a * gb + bb * gc;
    let q2 = bb * ga + c * gb;
    let q3 = bb * gb + c * gc;
    let gs00 = 0.0 - (q0 * a + q1 * bb);
    let gs01 = 0.0 - (q0 * bb + q1 * c);
    let gs11 = 0.0 - (q2 * bb + q3 * c);

    let (m0x, m0y, m0z) = (p.m0x, p.m0y, p.m0z);
    let (m1x, m1y, m1z) = (p.m1x, p.m1y, p.m1z);
    let s0x = p.s_xx * m0x + p.s_xy * m0y + p.s_xz * m0z;
    let s0y = p.s_xy * m0x + p.s_yy * m0y + p.s_yz * m0z;
    let s0z = p.s_xz * m0x + p.s_yz * m0y + p.s_zz * m0z;
    let s1x = p.s_xx * m1x + p.s_xy * m1y + p.s_xz * m1z;
    let s1y = p.s_xy * m1x + p.s_yy * m1y + p.s_yz * m1z;
    let s1z = p.s_xz * m1x + p.s_yz * m1y + p.s_zz * m1z;
    // g_cov3 = gs00 m0 m0^T + gs01 (m0 m1^T + m1 m0^T) + gs11 m1 m1^T (symmetric).
    let gc00 = gs00 * m0x * m0x + 2.0 * gs01 * m0x * m1x + gs11 * m1x * m1x;
    let gc01 = gs00 * m0x * m0y + gs01 * (m0x * m1y + m1x * m0y) + gs11 * m1x * m1y;
    let gc02 = gs00 * m0x * m0z + gs01 * (m0x * m1z + m1x * m0z) + gs11 * m1x * m1z;
    let gc11 = gs00 * m0y * m0y + 2.0 * gs01 * m0y * m1y + gs11 * m1y * m1y;
    let gc12 = gs00 * m0y * m0z + gs01 * (m0y * m1z + m1y * m0z) + gs11 * m1y * m1z;
    let gc22 = gs00 * m0z * m0z + 2.0 * gs01 * m0z * m1z + gs11 * m1z * m1z;
    let gm0x = 2.0 * (gs00 * s0x + gs01 * s1x);
    let gm0y = 2.0 * (gs00 * s0y + gs01 * s1y);
    let gm0z = 2.0 * (gs00 * s0z + gs01 * s1z);
    let gm1x = 2.0 * (gs01 * s0x + gs11 * s1x);
    let gm1y = 2.0 * (gs01 * s0y + gs11 * s1y);
    let gm1z = 2.0 * (gs01 * s0z + gs11 * s1z);
    // g_j = W g_m.
    let gj0x = views[vb] * gm0x + views[vb + 1] * gm0y + views[vb + 2] * gm0z;
    let gj0z = views[vb + 6] * gm0x + views[vb + 7] * gm0y + views[vb + 8] * gm0z;
    let gj1y = views[vb + 3] * gm1x + views[vb + 4] * gm1y + views[vb + 5] * gm1z;
    let gj1z = views[vb + 6] * gm1x + views[vb + 7] * gm1y + views[vb + 8] * gm1z;

    let mut gcx = 0.0f32;
    let mut gcy = 0.0f32;
    let mut gcz = -fx * rz2 * gj0x - fy * rz2 * gj1y;
    if p.clamped_x {
        gcz += fx * p.ratio_x * rz2 * gj0z;
    } else {
        gcx += -fx * rz2 * gj0z;
        gcz += 2.0 * fx * p.cx * rz2 * rz * gj0z;
    }
    if p.clamped_y {
        gcz += fy * p.ratio_y * rz2 * gj1z;
    } else {
        gcy += -fy * rz2 * gj1z;
        gcz += 2.0 * fy * p.cy * rz2 * rz * gj1z;
    }
    gcx += fx * rz * gu;
    gcy += fy * rz * gv;
    gcz += -fx * p.cx * rz2 * gu - fy * p.cy * rz2 * gv + gdepth;
    // g_mean = W^T g_cam.
    g_means[3 * g] = views[vb] * gcx + views[vb + 3] * gcy + views[vb + 6] * gcz;
    g_means[3 * g + 1] = views[vb + 1] * gcx + views[vb + 4] * gcy + views[vb + 7] * gcz;
    g_means[3 * g + 2] = views[vb + 2] * gcx + views[vb + 5] * gcy + views[vb + 8] * gcz;

    // g_RS = 2 g_cov3 RS; RS[r][k] = R[r][k] s_k.
    let (qw, qx, qy, qz) = (p.qw, p.qx, p.qy, p.qz);
    let r = rotation(qw, qx, qy, qz);
    let (r00, r01, r02) = (r.m00, r.m01, r.m02);
    let (r10, r11, r12) = (r.m10, r.m11, r.m12);
    let (r20, r21, r22) = (r.m20, r.m21, r.m22);
    // Column k of g_RS: 2 g_cov3 (column k of RS).
    let g00 = 2.0 * (gc00 * r00 + gc01 * r10 + gc02 * r20) * p.sx;
    let g10 = 2.0 * (gc01 * r00 + gc11 * r10 + gc12 * r20) * p.sx;
    let g20 = 2.0 * (gc02 * r00 + gc12 * r10 + gc22 * r20) * p.sx;
    let g01 = 2.0 * (gc00 * r01 + gc01 * r11 + gc02 * r21) * p.sy;
    let g11 = 2.0 * (gc01 * r01 + gc11 * r11 + gc12 * r21) * p.sy;
    let g21 = 2.0 * (gc02 * r01 + gc12 * r11 + gc22 * r21) * p.sy;
    let g02 = 2.0 * (gc00 * r02 + gc01 * r12 + gc02 * r22) * p.sz;
    let g12 = 2.0 * (gc01 * r02 + gc11 * r12 + gc12 * r22) * p.sz;
    let g22 = 2.0 * (gc02 * r02 + gc12 * r12 + gc22 * r22) * p.sz;
    // d/d log s_k = s_k (R col k . g_RS col k).
    g_log_scales[3 * g] = (r00 * g00 + r10 * g10 + r20 * g20) * p.sx;
    g_log_scales[3 * g + 1] = (r01 * g01 + r11 * g11 + r21 * g21) * p.sy;
    g_log_scales[3 * g + 2] = (r02 * g02 + r12 * g12 + r22 * g22) * p.sz;
    // g_R[r][k] = g_RS[r][k] s_k, then through the unit quaternion (host `quat_backward`).
    let (h00, h10, h20) = (g00 * p.sx, g10 * p.sx, g20 * p.sx);
    let (h01, h11, h21) = (g01 * p.sy, g11 * p.sy, g21 * p.sy);
    let (h02, h12, h22) = (g02 * p.sz, g12 * p.sz, g22 * p.sz);
    let dw = (qy * h02 + qz * h10 + qx * h21 - qz * h01 - qx * h12 - qy * h20) * 2.0;
    let dx = (qy * h01 + qz * h02 + qy * h10 + qz * h20 + qw * h21
        - qw * h12
        - qx * h11 * 2.0
        - qx * h22 * 2.0)
        * 2.0;
    let dy = (qx * h01 + qw * h02 + qx * h10 + qz * h12 + qz * h21
        - qw * h20
        - qy * h00 * 2.0
        - qy * h22 * 2.0)
        * 2.0;
    let dz = (qx * h02 + qw * h10 + qy * h12 + qx * h20 + qy * h21
        - qw * h01
        - qz * h00 * 2.0
        - qz * h11 * 2.0)
        * 2.0;
    let dot = qw * dw + qx * dx + qy * dy + qz * dz;
    g_rotations[4 * g] = (dw - qw * dot) / p.qn;
    g_rotations[4 * g + 1] = (dx - qx * dot) / p.qn;
    g_rotations[4 * g + 2] = (dy - qy * dot) / p.qn;
    g_rotations[4 * g + 3] = (dz - qz * dot) / p.qn;
    let opacity = 1.0 / (1.0 + f32::exp(-opacity_logits[g]));
    g_opacity_logits[g] = grads[slot + 6] * opacity * (1.0 - opacity);
}
