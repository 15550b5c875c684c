//! The wgpu keyframe renderer (paper section II-B).
//!
//! Owns a wgpu device on one adapter (hardware, or Mesa's software
//! lavapipe/llvmpipe), the mesh split into spatial chunks and uploaded once
//! (vertex and index buffers, gray textures sampled bilinearly with repeat
//! addressing; each render draws only the chunks that meet the view
//! frustum, adjacent ones merged into one draw call, and of those the
//! clusters not hidden behind what a first pass drew: `occlusion`) or,
//! when its vertex
//! and index data exceed `[render] gpu_budget_mb`, streamed through a
//! fixed pool of chunk slots (`stream`), the pipeline
//! built from `shaders/mesh.wgsl`, and the
//! offscreen targets: gray and linear metric depth (both `R32Float`, written
//! by the shader) plus a `Depth32Float` z-buffer for occlusion. Takes a pose
//! and pinhole intrinsics per render; gives out a [`RenderedView`] through
//! the [`Renderer`] trait, or through [`GpuRenderer::submit`] and
//! [`GpuRenderer::collect`], which pipeline the readback of one view with
//! the render of the next (two staging buffers, rows padded to 256 bytes,
//! `map_async`).
//!
//! Pixel centers are at integer coordinates as everywhere in `star`; the
//! half-pixel shift to wgpu's fragment centers is in [`projection`].
//! Back faces are drawn unless culled ([`GpuRenderer::set_cull_back_faces`],
//! the same triangles the CPU rasterizer culls); surfaces closer than [`projection::NEAR_M`] are
//! clipped. Pixels that see nothing get [`crate::render::NO_DEPTH`] and gray 0.
//!
//! Errors (validation, out of memory, device lost) are caught by the
//! device's error handler and returned as [`GpuError`] from the next call;
//! `render::select` then falls back to the next renderer.

pub mod adapter;
pub mod cull_timing;
mod draws;
mod frame;
mod occlusion;
mod pass;
mod pipeline;
pub mod projection;
mod renderer;
mod stream;
mod upload;

pub use adapter::{
    auto_choice, lavapipe_installed, list_adapters, AdapterClass, AdapterPreference, AdapterSummary,
};
pub use occlusion::OcclusionStats;
pub use renderer::{GpuMemory, GpuRenderer, PendingRender};
pub use stream::StreamStats;
pub use upload::TextureFormat;

#[cfg(doc)]
use crate::render::{RenderedView, Renderer};

/// Errors from the wgpu renderer.
#[derive(Debug, thiserror::Error)]
pub enum GpuError {
    /// No adapter of the requested class could open a device.
    #[error("no {preference} wgpu adapter could be used (seen: {seen})")]
    NoAdapter {
        /// The class asked for.
        preference: AdapterPreference,
        /// Every adapter seen, with why each was not used.
        seen: String,
    },
    /// The mesh is not renderable (see [`crate::map::Mesh::validate`]).
    #[error("mesh rejected by the wgpu renderer: {0}")]
    Mesh(#[from] crate::map::MapError),
    /// The mesh could not be split into chunks (too many vertices or
    /// indices after the split).
    #[error("mesh cannot be split into chunks: {0}")]
    Chunks(String),
    /// A texture is larger than the adapter allows.
    #[error(
        "mesh texture {texture} is {width}x{height}, the adapter allows at most \
         {max_dimension} texels a side"
    )]
    TextureTooLarge {
        /// Texture number.
        texture: usize,
        /// Width found.
        width: u32,
        /// Height found.
        height: u32,
        /// The adapter's `max_texture_dimension_2d`.
        max_dimension: u32,
    },
    /// `render.gpu_budget_mb` is nonzero, below the mesh's vertex and
    /// index data, and too small for even one chunk slot.
    #[error(
        "render.gpu_budget_mb = {budget_mb} MB cannot hold one chunk of this mesh \
         ({triangles} triangles, {chunks} chunks): the minimum is {min_mb} MB (one \
         slot of the largest chunk); the whole mesh takes {mesh_mb} MB; 0 turns the budget off"
    )]
    BudgetTooSmall {
        /// The budget, MB (10^6 bytes).
        budget_mb: f64,
        /// The smallest budget that streams this mesh, MB, rounded up.
        min_mb: f64,
        /// The mesh's vertex and index data when wholly resident, MB.
        mesh_mb: f64,
        /// Chunks in the mesh.
        chunks: usize,
        /// Triangles in the mesh.
        triangles: usize,
    },
    /// A vertex or index buffer exceeds the adapter's buffer size limit.
    #[error("mesh buffer of {bytes} bytes exceeds the adapter limit of {max_bytes} bytes")]
    MeshTooLarge {
        /// Bytes needed.
        bytes: u64,
        /// The adapter's `max_buffer_size`.
        max_bytes: u64,
    },
    /// The camera image is empty or larger than the adapter's textures.
    #[error("image size {width}x{height} is not within 1..={max_dimension} a side")]
    TargetSize {
        /// Requested width.
        width: u32,
        /// Requested height.
        height: u32,
        /// The adapter's `max_texture_dimension_2d`.
        max_dimension: u32,
    },
    /// Both staging buffers hold readbacks not yet collected, or the image
    /// size changed while one was in flight.
    #[error("both readback buffers are in flight; collect a pending render first")]
    Busy,
    /// The device reported an error (validation, out of memory, internal) or was lost.
    #[error("wgpu device on {adapter} failed: {message}")]
    Device {
        /// The adapter's name.
        adapter: String,
        /// wgpu's message.
        message: String,
    },
    /// The render did not finish in time.
    #[error("render on {adapter} did not finish within {waited_secs} s")]
    Timeout {
        /// The adapter's name.
        adapter: String,
        /// How long it waited.
        waited_secs: u64,
    },
    /// Mapping the staging buffer for readback failed.
    #[error("readback mapping failed on {adapter}")]
    MapFailed {
        /// The adapter's name.
        adapter: String,
    },
    /// A failure injected by [`GpuRenderer::inject_failure_after`] (tests).
    #[error("injected failure after {renders} renders")]
    Injected {
        /// Renders that succeeded before it.
        renders: u64,
    },
}

impl From<GpuError> for crate::render::RenderError {
    fn from(e: GpuError) -> Self {
        match e {
            GpuError::BudgetTooSmall { .. } => crate::render::RenderError::Setting(e.to_string()),
            e => crate::render::RenderError::Backend(e.to_string()),
        }
    }
}
