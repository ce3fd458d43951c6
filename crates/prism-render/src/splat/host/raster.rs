//! Tiling, depth sorting and front-to-back alpha compositing of projected Gaussians in one
//! camera, and the reverse pass that yields their gradients.
//!
//! For a pixel with centre `x`, the Gaussians of its tile are visited in depth order:
//!
//! ```text
//! d = x - (u, v),  power = d^T conic d / 2
//! alpha_i = min(0.99, o_i exp(-power))        skipped when < 1/255 or outside 3 sigma
//! out = sum_i f_i alpha_i T_i,   T_i = prod_{j<i} (1 - alpha_j)
//! ```
//!
//! stopping before the Gaussian that would push the transmittance below 1e-4. The composited
//! channels are the `C` features, then `1` (giving the alpha `1 - T`) and the depth `z`.
//!
//! The reverse pass walks each pixel's list back to front (3DGS paper, Sec. 6 and its code):
//! `T_i = T_{i+1} / (1 - alpha_i)` and, with `B_i` the channels composited behind `i`
//! (`B_{i-1} = alpha_i f_i + (1 - alpha_i) B_i`), `dout/dalpha_i = T_i (f_i - B_i)`.

use multiversion::multiversion;
use prism_kernels::math;
use rayon::prelude::*;

use super::project::Projected;
use super::view::View;
use super::{MAX_ALPHA, MAX_POWER, MIN_ALPHA, MIN_TRANSMITTANCE, TILE_SIZE};

/// Per tile, the indices of the Gaussians that touch it, sorted front to back.
#[derive(Clone, Debug, Default)]
pub struct TileLists {
    /// `offsets[t]..offsets[t + 1]` is tile `t`'s range in `ids`.
    pub offsets: Vec<usize>,
    /// Gaussian indices.
    pub ids: Vec<u32>,
}

impl TileLists {
    /// Tile `t`'s Gaussians, front to back.
    pub fn tile(&self, t: usize) -> &[u32] {
        &self.ids[self.offsets[t]..self.offsets[t + 1]]
    }
}

/// Sorts the visible Gaussians by depth (ties by index, so the order is deterministic) and
/// lists, per tile, those whose box ([`Projected::extent`]) covers one of its pixel centres.
pub fn bin(projected: &[Option<Projected>], view: &View) -> TileLists {
    let (w, h) = (view.width, view.height);
    let tiles_x = view.tiles_x();
    let tiles = tiles_x * view.tiles_y();
    let mut order: Vec<(u32, f32, [usize; 4])> = projected
        .par_iter()
        .enumerate()
        .filter_map(|(i, p)| {
            let p = p.as_ref()?;
            let r = p.pixel_rect(w, h)?;
            let tile_rect = [
                r[0] / TILE_SIZE,
                r[1] / TILE_SIZE,
                r[2] / TILE_SIZE,
                r[3] / TILE_SIZE,
            ];
            Some((i as u32, p.depth, tile_rect))
        })
        .collect();
    order.par_sort_unstable_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));

    let mut counts = vec![0usize; tiles + 1];
    for (_, _, r) in &order {
        for ty in r[1]..=r[3] {
            for tx in r[0]..=r[2] {
                counts[ty * tiles_x + tx + 1] += 1;
            }
        }
    }
    for t in 0..tiles {
        counts[t + 1] += counts[t];
    }
    let mut cursor = counts.clone();
    let mut ids = vec![0u32; counts[tiles]];
    for (i, _, r) in &order {
        for ty in r[1]..=r[3] {
            for tx in r[0]..=r[2] {
                let t = ty * tiles_x + tx;
                ids[cursor[t]] = *i;
                cursor[t] += 1;
            }
        }
    }
    TileLists {
        offsets: counts,
        ids,
    }
}

/// The pixel rectangle of tile `t`: `(x0, y0, width, height)`.
fn tile_rect(t: usize, view: &View) -> (usize, usize, usize, usize) {
    let tiles_x = view.tiles_x();
    let (x0, y0) = ((t % tiles_x) * TILE_SIZE, (t / tiles_x) * TILE_SIZE);
    (
        x0,
        y0,
        TILE_SIZE.min(view.width - x0),
        TILE_SIZE.min(view.height - y0),
    )
}

