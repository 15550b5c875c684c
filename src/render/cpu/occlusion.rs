//! Occlusion culling for the CPU rasterizer, exact, of whole chunks and of
//! single triangles.
//!
//! Takes the chunks that passed the frustum test and the depth buffer as
//! the render draws it; decides which chunks, and which triangles of the
//! chunks set up, are hidden behind what has already been drawn. The
//! visible chunks are ordered nearest first (by the nearest camera depth of
//! their box) and drawn in batches: the first [`first_batch`] chunks, then
//! batches of twice as many *drawn* chunks each time (the chunks found
//! hidden on the way do not count), at most [`MAX_BATCHES`] in all (the
//! last takes the rest). After each batch but the last every 16 x
//! 16-pixel tile of the image (one tile row per raster band) gets the
//! farthest depth drawn in it (as the smallest `1/z`, 0 when a pixel of it
//! is still empty); the raster bands compute their own tiles as they
//! finish. Then, in the next batch:
//!
//! - a chunk is skipped when, over every tile its box's projection touches
//!   (padded by 2 pixels), that farthest depth is nearer than the box's
//!   nearest point (a box reaching behind the near plane is never skipped);
//! - of the chunks set up, a projected triangle is dropped when, over every
//!   tile its pixel bounds touch, that farthest depth is nearer than its
//!   nearest vertex (depth over a triangle lies between its vertices'
//!   depths, and the rasterizer's interpolated `1/z`, rounded to `f32`, never
//!   exceeds its largest vertex value).
//!
//! Both comparisons have a relative margin far above `f32` rounding; the
//! z-buffer only gets nearer, so no pixel of what is dropped could pass the
//! depth test, then or later, and the image is the same, bit for bit, as
//! without the cull (the tie-break by mesh triangle number makes the
//! drawing order irrelevant).
//!
//! All scratch is sized at construction (per chunk) or on the first render
//! of an image size (per tile), and reused.

use super::view::{View, NEAR_M};
use crate::render::chunks::MeshChunk;

/// Tile edge, pixels.
pub(super) const TILE_PX: usize = 16;
/// Most batches of one render; the first is never culled.
pub(super) const MAX_BATCHES: usize = 8;
/// The first batch holds this share of the visible chunks...
const FIRST_BATCH_DIVISOR: usize = 32;
/// ...and at least this many.
const FIRST_BATCH_MIN: usize = 4;
/// Relative margin of the depth comparison.
const MARGIN: f32 = 1e-3;
/// Padding of the boxes, meters (as the frustum test's).
const BOX_PAD_M: f32 = 1e-3;
/// Padding of the projected rectangles, pixels.
const RECT_PAD_PX: f32 = 2.0;

/// Per-render scratch of the occlusion cull. See the module docs.
#[derive(Debug, Default)]
pub(super) struct Occlusion {
    /// Per chunk: `1/z` of its box's nearest point (0: not occludable).
    near_inv_z: Vec<f32>,
    /// Per chunk: the tiles its box covers, `[x0, y0, x1, y1]` inclusive.
    rect: Vec<[u16; 4]>,
    /// The visible chunks, nearest first.
    pub order: Vec<u32>,
    /// Per tile, the smallest `1/z` drawn (0 where a pixel is empty).
    tile_min_inv_z: Vec<f32>,
    tiles_x: usize,
    tiles_y: usize,
}

impl Occlusion {
    /// Scratch for `chunks` chunks.
    pub fn new(chunks: usize) -> Self {
        Self {
            near_inv_z: vec![0.0; chunks],
            rect: vec![[0; 4]; chunks],
            order: Vec::with_capacity(chunks),
            ..Self::default()
        }
    }

