//! The CPU rasterizer: the keyframe renderer of last resort, the renderer
//! `star synth` draws synthetic camera images with, and the reference the
//! GPU renderer is tested against.
//!
//! Takes a validated [`Mesh`] once, then renders a pose and an ideal pinhole
//! camera into a [`RenderedView`]: gray (vertex gray, times the bilinear
//! texel / 255 on textured groups) and metric depth (z in the camera optical
//! frame), [`crate::render::NO_DEPTH`] and gray 0 where nothing is hit.
//!
//! At construction the mesh is split into spatial chunks
//! ([`crate::render::chunks`]); a render sets up only the chunks whose box
//! meets the view frustum (cut at the far limit, when one is set with
//! [`CpuRenderer::set_far_m`]), and draws them in batches (first what the
//! previous render saw when its camera was near, then nearest first),
//! skipping the chunks, the clusters of 256 triangles and the triangles
//! hidden behind what earlier batches drew ([`occlusion`]), so its cost
//! follows what is visible.
//!
//! Pipeline, per batch, each stage parallel over fixed work units (rayon):
//! 1. [`setup`], per chunk of the batch, cluster by cluster (a cluster
//!    outside the frustum or hidden is skipped whole): its vertices into
//!    the camera frame ([`view`]: outcodes, projection to fixed-point
//!    pixels, 8 fraction bits, pixel centers at integers), then its
//!    triangles culled, clipped against the near plane (`z = 0.05 m`) and
//!    the guard band ([`clip`]), and, unless hidden, binned into bands of
//!    [`setup::BAND_ROWS`] rows;
//! 2. [`raster`]: per band, integer edge functions with a top-left rule,
//!    z-buffer on `1/z`, perspective-correct interpolation, shading; then
//!    the band's occlusion tiles for the next batch.
//!
//! Each band is owned by one task and sees its triangles in a fixed order;
//! of two at equal depth on a pixel the one first in mesh order wins (a
//! per-pixel triangle number breaks the tie), so the output is the same as
//! drawing the whole mesh in mesh order, bit for bit, for any thread count
//! and with or without the culls, whatever was rendered before. Both sides
//! of a triangle are drawn unless back faces are culled
//! ([`Renderer::set_cull_back_faces`], for maps wound counter-clockwise
//! toward where they are seen). All scratch
//! (camera-frame vertices, sized at construction; screen triangles and bins,
//! which grow per chunk to the most it has shown, as before the cull) lives
//! in the renderer and keeps its capacity, so steady-state renders do not
//! allocate beyond what rayon does to schedule tasks.

mod batches;
mod clip;
mod occlusion;
mod raster;
mod setup;
mod validate;
mod view;

#[cfg(test)]
mod tests;
#[cfg(test)]
mod tests_cull;
#[cfg(test)]
mod tests_scenes;

use std::sync::Arc;

use self::batches::draw;
use self::occlusion::Occlusion;
use self::setup::{ChunkSetup, SetupSlot, NO_TEXTURE};
use self::view::{View, NEAR_M};
use crate::geometry::{PinholeCamera, Pose};
use crate::map::{GrayTexture, Mesh, MeshGroup};
use crate::render::chunks::{ChunkedMesh, CullStats};
use crate::render::frustum::Frustum;
use crate::render::lod::LodView;
use crate::render::{check_request, RenderError, RenderedView, Renderer};