/// The overlap of a Gaussian's pixel box with a tile, in tile-local inclusive coordinates.
fn overlap(p: &Projected, view: &View, tile: (usize, usize, usize, usize)) -> Option<[usize; 4]> {
    let r = p.pixel_rect(view.width, view.height)?;
    let (x0, y0, tw, th) = tile;
    let (ax0, ay0) = (r[0].max(x0), r[1].max(y0));
    let (ax1, ay1) = (r[2].min(x0 + tw - 1), r[3].min(y0 + th - 1));
    (ax0 <= ax1 && ay0 <= ay1).then(|| [ax0 - x0, ay0 - y0, ax1 - x0, ay1 - y0])
}

/// Where a Gaussian may be drawn, row by row: the quadratic of [`RowSpans::span`] with its
/// per-Gaussian terms worked out once, not once per row.
struct RowSpans {
    u: f32,
    b: f32,
    inv_a: f32,
    /// `b^2 - a c`, the discriminant's factor of `dy^2`.
    k: f32,
    /// `2 a limit`, the discriminant's constant.
    m: f32,
}

impl RowSpans {
    fn of(p: &Projected) -> Self {
        let [a, b, c] = p.conic;
        let limit = p.support;
        Self {
            u: p.u,
            b,
            inv_a: 1.0 / a,
            k: b * b - a * c,
            m: 2.0 * a * limit,
        }
    }

    /// The tile-local columns of `lx0..=lx1` in the row at offset `dy` from the Gaussian's
    /// centre where it may be drawn: where `power <= min(3-sigma limit, ln(255 o))` (beyond
    /// that the alpha is below 1/255), solved for `dx` and widened by a pixel, so that
    /// [`alpha_at`] still decides at the border. A pure speed-up: it only skips pixels that
    /// [`alpha_at`] rejects.
    #[inline]
    fn span(&self, dy: f32, x0: usize, lx0: usize, lx1: usize) -> Option<(usize, usize)> {
        // 0.5 a dx^2 + b dy dx + 0.5 c dy^2 - limit <= 0, with a > 0.
        let disc = self.k * dy * dy + self.m;
        if disc.is_nan() || disc < 0.0 {
            return None;
        }
        let root = disc.sqrt();
        let x0 = x0 as f32 + 0.5;
        let lo = self.u + (-self.b * dy - root) * self.inv_a - x0;
        let hi = self.u + (-self.b * dy + root) * self.inv_a - x0;
        let first = (ceil_near(lo) - 1.0).max(lx0 as f32);
        let last = (floor_near(hi) + 1.0).min(lx1 as f32);
        (first <= last).then_some((first as usize, last as usize))
    }
}

/// Tile-local columns lie in `0..TILE_SIZE`: a bound outside this margin around them clamps to
/// the same span.
const SPAN_MARGIN: f32 = 4.0;

/// `x.ceil()` for `x` clamped to the tile's columns and a margin: a cast, where the baseline
/// x86-64 target makes `ceil` a library call.
#[inline]
fn ceil_near(x: f32) -> f32 {
    let x = x.clamp(-SPAN_MARGIN, TILE_SIZE as f32 + SPAN_MARGIN);
    let t = x as i32 as f32;
    if t < x { t + 1.0 } else { t }
}

/// `x.floor()` for `x` clamped as in [`ceil_near`].
#[inline]
fn floor_near(x: f32) -> f32 {
    let x = x.clamp(-SPAN_MARGIN, TILE_SIZE as f32 + SPAN_MARGIN);
    let t = x as i32 as f32;
    if t > x { t - 1.0 } else { t }
}

