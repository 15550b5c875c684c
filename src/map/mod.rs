//! The map: a gray-intensity triangle mesh of the building, in the world
//! frame, in meters.
//!
//! Owns mesh loading (OBJ through `tobj`, with per-vertex colors or MTL
//! diffuse textures), validation, and bounds. Gives out a [`Mesh`] that every
//! renderer consumes as-is: positions, per-vertex gray, per-vertex texture
//! coordinates, triangle indices grouped by texture, and gray textures.
//!
//! - [`load_obj`] / [`write_obj`]: Wavefront OBJ + MTL + textures, to gray.
//! - [`Mesh::validate`]: the structural checks every loader and renderer
//!   relies on, with [`MapError`] / [`MeshProblem`] naming the defect.
//! - [`subdivide`]: 1-to-4 subdivision for large benchmark meshes.
//! - [`floor::find_floor`]: the floor's height, which the relocalization
//!   grid's heights are measured from.

mod config;
mod error;
pub mod floor;
mod obj;
mod obj_write;
mod subdivide;
mod validate;

pub use config::{MapConfig, MeshTransformConfig, MESH_SCALE_RANGE};
pub use error::{MapError, MeshProblem, IN_MEMORY};
pub use obj::{load_gray_texture, load_obj, luma601_255, MAX_VERTEX_COLOR, MAX_VERTEX_COORDINATE};
pub use obj_write::write_obj;
pub use subdivide::{subdivide, MAX_SUBDIVIDED_TRIANGLES};

/// A texture converted to gray intensity (0..=255 as f32), row-major,
/// with `v = 0` at the top row (image convention, OBJ `vt` is flipped on load).
#[derive(Debug, Clone, PartialEq)]
pub struct GrayTexture {
    /// Width in texels.
    pub width: u32,
    /// Height in texels.
    pub height: u32,
    /// Intensities, row-major, `width * height` of them.
    pub texels: Vec<f32>,
}

/// A run of triangles that share one texture (or none).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MeshGroup {
    /// Offset into [`Mesh::indices`] of the first index (multiple of 3).
    pub first_index: u32,
    /// Number of indices (multiple of 3).
    pub index_count: u32,
    /// Texture in [`Mesh::textures`]; `None` means per-vertex gray only.
    /// When set, the surface intensity is `vertex_gray/255 * texel`
    /// (the texture modulated by the vertex color, as OBJ `Kd * map_Kd`).
    pub texture: Option<u32>,
}

/// A triangle mesh with gray intensity, ready to render.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Mesh {
    /// Vertex positions in the world frame, meters.
    pub positions: Vec<[f32; 3]>,
    /// Per-vertex gray intensity, 0..=255.
    pub gray: Vec<f32>,
    /// Per-vertex texture coordinates, `[u, v]` with v down (image rows);
    /// zero when the vertex has none; may be empty when no group is textured.
    pub uvs: Vec<[f32; 2]>,
    /// Triangle vertex indices, three per triangle, counter-clockwise or not
    /// (renderers do not cull back faces).
    pub indices: Vec<u32>,
    /// Triangle groups by texture, covering `indices` exactly once, in
    /// order; empty means every triangle is untextured.
    pub groups: Vec<MeshGroup>,
    /// Gray textures referenced by the groups.
    pub textures: Vec<GrayTexture>,
}

impl Mesh {
    /// Number of triangles.
    pub fn triangle_count(&self) -> usize {
        self.indices.len() / 3
    }

    /// Axis-aligned bounds `(min, max)` of the vertices; `None` when empty.
    pub fn bounds(&self) -> Option<([f32; 3], [f32; 3])> {
        let first = *self.positions.first()?;
        Some(self.positions.iter().fold((first, first), |(lo, hi), p| {
            (
                [lo[0].min(p[0]), lo[1].min(p[1]), lo[2].min(p[2])],
                [hi[0].max(p[0]), hi[1].max(p[1]), hi[2].max(p[2])],
            )
        }))
    }
}
