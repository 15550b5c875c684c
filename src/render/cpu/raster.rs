//! Rasterization and shading of one band of rows.
//!
//! Takes the binned [`ScreenTri`]s of a band (chunk by chunk, the chunks
//! set up in this render only) and the band's slices of the output images,
//! and fills them: exact integer edge functions with a top-left fill rule,
//! sampled at pixel centers (integer coordinates), a z-buffer on `1/z` with
//! ties won by the lower mesh triangle number (as drawing in mesh order
//! would), perspective-correct gray and texture coordinates, bilinear
//! texture sampling with repeat addressing. With a far limit, a pixel
//! whose `1/z` is below `1/far` is not drawn.
//!
//! While a band is drawn, its depth slice holds `1/z` (0 = empty); the band
//! is finished by turning it into metric depth.

use std::sync::atomic::{AtomicBool, Ordering};

use super::setup::{ScreenTri, SetupSlot, BAND_ROWS, NO_TEXTURE};
use super::view::SUBPIXEL;
use crate::map::GrayTexture;
use crate::render::tiles::{band_tiles, TILE_PX};
use crate::render::NO_DEPTH;

// A band is whole rows of occlusion tiles.
const _: () = assert!(BAND_ROWS % TILE_PX == 0);

/// Draws band `band` (rows `band * BAND_ROWS ..`) of a `width`-wide image
/// into `gray` and `depth_m` (the band's rows only), with `order` (as many
/// pixels) as scratch for the depth tie-break: the triangles set up in
/// `slots` (one chunk each, in the batch's order), marking in `seen` (when
/// given, per setup cluster of every chunk) each cluster of which a triangle wins a pixel's
/// depth test; pixels with `1/z` below `min_inv_z`
/// are not drawn. A render may draw a band in several passes (one per
/// batch of chunks): `first` clears it, `last` turns its `1/z` into metric
/// depth; in between `depth_m` holds `1/z`, and `tiles`, when given, gets
/// the band's row of occlusion tiles.
#[allow(clippy::too_many_arguments)]
pub(super) fn draw_band(
    band: usize,
    width: usize,
    min_inv_z: f32,
    (first, last): (bool, bool),
    (slots, seen): (&[SetupSlot], Option<&[AtomicBool]>),
    textures: &[GrayTexture],
    gray: &mut [f32],
    depth_m: &mut [f32],
    order: &mut [u32],
    tiles: Option<&mut [f32]>,
) {
    if first {
        gray.fill(0.0);
        depth_m.fill(0.0);
        // With depth 0 (empty) no triangle number is below 0: no tie to win.
        order.fill(0);
    }
    let rows = gray.len() / width.max(1);
    let mut target = Band {
        y0: band * BAND_ROWS,
        rows,
        width,
        min_inv_z,
        gray,
        inv_z: depth_m,
        order,
    };
    for chunk in slots {
        let Some(bin) = chunk.bins.get(band) else {
            continue;
        };
        for &t in bin {
            if let Some(tri) = chunk.tris.get(t as usize) {
                if target.draw(tri, textures) {
                    let cluster = chunk.tri_cluster.get(t as usize).copied().unwrap_or(0);
                    if let Some(flag) =
                        seen.and_then(|s| s.get(chunk.first_cluster + usize::from(cluster)))
                    {
                        flag.store(true, Ordering::Relaxed);
                    }
                }
            }
        }
    }
    if last {
        for d in target.inv_z.iter_mut() {
            *d = if *d > 0.0 { 1.0 / *d } else { NO_DEPTH };
        }
    } else if let Some(tiles) = tiles {
        band_tiles(target.inv_z, width, tiles);
    }
}

/// The output rows of one band.
struct Band<'a> {
    y0: usize,
    rows: usize,
    width: usize,
    /// `1/far`: pixels with a smaller `1/z` are not drawn.
    min_inv_z: f32,
    gray: &'a mut [f32],
    /// `1/z` during drawing, 0 where empty.
    inv_z: &'a mut [f32],
    /// Mesh triangle number of the triangle drawn at each pixel.
    order: &'a mut [u32],
}

/// One edge function `E(p) = dx (py - ay) - dy (px - ax)` in fixed point.
#[derive(Clone, Copy)]
struct Edge {
    /// Value at the first pixel center of the current row.
    row: i64,
    /// Increment per pixel along x.
    step_x: i64,
    /// Increment per row.
    step_y: i64,
    /// 0 for top-left edges, 1 otherwise: the pixel is inside when
    /// `E - bias >= 0`, so pixels exactly on an edge belong to one triangle.
    bias: i64,
}