/// The Gaussian's alpha at offset `(dx, dy)` from its centre, with `exp(-power)` and the
/// unclamped `o exp(-power)`. The alpha is 0 where the pixel is skipped (outside 3 sigma, below
/// 1/255, or a NaN power). Branch-free, so that [`RowAlphas::of`] computes a row of them as
/// vectors.
#[inline(always)]
fn alpha_at(p: &Projected, dx: f32, dy: f32) -> (f32, f32, f32) {
    let [a, b, c] = p.conic;
    let power = 0.5 * (a * dx * dx + c * dy * dy) + b * dx * dy;
    // Clamped, so that the lanes far outside the support do not reach the subnormals (each of
    // which takes a microcode assist on Intel's cores); those lanes are not drawn anyway.
    let g = math::exp(-power.min(2.0 * MAX_POWER));
    let raw = p.opacity * g;
    let alpha = raw.min(MAX_ALPHA);
    // Both comparisons are false for a NaN.
    let drawn = power <= MAX_POWER && alpha >= MIN_ALPHA;
    (if drawn { alpha } else { 0.0 }, g, raw)
}

/// [`alpha_at`] for the pixels of one tile row: lane `i` is the tile's column `i`. Lanes outside
/// the row's span `first..=last` are 0 (not drawn), so that a whole row is updated as vectors.
struct RowAlphas {
    alpha: [f32; TILE_SIZE],
    gauss: [f32; TILE_SIZE],
    raw: [f32; TILE_SIZE],
}

impl RowAlphas {
    /// `dx` is the offset of column `first`'s centre from the Gaussian's centre; column `i`'s
    /// offset is `dx + (i - first)`, so that every lane of the span sees the same offset in the
    /// forward pass as its pixel in the reverse pass's [`BoxPixels`].
    #[inline(always)]
    fn of(p: &Projected, (first, last): (usize, usize), dx: f32, dy: f32) -> Self {
        let mut s = Self {
            alpha: [0.0; TILE_SIZE],
            gauss: [0.0; TILE_SIZE],
            raw: [0.0; TILE_SIZE],
        };
        for i in 0..TILE_SIZE {
            let (alpha, gauss, raw) = alpha_at(p, dx + lane_offset(i, first), dy);
            let in_span = first <= i && i <= last;
            s.alpha[i] = if in_span { alpha } else { 0.0 };
            (s.gauss[i], s.raw[i]) = (gauss, raw);
        }
        s
    }
}

/// `i - first` as a float (exact for tile columns).
#[inline(always)]
fn lane_offset(i: usize, first: usize) -> f32 {
    i as f32 - first as f32
}

/// The result of compositing one camera.
#[derive(Clone, Debug, Default)]
pub struct Composited {
    /// `[C + 2, H, W]`: features, alpha, accumulated depth `sum_i w_i z_i` (moved out into the
    /// output by `host::forward`; the reverse pass does not read it).
    pub image: Vec<f32>,
    /// Per pixel, the final transmittance.
    pub transmittance: Vec<f32>,
    /// Per pixel, one past the tile-list position of the last Gaussian composited.
    pub contributors: Vec<u32>,
}

/// Pixels of a full tile.
const TILE_PIXELS: usize = TILE_SIZE * TILE_SIZE;

/// Where channel `c` of the tile's row `ly` starts in a channel-major tile buffer
/// (`[channels][TILE_SIZE][TILE_SIZE]`, full rows even in a tile cut by the image border), so
/// that a row of one channel is one vector of lanes.
#[inline(always)]
fn row_start(c: usize, ly: usize) -> usize {
    (c * TILE_SIZE + ly) * TILE_SIZE
}

/// One tile's compositing state, in full `TILE_SIZE`-wide rows: the channels channel-major
/// ([`row_start`]), transmittance and contributor count row-major.
struct TileOut {
    acc: Vec<f32>,
    t: [f32; TILE_PIXELS],
    n: [u32; TILE_PIXELS],
}

/// Gaussian `j`'s composited channels: its `C` features, then `1` (for the alpha) and its depth.
#[inline]
fn channels_of(fe: &mut [f32], features: &[f32], channels: usize, j: usize, depth: f32) {
    fe[..channels].copy_from_slice(&features[j * channels..(j + 1) * channels]);
    fe[channels] = 1.0;
    fe[channels + 1] = depth;
}

