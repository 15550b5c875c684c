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

use std::sync::atomic::{AtomicBool, Ordering};

use super::setup::BAND_ROWS;
use super::view::{View, NEAR_M};
use crate::render::chunks::{Aabb, MeshChunk};

/// Tile edge, pixels.
pub(super) const TILE_PX: usize = 8;
/// Most batches of one render; the first is never culled.
pub(super) const MAX_BATCHES: usize = 8;
/// The first batch holds this share of the visible chunks...
const FIRST_BATCH_DIVISOR: usize = 32;
/// ...and at least this many.
const FIRST_BATCH_MIN: usize = 4;
/// The previous render's visible chunks are drawn first when its camera
/// was less than this far away, meters.
pub(super) const COHERENT_M: f64 = 2.0;
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
    /// Per chunk, the number of its first cluster (of the setup clusters,
    /// numbered chunk by chunk); one more element for the end.
    cluster_first: Vec<u32>,
    /// Per cluster: whether a triangle of it won a pixel's depth test in
    /// the render being drawn (set by the raster bands).
    pub seen: Vec<AtomicBool>,
    /// Per cluster: whether the previous render, from nearby, marked it
    /// [`Occlusion::seen`]: the first batch of this one draws these.
    seen_before: Vec<bool>,
    /// Per chunk: whether any of its clusters is `seen_before`.
    pub chunk_seen_before: Vec<bool>,
    /// Whether `seen_before` holds any cluster.
    pub coherent: bool,
    /// Camera position of the previous render with the cull, world frame,
    /// meters.
    last_position_m: Option<[f64; 3]>,
}

impl Occlusion {
    /// Scratch for chunks of `clusters[i]` setup clusters each.
    pub fn new(clusters: impl Iterator<Item = usize>) -> Self {
        let mut cluster_first = vec![0u32];
        for n in clusters {
            let last = cluster_first.last().copied().unwrap_or(0);
            cluster_first.push(last.saturating_add(n as u32));
        }
        let chunks = cluster_first.len() - 1;
        let total = cluster_first.last().copied().unwrap_or(0) as usize;
        Self {
            near_inv_z: vec![0.0; chunks],
            rect: vec![[0; 4]; chunks],
            order: Vec::with_capacity(chunks),
            cluster_first,
            seen: (0..total).map(|_| AtomicBool::new(false)).collect(),
            seen_before: vec![false; total],
            chunk_seen_before: vec![false; chunks],
            ..Self::default()
        }
    }

    /// The first cluster number of chunk `i`.
    pub fn first_cluster(&self, i: usize) -> usize {
        self.cluster_first.get(i).copied().unwrap_or(0) as usize
    }

    /// Per cluster of chunk `i`, whether the previous render saw it.
    pub fn clusters_seen_before(&self, i: usize) -> &[bool] {
        let first = self.first_cluster(i);
        let end = self.first_cluster(i + 1).max(first);
        self.seen_before.get(first..end).unwrap_or(&[])
    }