impl Edge {
    #[inline]
    fn new(ax: i64, ay: i64, bx: i64, by: i64, px: i64, py: i64) -> Self {
        let (dx, dy) = (bx - ax, by - ay);
        let top_left = dy < 0 || (dy == 0 && dx > 0);
        Self {
            row: dx * (py - ay) - dy * (px - ax),
            step_x: -dy * SUBPIXEL,
            step_y: dx * SUBPIXEL,
            bias: i64::from(!top_left),
        }
    }
}

impl Band<'_> {
    /// Draws `tri`; true when it won the depth test on some pixel.
    #[inline]
    fn draw(&mut self, tri: &ScreenTri, textures: &[GrayTexture]) -> bool {
        let plane = |a: [f32; 3]| {
            let a0 = f64::from(a[0]);
            (a0, f64::from(a[1]) - a0, f64::from(a[2]) - a0)
        };
        let iz = plane(tri.inv_z);
        let gz = plane(tri.gray_z);
        let (uz, vz) = (plane(tri.u_z), plane(tri.v_z));
        let texture = if tri.texture == NO_TEXTURE {
            None
        } else {
            textures.get(tri.texture as usize)
        };
        let y_hi = self.y0 + self.rows - 1;
        let (y0, width, min_inv_z) = (self.y0, self.width, self.min_inv_z);
        let (gray, inv_z_buf, order_buf) = (&mut *self.gray, &mut *self.inv_z, &mut *self.order);
        let order = tri.order;
        let mut won = false;
        for_each_span(tri, y0, y_hi, |span, dw1, dw2| {
            let start = (span.y - y0) * width + span.x_start;
            let end = (span.y - y0) * width + span.x_end;
            let (Some(depth_run), Some(gray_run), Some(order_run)) = (
                inv_z_buf.get_mut(start..=end),
                gray.get_mut(start..=end),
                order_buf.get_mut(start..=end),
            ) else {
                return;
            };
            let (mut w1, mut w2) = (span.w1, span.w2);
            for ((d, g_out), o) in depth_run.iter_mut().zip(gray_run).zip(order_run) {
                let inv_z = iz.0 + w1 * iz.1 + w2 * iz.2;
                let inv_z32 = inv_z as f32;
                if (inv_z32 > *d || (inv_z32 == *d && order < *o)) && inv_z32 >= min_inv_z {
                    *d = inv_z32;
                    *o = order;
                    won = true;
                    let z = 1.0 / inv_z;
                    let mut g = (gz.0 + w1 * gz.1 + w2 * gz.2) * z;
                    if let Some(tex) = texture {
                        let u = (uz.0 + w1 * uz.1 + w2 * uz.2) * z;
                        let v = (vz.0 + w1 * vz.1 + w2 * vz.2) * z;
                        g *= sample_repeat(tex, u, v) * (1.0 / 255.0);
                    }
                    *g_out = g.clamp(0.0, 255.0) as f32;
                }
                w1 += dw1;
                w2 += dw2;
            }
        });
        won
    }
}

/// A run of covered pixel centers in one row, with the barycentric weights
/// of vertices 1 and 2 at its first pixel.
struct Span {
    y: usize,
    x_start: usize,
    /// Last covered column (inclusive).
    x_end: usize,
    w1: f64,
    w2: f64,
}

/// Bounding boxes at most this wide are scanned pixel by pixel; wider ones
/// get their spans from the edge equations (three divisions per row).
const SCAN_MAX_WIDTH_PX: usize = 12;

/// Calls `f(span, dw1, dw2)` for every row of `y_lo..=y_hi` where `tri`
/// covers pixel centers (top-left rule); `dw1, dw2` are the barycentric
/// steps per pixel along x. Triangles are convex, so each row is one span.
#[inline(always)]
fn for_each_span(tri: &ScreenTri, y_lo: usize, y_hi: usize, mut f: impl FnMut(&Span, f64, f64)) {
    let [bx0, bx1, by0, by1] = tri.bbox.map(usize::from);
    let (y_lo, y_hi) = (by0.max(y_lo), by1.min(y_hi));
    if y_lo > y_hi {
        return;
    }
    let x = tri.x.map(i64::from);
    let y = tri.y.map(i64::from);
    let area2 = (x[1] - x[0]) * (y[2] - y[0]) - (y[1] - y[0]) * (x[2] - x[0]);
    if area2 <= 0 {
        return;
    }
    let inv_area = 1.0 / area2 as f64;
    let (px, py) = (bx0 as i64 * SUBPIXEL, y_lo as i64 * SUBPIXEL);
    // Edge k is opposite vertex k; its value over the doubled area is the
    // barycentric weight of vertex k.
    let mut e = [
        Edge::new(x[1], y[1], x[2], y[2], px, py),
        Edge::new(x[2], y[2], x[0], y[0], px, py),
        Edge::new(x[0], y[0], x[1], y[1], px, py),
    ];
    let (dw1, dw2) = (e[1].step_x as f64 * inv_area, e[2].step_x as f64 * inv_area);
    let last = (bx1 - bx0) as i64;
    let narrow = bx1 - bx0 < SCAN_MAX_WIDTH_PX;
    for row_y in y_lo..=y_hi {
        let run = if narrow {
            scan_row(&e, last)
        } else {
            solve_row(&e, last)
        };
        if let Some((k0, k1)) = run {
            let e1 = e[1].row + e[1].step_x * k0;
            let e2 = e[2].row + e[2].step_x * k0;
            let span = Span {
                y: row_y,
                x_start: bx0 + k0 as usize,
                x_end: bx0 + k1 as usize,
                w1: e1 as f64 * inv_area,
                w2: e2 as f64 * inv_area,
            };
            f(&span, dw1, dw2);
        }
        for edge in &mut e {
            edge.row += edge.step_y;
        }
    }
}