/// Front-to-back compositing of one camera, in parallel over tiles. `features` is `[N, C]`.
pub fn composite(
    projected: &[Option<Projected>],
    features: &[f32],
    channels: usize,
    lists: &TileLists,
    view: &View,
) -> Composited {
    let tiles = view.tiles_x() * view.tiles_y();
    let ch = channels + 2;
    let scene = Scene {
        projected,
        features,
        channels,
        view,
    };
    let outs: Vec<TileOut> = (0..tiles)
        .into_par_iter()
        .map(|tile| composite_tile(&scene, tile, lists.tile(tile)))
        .collect();

    let (w, h) = (view.width, view.height);
    let mut out = Composited {
        image: vec![0.0; ch * w * h],
        transmittance: vec![1.0; w * h],
        contributors: vec![0; w * h],
    };
    for (tile, o) in outs.iter().enumerate() {
        let (x0, y0, tw, th) = tile_rect(tile, view);
        for ly in 0..th {
            let row = (y0 + ly) * w + x0;
            let src = ly * TILE_SIZE;
            out.transmittance[row..row + tw].copy_from_slice(&o.t[src..src + tw]);
            out.contributors[row..row + tw].copy_from_slice(&o.n[src..src + tw]);
            for c in 0..ch {
                let src = row_start(c, ly);
                out.image[c * w * h + row..][..tw].copy_from_slice(&o.acc[src..src + tw]);
            }
        }
    }
    out
}

/// What every tile of one camera reads: the projected Gaussians, their `[N, C]` features and
/// the view.
struct Scene<'a> {
    projected: &'a [Option<Projected>],
    features: &'a [f32],
    channels: usize,
    view: &'a View,
}

/// One tile of [`composite`]: its Gaussians (`list`, front to back) composited into its
/// pixels, a tile row at a time as vectors of lanes ([`RowAlphas`]). Compiled for AVX-512 and
/// AVX2 too, chosen at run time.
#[multiversion(targets("x86_64+avx512f+avx512vl+avx512dq", "x86_64+avx2+fma"))]
fn composite_tile(scene: &Scene<'_>, tile: usize, list: &[u32]) -> TileOut {
    let (view, channels) = (scene.view, scene.channels);
    let ch = channels + 2;
    let rect = tile_rect(tile, view);
    let (x0, y0, tw, th) = rect;
    let mut out = TileOut {
        acc: vec![0.0f32; ch * TILE_PIXELS],
        t: [1.0; TILE_PIXELS],
        n: [0; TILE_PIXELS],
    };
    // 1 for a pixel still compositing, 0 once it stopped: multiplies the alphas, as a vector.
    let mut open = [1.0f32; TILE_PIXELS];
    let mut live = tw * th;
    let mut fe = vec![0.0f32; ch];
    for (k, &j) in list.iter().enumerate() {
        if live == 0 {
            break;
        }
        let j = j as usize;
        let Some(p) = scene.projected[j].as_ref() else {
            continue;
        };
        let Some([lx0, ly0, lx1, ly1]) = overlap(p, view, rect) else {
            continue;
        };
        channels_of(&mut fe, scene.features, channels, j, p.depth);
        let rows = RowSpans::of(p);
        for ly in ly0..=ly1 {
            let dy = (y0 + ly) as f32 + 0.5 - p.v;
            let Some(span) = rows.span(dy, x0, lx0, lx1) else {
                continue;
            };
            let dx = (x0 + span.0) as f32 + 0.5 - p.u;
            let alphas = RowAlphas::of(p, span, dx, dy);
            let base = ly * TILE_SIZE;
            let (t, n) = (
                &mut out.t[base..][..TILE_SIZE],
                &mut out.n[base..][..TILE_SIZE],
            );
            let open = &mut open[base..][..TILE_SIZE];
            // The weights `alpha T`, 0 where the pixel is not drawn.
            let mut weight = [0.0f32; TILE_SIZE];
            let mut stopped = 0;
            for i in 0..TILE_SIZE {
                let alpha = alphas.alpha[i] * open[i];
                let next = t[i] * (1.0 - alpha);
                let stop = alpha != 0.0 && next < MIN_TRANSMITTANCE;
                let drawn = alpha != 0.0 && !stop;
                weight[i] = if drawn { alpha * t[i] } else { 0.0 };
                t[i] = if drawn { next } else { t[i] };
                n[i] = if drawn { k as u32 + 1 } else { n[i] };
                open[i] = if stop { 0.0 } else { open[i] };
                stopped += usize::from(stop);
            }
            live -= stopped;
            // A zero weight adds nothing (the features are finite).
            for (c, &f) in fe.iter().enumerate() {
                let acc = &mut out.acc[row_start(c, ly)..][..TILE_SIZE];
                for i in 0..TILE_SIZE {
                    acc[i] += weight[i] * f;
                }
            }
        }
    }
    out
}