    /// Measures every visible chunk's box in `view` and orders the visible
    /// chunks nearest first; takes the chunks the previous render saw as
    /// this one's first batch when it was made less than [`COHERENT_M`]
    /// from `position_m` (the camera's, world frame).
    pub fn prepare(
        &mut self,
        chunks: &[MeshChunk],
        visible: &[bool],
        view: &View,
        position_m: [f64; 3],
    ) {
        let near = self.last_position_m.is_some_and(|p| {
            let d2: f64 = (0..3).map(|k| (p[k] - position_m[k]).powi(2)).sum();
            d2 < COHERENT_M * COHERENT_M
        });
        self.last_position_m = Some(position_m);
        self.chunk_seen_before.resize(chunks.len(), false);
        self.coherent = false;
        for (i, (any, &in_view)) in self.chunk_seen_before.iter_mut().zip(visible).enumerate() {
            let first = self.cluster_first.get(i).copied().unwrap_or(0) as usize;
            let end = (self.cluster_first.get(i + 1).copied().unwrap_or(0) as usize).max(first);
            let (Some(before), Some(seen)) = (
                self.seen_before.get_mut(first..end),
                self.seen.get(first..end),
            ) else {
                continue;
            };
            *any = false;
            for (b, s) in before.iter_mut().zip(seen) {
                *b = near && in_view && s.swap(false, Ordering::Relaxed);
                *any |= *b;
            }
            self.coherent |= *any;
        }
        self.tiles_x = view.width.div_ceil(TILE_PX);
        self.tiles_y = view.height.div_ceil(TILE_PX);
        self.tile_min_inv_z.resize(self.tiles_x * self.tiles_y, 0.0);
        self.near_inv_z.resize(chunks.len(), 0.0);
        self.rect.resize(chunks.len(), [0; 4]);
        self.order.clear();
        for (i, (chunk, &seen)) in chunks.iter().zip(visible).enumerate() {
            if !seen {
                continue;
            }
            self.order.push(i as u32);
            let (Some(inv), Some(r)) = (self.near_inv_z.get_mut(i), self.rect.get_mut(i)) else {
                continue;
            };
            (*inv, *r) = screen_box(view, &chunk.bounds).unwrap_or((0.0, [0; 4]));
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

    /// What the raster bands write: the tiles, to fill, with the number of
    /// them under one band ([`BAND_ROWS`]` / `[`TILE_PX`] rows of
    /// `tiles_x`), and the per-cluster flags of [`Occlusion::seen`].
    pub fn raster_targets(&mut self) -> (&mut [f32], usize, &[AtomicBool]) {
        (
            &mut self.tile_min_inv_z,
            (self.tiles_x * (BAND_ROWS / TILE_PX)).max(1),
            &self.seen,
        )
    }

    /// Forgets the chunks seen so far (a render without the cull).
    pub fn forget(&mut self) {
        self.last_position_m = None;
    }

    /// Whether chunk `i` is hidden behind the tiles as last updated.
    pub fn hidden(&self, i: usize) -> bool {
        match (self.near_inv_z.get(i), self.rect.get(i)) {
            (Some(&inv), Some(&rect)) => self.tiles().hides_box(rect, inv),
            _ => false,
        }
    }
}

/// The nearest `1/z` of box `b` (padded) in `view` and the tiles its
/// projection touches (padded), `[x0, y0, x1, y1]` inclusive; `None` when
/// the box reaches behind the near plane (it cannot be proved hidden).
pub(super) fn screen_box(view: &View, b: &Aabb) -> Option<(f32, [u16; 4])> {
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
    if !(near > NEAR_M && near.is_finite()) {
        return None;
    }
    let (w, h) = (view.width as f32, view.height as f32);
    let tile = |x: f32, limit: f32| {
        ((x.clamp(0.0, limit - 1.0)) as usize / TILE_PX).min(u16::MAX as usize) as u16
    };
    Some((
        1.0 / near,
        [
            tile(u0 - RECT_PAD_PX, w),
            tile(v0 - RECT_PAD_PX, h),
            tile(u1 + RECT_PAD_PX, w),
            tile(v1 + RECT_PAD_PX, h),
        ],
    ))
}

/// Chunks in the first batch when `visible` chunks pass the frustum test.
pub(super) fn first_batch(visible: usize) -> usize {
    (visible / FIRST_BATCH_DIVISOR).max(FIRST_BATCH_MIN)
}

/// Sets each element of `tiles` (the rows of tiles under one band) to the
/// smallest `1/z` of the `width`-wide band `inv_z` under it (0 where a
/// pixel is empty).
pub(super) fn band_tiles(inv_z: &[f32], width: usize, tiles: &mut [f32]) {
    tiles.fill(f32::INFINITY);
    let tiles_x = width.div_ceil(TILE_PX).max(1);
    for (y, row) in inv_z.chunks_exact(width.max(1)).enumerate() {
        let first = y / TILE_PX * tiles_x;
        let Some(tile_row) = tiles.get_mut(first..first + tiles_x) else {
            continue;
        };
        for (tile, px) in tile_row.iter_mut().zip(row.chunks(TILE_PX)) {
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
    /// Whether a box whose nearest `1/z` is `near_inv_z` (0: not
    /// occludable) and whose projection touches tiles `[x0, y0, x1, y1]`
    /// (as [`screen_box`] gives them) is hidden behind every one of them.
    #[inline]
    pub fn hides_box(&self, [x0, y0, x1, y1]: [u16; 4], near_inv_z: f32) -> bool {
        if near_inv_z == 0.0 {
            return false;
        }
        let limit = near_inv_z * (1.0 + MARGIN);
        let (x0, x1) = (usize::from(x0), usize::from(x1));
        (usize::from(y0)..=usize::from(y1)).all(|ty| {
            self.min_inv_z
                .get(ty * self.tiles_x + x0..=ty * self.tiles_x + x1)
                .is_some_and(|row| row.iter().all(|&t| t > limit))
        })
    }

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
