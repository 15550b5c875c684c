//! Rasterization and shading of one band of rows.
//!
//! Takes the binned [`ScreenTri`]s of a band (chunk by chunk, in mesh order)
//! and the band's slices of the output images, and fills them: exact integer
//! edge functions with a top-left fill rule, sampled at pixel centers
//! (integer coordinates), a z-buffer on `1/z`, perspective-correct gray and
//! texture coordinates, bilinear texture sampling with repeat addressing.
//!
//! While a band is drawn, its depth slice holds `1/z` (0 = empty); the band
//! is finished by turning it into metric depth.

use super::setup::{Chunk, ScreenTri, NO_TEXTURE};
use super::view::{floor_i64, SUBPIXEL};
use crate::map::GrayTexture;
use crate::render::NO_DEPTH;

/// Draws band `band` (rows `y0 .. y0 + rows`) of a `width`-wide image into
/// `gray` and `depth_m` (the band's rows only).
pub(super) fn draw_band(
    band: usize,
    y0: usize,
    width: usize,
    chunks: &[Chunk],
    textures: &[GrayTexture],
    gray: &mut [f32],
    depth_m: &mut [f32],
) {
    gray.fill(0.0);
    depth_m.fill(0.0);
    let rows = gray.len() / width.max(1);
    let mut target = Band {
        y0,
        rows,
        width,
        gray,
        inv_z: depth_m,
    };
    for chunk in chunks {
        if let Some(bin) = chunk.bins.get(band) {
            for &t in bin {
                if let Some(tri) = chunk.tris.get(t as usize) {
                    target.draw(tri, textures);
                }
            }
        }
    }
    for d in target.inv_z.iter_mut() {
        *d = if *d > 0.0 { 1.0 / *d } else { NO_DEPTH };
    }
}

/// The output rows of one band.
struct Band<'a> {
    y0: usize,
    rows: usize,
    width: usize,
    gray: &'a mut [f32],
    /// `1/z` during drawing, 0 where empty.
    inv_z: &'a mut [f32],
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
    #[inline]
    fn draw(&mut self, tri: &ScreenTri, textures: &[GrayTexture]) {
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
        let (y0, width) = (self.y0, self.width);
        let (gray, inv_z_buf) = (&mut *self.gray, &mut *self.inv_z);
        for_each_covered(tri, y0, y_hi, |col, row_y, w1, w2| {
            let inv_z = iz.0 + w1 * iz.1 + w2 * iz.2;
            let idx = (row_y - y0) * width + col;
            let (Some(d), Some(g_out)) = (inv_z_buf.get_mut(idx), gray.get_mut(idx)) else {
                return;
            };
            if (inv_z as f32) > *d {
                *d = inv_z as f32;
                let z = 1.0 / inv_z;
                let mut g = (gz.0 + w1 * gz.1 + w2 * gz.2) * z;
                if let Some(tex) = texture {
                    let u = (uz.0 + w1 * uz.1 + w2 * uz.2) * z;
                    let v = (vz.0 + w1 * vz.1 + w2 * vz.2) * z;
                    g *= sample_repeat(tex, u, v) * (1.0 / 255.0);
                }
                *g_out = g.clamp(0.0, 255.0) as f32;
            }
        });
    }
}

/// Calls `f(x, y, w1, w2)` for every pixel center of rows `y_lo..=y_hi`
/// covered by `tri` under the top-left rule, with the barycentric weights of
/// vertices 1 and 2 at that center.
#[inline(always)]
fn for_each_covered(
    tri: &ScreenTri,
    y_lo: usize,
    y_hi: usize,
    mut f: impl FnMut(usize, usize, f64, f64),
) {
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
    let [b0, b1, b2] = [e[0].bias, e[1].bias, e[2].bias];
    for row_y in y_lo..=y_hi {
        let (mut e0, mut e1, mut e2) = (e[0].row, e[1].row, e[2].row);
        for col in bx0..=bx1 {
            if ((e0 - b0) | (e1 - b1) | (e2 - b2)) >= 0 {
                f(col, row_y, e1 as f64 * inv_area, e2 as f64 * inv_area);
            }
            e0 += e[0].step_x;
            e1 += e[1].step_x;
            e2 += e[2].step_x;
        }
        for edge in &mut e {
            edge.row += edge.step_y;
        }
    }
}

/// Bilinear sample of `tex` at texture coordinates `(u, v)` with repeat
/// addressing. Texel `(i, j)` has its center at `((i + 0.5) / width,
/// (j + 0.5) / height)`, as GPU samplers do.
#[inline]
pub(super) fn sample_repeat(tex: &GrayTexture, u: f64, v: f64) -> f64 {
    let (w, h) = (i64::from(tex.width), i64::from(tex.height));
    let tx = u * w as f64 - 0.5;
    let ty = v * h as f64 - 0.5;
    let (fx0, fy0) = (floor_i64(tx), floor_i64(ty));
    let (ax, ay) = (tx - fx0 as f64, ty - fy0 as f64);
    let x0 = fx0.rem_euclid(w) as usize;
    let y0 = fy0.rem_euclid(h) as usize;
    let x1 = if x0 + 1 == w as usize { 0 } else { x0 + 1 };
    let y1 = if y0 + 1 == h as usize { 0 } else { y0 + 1 };
    let wu = w as usize;
    let t = |x: usize, y: usize| f64::from(tex.texels.get(y * wu + x).copied().unwrap_or(0.0));
    let top = t(x0, y0) + ax * (t(x1, y0) - t(x0, y0));
    let bottom = t(x0, y1) + ax * (t(x1, y1) - t(x0, y1));
    top + ay * (bottom - top)
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
            bbox: [lo(x), hi(x), lo(y), hi(y)],
        })
    }

    /// A jittered grid whose vertices often sit exactly on pixel centers and
    /// whose edges pass exactly through pixel centers (horizontal, vertical
    /// and diagonal): every pixel must be covered exactly once.
    #[test]
    fn shared_edges_cover_each_pixel_exactly_once() {
        let n = 8;
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
                grid[j * (n + 1) + i] = [-4.0 + i as f64 * 9.0 + jx, -4.0 + j as f64 * 9.0 + jy];
            }
        }
        let mut count = vec![0u32; 64 * 64];
        let mut draw = |p: [[f64; 2]; 3]| {
            if let Some(t) = tri(p) {
                for_each_covered(&t, 0, 63, |x, y, _, _| count[y * 64 + x] += 1);
            }
        };
        for j in 0..n {
            for i in 0..n {
                let g = |a: usize, b: usize| grid[(j + b) * (n + 1) + i + a];
                draw([g(0, 0), g(1, 0), g(1, 1)]);
                draw([g(0, 0), g(1, 1), g(0, 1)]);
            }
        }
        // The grid spans [-4, 68]: the whole 64x64 image.
        for (i, &c) in count.iter().enumerate() {
            assert_eq!(c, 1, "pixel ({}, {}) covered {c} times", i % 64, i / 64);
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
