//! Occlusion culling for the wgpu renderer, exact, of clusters of 256
//! triangles, in two or three render passes.
//!
//! Takes the chunks that passed the frustum test, the render's projection
//! and, between passes, the metric depth drawn so far, read back from the
//! device; gives out each pass's draw list. The first pass draws what the
//! previous render kept (below) when its camera was less than
//! [`COHERENT_M`] away, else the nearest [`FIRST_SHARE`] of the clusters
//! in view (at least [`FIRST_MIN`]) and, in a second pass, the next nearest
//! [`SECOND_SHARE`]. After every pass but the last the depth target is
//! copied back, and each 8 x 8 tile gets the farthest depth drawn in it
//! (`render::tiles`, as the CPU rasterizer's cull). The next pass draws
//! only the clusters in view that are not hidden behind every tile their
//! box's projection touches; a box reaching behind the near plane is never
//! hidden. The z-buffer only gets nearer, so what is left out could not
//! have won a depth test: every pixel gets the surface it would get
//! without the cull. Two exceptions, both outside the geometry: a tie,
//! two surfaces at exactly the same depth on one pixel, could resolve
//! otherwise, since the draw order changes; and a surface seen exactly
//! edge-on (a camera in the plane of a wall) is a zero-area triangle that
//! lavapipe may still rasterize into a pixel, at a depth extrapolated far
//! from its vertices' (seen: 0.755 m on a wall 8.4 m away), which the cull,
//! reasoning from the box, leaves out. The tests compare the images bit
//! for bit from poses off such planes.
//!
//! With back faces culled ([`GpuOcclusion::set_cull_back_faces`]), a flat
//! cluster seen from behind its plane (`chunks::FrontPlane`) is not in
//! view at all: the pipeline would cull every one of its triangles.
//!
//! A view with fewer than [`MIN_CLUSTERS`] clusters in it is drawn in one
//! pass: drawing them costs less than a readback.
//!
//! When the render has been read back, the clusters it drew are tested
//! against the final image's tiles: those not hidden are *kept* for the
//! next render's first pass (a cluster that owns a pixel is never hidden,
//! so the set shrinks to about what is seen).
//!
//! All scratch is sized at construction (per cluster) or on the first
//! render of an image size (per tile), and reused.

use glam::{Affine3A, Mat4, Vec3A};

use super::draws::Draw;
use crate::geometry::{PinholeCamera, Pose};
use crate::render::chunks::{self, Aabb, ChunkedMesh};
use crate::render::frustum::Frustum;
use crate::render::tiles::{screen_box, BoxProjection, TileDepth, TILE_PX};

/// The previous render's kept clusters are drawn first when its camera was
/// less than this far away, meters.
pub const COHERENT_M: f64 = 2.0;
/// Without a coherent previous render: the first pass draws this share of
/// the clusters in view, nearest first...
const FIRST_SHARE: usize = 16;
/// ...at least this many...
const FIRST_MIN: usize = 16;
/// ...and the second pass, of those not hidden, up to this share.
const SECOND_SHARE: usize = 4;
/// Fewer clusters in view than this (64 k triangles) are drawn in one
/// pass, without the cull: on lavapipe, a one-room view of the `building`
/// preset (about 200 clusters) takes 8.1 ms in one pass and 9.0 ms in two
/// (the readback between them), docs/building-scale.md.
pub const MIN_CLUSTERS: usize = 256;

/// One cluster: a run of triangles of one chunk, drawn with one texture.
#[derive(Debug, Clone)]
struct GpuCluster {
    /// Indices into the resident index buffer.
    indices: std::ops::Range<u32>,
    /// Bind group number, as [`Draw::texture`].
    texture: usize,
    /// Bounds of its vertices, world frame.
    bounds: Aabb,
    /// Its plane, when flat (`chunks::FrontPlane`).
    plane: Option<chunks::FrontPlane>,
}

/// The render's pinhole projection, for box tests (the same intrinsics the
/// device projects with; its half-pixel shift is `super::projection`'s).
#[derive(Debug, Clone, Copy)]
pub struct BoxView {
    camera_from_world: Affine3A,
    fx: f64,
    fy: f64,
    cx: f64,
    cy: f64,
    width: usize,
    height: usize,
    near_m: f32,
}

