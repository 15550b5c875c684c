//! The draw list of one wgpu render.
//!
//! Takes the uploaded chunks (with the bind group each samples, or none for
//! chunks that are not drawn), the render's [`Frustum`] and reused buffers;
//! gives out the draw calls: the index ranges of the chunks that pass the
//! frustum test, runs of adjacent chunks of one bind group merged into one
//! `draw_indexed`, in index-buffer order (mesh group order, as before
//! chunking); or, for a streamed mesh, the visible chunks themselves, in
//! the same order, for `super::stream` to place in slots.

use std::ops::Range;

use crate::render::chunks::{self, CullStats, MeshChunk};
use crate::render::frustum::Frustum;
use crate::render::lod::{LodTable, LodView};

/// One draw call: an index range and the texture bind group it samples.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Draw {
    /// Indices into the index buffer.
    pub indices: Range<u32>,
    /// Added to every index (a streamed chunk's slot; 0 when resident).
    pub base_vertex: i32,
    /// Index of the bind group in [`super::upload::GpuMesh::texture_groups`].
    pub texture: usize,
}

/// Fills `draws` (cleared first) with the chunks, at the level of detail
/// `lod` chooses ([`chunks::mark_visible`]), that pass `frustum` (all of
/// them when `None`) and have a bind group in `chunk_texture`; `visible`
/// is scratch. Neither buffer allocates once it has held every chunk.
pub fn select(
    (chunks, table): (&[MeshChunk], &LodTable),
    chunk_texture: &[Option<usize>],
    (lod, frustum): (Option<&LodView>, Option<&Frustum>),
    visible: &mut Vec<bool>,
    draws: &mut Vec<Draw>,
) -> CullStats {
    let stats = chunks::mark_visible(chunks, table, lod, frustum, visible);
    draws.clear();
    for ((chunk, &texture), &visible) in chunks.iter().zip(chunk_texture).zip(visible.iter()) {
        let (Some(texture), true) = (texture, visible) else {
            continue;
        };
        let indices = chunk.index_range();
        match draws.last_mut() {
            Some(last) if last.texture == texture && last.indices.end == indices.start => {
                last.indices.end = indices.end;
            }
            _ => draws.push(Draw {
                indices,
                base_vertex: 0,
                texture,
            }),
        }
    }
    stats
}

/// Fills `wanted` (cleared first) with the numbers of the chunks, at the
/// level of detail `lod` chooses, that pass `frustum` (all of them when
/// `None`) and have a bind group in `chunk_texture`, in index-buffer
/// order; `visible` is scratch. Neither buffer allocates once it has held
/// every chunk.
pub fn visible_chunks(
    (chunks, table): (&[MeshChunk], &LodTable),
    chunk_texture: &[Option<usize>],
    (lod, frustum): (Option<&LodView>, Option<&Frustum>),
    visible: &mut Vec<bool>,
    wanted: &mut Vec<u32>,
) -> CullStats {
    let stats = chunks::mark_visible(chunks, table, lod, frustum, visible);
    wanted.clear();
    for (c, (texture, &visible)) in chunk_texture.iter().zip(visible.iter()).enumerate() {
        if texture.is_some() && visible {
            wanted.push(c as u32);
        }
    }
    stats
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{PinholeCamera, Pose};
    use crate::render::chunks::Aabb;

    /// A chunk of `n` triangles from `first`, in a 1 m box at `x` along the
    /// optical axis (z) of an identity camera.
    fn chunk(first: u32, n: u32, z_m: f32) -> MeshChunk {
        MeshChunk {
            triangles: first..first + n,
            vertices: 0..0,
            group: 0,
            bounds: Aabb {
                min_m: [-0.5, -0.5, z_m - 0.5],
                max_m: [0.5, 0.5, z_m + 0.5],
            },
        }
    }

    #[test]
    fn adjacent_visible_chunks_of_one_texture_merge() {
        // In front, in front, behind, in front (texture 1), in front,
        // undrawn, in front.
        let chunks = [
            chunk(0, 10, 3.0),
            chunk(10, 5, 3.0),
            chunk(15, 5, -3.0),
            chunk(20, 5, 3.0),
            chunk(25, 5, 3.0),
            chunk(30, 5, 3.0),
            chunk(35, 5, 3.0),
        ];
        let texture = [Some(0), Some(0), Some(0), Some(1), Some(0), None, Some(0)];
        let cam = PinholeCamera::new(64, 48, 50.0, 50.0, 31.5, 23.5);
        let frustum = Frustum::new(&Pose::identity(), &cam, 0.05);
        let (mut visible, mut draws) = (Vec::new(), Vec::new());
        let fine = LodTable::fine_only(chunks.len());
        let stats = select(
            (&chunks, &fine),
            &texture,
            (None, Some(&frustum)),
            &mut visible,
            &mut draws,
        );
        assert_eq!(stats.visible_chunks, 6);
        assert_eq!(stats.visible_triangles, 35);
        let d = |indices: Range<u32>, texture: usize| Draw {
            indices,
            base_vertex: 0,
            texture,
        };
        assert_eq!(
            draws,
            vec![d(0..45, 0), d(60..75, 1), d(75..90, 0), d(105..120, 0)]
        );
        // Without the frustum, the chunk behind joins the first run.
        select(
            (&chunks, &fine),
            &texture,
            (None, None),
            &mut visible,
            &mut draws,
        );
        assert_eq!(
            draws,
            vec![d(0..60, 0), d(60..75, 1), d(75..90, 0), d(105..120, 0)]
        );
        // For streaming: the chunks themselves, without the undrawn one.
        let mut wanted = Vec::new();
        let stats = visible_chunks(
            (&chunks, &fine),
            &texture,
            (None, Some(&frustum)),
            &mut visible,
            &mut wanted,
        );
        assert_eq!(stats.visible_chunks, 6);
        assert_eq!(wanted, vec![0, 1, 3, 4, 6]);
    }
}