/// The tiled, multithreaded software rasterizer. See the module docs.
pub struct CpuRenderer {
    /// The map's gray textures (shared by the renderers of one map). The
    /// map's own vertex and index arrays are not kept: everything drawn
    /// comes from `chunked`.
    textures: Arc<[GrayTexture]>,
    /// Triangles in the map.
    map_triangles: usize,
    /// The mesh split into spatial chunks (shared by the renderers of one
    /// map: [`CpuRenderer::share`]).
    chunked: Arc<ChunkedMesh>,
    /// Dedicated thread pool, or `None` for rayon's global pool.
    pool: Option<rayon::ThreadPool>,
    /// What the setup of each chunk of `chunked` needs (its clusters);
    /// shared like `chunked`.
    setups: Arc<[ChunkSetup]>,
    /// Setup scratch: one slot per chunk of the largest batch drawn so far
    /// (not per chunk of the map: a floor's views set up a few percent of
    /// its chunks, and a slot holds a chunk's camera-frame vertices and
    /// screen triangles, about 90 bytes a triangle).
    slots: Vec<SetupSlot>,
    /// Whether each chunk passed the frustum test in the current render.
    visible: Vec<bool>,
    /// Per pixel, the mesh number of the triangle drawn there (valid where
    /// depth is set): the depth tie-break.
    tri_order: Vec<u32>,
    /// Whether chunks outside the frustum are skipped (on by default).
    cull: bool,
    /// Counts of the last render's frustum test.
    stats: CullStats,
    /// Far limit along the optical axis, meters; `None`: none.
    far_m: Option<f64>,
    /// Whether chunks hidden behind nearer ones are skipped (on by
    /// default, with the frustum cull).
    occlusion_cull: bool,
    /// Scratch of the occlusion cull.
    occlusion: Occlusion,
    /// The chunks of the current batch.
    batch: Vec<u32>,
    /// Screen triangles binned in the last render.
    binned_triangles: usize,
    /// Largest level-of-detail cell on the image, pixels (0: full detail).
    lod_max_px: f32,
    /// Whether back faces are culled (off by default).
    cull_back_faces: bool,
}

impl std::fmt::Debug for CpuRenderer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CpuRenderer")
            .field("triangles", &self.map_triangles)
            .field("threads", &self.threads())
            .finish()
    }
}

impl CpuRenderer {
    /// A renderer of `mesh` on rayon's global thread pool. Fails when the
    /// mesh has non-finite values or out-of-range indices. The renderer
    /// keeps its own chunked copy of the mesh and a copy of its textures,
    /// not `mesh`: drop it once the renderers are built.
    pub fn new(mesh: Arc<Mesh>) -> Result<Self, RenderError> {
        Self::with_lod(mesh, 0.0)
    }

    /// As [`CpuRenderer::new`], drawing chunks at a coarser level of
    /// detail where its error spans at most `lod_max_px` pixels
    /// (0: full detail, exactly as [`CpuRenderer::new`]; see
    /// [`crate::render::lod`] and
    /// [`crate::render::RenderConfig::lod_max_px`]).
    pub fn with_lod(mesh: Arc<Mesh>, lod_max_px: f32) -> Result<Self, RenderError> {
        validate::validate_mesh(&mesh)?;
        let lod_max_px = crate::render::lod::cell_limit_px(lod_max_px);
        let chunked = Arc::new(ChunkedMesh::build_with_levels(&mesh, lod_max_px > 0.0)?);
        let textures: Arc<[GrayTexture]> = mesh.textures.as_slice().into();
        Ok(Self::on_chunks(
            &mesh.groups,
            textures,
            mesh.triangle_count(),
            chunked,
            lod_max_px,
        ))
    }

    /// Another renderer of the same map, sharing this one's chunked mesh
    /// (and its levels of detail) rather than building its own: one per
    /// thread of a database build holds the map's chunks once. Its own
    /// settings start at the defaults, but for the level of detail and the
    /// far limit, which are this one's; on rayon's global pool.
    pub fn share(&self) -> Self {
        let mut other = Self::with_setups(
            Arc::clone(&self.setups),
            Arc::clone(&self.textures),
            self.map_triangles,
            Arc::clone(&self.chunked),
            self.lod_max_px,
        );
        other.far_m = self.far_m;
        other.cull_back_faces = self.cull_back_faces;
        other
    }

    fn on_chunks(
        groups: &[MeshGroup],
        textures: Arc<[GrayTexture]>,
        map_triangles: usize,
        chunked: Arc<ChunkedMesh>,
        lod_max_px: f32,
    ) -> Self {
        let setups: Arc<[ChunkSetup]> = chunked
            .chunks
            .iter()
            .map(|c| {
                ChunkSetup::new(
                    c,
                    &chunked,
                    groups
                        .get(c.group as usize)
                        .and_then(|g| g.texture)
                        .unwrap_or(NO_TEXTURE),
                )
            })
            .collect();
        Self::with_setups(setups, textures, map_triangles, chunked, lod_max_px)
    }