impl BoxView {
    /// The view of `camera` at `world_from_camera`, near plane `near_m`.
    pub fn new(world_from_camera: &Pose, camera: &PinholeCamera, near_m: f64) -> Self {
        let camera_from_world = world_from_camera.inverse().to_homogeneous();
        Self {
            camera_from_world: Affine3A::from_mat4(Mat4::from_cols_array_2d(
                &camera_from_world.cast::<f32>().into(),
            )),
            fx: camera.fx,
            fy: camera.fy,
            cx: camera.cx,
            cy: camera.cy,
            width: camera.width as usize,
            height: camera.height as usize,
            near_m: near_m as f32,
        }
    }
}

impl BoxProjection for BoxView {
    fn camera_point(&self, p_world: [f32; 3]) -> Vec3A {
        self.camera_from_world
            .transform_point3a(Vec3A::from_array(p_world))
    }

    fn pixel_f32(&self, p: Vec3A) -> (f32, f32) {
        let (x, y, z) = (f64::from(p.x), f64::from(p.y), f64::from(p.z));
        (
            (self.fx * x / z + self.cx) as f32,
            (self.fy * y / z + self.cy) as f32,
        )
    }

    fn size_px(&self) -> (usize, usize) {
        (self.width, self.height)
    }

    fn near_m(&self) -> f32 {
        self.near_m
    }
}

/// Counts of the occlusion cull since start.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct OcclusionStats {
    /// Renders drawn with the occlusion cull.
    pub renders: u64,
    /// Of those, renders whose first pass was the previous render's kept
    /// clusters.
    pub coherent_renders: u64,
    /// Render passes of those renders.
    pub passes: u64,
    /// Clusters in view (frustum test of chunk and cluster), summed.
    pub clusters_in_view: u64,
    /// Clusters drawn, summed.
    pub clusters_drawn: u64,
    /// Triangles drawn, summed.
    pub triangles_drawn: u64,
    /// Clusters drawn in first passes, summed.
    pub clusters_first_pass: u64,
    /// Draw calls, summed.
    pub draw_calls: u64,
}

/// State and scratch of the wgpu occlusion cull. See the module docs.
#[derive(Debug)]
pub struct GpuOcclusion {
    clusters: Vec<GpuCluster>,
    /// Per chunk, its first cluster; one more element for the end.
    chunk_first: Vec<u32>,
    /// Per cluster: kept by the last render collected.
    kept: Vec<bool>,
    /// The clusters drawn in the current render.
    drawn_list: Vec<u32>,
    /// The clusters in view not drawn yet, nearest first.
    pending: Vec<u32>,
    /// Per cluster: `1/z` of its box's nearest point (0: not occludable).
    near_inv_z: Vec<f32>,
    /// Per cluster: the tiles its box covers.
    rect: Vec<[u16; 4]>,
    /// Per tile, the smallest `1/z` drawn (0 where a pixel is empty).
    tile_min_inv_z: Vec<f32>,
    /// Scratch of [`fill_tiles`]: a band's farthest depth per column.
    row_far_m: Vec<f32>,
    tiles_x: usize,
    /// Camera position of the last render with the cull, world frame.
    last_position_m: Option<[f64; 3]>,
    /// Whether the current render's first pass is the kept set.
    coherent: bool,
    /// Passes of the current render so far.
    pass: usize,
    /// How many of `drawn_list` earlier passes drew.
    emitted: usize,
    /// The render whose boxes are measured, to match its collect.
    render: Option<u64>,
    /// Whether back faces are culled: then a flat cluster seen from behind
    /// its plane is not drawn at all.
    cull_back_faces: bool,
    stats: OcclusionStats,
}

impl GpuOcclusion {
    /// The clusters of every drawn chunk of `mesh`; `chunk_texture` gives
    /// each chunk's bind group (`None`: not drawn).
    pub fn new(mesh: &ChunkedMesh, chunk_texture: &[Option<usize>]) -> Self {
        let mut clusters = Vec::new();
        let mut chunk_first = Vec::with_capacity(mesh.chunks.len() + 1);
        for (c, chunk) in mesh.chunks.iter().enumerate() {
            chunk_first.push(clusters.len() as u32);
            let Some(texture) = chunk_texture.get(c).copied().flatten() else {
                continue;
            };
            let base = 3 * chunk.triangles.start;
            for cluster in chunks::clusters(mesh, chunk) {
                clusters.push(GpuCluster {
                    indices: base + 3 * cluster.triangles.start as u32
                        ..base + 3 * cluster.triangles.end as u32,
                    texture,
                    bounds: cluster.bounds,
                    plane: cluster.plane,
                });
            }
        }
        chunk_first.push(clusters.len() as u32);
        let n = clusters.len();
        Self {
            clusters,
            chunk_first,
            kept: vec![false; n],
            drawn_list: Vec::with_capacity(n),
            pending: Vec::with_capacity(n),
            near_inv_z: vec![0.0; n],
            rect: vec![[0; 4]; n],
            tile_min_inv_z: Vec::new(),
            row_far_m: Vec::new(),
            tiles_x: 0,
            last_position_m: None,
            coherent: false,
            pass: 0,
            emitted: 0,
            render: None,
            cull_back_faces: false,
            stats: OcclusionStats::default(),
        }
    }

