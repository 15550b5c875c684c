//! The depth tiles of both renderers' occlusion culls, and the test of a
//! box against them.
//!
//! Owns the tile size, the margins and the arithmetic: each 8 x 8-pixel
//! tile of an image holds the farthest depth drawn in it so far, as the
//! smallest `1/z` (0 when a pixel of it is still empty); a box is hidden
//! when, over every tile its padded projection touches, that farthest
//! depth is nearer than the box's nearest point by a relative margin far
//! above `f32` rounding. A z-buffer only gets nearer, so nothing hidden
//! could win a depth test, then or later. The CPU rasterizer fills its
//! tiles band by band from its own `1/z` buffer (`cpu::occlusion`); the
//! wgpu renderer from a metric depth image read back from the device
//! (`gpu::occlusion`). The projection is each renderer's own, through
//! [`BoxProjection`].

use glam::Vec3A;

use crate::render::chunks::Aabb;

/// Tile edge, pixels.
pub(crate) const TILE_PX: usize = 8;
/// Relative margin of the depth comparison.
const MARGIN: f32 = 1e-3;
/// Padding of the boxes, meters (as the frustum test's).
const BOX_PAD_M: f32 = 1e-3;
/// Padding of the projected rectangles, pixels.
const RECT_PAD_PX: f32 = 2.0;

/// A pinhole projection that boxes are measured in.
pub(crate) trait BoxProjection {
    /// A world point in the camera frame.
    fn camera_point(&self, p_world: [f32; 3]) -> Vec3A;
    /// Pixel coordinates (centers at integers) of a camera-frame point in
    /// front of the camera.
    fn pixel_f32(&self, p: Vec3A) -> (f32, f32);
    /// Image `(width, height)`, pixels.
    fn size_px(&self) -> (usize, usize);
    /// The near plane, meters: a box reaching nearer is never hidden.
    fn near_m(&self) -> f32;
}

/// The nearest `1/z` of box `b` (padded) in `view` and the tiles its
/// projection touches (padded), `[x0, y0, x1, y1]` inclusive; `None` when
/// the box reaches behind the near plane (it cannot be proved hidden).
pub(crate) fn screen_box(view: &impl BoxProjection, b: &Aabb) -> Option<(f32, [u16; 4])> {
    let near_plane_m = view.near_m();
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
        if p.z > near_plane_m {
            let (u, v) = view.pixel_f32(p);
            u0 = u0.min(u);
            v0 = v0.min(v);
            u1 = u1.max(u);
            v1 = v1.max(v);
        }
    }
    if !(near > near_plane_m && near.is_finite()) {
        return None;
    }
    let (w, h) = view.size_px();
    let (w, h) = (w as f32, h as f32);
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

/// Sets each element of `tiles` (the rows of tiles under one band) to the
/// smallest `1/z` of the `width`-wide band `inv_z` under it (0 where a
/// pixel is empty).
pub(crate) fn band_tiles(inv_z: &[f32], width: usize, tiles: &mut [f32]) {
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
pub(crate) struct TileDepth<'a> {
    min_inv_z: &'a [f32],
    tiles_x: usize,
}

impl<'a> TileDepth<'a> {
    /// The tiles `min_inv_z`, rows of `tiles_x`.
    pub fn new(min_inv_z: &'a [f32], tiles_x: usize) -> Self {
        Self { min_inv_z, tiles_x }
    }
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