/// Per projected Gaussian, the number of gradient values the reverse pass accumulates:
/// `u, v, depth, conic a, b, c, opacity`, then the `C` features.
pub const GRAD_HEAD: usize = 7;

/// The reverse pass of [`composite`]. `grad_image` is `dL/d(image)` in the layout of
/// [`Composited::image`]. Returns `[N, GRAD_HEAD + C]`: per Gaussian `dL/du, dL/dv, dL/dz`
/// (depth channel only), `dL/dconic`, `dL/dopacity`, `dL/dfeatures`.
pub fn composite_backward(
    projected: &[Option<Projected>],
    features: &[f32],
    channels: usize,
    lists: &TileLists,
    view: &View,
    forward: &Composited,
    grad_image: &[f32],
) -> Vec<f32> {
    let tiles = view.tiles_x() * view.tiles_y();
    let stride = GRAD_HEAD + channels;
    let scene = Scene {
        projected,
        features,
        channels,
        view,
    };
    let per_tile: Vec<Vec<f32>> = (0..tiles)
        .into_par_iter()
        .map(|tile| backward_tile(&scene, tile, lists.tile(tile), forward, grad_image))
        .collect();

    let mut grads = vec![0.0f32; projected.len() * stride];
    for (tile, slots) in per_tile.iter().enumerate() {
        for (k, &j) in lists.tile(tile).iter().enumerate() {
            let Some(slot) = slots.get(k * stride..(k + 1) * stride) else {
                break;
            };
            let dst = &mut grads[j as usize * stride..(j as usize + 1) * stride];
            for (d, s) in dst.iter_mut().zip(slot) {
                *d += s;
            }
        }
    }
    grads
}

/// The pixels of one Gaussian's box in a tile that its rows' spans keep, packed densely in
/// row order, with their offsets from its centre and their [`alpha_at`] values: a Gaussian
/// covers about 5 columns of each of about 4 rows of a tile, so packed, its alphas take about
/// half the vectors that a row of [`RowAlphas`] each would.
struct BoxPixels {
    len: usize,
    /// Tile-local pixel index `ly * tw + lx`.
    pixel: [u16; TILE_PIXELS],
    dx: [f32; TILE_PIXELS],
    dy: [f32; TILE_PIXELS],
    alpha: [f32; TILE_PIXELS],
    gauss: [f32; TILE_PIXELS],
    raw: [f32; TILE_PIXELS],
}

impl BoxPixels {
    /// No pixels yet.
    fn new() -> Self {
        Self {
            len: 0,
            pixel: [0; TILE_PIXELS],
            dx: [0.0; TILE_PIXELS],
            dy: [0.0; TILE_PIXELS],
            alpha: [0.0; TILE_PIXELS],
            gauss: [0.0; TILE_PIXELS],
            raw: [0.0; TILE_PIXELS],
        }
    }

    /// Empties the list for the next Gaussian.
    fn clear(&mut self) {
        self.len = 0;
    }