    /// Leaves out flat clusters seen from behind when `on` (the pipeline
    /// culls back faces: none of their triangles would be drawn).
    pub fn set_cull_back_faces(&mut self, on: bool) {
        self.cull_back_faces = on;
    }

    /// Counts since start.
    pub fn stats(&self) -> OcclusionStats {
        self.stats
    }

    /// Forgets the kept clusters (a render without the cull).
    pub fn forget(&mut self) {
        self.last_position_m = None;
        self.render = None;
    }

    /// Starts render number `render`: measures the boxes of the clusters
    /// of the chunks marked in `visible` that `frustum` keeps, in `view`,
    /// and fills `draws` (cleared first) with the first pass.
    pub fn begin(
        &mut self,
        render: u64,
        (view, frustum, position_m): (&BoxView, &Frustum, [f64; 3]),
        visible: &[bool],
        draws: &mut Vec<Draw>,
    ) {
        self.coherent = self.last_position_m.is_some_and(|p| {
            let d2: f64 = (0..3).map(|k| (p[k] - position_m[k]).powi(2)).sum();
            d2 < COHERENT_M * COHERENT_M
        }) && self.render.is_none();
        self.last_position_m = Some(position_m);
        self.render = Some(render);
        self.pass = 0;
        self.emitted = 0;
        self.drawn_list.clear();
        self.pending.clear();
        let (w, h) = view.size_px();
        self.tiles_x = w.div_ceil(TILE_PX);
        self.tile_min_inv_z
            .resize(self.tiles_x * h.div_ceil(TILE_PX), 0.0);
        for (c, &in_view) in visible.iter().enumerate() {
            if !in_view {
                continue;
            }
            let first = self.chunk_first.get(c).copied().unwrap_or(0) as usize;
            let end = (self.chunk_first.get(c + 1).copied().unwrap_or(0) as usize).max(first);
            for k in first..end {
                let Some(cluster) = self.clusters.get(k) else {
                    continue;
                };
                if !frustum.intersects(&cluster.bounds)
                    || (self.cull_back_faces
                        && cluster
                            .plane
                            .is_some_and(|p| p.is_behind(&cluster.bounds, position_m)))
                {
                    continue;
                }
                let (inv, rect) = screen_box(view, &cluster.bounds).unwrap_or((0.0, [0; 4]));
                if let (Some(n), Some(r)) = (self.near_inv_z.get_mut(k), self.rect.get_mut(k)) {
                    (*n, *r) = (inv, rect);
                }
                self.pending.push(k as u32);
            }
        }
        let near_inv_z = &self.near_inv_z;
        let key = |k: &u32| {
            let inv = near_inv_z.get(*k as usize).copied().unwrap_or(0.0);
            // Not occludable (0) first, then nearest first.
            if inv == 0.0 {
                f32::INFINITY
            } else {
                inv
            }
        };
        self.pending
            .sort_unstable_by(|a, b| key(b).total_cmp(&key(a)).then(a.cmp(b)));
        self.stats.renders += 1;
        self.stats.clusters_in_view += self.pending.len() as u64;
        if self.coherent {
            self.stats.coherent_renders += 1;
        }
        let quota = if self.pending.len() < MIN_CLUSTERS {
            usize::MAX
        } else if self.coherent {
            0
        } else {
            (self.pending.len() / FIRST_SHARE).max(FIRST_MIN)
        };
        let coherent = self.coherent;
        let mut pending = std::mem::take(&mut self.pending);
        let mut taken = 0;
        pending.retain(|&k| {
            let kept = coherent && self.kept.get(k as usize) == Some(&true);
            if !kept && taken >= quota {
                return true;
            }
            taken += 1;
            self.drawn_list.push(k);
            false
        });
        self.pending = pending;
        draws.clear();
        self.emit(draws);
        self.pass += 1;
        self.stats.passes += 1;
    }