/// The covered offsets `k0..=k1` (from the row start, `0..=last`) found by
/// testing every pixel center.
#[inline(always)]
fn scan_row(e: &[Edge; 3], last: i64) -> Option<(i64, i64)> {
    let mut v = e.map(|edge| edge.row - edge.bias);
    let mut first = None;
    for k in 0..=last {
        if (v[0] | v[1] | v[2]) >= 0 {
            first.get_or_insert(k);
        } else if let Some(k0) = first {
            return Some((k0, k - 1));
        }
        for (value, edge) in v.iter_mut().zip(e) {
            *value += edge.step_x;
        }
    }
    first.map(|k0| (k0, last))
}

/// The covered offsets `k0..=k1` (from the row start, `0..=last`) solved
/// from the edge equations: `row - bias + step_x * k >= 0` for all edges.
/// Exactly the pixels [`scan_row`] finds.
#[inline(always)]
fn solve_row(e: &[Edge; 3], last: i64) -> Option<(i64, i64)> {
    let (mut lo, mut hi) = (0i64, last);
    for edge in e {
        let r = edge.row - edge.bias;
        let s = edge.step_x;
        if s > 0 {
            if r < 0 {
                // k >= ceil(-r / s)
                lo = lo.max((-r + s - 1) / s);
            }
        } else if s < 0 {
            if r < 0 {
                return None;
            }
            // k <= floor(r / -s)
            hi = hi.min(r / -s);
        } else if r < 0 {
            return None;
        }
    }
    (lo <= hi).then_some((lo, hi))
}

/// Bilinear sample of `tex` at texture coordinates `(u, v)` with repeat
/// addressing. Texel `(i, j)` has its center at `((i + 0.5) / width,
/// (j + 0.5) / height)`, as GPU samplers do.
#[inline]
pub(super) fn sample_repeat(tex: &GrayTexture, u: f64, v: f64) -> f64 {
    let (x0, x1, ax) = wrap_axis(u, tex.width);
    let (y0, y1, ay) = wrap_axis(v, tex.height);
    let w = tex.width as usize;
    let t = |x: usize, y: usize| f64::from(tex.texels.get(y * w + x).copied().unwrap_or(0.0));
    let top = t(x0, y0) + ax * (t(x1, y0) - t(x0, y0));
    let bottom = t(x0, y1) + ax * (t(x1, y1) - t(x0, y1));
    top + ay * (bottom - top)
}