    /// Adds tile pixel `pixel` at offset `(dx, dy)` from the Gaussian's centre.
    #[inline(always)]
    fn push(&mut self, pixel: usize, dx: f32, dy: f32) {
        (self.pixel[self.len], self.dx[self.len], self.dy[self.len]) = (pixel as u16, dx, dy);
        self.len += 1;
    }

    /// [`alpha_at`] of every pixel, a vector of lanes at a time: each pixel's value is the one
    /// [`RowAlphas::of`] gives it in the forward pass (the same offsets, the same operations).
    #[inline(always)]
    fn alphas(&mut self, p: &Projected) {
        for start in (0..self.len).step_by(TILE_SIZE) {
            let (dx, dy) = (
                &self.dx[start..][..TILE_SIZE],
                &self.dy[start..][..TILE_SIZE],
            );
            let alpha = &mut self.alpha[start..][..TILE_SIZE];
            let gauss = &mut self.gauss[start..][..TILE_SIZE];
            let raw = &mut self.raw[start..][..TILE_SIZE];
            for i in 0..TILE_SIZE {
                (alpha[i], gauss[i], raw[i]) = alpha_at(p, dx[i], dy[i]);
            }
        }
    }
}

/// One tile of [`composite_backward`]: the gradient slots of its list's Gaussians, in list
/// order. The pixels of each Gaussian's row spans are packed first ([`BoxPixels`]), their alphas
/// computed as vectors, then undone one pixel at a time in row order. Compiled per CPU as
/// [`composite_tile`] is.
#[multiversion(targets("x86_64+avx512f+avx512vl+avx512dq", "x86_64+avx2+fma"))]
fn backward_tile(
    scene: &Scene<'_>,
    tile: usize,
    list: &[u32],
    forward: &Composited,
    grad_image: &[f32],
) -> Vec<f32> {
    let (view, channels) = (scene.view, scene.channels);
    let ch = channels + 2;
    let stride = GRAD_HEAD + channels;
    let (w, h) = (view.width, view.height);
    let mut slots = vec![0.0f32; list.len() * stride];
    let rect = tile_rect(tile, view);
    let (x0, y0, tw, th) = rect;
    let np = tw * th;
    let mut t = vec![0.0f32; np];
    let mut n = vec![0u32; np];
    // Pixel-major, like the forward's tile: pixel `i`'s channels at `i * ch..`.
    let mut g = vec![0.0f32; np * ch];
    let mut behind = vec![0.0f32; np * ch];
    let mut last = 0usize;
    for ly in 0..th {
        for lx in 0..tw {
            let (idx, pix) = (ly * tw + lx, (y0 + ly) * w + x0 + lx);
            t[idx] = forward.transmittance[pix];
            n[idx] = forward.contributors[pix];
            last = last.max(n[idx] as usize);
            for c in 0..ch {
                g[idx * ch + c] = grad_image[c * w * h + pix];
            }
        }
    }
    let mut fe = vec![0.0f32; ch];
    let mut box_pixels = BoxPixels::new();
    for k in (0..last).rev() {
        let j = list[k] as usize;
        let Some(p) = scene.projected[j].as_ref() else {
            continue;
        };
        let Some([lx0, ly0, lx1, ly1]) = overlap(p, view, rect) else {
            continue;
        };
        channels_of(&mut fe, scene.features, channels, j, p.depth);
        let slot = &mut slots[k * stride..(k + 1) * stride];
        let [a, b, c] = p.conic;
        let rows = RowSpans::of(p);
        box_pixels.clear();
        for ly in ly0..=ly1 {
            let dy = (y0 + ly) as f32 + 0.5 - p.v;
            let Some((sx0, sx1)) = rows.span(dy, x0, lx0, lx1) else {
                continue;
            };
            let dx0 = (x0 + sx0) as f32 + 0.5 - p.u;
            for lx in sx0..=sx1 {
                box_pixels.push(ly * tw + lx, dx0 + lane_offset(lx, sx0), dy);
            }
        }
        box_pixels.alphas(p);
        for q in 0..box_pixels.len {
            let idx = box_pixels.pixel[q] as usize;
            let alpha = box_pixels.alpha[q];
            if alpha == 0.0 || k as u32 >= n[idx] {
                continue;
            }
            let (gauss, raw) = (box_pixels.gauss[q], box_pixels.raw[q]);
            let (dx, dy) = (box_pixels.dx[q], box_pixels.dy[q]);
            let tk = t[idx] / (1.0 - alpha);
            t[idx] = tk;
            let wk = alpha * tk;
            let gp = &g[idx * ch..(idx + 1) * ch];
            let bp = &mut behind[idx * ch..(idx + 1) * ch];
            let mut d_alpha = 0.0;
            for ((&fc, &gc), bc) in fe.iter().zip(gp).zip(bp.iter_mut()) {
                d_alpha += (fc - *bc) * gc;
                *bc = alpha * fc + (1.0 - alpha) * *bc;
            }
            d_alpha *= tk;
            for (s, &gc) in slot[GRAD_HEAD..].iter_mut().zip(&gp[..channels]) {
                *s += wk * gc;
            }
            slot[2] += wk * gp[channels + 1];
            if raw < MAX_ALPHA {
                slot[6] += gauss * d_alpha;
                let d_power = -alpha * d_alpha;
                slot[0] -= d_power * (a * dx + b * dy);
                slot[1] -= d_power * (b * dx + c * dy);
                slot[3] += 0.5 * dx * dx * d_power;
                slot[4] += dx * dy * d_power;
                slot[5] += 0.5 * dy * dy * d_power;
            }
        }
    }
    slots
}