    /// Whether another pass follows the one just filled (whose tiles then
    /// have to be read back before [`GpuOcclusion::next_pass`]).
    pub fn more(&self) -> bool {
        !self.pending.is_empty()
    }

    /// Fills the tiles from the metric depth drawn so far (`rows` of
    /// `width` pixels, top first; [`fill_tiles`]).
    pub fn fill_tiles(&mut self, rows: &mut dyn Iterator<Item = &[f32]>, width: usize) {
        fill_tiles(
            rows,
            width,
            &mut self.tile_min_inv_z,
            self.tiles_x,
            &mut self.row_far_m,
        );
    }

    /// Empties the tiles: they hide nothing.
    pub fn clear_tiles(&mut self) {
        self.tile_min_inv_z.fill(0.0);
    }

    /// Fills `draws` (cleared first) with the next pass: of the clusters
    /// not drawn yet, those the tiles do not hide (all of them in the last
    /// pass; up to a quota in the second of a render without a coherent
    /// first pass). Hidden clusters are dropped for good.
    pub fn next_pass(&mut self, draws: &mut Vec<Draw>) {
        let quota = if !self.coherent && self.pass == 1 {
            (self.pending.len() / SECOND_SHARE).max(FIRST_MIN)
        } else {
            usize::MAX
        };
        let tiles = TileDepth::new(&self.tile_min_inv_z, self.tiles_x);
        let (near_inv_z, rect) = (&self.near_inv_z, &self.rect);
        let hidden = |k: usize| match (near_inv_z.get(k), rect.get(k)) {
            (Some(&inv), Some(&r)) => tiles.hides_box(r, inv),
            _ => false,
        };
        let mut pending = std::mem::take(&mut self.pending);
        let mut taken = 0;
        pending.retain(|&k| {
            if hidden(k as usize) {
                return false;
            }
            if taken >= quota {
                return true;
            }
            taken += 1;
            self.drawn_list.push(k);
            false
        });
        self.pending = pending;
        draws.clear();
        self.emit(draws);
        self.pass += 1;
        self.stats.passes += 1;
    }

    /// Appends the draws of this pass: the clusters drawn since the last
    /// call, in index-buffer order, adjacent ones of one texture merged.
    fn emit(&mut self, draws: &mut Vec<Draw>) {
        let start = self.emitted;
        let this_pass = self.drawn_list.get_mut(start..).unwrap_or(&mut []);
        this_pass.sort_unstable();
        for &k in this_pass.iter() {
            let Some(cluster) = self.clusters.get(k as usize) else {
                continue;
            };
            self.stats.clusters_drawn += 1;
            self.stats.triangles_drawn += u64::from(cluster.indices.len() as u32 / 3);
            match draws.last_mut() {
                Some(last)
                    if last.texture == cluster.texture
                        && last.indices.end == cluster.indices.start =>
                {
                    last.indices.end = cluster.indices.end;
                }
                _ => draws.push(Draw {
                    indices: cluster.indices.clone(),
                    base_vertex: 0,
                    texture: cluster.texture,
                }),
            }
        }
        self.emitted = self.drawn_list.len();
        if self.pass == 0 {
            self.stats.clusters_first_pass += self.emitted as u64;
        }
        self.stats.draw_calls += draws.len() as u64;
    }
}

impl GpuOcclusion {
    /// Ends render number `render`, read back: its final tiles are in
    /// [`GpuOcclusion::fill_tiles`]. The clusters it drew that they do not
    /// hide are kept for the next render's first pass. A render other than
    /// the one last begun (two in flight) keeps nothing: the next render
    /// starts afresh.
    pub fn finish(&mut self, render: u64) {
        self.kept.fill(false);
        if self.render != Some(render) {
            self.render = None;
            self.last_position_m = None;
            return;
        }
        self.render = None;
        let tiles = TileDepth::new(&self.tile_min_inv_z, self.tiles_x);
        for &k in &self.drawn_list {
            let k = k as usize;
            let hidden = match (self.near_inv_z.get(k), self.rect.get(k)) {
                (Some(&inv), Some(&r)) => tiles.hides_box(r, inv),
                _ => false,
            };
            if let Some(keep) = self.kept.get_mut(k) {
                *keep = !hidden;
            }
        }
    }