    fn with_setups(
        setups: Arc<[ChunkSetup]>,
        textures: Arc<[GrayTexture]>,
        map_triangles: usize,
        chunked: Arc<ChunkedMesh>,
        lod_max_px: f32,
    ) -> Self {
        let chunked_count = chunked.chunks.len();
        let occlusion = Occlusion::new(setups.iter().map(ChunkSetup::cluster_count));
        Self {
            visible: vec![true; chunked.chunks.len()],
            textures,
            map_triangles,
            chunked,
            pool: None,
            setups,
            slots: Vec::new(),
            tri_order: Vec::new(),
            cull: true,
            stats: CullStats::default(),
            far_m: None,
            occlusion_cull: true,
            occlusion,
            batch: Vec::with_capacity(chunked_count),
            binned_triangles: 0,
            lod_max_px,
            cull_back_faces: false,
        }
    }

    /// Sets the largest level-of-detail cell on the image, pixels (0: full
    /// detail). Only a renderer built [`CpuRenderer::with_lod`] a positive
    /// size has coarse chunks to choose from; for others this changes
    /// nothing.
    pub fn set_lod_max_px(&mut self, lod_max_px: f32) {
        self.lod_max_px = crate::render::lod::cell_limit_px(lod_max_px);
    }

    /// Number of coarse chunks (levels of detail) the renderer holds.
    pub fn coarse_chunks(&self) -> usize {
        self.chunked.lod.coarse_chunks()
    }

    /// A renderer of `mesh` on its own pool of `threads` threads (at least
    /// one). The output does not depend on the thread count.
    pub fn with_threads(mesh: Arc<Mesh>, threads: usize) -> Result<Self, RenderError> {
        let mut renderer = Self::new(mesh)?;
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads.max(1))
            .thread_name(|i| format!("star-cpu-render-{i}"))
            .build()
            .map_err(|e| RenderError::Backend(format!("cannot start render threads: {e}")))?;
        renderer.pool = Some(pool);
        Ok(renderer)
    }

    /// Number of threads rendering.
    pub fn threads(&self) -> usize {
        self.pool
            .as_ref()
            .map_or_else(rayon::current_num_threads, |p| p.current_num_threads())
    }

    /// Turns the skipping of chunks outside the view frustum on (the
    /// default) or off. The output is the same either way; off, every
    /// triangle is set up (for tests and benchmarks).
    pub fn set_frustum_cull(&mut self, on: bool) {
        self.cull = on;
    }

    /// Chunk and triangle counts of the last render's frustum test (less
    /// the chunks the occlusion cull skipped).
    pub fn cull_stats(&self) -> CullStats {
        self.stats
    }

    /// Screen triangles the last render binned for rasterization: those of
    /// the chunks it set up that cover a pixel center, after near-plane
    /// clipping, less those the occlusion cull dropped.
    pub fn binned_triangles(&self) -> usize {
        self.binned_triangles
    }

    /// Turns the skipping of chunks hidden behind nearer ones on (the
    /// default) or off. It works only with the frustum cull on. The output
    /// is the same either way.
    pub fn set_occlusion_cull(&mut self, on: bool) {
        self.occlusion_cull = on;
    }

    /// Sets the far limit (`None`, the default: none): pixels deeper than
    /// `far_m` along the optical axis render as no hit, and chunks wholly
    /// beyond it are not set up.
    pub fn set_far_m(&mut self, far_m: Option<f64>) {
        self.far_m = far_m.filter(|f| f.is_finite() && *f > f64::from(NEAR_M));
    }

    /// Chunks and triangles of the chunks that own at least one pixel of
    /// the last render's image (`out`, as it left it): what an exact
    /// chunk-level visibility cull would still have to draw. For benchmarks
    /// and tests; allocates.
    pub fn seen_chunks(&self, out: &RenderedView) -> (usize, usize) {
        let (chunks, triangles, _) = self.seen(out);
        (chunks, triangles)
    }

    /// [`CpuRenderer::seen_chunks`], and the number of mesh triangles that
    /// own at least one pixel.
    pub fn seen(&self, out: &RenderedView) -> (usize, usize, usize) {
        let mut chunk_of = vec![0u32; self.chunked.triangle_count()];
        for (c, chunk) in self.chunked.chunks.iter().enumerate() {
            for t in chunk.triangles.clone() {
                if let Some(&src) = self.chunked.source_triangle.get(t as usize) {
                    if let Some(slot) = chunk_of.get_mut(src as usize) {
                        *slot = c as u32;
                    }
                }
            }
        }
        let mut seen = vec![false; self.chunked.chunks.len()];
        let mut seen_triangle = vec![false; self.chunked.triangle_count()];
        for (&d, &t) in out.depth_m.data().iter().zip(&self.tri_order) {
            if RenderedView::is_hit(d) {
                if let Some(s) = seen_triangle.get_mut(t as usize) {
                    *s = true;
                }
                if let Some(&c) = chunk_of.get(t as usize) {
                    if let Some(s) = seen.get_mut(c as usize) {
                        *s = true;
                    }
                }
            }
        }
        let triangles = self
            .chunked
            .chunks
            .iter()
            .zip(&seen)
            .filter(|(_, &s)| s)
            .map(|(c, _)| c.triangle_count())
            .sum();
        (
            seen.iter().filter(|&&s| s).count(),
            triangles,
            seen_triangle.iter().filter(|&&s| s).count(),
        )
    }

    /// Bytes the renderer holds for the mesh: the chunked copy (vertices,
    /// indices, triangle numbers) plus the textures.
    pub fn mesh_bytes(&self) -> u64 {
        let c = &self.chunked;
        let texels: usize = self.textures.iter().map(|t| t.texels.len()).sum();
        (c.positions.len() * 12
            + c.gray.len() * 4
            + c.uvs.len() * 8
            + c.indices.len() * 4
            + c.source_triangle.len() * 4
            + texels * 4) as u64
    }
}