/// The two texels (repeat addressing) around texture coordinate `t` on an
/// axis of `n` texels, and the weight of the second. Branch-free apart
/// from selects: this runs once per textured pixel.
#[inline(always)]
fn wrap_axis(t: f64, n: u32) -> (usize, usize, f64) {
    // Into one period [0, 1): truncation, then a select for negatives.
    // (Saturating casts keep absurd coordinates in range; they sample
    // some texel instead of panicking.)
    let mut frac = t - (t as i64) as f64;
    if frac < 0.0 {
        frac += 1.0;
    }
    // x + 1 is in [0.5, n + 0.5): positive, so truncation is floor.
    let x1 = frac * f64::from(n) + 0.5;
    let k = x1 as i64;
    let a = x1 - k as f64;
    let last = n as usize - 1;
    let i0 = if k == 0 {
        last
    } else {
        (k as usize - 1).min(last)
    };
    let i1 = if i0 == last { 0 } else { i0 + 1 };
    (i0, i1, a)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tri(p: [[f64; 2]; 3]) -> Option<ScreenTri> {
        let s = SUBPIXEL as f64;
        let mut x = p.map(|q| (q[0] * s).round() as i32);
        let mut y = p.map(|q| (q[1] * s).round() as i32);
        let a = (x[1] - x[0]) as i64 * (y[2] - y[0]) as i64
            - (y[1] - y[0]) as i64 * (x[2] - x[0]) as i64;
        if a == 0 {
            return None;
        }
        if a < 0 {
            x.swap(1, 2);
            y.swap(1, 2);
        }
        let lo = |v: [i32; 3]| {
            (v.iter().min().copied().unwrap_or(0) as f64 / s)
                .ceil()
                .max(0.0) as u16
        };
        let hi = |v: [i32; 3]| {
            (v.iter().max().copied().unwrap_or(0) as f64 / s)
                .floor()
                .min(63.0) as u16
        };
        Some(ScreenTri {
            x,
            y,
            inv_z: [1.0; 3],
            gray_z: [0.0; 3],
            u_z: [0.0; 3],
            v_z: [0.0; 3],
            texture: NO_TEXTURE,
            order: 0,
            bbox: [lo(x), hi(x), lo(y), hi(y)],
        })
    }

    /// A jittered grid whose vertices often sit exactly on pixel centers and
    /// whose edges pass exactly through pixel centers (horizontal, vertical
    /// and diagonal): every pixel must be covered exactly once, with cells
    /// narrow enough to be scanned and wide enough to be solved.
    #[test]
    fn shared_edges_cover_each_pixel_exactly_once() {
        for (n, spacing) in [(8usize, 9.0f64), (4, 21.0)] {
            let mut state = 12345u64;
            let mut rnd = || {
                state = state
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                ((state >> 33) % 5) as f64 * 0.5 - 1.0
            };
            let mut grid = vec![[0.0f64; 2]; (n + 1) * (n + 1)];
            for j in 0..=n {
                for i in 0..=n {
                    let inner = i > 0 && i < n && j > 0 && j < n;
                    let (jx, jy) = if inner { (rnd(), rnd()) } else { (0.0, 0.0) };
                    grid[j * (n + 1) + i] = [
                        -4.0 + i as f64 * spacing + jx,
                        -4.0 + j as f64 * spacing + jy,
                    ];
                }
            }
            let mut count = vec![0u32; 64 * 64];
            let mut draw = |p: [[f64; 2]; 3]| {
                if let Some(t) = tri(p) {
                    for_each_span(&t, 0, 63, |span, _, _| {
                        for x in span.x_start..=span.x_end {
                            count[span.y * 64 + x] += 1;
                        }
                    });
                }
            };
            for j in 0..n {
                for i in 0..n {
                    let g = |a: usize, b: usize| grid[(j + b) * (n + 1) + i + a];
                    draw([g(0, 0), g(1, 0), g(1, 1)]);
                    draw([g(0, 0), g(1, 1), g(0, 1)]);
                }
            }
            // The grid covers the whole 64x64 image.
            for (i, &c) in count.iter().enumerate() {
                assert_eq!(
                    c,
                    1,
                    "spacing {spacing}: pixel ({}, {}) covered {c} times",
                    i % 64,
                    i / 64
                );
            }
        }
    }

    #[test]
    fn solved_spans_match_scanned_spans() {
        let mut state = 99u64;
        let mut rnd = |m: i64| {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((state >> 33) as i64 % (2 * m + 1)) - m
        };
        for _ in 0..20_000 {
            let p = [0; 6].map(|_| rnd(40 * SUBPIXEL));
            let (px, py) = (rnd(50) * SUBPIXEL, rnd(50) * SUBPIXEL);
            let e = [
                Edge::new(p[0], p[1], p[2], p[3], px, py),
                Edge::new(p[2], p[3], p[4], p[5], px, py),
                Edge::new(p[4], p[5], p[0], p[1], px, py),
            ];
            let last = rnd(60).abs();
            assert_eq!(
                scan_row(&e, last),
                solve_row(&e, last),
                "{p:?} {px} {py} {last}"
            );
        }
    }

    #[test]
    fn texel_centers_sample_exactly_and_wrap() {
        let tex = GrayTexture {
            width: 4,
            height: 2,
            texels: vec![0.0, 10.0, 20.0, 30.0, 100.0, 110.0, 120.0, 130.0],
        };
        // Texel (1, 0) center.
        assert_eq!(sample_repeat(&tex, 1.5 / 4.0, 0.5 / 2.0), 10.0);
        // Texel (2, 1) center, and the same point one period away.
        assert_eq!(sample_repeat(&tex, 2.5 / 4.0, 1.5 / 2.0), 120.0);
        assert_eq!(
            sample_repeat(&tex, 1.0 + 2.5 / 4.0, -1.0 + 1.5 / 2.0),
            120.0
        );
        // Halfway between texels (3, 0) and (0, 0) across the wrap.
        assert_eq!(sample_repeat(&tex, 1.0, 0.25), 15.0);
    }
}