    /// Measures every visible chunk's box in `view` and orders the visible
    /// chunks nearest first.
    pub fn prepare(&mut self, chunks: &[MeshChunk], visible: &[bool], view: &View) {
        self.tiles_x = view.width.div_ceil(TILE_PX);
        self.tiles_y = view.height.div_ceil(TILE_PX);
        self.tile_min_inv_z.resize(self.tiles_x * self.tiles_y, 0.0);
        self.near_inv_z.resize(chunks.len(), 0.0);
        self.rect.resize(chunks.len(), [0; 4]);
        self.order.clear();
        let (w, h) = (view.width as f32, view.height as f32);
        for (i, (chunk, &seen)) in chunks.iter().zip(visible).enumerate() {
            if !seen {
                continue;
            }
            let b = &chunk.bounds;
            self.order.push(i as u32);
            let mut near = f32::INFINITY;
            let (mut u0, mut v0, mut u1, mut v1) = (
                f32::INFINITY,
                f32::INFINITY,
                f32::NEG_INFINITY,
                f32::NEG_INFINITY,
            );
            for corner in 0..8 {
                let pick = |k: usize, bit: usize| {
                    if corner >> bit & 1 == 0 {
                        b.min_m[k] - BOX_PAD_M
                    } else {
                        b.max_m[k] + BOX_PAD_M
                    }
                };
                let p = view.camera_point([pick(0, 0), pick(1, 1), pick(2, 2)]);
                near = near.min(p.z);
                if p.z > NEAR_M {
                    let (u, v) = view.pixel_f32(p);
                    u0 = u0.min(u);
                    v0 = v0.min(v);
                    u1 = u1.max(u);
                    v1 = v1.max(v);
                }
            }
            let (Some(inv), Some(r)) = (self.near_inv_z.get_mut(i), self.rect.get_mut(i)) else {
                continue;
            };
            if !(near > NEAR_M && near.is_finite()) {
                *inv = 0.0;
                continue;
            }
            *inv = 1.0 / near;
            let tile = |x: f32, limit: f32| {
                ((x.clamp(0.0, limit - 1.0)) as usize / TILE_PX).min(u16::MAX as usize) as u16
            };
            *r = [
                tile(u0 - RECT_PAD_PX, w),
                tile(v0 - RECT_PAD_PX, h),
                tile(u1 + RECT_PAD_PX, w),
                tile(v1 + RECT_PAD_PX, h),
            ];
        }
        let key = |i: &u32| {
            let inv = self.near_inv_z.get(*i as usize).copied().unwrap_or(0.0);
            // Not occludable (0) first, then nearest first.
            if inv == 0.0 {
                f32::INFINITY
            } else {
                inv
            }
        };
        self.order
            .sort_unstable_by(|a, b| key(b).total_cmp(&key(a)).then(a.cmp(b)));
    }

    /// The tiles as last updated, for the triangle test.
    pub fn tiles(&self) -> TileDepth<'_> {
        TileDepth {
            min_inv_z: &self.tile_min_inv_z,
            tiles_x: self.tiles_x,
        }
    }

    /// The tiles, one row (of `tiles_x`) per raster band, for the bands to
    /// fill, and the row length.
    pub fn tile_rows_mut(&mut self) -> (&mut [f32], usize) {
        (&mut self.tile_min_inv_z, self.tiles_x.max(1))
    }

    /// Whether chunk `i` is hidden behind the tiles as last updated.
    pub fn hidden(&self, i: usize) -> bool {
        let (Some(&inv), Some(&[x0, y0, x1, y1])) = (self.near_inv_z.get(i), self.rect.get(i))
        else {
            return false;
        };
        if inv == 0.0 {
            return false;
        }
        let limit = inv * (1.0 + MARGIN);
        (y0 as usize..=y1 as usize).all(|ty| {
            (x0 as usize..=x1 as usize).all(|tx| {
                self.tile_min_inv_z
                    .get(ty * self.tiles_x + tx)
                    .is_some_and(|&t| t > limit)
            })
        })
    }
}

/// Chunks in the first batch when `visible` chunks pass the frustum test.
pub(super) fn first_batch(visible: usize) -> usize {
    (visible / FIRST_BATCH_DIVISOR).max(FIRST_BATCH_MIN)
}

/// Sets each element of `tiles` (one row of tiles) to the smallest `1/z`
/// of the `width`-wide band `inv_z` under it (0 where a pixel is empty).
pub(super) fn band_tiles(inv_z: &[f32], width: usize, tiles: &mut [f32]) {
    tiles.fill(f32::INFINITY);
    for row in inv_z.chunks_exact(width.max(1)) {
        for (tile, px) in tiles.iter_mut().zip(row.chunks(TILE_PX)) {
            *tile = px.iter().fold(*tile, |m, &d| m.min(d));
        }
    }
}

/// The farthest depth drawn per tile, read-only, for the triangle test.
#[derive(Debug, Clone, Copy)]
pub(super) struct TileDepth<'a> {
    min_inv_z: &'a [f32],
    tiles_x: usize,
}

impl TileDepth<'_> {
    /// Whether a triangle whose covered pixel centers lie in columns
    /// `x0..=x1` and rows `y0..=y1` and whose largest vertex `1/z` is
    /// `max_inv_z` is hidden behind every tile it touches.
    #[inline]
    pub fn hides(&self, [x0, x1, y0, y1]: [usize; 4], max_inv_z: f32) -> bool {
        let limit = max_inv_z * (1.0 + MARGIN);
        if !(limit > 0.0) {
            return false;
        }
        let (tx0, tx1) = (x0 / TILE_PX, x1 / TILE_PX);
        (y0 / TILE_PX..=y1 / TILE_PX).all(|ty| {
            self.min_inv_z
                .get(ty * self.tiles_x + tx0..=ty * self.tiles_x + tx1)
                .is_some_and(|row| row.iter().all(|&t| t > limit))
        })
    }
}