    /// Whether render `render` is the one being drawn with the cull.
    pub fn drawing(&self, render: u64) -> bool {
        self.render == Some(render)
    }
}

/// Fills `tiles` (rows of `tiles_x`) with the farthest depth of each
/// [`TILE_PX`]-square tile of a metric depth image, as the smallest `1/z`
/// (0 where a pixel is empty: [`crate::render::NO_DEPTH`], or not a
/// positive finite depth); `rows` are its rows of `width` pixels, top
/// first. `row_far_m` is scratch (`width` floats, allocated once).
///
/// Each band of [`TILE_PX`] rows is reduced column by column first (an
/// element-wise maximum, which the compiler vectorizes), then each tile's
/// [`TILE_PX`] columns: the per-pixel branch of a tile-by-tile loop took
/// 0.5 ms of a 640 x 512 image on this project's 2-core VM, twice a floor
/// keyframe.
pub fn fill_tiles(
    rows: &mut dyn Iterator<Item = &[f32]>,
    width: usize,
    tiles: &mut [f32],
    tiles_x: usize,
    row_far_m: &mut Vec<f32>,
) {
    // Farthest depth per tile, infinity where a pixel is empty, 0 where no
    // pixel was read.
    tiles.fill(0.0);
    row_far_m.clear();
    row_far_m.resize(width, 0.0);
    let mut band = None;
    for (y, row) in rows.enumerate() {
        let this_band = y / TILE_PX;
        if band != Some(this_band) {
            if let Some(done) = band {
                reduce_band(row_far_m, tiles, done, tiles_x);
            }
            row_far_m.fill(0.0);
            band = Some(this_band);
        }
        let pixels = row.get(..width).unwrap_or(row);
        for (far, &d) in row_far_m.iter_mut().zip(pixels) {
            // `d < INFINITY` is false for NaN too.
            let d = if d > 0.0 && d < f32::INFINITY {
                d
            } else {
                f32::INFINITY
            };
            *far = if d > *far { d } else { *far };
        }
    }
    if let Some(done) = band {
        reduce_band(row_far_m, tiles, done, tiles_x);
    }
    for t in tiles.iter_mut() {
        // A tile with an empty pixel, or none read, hides nothing.
        *t = if *t > 0.0 && t.is_finite() {
            1.0 / *t
        } else {
            0.0
        };
    }
}

/// Writes band `band`'s farthest depth per column, `row_far_m`, into its
/// row of `tiles` (rows of `tiles_x`); a band past the tiles is dropped.
fn reduce_band(row_far_m: &[f32], tiles: &mut [f32], band: usize, tiles_x: usize) {
    let first = band * tiles_x;
    let Some(tile_row) = tiles.get_mut(first..first + tiles_x) else {
        return;
    };
    for (tile, columns) in tile_row.iter_mut().zip(row_far_m.chunks(TILE_PX)) {
        *tile = columns
            .iter()
            .fold(0.0, |far, &d| if d > far { d } else { far });
    }
}

#[cfg(test)]
#[allow(clippy::expect_used, clippy::unwrap_used)]
mod tests {
    use super::*;

    #[test]
    fn tiles_hold_the_farthest_depth_and_nothing_where_a_pixel_is_empty() {
        // 16 x 10 pixels: 2 x 2 tiles, the bottom row of tiles cut short.
        let (w, h) = (16, 10);
        let mut depth = vec![2.0f32; w * h];
        depth[3 * w + 5] = 4.0; // tile (0, 0): farthest 4 m
        depth[2 * w + 12] = 0.0; // tile (1, 0): an empty pixel
        depth[9 * w + 2] = f32::NAN; // tile (0, 1): not a depth
        let tiles_x = 2;
        let mut tiles = vec![9.0; 4];
        let mut scratch = Vec::new();
        fill_tiles(
            &mut depth.chunks_exact(w),
            w,
            &mut tiles,
            tiles_x,
            &mut scratch,
        );
        assert_eq!(tiles, vec![0.25, 0.0, 0.0, 0.5]);
        let t = TileDepth::new(&tiles, tiles_x);
        // A box nearest at 5 m behind tile (1, 1) (farthest 2 m): hidden;
        // at 2 m: not (the margin); over the empty tile: never.
        assert!(t.hides_box([1, 1, 1, 1], 1.0 / 5.0));
        assert!(!t.hides_box([1, 1, 1, 1], 1.0 / 2.0));
        assert!(!t.hides_box([1, 0, 1, 1], 1.0 / 50.0));
        // Rows missing (a short read): those tiles hide nothing.
        fill_tiles(
            &mut depth.chunks_exact(w).take(8),
            w,
            &mut tiles,
            tiles_x,
            &mut scratch,
        );
        assert_eq!(&tiles[2..], &[0.0, 0.0]);
    }

