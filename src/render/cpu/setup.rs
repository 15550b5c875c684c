//! Triangle setup and binning.
//!
//! Takes one spatial chunk of the mesh ([`MeshChunk`]): transforms its own
//! vertices into the camera frame, culls the triangles that cannot cover a
//! pixel center, clips those that cross the near plane or the guard band,
//! and gives out screen-space triangles ([`ScreenTri`]) binned into
//! horizontal bands of [`BAND_ROWS`] rows. Chunks are fixed at renderer
//! construction, so neither the work split nor the order in which a band
//! sees its triangles depends on the thread count.

use super::clip::{ClipVertex, Polygon, MAX_POLY};

use super::view::{CamVertex, View, CLIP_MASK, CULL_MASK, OUT_INVALID, SUBPIXEL_BITS};
use crate::render::chunks::{self, ChunkedMesh, Cluster, MeshChunk};
use crate::render::frustum::Frustum;
use crate::render::tiles::{screen_box, TileDepth};

/// Rows per band: the unit of work of the raster stage.
pub(super) const BAND_ROWS: usize = 16;
/// Texture index meaning "no texture".
pub(super) const NO_TEXTURE: u32 = u32::MAX;

/// A projected, positively oriented triangle ready to rasterize.
#[derive(Debug, Clone, Copy)]
pub(super) struct ScreenTri {
    /// Fixed-point screen x of the vertices.
    pub x: [i32; 3],
    /// Fixed-point screen y of the vertices.
    pub y: [i32; 3],
    /// `1/z` at the vertices.
    pub inv_z: [f32; 3],
    /// `gray/z` at the vertices.
    pub gray_z: [f32; 3],
    /// `u/z` at the vertices.
    pub u_z: [f32; 3],
    /// `v/z` at the vertices.
    pub v_z: [f32; 3],
    /// Texture index, or [`NO_TEXTURE`].
    pub texture: u32,
    /// Mesh triangle number: of two triangles at equal depth on a pixel,
    /// the lower number wins, as if drawn in mesh order.
    pub order: u32,
    /// Pixel-center bounds `[x_min, x_max, y_min, y_max]`, inclusive,
    /// clamped to the image.
    pub bbox: [u16; 4],
}

/// What the setup of one chunk needs that does not change: fixed at
/// renderer construction, one per chunk of the map.
#[derive(Debug)]
pub(super) struct ChunkSetup {
    /// Texture index of the chunk's group, or [`NO_TEXTURE`].
    texture: u32,
    /// The chunk's triangles in runs of [`chunks::CLUSTER_TRIS`], each tested
    /// against the view before its vertices are transformed.
    clusters: Vec<Cluster>,
}

impl ChunkSetup {
    /// The setup of `chunk` (of `mesh`), whose triangles sample `texture`
    /// (or [`NO_TEXTURE`]).
    pub fn new(chunk: &MeshChunk, mesh: &ChunkedMesh, texture: u32) -> Self {
        Self {
            texture,
            clusters: chunks::clusters(mesh, chunk),
        }
    }

    /// Number of setup clusters.
    pub fn cluster_count(&self) -> usize {
        self.clusters.len()
    }
}

/// Scratch of one chunk being set up and rasterized: a slot of the
/// renderer's pool, which holds one per chunk of the largest batch drawn
/// so far, not one per chunk of the map. Each slot keeps its capacity
/// across renders: it grows to the largest chunk it has held, and a
/// render of views like those before allocates nothing.
#[derive(Debug, Default)]
pub(super) struct SetupSlot {
    /// The chunk's vertices in the camera frame.
    verts: Vec<CamVertex>,
    /// The chunk's screen triangles.
    pub tris: Vec<ScreenTri>,
    /// Per band, the indices into `tris` of the triangles touching it.
    pub bins: Vec<Vec<u32>>,
    /// Per screen triangle, the number of its cluster in the chunk.
    pub tri_cluster: Vec<u8>,
    /// The number of the chunk's first cluster among all chunks' (as the
    /// current render's setup was told).
    pub first_cluster: usize,
}

/// Which of a chunk's clusters to set up.
#[derive(Debug, Clone, Copy)]
pub(super) enum Clusters<'a> {
    /// All of them.
    All,
    /// Those marked true (one flag per cluster).
    Only(&'a [bool]),
    /// Those not marked true.
    Except(&'a [bool]),
}

impl Clusters<'_> {
    /// Whether cluster `k` is set up.
    fn takes(&self, k: usize) -> bool {
        match self {
            Self::All => true,
            Self::Only(flags) => flags.get(k) == Some(&true),
            Self::Except(flags) => flags.get(k) != Some(&true),
        }
    }
}

