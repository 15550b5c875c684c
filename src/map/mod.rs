//! The map: a gray-intensity triangle mesh of the building, in the world
//! frame, in meters.
//!
//! Owns mesh loading (OBJ through `tobj`, PLY through `ply-rs-bw`, glTF and
//! GLB through `gltf`; the format from the extension, checked against the
//! content), validation, bounds, and finding the floor. Gives out a
//! [`Mesh`] that every renderer consumes as-is: positions, per-vertex gray,
//! per-vertex texture coordinates, triangle indices grouped by texture, and
//! gray textures.
//!
//! - [`load_mesh`]: any supported format, by extension ([`MapFormat`]);
//!   [`load_obj`], [`load_ply`], [`load_gltf`] for one format.
//! - [`write_obj`], [`write_ply`], [`write_glb`]: the inverse, for tests,
//!   tools and conversions.
//! - [`Mesh::validate`]: the structural checks every loader and renderer
//!   relies on, with [`MapError`] / [`MeshProblem`] naming the defect.
//! - [`subdivide`]: 1-to-4 subdivision for large benchmark meshes.
//! - [`floor::find_floor`]: the floor's height in a z-up map, which the
//!   relocalization grid's heights are measured from;
//!   [`align::find_floor_plane`]: the floor of a mesh in any frame (RANSAC),
//!   and the `world_from_mesh` that makes it z-up.

pub mod align;
mod config;
mod detail;
mod error;
pub mod floor;
mod format;
mod gltf;
mod gltf_write;
mod obj;
mod obj_write;
mod ply;
mod ply_write;
pub mod repeats;
mod subdivide;
mod validate;

pub use config::{MapConfig, MeshTransformConfig, MESH_SCALE_RANGE};
pub use error::{MapError, MeshProblem, IN_MEMORY};
pub use format::{check_content, load_mesh, MapFormat};
pub use gltf::load_gltf;
pub use gltf_write::write_glb;
pub use obj::{
    gray_texture, load_gray_texture, load_obj, luma601_255, MAX_VERTEX_COLOR, MAX_VERTEX_COORDINATE,
};
pub use obj_write::write_obj;
pub use ply::load_ply;
pub use ply_write::{write_ply, PlyEncoding};
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
    /// Triangle vertex indices, three per triangle, counter-clockwise or not:
    /// the renderers draw both sides, unless `[render] cull_back_faces` says
    /// the map's triangles are counter-clockwise seen from where they can
    /// be seen (the front), as `star synth`'s maps and TSDF scans mostly are.
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
