//! The CPU rasterizer: the keyframe renderer of last resort, the renderer
//! `star synth` draws synthetic camera images with, and the reference the
//! GPU renderer is tested against.
//!
//! Takes a validated [`Mesh`] once, then renders a pose and an ideal pinhole
//! camera into a [`RenderedView`]: gray (vertex gray, times the bilinear
//! texel / 255 on textured groups) and metric depth (z in the camera optical
//! frame), [`crate::render::NO_DEPTH`] and gray 0 where nothing is hit.
//!
//! Pipeline, each stage parallel over fixed work units (rayon):
//! 1. [`view`]: vertices into the camera frame, outcodes, projection to
//!    fixed-point pixels (8 fraction bits, pixel centers at integers);
//! 2. [`setup`]: per chunk of [`setup::CHUNK_TRIS`] triangles, cull, clip
//!    against the near plane (`z = 0.05 m`) and the guard band ([`clip`]),
//!    and bin into bands of [`setup::BAND_ROWS`] rows;
//! 3. [`raster`]: per band, integer edge functions with a top-left rule,
//!    z-buffer on `1/z`, perspective-correct interpolation, shading.
//!
//! Each band is owned by one task and sees its triangles in mesh order, so
//! the output is bit-identical for any thread count. No back-face culling.
//! All scratch (camera-frame vertices, screen triangles, bins) lives in the
//! renderer and keeps its capacity, so steady-state renders do not allocate
//! beyond what rayon does to schedule tasks.

mod clip;
mod raster;
mod setup;
mod validate;
mod view;

#[cfg(test)]
mod tests;
#[cfg(test)]
mod tests_scenes;

use std::sync::Arc;

use rayon::prelude::*;

use self::setup::{Chunk, BAND_ROWS, CHUNK_TRIS};
use self::view::{CamVertex, View};
use crate::geometry::{PinholeCamera, Pose};
use crate::map::Mesh;
use crate::render::{check_request, RenderError, RenderedView, Renderer};

/// Vertices per task of the vertex stage.
const VERTEX_CHUNK: usize = 8192;

/// The tiled, multithreaded software rasterizer. See the module docs.
pub struct CpuRenderer {
    mesh: Arc<Mesh>,
    /// Texture index of each triangle (or `setup::NO_TEXTURE`).
    tri_texture: Vec<u32>,
    /// Dedicated thread pool, or `None` for rayon's global pool.
    pool: Option<rayon::ThreadPool>,
    /// Camera-frame vertices of the current render.
    verts: Vec<CamVertex>,
    /// Setup scratch, one per chunk of `CHUNK_TRIS` triangles.
    chunks: Vec<Chunk>,
}

impl std::fmt::Debug for CpuRenderer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CpuRenderer")
            .field("triangles", &self.mesh.triangle_count())
            .field("threads", &self.threads())
            .finish()
    }
}

impl CpuRenderer {
    /// A renderer of `mesh` on rayon's global thread pool. Fails when the
    /// mesh has non-finite values or out-of-range indices.
    pub fn new(mesh: Arc<Mesh>) -> Result<Self, RenderError> {
        let tri_texture = validate::validate_mesh(&mesh)?;
        let chunks = (0..tri_texture.len().div_ceil(CHUNK_TRIS))
            .map(|_| Chunk::default())
            .collect();
        Ok(Self {
            verts: vec![CamVertex::default(); mesh.positions.len()],
            mesh,
            tri_texture,
            pool: None,
            chunks,
        })
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

    /// The mesh being rendered.
    pub fn mesh(&self) -> &Arc<Mesh> {
        &self.mesh
    }
}

impl Renderer for CpuRenderer {
    fn name(&self) -> String {
        "cpu".to_string()
    }

    fn render(
        &mut self,
        world_from_camera: &Pose,
        camera: &PinholeCamera,
        out: &mut RenderedView,
    ) -> Result<(), RenderError> {
        check_request(world_from_camera, camera)?;
        out.check_size(camera)?;
        let view = View::new(world_from_camera, camera);
        let Self {
            mesh,
            tri_texture,
            pool,
            verts,
            chunks,
        } = self;
        let mut work = || draw(mesh, tri_texture, verts, chunks, &view, out);
        match pool {
            Some(pool) => pool.install(work),
            None => work(),
        }
        Ok(())
    }
}

/// Runs the three stages. `out` has been checked against `view`.
fn draw(
    mesh: &Mesh,
    tri_texture: &[u32],
    verts: &mut [CamVertex],
    chunks: &mut [Chunk],
    view: &View,
    out: &mut RenderedView,
) {
    verts
        .par_chunks_mut(VERTEX_CHUNK)
        .zip(mesh.positions.par_chunks(VERTEX_CHUNK))
        .for_each(|(out_v, in_p)| {
            for (v, p) in out_v.iter_mut().zip(in_p) {
                *v = view.vertex(*p);
            }
        });
    let verts = &*verts;
    let bands = view.height.div_ceil(BAND_ROWS);
    chunks.par_iter_mut().enumerate().for_each(|(i, chunk)| {
        chunk.build(i * CHUNK_TRIS, mesh, tri_texture, verts, view, bands);
    });
    let chunks = &*chunks;
    let band_len = view.width * BAND_ROWS;
    out.gray
        .data_mut()
        .par_chunks_mut(band_len)
        .zip(out.depth_m.data_mut().par_chunks_mut(band_len))
        .enumerate()
        .for_each(|(band, (gray, depth_m))| {
            raster::draw_band(
                band,
                band * BAND_ROWS,
                view.width,
                chunks,
                &mesh.textures,
                gray,
                depth_m,
            );
        });
}