    /// The tile-by-tile, pixel-by-pixel fill [`fill_tiles`] replaced.
    fn fill_tiles_pixel_by_pixel(
        rows: &mut dyn Iterator<Item = &[f32]>,
        width: usize,
        tiles: &mut [f32],
        tiles_x: usize,
    ) {
        tiles.fill(0.0);
        for (y, row) in rows.enumerate() {
            let first = y / TILE_PX * tiles_x;
            let Some(tile_row) = tiles.get_mut(first..first + tiles_x) else {
                continue;
            };
            let pixels = row.get(..width).unwrap_or(row);
            for (tile, px) in tile_row.iter_mut().zip(pixels.chunks(TILE_PX)) {
                for &d in px {
                    let d = if d > 0.0 && d.is_finite() {
                        d
                    } else {
                        f32::INFINITY
                    };
                    *tile = tile.max(d);
                }
            }
        }
        for t in tiles.iter_mut() {
            *t = if *t > 0.0 && t.is_finite() {
                1.0 / *t
            } else {
                0.0
            };
        }
    }

    #[test]
    fn tiles_are_those_of_a_pixel_by_pixel_fill_on_any_image() {
        let mut rng = crate::rng::SplitMix64::new(22);
        let mut scratch = Vec::new();
        // Sizes off the tile grid, short rows and reads, and every kind of
        // pixel that is not a depth.
        for (w, h, rows_read, short_row) in [
            (640usize, 512usize, 512usize, None::<(usize, usize)>),
            (13, 11, 11, None),
            (21, 17, 9, Some((3, 5))),
            (8, 8, 8, Some((7, 0))),
            (1, 3, 3, None),
        ] {
            let depth: Vec<f32> = (0..w * h)
                .map(|_| match rng.below(400) {
                    0 => 0.0,
                    1 => f32::NAN,
                    2 => f32::INFINITY,
                    3 => -1.5,
                    4 => f32::NEG_INFINITY,
                    _ => rng.range(0.1, 30.0) as f32,
                })
                .collect();
            let tiles_x = w.div_ceil(TILE_PX);
            let n = tiles_x * h.div_ceil(TILE_PX);
            let rows = || {
                depth
                    .chunks_exact(w)
                    .take(rows_read)
                    .enumerate()
                    .map(move |(y, r)| match short_row {
                        Some((sy, len)) if sy == y => &r[..len],
                        _ => r,
                    })
            };
            let (mut fast, mut slow) = (vec![7.0; n], vec![7.0; n]);
            fill_tiles(&mut rows(), w, &mut fast, tiles_x, &mut scratch);
            fill_tiles_pixel_by_pixel(&mut rows(), w, &mut slow, tiles_x);
            assert_eq!(fast, slow, "{w} x {h}, {rows_read} rows read");
            if w == 640 {
                // About half the tiles hold a depth, the others a pixel
                // that is not one.
                let held = fast.iter().filter(|&&t| t > 0.0).count();
                assert!(held > n / 4 && held < 3 * n / 4, "{held} of {n}");
            }
        }
    }

    #[test]
    fn box_view_projects_as_the_pinhole_camera() {
        let camera = PinholeCamera::new(640, 512, 420.0, 420.0, 319.5, 255.5);
        let view = BoxView::new(&Pose::identity(), &camera, 0.05);
        let p = view.camera_point([0.5, -0.25, 2.0]);
        let (u, v) = view.pixel_f32(p);
        let expect = camera
            .project(&nalgebra::Vector3::new(0.5, -0.25, 2.0))
            .unwrap();
        assert!((f64::from(u) - expect.x).abs() < 1e-3);
        assert!((f64::from(v) - expect.y).abs() < 1e-3);
        // A box reaching behind the near plane is never occludable.
        let b = Aabb {
            min_m: [-0.1, -0.1, 0.0],
            max_m: [0.1, 0.1, 1.0],
        };
        assert!(screen_box(&view, &b).is_none());
    }
}