#[cfg(test)]
mod tests {
    use super::super::project::{half_extent, support_power};
    use super::*;

    /// Uniform numbers in `[0, 1)` from a fixed seed (a linear congruential generator).
    fn uniform(seed: u64) -> impl FnMut() -> f32 {
        let mut state = seed;
        move || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 40) as f32 / (1u64 << 24) as f32
        }
    }

    /// A random positive-definite 2D covariance `[xx, xy, yy]` (0.2 to 6.2 px along random
    /// axes, with the dilation) and its conic.
    fn random_covariance(rand: &mut impl FnMut() -> f32) -> ([f32; 3], [f32; 3]) {
        let (sx, sy, t) = (0.2 + 6.0 * rand(), 0.2 + 6.0 * rand(), 6.3 * rand());
        let (cs, sn) = (t.cos(), t.sin());
        let cov = [
            cs * cs * sx * sx + sn * sn * sy * sy + 0.3,
            cs * sn * (sx * sx - sy * sy),
            sn * sn * sx * sx + cs * cs * sy * sy + 0.3,
        ];
        let det = cov[0] * cov[2] - cov[1] * cov[1];
        (cov, [cov[2] / det, -cov[1] / det, cov[0] / det])
    }

    /// The bounding box of a Gaussian's drawn support (`Projected::pixel_rect`) holds every
    /// pixel that `alpha_at` draws, for opaque Gaussians and for faint ones, whose box is
    /// smaller than the 3-sigma one.
    #[test]
    fn pixel_rects_contain_every_drawn_pixel() {
        let mut rand = uniform(987);
        let (mut drawn, mut smaller) = (0, 0);
        for _ in 0..400 {
            let (cov, conic) = random_covariance(&mut rand);
            // Opacities from 0.0002 (never drawn) to 1, evenly in the logarithm.
            let opacity = (10.0f32).powf(-3.7 * rand());
            let support = support_power(opacity);
            let p = Projected {
                u: 32.0 + rand(),
                v: 32.0 + rand(),
                depth: 1.0,
                conic,
                opacity,
                support,
                extent: [half_extent(cov[0], support), half_extent(cov[2], support)],
            };
            if p.extent[0] < 3.0 * cov[0].sqrt() {
                smaller += 1;
            }
            let rect = p.pixel_rect(64, 64);
            for y in 0..64usize {
                for x in 0..64usize {
                    let (dx, dy) = (x as f32 + 0.5 - p.u, y as f32 + 0.5 - p.v);
                    if alpha_at(&p, dx, dy).0 > 0.0 {
                        drawn += 1;
                        let [x0, y0, x1, y1] = rect.expect("a drawn pixel outside an empty box");
                        assert!(
                            (x0..=x1).contains(&x) && (y0..=y1).contains(&y),
                            "({x}, {y}) outside {rect:?} at opacity {opacity}"
                        );
                    }
                }
            }
        }
        assert!(
            drawn > 10_000 && smaller > 100,
            "{drawn} drawn, {smaller} smaller boxes"
        );
    }

    /// Packed, every pixel of a Gaussian's row spans gets the alpha, Gaussian value and
    /// unclamped alpha that its row's `RowAlphas` gives it, to the bit.
    #[test]
    fn packed_pixels_have_their_rows_alphas() {
        let mut rand = uniform(4321);
        let mut pixels = BoxPixels::new();
        let (mut packed, mut drawn) = (0, 0);
        for _ in 0..200 {
            let (_, conic) = random_covariance(&mut rand);
            let opacity = 0.003 + rand();
            let p = Projected {
                u: 8.0 + 16.0 * rand(),
                v: 8.0 + 16.0 * rand(),
                depth: 1.0,
                conic,
                opacity,
                support: support_power(opacity),
                extent: [0.0; 2],
            };
            // The tile at (16, 16), where the Gaussian's centre is near its top left.
            let (x0, y0) = (TILE_SIZE, TILE_SIZE);
            let rows = RowSpans::of(&p);
            let mut expected = Vec::new();
            pixels.clear();
            for ly in 0..TILE_SIZE {
                let dy = (y0 + ly) as f32 + 0.5 - p.v;
                let Some((first, last)) = rows.span(dy, x0, 0, TILE_SIZE - 1) else {
                    continue;
                };
                let dx = (x0 + first) as f32 + 0.5 - p.u;
                let row = RowAlphas::of(&p, (first, last), dx, dy);
                for lx in first..=last {
                    pixels.push(ly * TILE_SIZE + lx, dx + lane_offset(lx, first), dy);
                    expected.push([row.alpha[lx], row.gauss[lx], row.raw[lx]].map(f32::to_bits));
                }
            }
            pixels.alphas(&p);
            assert_eq!(pixels.len, expected.len());
            for (q, want) in expected.iter().enumerate() {
                let got = [pixels.alpha[q], pixels.gauss[q], pixels.raw[q]].map(f32::to_bits);
                assert_eq!(&got, want, "pixel {} of the list", q);
                drawn += usize::from(pixels.alpha[q] != 0.0);
            }
            packed += pixels.len;
        }
        assert!(
            packed > 5_000 && drawn > 2_000,
            "{packed} packed, {drawn} drawn"
        );
    }

    /// `RowSpans::span` never drops a pixel that `alpha_at` would draw.
    #[test]
    fn row_spans_contain_every_drawn_pixel() {
        let mut rand = uniform(12345);
        let mut drawn = 0;
        for _ in 0..300 {
            let (_, conic) = random_covariance(&mut rand);
            let opacity = 0.003 + rand();
            let p = Projected {
                u: 20.0 + 10.0 * rand(),
                v: 0.0,
                depth: 1.0,
                conic,
                opacity,
                support: support_power(opacity),
                extent: [0.0; 2],
            };
            for row in -25..=25 {
                let dy = row as f32 + 0.5 * rand();
                // Four tiles side by side, the Gaussian's centre in the second.
                for x0 in (0..4).map(|t| t * TILE_SIZE) {
                    let span = RowSpans::of(&p).span(dy, x0, 0, TILE_SIZE - 1);
                    for lx in 0..TILE_SIZE {
                        if alpha_at(&p, (x0 + lx) as f32 + 0.5 - p.u, dy).0 > 0.0 {
                            drawn += 1;
                            let (a, b) = span.expect("a drawn pixel in a rejected row");
                            assert!(a <= lx && lx <= b, "{x0} + {lx} outside {a}..={b}");
                        }
                    }
                }
            }
        }
        assert!(drawn > 10_000, "{drawn}");
    }
}