impl Renderer for CpuRenderer {
    fn name(&self) -> String {
        "cpu".to_string()
    }

    /// A triangle clockwise on the image (screen y down) is dropped at
    /// setup; a flat cluster seen from behind its plane is skipped whole
    /// (`chunks::FrontPlane`). The wgpu renderer culls the same triangles.
    fn set_cull_back_faces(&mut self, on: bool) {
        self.cull_back_faces = on;
    }

    fn cull_back_faces(&self) -> bool {
        self.cull_back_faces
    }

    fn set_far_m(&mut self, far_m: Option<f64>) {
        CpuRenderer::set_far_m(self, far_m);
    }

    fn far_m(&self) -> Option<f64> {
        self.far_m
    }

    fn render(
        &mut self,
        world_from_camera: &Pose,
        camera: &PinholeCamera,
        out: &mut RenderedView,
    ) -> Result<(), RenderError> {
        check_request(world_from_camera, camera)?;
        out.check_size(camera)?;
        let view = View::new(world_from_camera, camera)
            .with_far(self.far_m)
            .with_back_faces_culled(self.cull_back_faces);
        let frustum = Frustum::new(world_from_camera, camera, f64::from(NEAR_M))
            .with_far(world_from_camera, self.far_m);
        let Self {
            textures,
            chunked,
            pool,
            setups,
            slots,
            visible,
            tri_order,
            cull,
            stats,
            occlusion_cull,
            occlusion,
            batch,
            binned_triangles,
            lod_max_px,
            ..
        } = self;
        let lod = LodView::new(world_from_camera, camera, *lod_max_px);
        *stats = chunked.mark_visible(lod.as_ref(), cull.then_some(&frustum), visible);
        // Sized once per image size; no allocation in steady state.
        tri_order.resize(view.width * view.height, 0);
        let position = world_from_camera.translation.vector;
        let position_m = [position.x, position.y, position.z];
        let occlusion = if *cull && *occlusion_cull {
            Some(occlusion)
        } else {
            occlusion.forget();
            None
        };
        let work = || {
            draw(
                chunked,
                textures,
                visible,
                (setups, slots),
                (&view, cull.then_some(&frustum)),
                tri_order,
                out,
                occlusion.map(|o| (o, position_m)),
                batch,
            )
        };
        let (hidden_chunks, hidden_triangles, binned) = match pool {
            Some(pool) => pool.install(work),
            None => work(),
        };
        *binned_triangles = binned;
        out.detail_m = chunked.detail_m;
        stats.visible_chunks -= hidden_chunks;
        stats.visible_triangles -= hidden_triangles;
        Ok(())
    }
}
