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
use super::view::View;
use crate::render::chunks::MeshChunk;
use crate::render::tiles::{screen_box, TileDepth, TILE_PX};
/// Most batches of one render; the first is never culled.
pub(super) const MAX_BATCHES: usize = 8;
/// The first batch holds this share of the visible chunks...
const FIRST_BATCH_DIVISOR: usize = 32;
/// ...and at least this many.
const FIRST_BATCH_MIN: usize = 4;
/// The previous render's visible chunks are drawn first when its camera
/// was less than this far away, meters.
pub(super) const COHERENT_M: f64 = 2.0;

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
        TileDepth::new(&self.tile_min_inv_z, self.tiles_x)
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

/// Chunks in the first batch when `visible` chunks pass the frustum test.
pub(super) fn first_batch(visible: usize) -> usize {
    (visible / FIRST_BATCH_DIVISOR).max(FIRST_BATCH_MIN)
}