/// A vertex after projection, before orientation.
#[derive(Clone, Copy, Default)]
struct Projected {
    sx: i32,
    sy: i32,
    inv_z: f32,
    gray: f32,
    uv: [f32; 2],
}

impl SetupSlot {
    /// Holds no triangles (keeps the capacity).
    pub fn clear(&mut self) {
        self.tris.clear();
        self.tri_cluster.clear();
        for bin in &mut self.bins {
            bin.clear();
        }
    }

    /// Sets up and bins the triangles of `chunk` (of `mesh`, its fixed
    /// part `setup`) for `view`,
    /// cluster by cluster, of the clusters `which` takes: a cluster outside
    /// `frustum` (when given), seen from behind its plane when the view
    /// culls back faces (with `frustum`), or hidden behind `occluders` (the
    /// depth drawn so far, per tile) is skipped whole; of the others the vertices are
    /// transformed and each triangle that `occluders` does not hide is
    /// binned. `bands` is the number of bands of the image;
    /// `first_cluster` the number of the chunk's first cluster.
    pub fn build(
        &mut self,
        (chunk, setup): (&MeshChunk, &ChunkSetup),
        mesh: &ChunkedMesh,
        (view, bands): (&View, usize),
        (frustum, occluders): (Option<&Frustum>, Option<TileDepth<'_>>),
        (which, first_cluster): (Clusters<'_>, usize),
    ) {
        let texture = setup.texture;
        self.first_cluster = first_cluster;
        self.tris.clear();
        self.tri_cluster.clear();
        if self.bins.len() != bands {
            self.bins.resize_with(bands, Vec::new);
        }
        for bin in &mut self.bins {
            bin.clear();
        }
        let first_vertex = chunk.vertices.start as usize;
        let positions = mesh
            .positions
            .get(first_vertex..chunk.vertices.end as usize)
            .unwrap_or(&[]);
        // Within capacity once the slot has held a chunk this large.
        self.verts.resize(positions.len(), CamVertex::default());
        // Taken out while `emit` borrows `self`; put back below.
        let mut verts = std::mem::take(&mut self.verts);
        let uv_at = |i: usize| mesh.uvs.get(i).copied().unwrap_or([0.0, 0.0]);
        let (t0, t1) = (chunk.triangles.start as usize, chunk.triangles.end as usize);
        let indices = mesh.indices.get(3 * t0..3 * t1).unwrap_or(&[]);
        let orders = mesh.source_triangle.get(t0..t1).unwrap_or(&[]);
        // The local vertices transformed in this render so far: `done`.
        let mut done = 0..0;
        for (number, cluster) in setup.clusters.iter().enumerate() {
            if !which.takes(number) || frustum.is_some_and(|f| !f.intersects(&cluster.bounds)) {
                continue;
            }
            // With the cull on, a flat cluster seen from behind is skipped
            // whole: every triangle of it would be dropped as a back face.
            if view.cull_back_faces
                && frustum.is_some()
                && cluster
                    .plane
                    .is_some_and(|p| p.is_behind(&cluster.bounds, view.eye_m))
            {
                continue;
            }
            if let Some(tiles) = occluders {
                if let Some((near_inv_z, rect)) = screen_box(view, &cluster.bounds) {
                    if tiles.hides_box(rect, near_inv_z) {
                        continue;
                    }
                }
            }
            let need = cluster.vertices.clone();
            let todo = if need.start >= done.start && need.start <= done.end {
                let todo = done.end..need.end.max(done.end);
                done.end = todo.end;
                todo
            } else {
                done = need.clone();
                need
            };
            if let (Some(out), Some(src)) = (verts.get_mut(todo.clone()), positions.get(todo)) {
                for (v, &p) in out.iter_mut().zip(src) {
                    *v = view.vertex(p);
                }
            }
            let tris = cluster.triangles.clone();
            let (Some(indices), Some(orders)) =
                (indices.get(3 * tris.start..3 * tris.end), orders.get(tris))
            else {
                continue;
            };
            for (tri, &order) in indices.chunks_exact(3).zip(orders) {
                let idx = [tri[0] as usize, tri[1] as usize, tri[2] as usize];
                // Every index of a chunk lies in its vertex range (ChunkedMesh),
                // and of a cluster in the cluster's, transformed above.
                let local = idx.map(|i| i - first_vertex);
                let cv = [verts[local[0]], verts[local[1]], verts[local[2]]];
                let all = cv[0].code & cv[1].code & cv[2].code;
                let any = cv[0].code | cv[1].code | cv[2].code;
                if all & CULL_MASK != 0 || any & OUT_INVALID != 0 {
                    continue;
                }
                if any & CLIP_MASK == 0 {
                    let p = |k: usize| Projected {
                        sx: cv[k].sx,
                        sy: cv[k].sy,
                        inv_z: cv[k].inv_z,
                        gray: mesh.gray[idx[k]],
                        uv: uv_at(idx[k]),
                    };
                    self.emit([p(0), p(1), p(2)], texture, order, view, occluders);
                } else {
                    let c = |k: usize| ClipVertex {
                        p: view.camera_point(mesh.positions[idx[k]]).into(),
                        gray: mesh.gray[idx[k]],
                        uv: uv_at(idx[k]),
                    };
                    let mut poly = Polygon::triangle([c(0), c(1), c(2)]);
                    poly.clip(view, any & CLIP_MASK);
                    if poly.len < 3 {
                        continue;
                    }
                    let mut proj = [Projected::default(); MAX_POLY];
                    for (slot, cvx) in proj.iter_mut().zip(&poly.verts[..poly.len]) {
                        let (sx, sy, inv_z) = view.project(cvx.p.into());
                        *slot = Projected {
                            sx,
                            sy,
                            inv_z,
                            gray: cvx.gray,
                            uv: cvx.uv,
                        };
                    }
                    for k in 1..poly.len - 1 {
                        self.emit(
                            [proj[0], proj[k], proj[k + 1]],
                            texture,
                            order,
                            view,
                            occluders,
                        );
                    }
                }
            }
            // The triangles just binned are of this cluster.
            self.tri_cluster.resize(self.tris.len(), number as u8);
        }
        // Keeps the capacity for the next render.
        self.verts = verts;
    }

    /// Orients, bounds and bins one projected triangle; drops it when it is
    /// degenerate, a back face the view culls, covers no pixel center or is
    /// hidden behind `occluders`.
    #[inline]
    fn emit(
        &mut self,
        mut v: [Projected; 3],
        texture: u32,
        order: u32,
        view: &View,
        occluders: Option<TileDepth<'_>>,
    ) {
        let area2 = (i64::from(v[1].sx) - i64::from(v[0].sx))
            * (i64::from(v[2].sy) - i64::from(v[0].sy))
            - (i64::from(v[1].sy) - i64::from(v[0].sy)) * (i64::from(v[2].sx) - i64::from(v[0].sx));
        // Screen y runs down: a triangle counter-clockwise on the image,
        // its front seen, has a negative area here.
        if area2 == 0 || (area2 > 0 && view.cull_back_faces) {
            return;
        }
        if area2 < 0 {
            v.swap(1, 2);
        }
        let bits = SUBPIXEL_BITS;
        let min_x = v[0].sx.min(v[1].sx).min(v[2].sx);
        let max_x = v[0].sx.max(v[1].sx).max(v[2].sx);
        let min_y = v[0].sy.min(v[1].sy).min(v[2].sy);
        let max_y = v[0].sy.max(v[1].sy).max(v[2].sy);
        // Pixel centers inside [min, max]: ceil(min) ..= floor(max).
        let x0 = (-((-min_x) >> bits)).max(0);
        let x1 = (max_x >> bits).min(view.width as i32 - 1);
        let y0 = (-((-min_y) >> bits)).max(0);
        let y1 = (max_y >> bits).min(view.height as i32 - 1);
        if x0 > x1 || y0 > y1 {
            return;
        }
        if let Some(tiles) = occluders {
            let nearest = v[0].inv_z.max(v[1].inv_z).max(v[2].inv_z);
            let bounds = [x0, x1, y0, y1].map(|c| c as usize);
            if tiles.hides(bounds, nearest) {
                return;
            }
        }
        let index = self.tris.len() as u32;
        self.tris.push(ScreenTri {
            x: [v[0].sx, v[1].sx, v[2].sx],
            y: [v[0].sy, v[1].sy, v[2].sy],
            inv_z: [v[0].inv_z, v[1].inv_z, v[2].inv_z],
            gray_z: [0, 1, 2].map(|k| v[k].gray * v[k].inv_z),
            u_z: [0, 1, 2].map(|k| v[k].uv[0] * v[k].inv_z),
            v_z: [0, 1, 2].map(|k| v[k].uv[1] * v[k].inv_z),
            texture,
            order,
            bbox: [x0 as u16, x1 as u16, y0 as u16, y1 as u16],
        });
        let (b0, b1) = (y0 as usize / BAND_ROWS, y1 as usize / BAND_ROWS);
        for bin in &mut self.bins[b0..=b1] {
            bin.push(index);
        }
    }
}
