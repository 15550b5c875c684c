//! Spatial chunks of a mesh, shared by both renderers so that a render costs
//! what is visible, not the map.
//!
//! Takes a validated [`Mesh`] once, at renderer construction, and gives out
//! a [`ChunkedMesh`]: the triangles split into spatially compact
//! [`MeshChunk`]s of at most [`MAX_CHUNK_TRIS`] (median splits on the longest
//! axis of the triangle centroids), each a contiguous range of the reordered
//! index buffer with a contiguous range of vertices of its own (a vertex
//! shared by two chunks is copied into both, so a chunk can be transformed
//! without the rest) and a world-frame [`Aabb`]. A chunk never mixes
//! triangles of two mesh groups. Within a chunk triangles keep their mesh
//! order; [`ChunkedMesh::source_triangle`] maps each back to its mesh index,
//! which the CPU rasterizer uses to break depth ties exactly as in mesh
//! order.
//!
//! With levels of detail ([`super::lod`]), coarse copies of runs of
//! chunks follow the fine chunks.
//!
//! Per render, each chunk's box (or, at a level of detail, its copy's) is
//! tested against the view [`Frustum`] ([`mark_visible`]).

use std::ops::Range;

use super::frustum::Frustum;
use super::lod::{self, LodTable, LodView};
use crate::map::Mesh;
use crate::render::RenderError;

/// Most triangles in one chunk: the CPU rasterizer's unit of setup work.
pub const MAX_CHUNK_TRIS: usize = 4096;

/// Group number of triangles outside every mesh group.
pub const NO_GROUP: u32 = u32::MAX;

/// An axis-aligned box in the world frame, meters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Aabb {
    /// Smallest coordinates.
    pub min_m: [f32; 3],
    /// Largest coordinates.
    pub max_m: [f32; 3],
}

impl Aabb {
    /// The box that contains nothing (grows from the first point added).
    pub(super) const EMPTY: Self = Self {
        min_m: [f32::INFINITY; 3],
        max_m: [f32::NEG_INFINITY; 3],
    };

    pub(super) fn add(&mut self, p: [f32; 3]) {
        for k in 0..3 {
            self.min_m[k] = self.min_m[k].min(p[k]);
            self.max_m[k] = self.max_m[k].max(p[k]);
        }
    }
}

/// One chunk: a contiguous run of triangles and of vertices.
#[derive(Debug, Clone, PartialEq)]
pub struct MeshChunk {
    /// Triangles (index `t` covers indices `3t..3t + 3`) of [`ChunkedMesh`].
    pub triangles: Range<u32>,
    /// The vertices these triangles use, and no others.
    pub vertices: Range<u32>,
    /// The mesh group of every triangle, or [`NO_GROUP`].
    pub group: u32,
    /// Bounds of the chunk's vertices.
    pub bounds: Aabb,
}

impl MeshChunk {
    /// Number of triangles.
    pub fn triangle_count(&self) -> usize {
        self.triangles.len()
    }

    /// Indices into [`ChunkedMesh::indices`].
    pub fn index_range(&self) -> Range<u32> {
        3 * self.triangles.start..3 * self.triangles.end
    }
}

/// A mesh reordered into spatial chunks. See the module docs.
#[derive(Debug, Clone, Default)]
pub struct ChunkedMesh {
    /// Vertex positions, world frame, meters (chunk by chunk).
    pub positions: Vec<[f32; 3]>,
    /// Vertex gray, 0..=255.
    pub gray: Vec<f32>,
    /// Texture coordinates; empty when the mesh has none.
    pub uvs: Vec<[f32; 2]>,
    /// Triangle indices into `positions`, chunk by chunk.
    pub indices: Vec<u32>,
    /// Mesh triangle number of each triangle here.
    pub source_triangle: Vec<u32>,
    /// The chunks, in index-buffer order: by group (mesh group order, then
    /// the ungrouped triangles), each group in the order of its split tree.
    pub chunks: Vec<MeshChunk>,
    /// How fine the mesh's appearance is, meters ([`Mesh::detail_spacing_m`]):
    /// every render of it says so ([`super::RenderedView::detail_m`]).
    pub detail_m: f32,
    /// Which chunks are coarse copies of which ([`super::lod`]): the fine
    /// chunks come first, in the order above, then the coarse copies.
    pub lod: LodTable,
}

/// Per-render counts of the frustum test.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct CullStats {
    /// Chunks in the mesh.
    pub chunks: usize,
    /// Chunks that passed the test (drawn).
    pub visible_chunks: usize,
    /// Triangles in the mesh.
    pub triangles: usize,
    /// Triangles in the chunks that passed.
    pub visible_triangles: usize,
}

impl CullStats {
    /// The share of triangles drawn, 0..=1 (1 for an empty mesh).
    pub fn visible_fraction(&self) -> f64 {
        if self.triangles == 0 {
            1.0
        } else {
            self.visible_triangles as f64 / self.triangles as f64
        }
    }
}

fn too_large(what: &str, count: usize) -> RenderError {
    RenderError::InvalidMesh {
        field: "indices",
        index: count,
        reason: format!("{what}: more than 2^32 after splitting into chunks"),
    }
}

impl ChunkedMesh {
    /// Splits `mesh` (already validated by the renderer: indices in range,
    /// groups whole triangles) into chunks, without levels of detail. Fails
    /// only when the copied vertices or indices no longer fit `u32`.
    pub fn build(mesh: &Mesh) -> Result<Self, RenderError> {
        Self::build_with_levels(mesh, false)
    }

    /// As [`ChunkedMesh::build`], with coarse copies of runs of chunks
    /// appended when `levels` ([`super::lod`]).
    pub fn build_with_levels(mesh: &Mesh, levels: bool) -> Result<Self, RenderError> {
        let triangles = mesh.indices.len() / 3;
        if triangles > u32::MAX as usize / 3 {
            return Err(too_large("triangles", triangles));
        }
        // Group of each triangle; group ranges were validated.
        let mut tri_group = vec![NO_GROUP; triangles];
        for (g, group) in mesh.groups.iter().enumerate() {
            let first = group.first_index as usize / 3;
            let last = first + group.index_count as usize / 3;
            if let Some(slots) = tri_group.get_mut(first..last) {
                slots.fill(g as u32);
            }
        }
        let position = |v: u32| mesh.positions.get(v as usize).copied().unwrap_or([0.0; 3]);
        let centroids: Vec<[f32; 3]> = mesh
            .indices
            .chunks_exact(3)
            .map(|t| {
                let (a, b, c) = (position(t[0]), position(t[1]), position(t[2]));
                [0, 1, 2].map(|k| (a[k] + b[k] + c[k]) / 3.0)
            })
            .collect();
        // Triangles grouped by group (in group order, ungrouped last), mesh
        // order within each group, then each group split.
        let mut order: Vec<u32> = (0..triangles as u32).collect();
        order.sort_by_key(|&t| tri_group[t as usize]);
        let mut leaves: Vec<(u32, Range<usize>)> = Vec::new();
        let mut start = 0;
        while start < order.len() {
            let group = tri_group[order[start] as usize];
            let end = start
                + order[start..]
                    .iter()
                    .position(|&t| tri_group[t as usize] != group)
                    .unwrap_or(order.len() - start);
            split(&mut order, start..end, &centroids, &mut |range| {
                leaves.push((group, range))
            });
            start = end;
        }
        // Only the order is needed from here; on a 15 M-triangle scan the
        // centroids and groups are 235 MB the copy and the levels of
        // detail below would otherwise hold beside their own arrays.
        drop(centroids);
        drop(tri_group);

        let mut out = Self {
            positions: Vec::with_capacity(mesh.positions.len() + mesh.positions.len() / 4),
            gray: Vec::with_capacity(mesh.positions.len() + mesh.positions.len() / 4),
            uvs: Vec::new(),
            indices: Vec::with_capacity(mesh.indices.len()),
            source_triangle: Vec::with_capacity(triangles),
            chunks: Vec::with_capacity(leaves.len()),
            detail_m: mesh.detail_spacing_m(),
            lod: LodTable::default(),
        };
        // For the levels of detail: the mesh vertex each copied vertex
        // copies, and the first and last chunk using each mesh vertex.
        let mut vertex_source: Vec<u32> = Vec::new();
        let per_vertex = |fill: u32| {
            if levels {
                vec![fill; mesh.positions.len()]
            } else {
                Vec::new()
            }
        };
        let mut first_chunk = per_vertex(u32::MAX);
        let mut last_chunk = per_vertex(0);
        let has_uvs = !mesh.uvs.is_empty();
        // Local number of each mesh vertex in the chunk being built, valid
        // where `stamp` holds that chunk's number.
        let mut local = vec![0u32; mesh.positions.len()];
        let mut stamp = vec![u32::MAX; mesh.positions.len()];
        for (chunk_number, (group, range)) in leaves.into_iter().enumerate() {
            let tris = &mut order[range];
            tris.sort_unstable();
            let first_tri = out.source_triangle.len() as u32;
            let first_vertex = out.positions.len();
            let mut bounds = Aabb::EMPTY;
            for &t in tris.iter() {
                let Some(tri) = mesh.indices.get(3 * t as usize..3 * t as usize + 3) else {
                    continue;
                };
                for &v in tri {
                    let v = v as usize;
                    let (Some(slot), Some(seen)) = (local.get_mut(v), stamp.get_mut(v)) else {
                        continue;
                    };
                    if *seen != chunk_number as u32 {
                        *seen = chunk_number as u32;
                        if levels {
                            vertex_source.push(v as u32);
                            if let Some(first) = first_chunk.get_mut(v) {
                                *first = (*first).min(chunk_number as u32);
                            }
                            if let Some(last) = last_chunk.get_mut(v) {
                                *last = chunk_number as u32;
                            }
                        }
                        let n = out.positions.len();
                        if n >= u32::MAX as usize {
                            return Err(too_large("vertices", n));
                        }
                        *slot = n as u32;
                        let p = mesh.positions.get(v).copied().unwrap_or([0.0; 3]);
                        bounds.add(p);
                        out.positions.push(p);
                        out.gray.push(mesh.gray.get(v).copied().unwrap_or(0.0));
                        if has_uvs {
                            out.uvs.push(mesh.uvs.get(v).copied().unwrap_or([0.0; 2]));
                        }
                    }
                    out.indices.push(*slot);
                }
                out.source_triangle.push(t);
            }
            out.chunks.push(MeshChunk {
                triangles: first_tri..out.source_triangle.len() as u32,
                vertices: first_vertex as u32..out.positions.len() as u32,
                group,
                bounds,
            });
        }
        drop((local, stamp, order));
        out.lod = LodTable::fine_only(out.chunks.len());
        if levels {
            let origins = lod::VertexOrigins {
                vertex_source: &vertex_source,
                first_chunk: &first_chunk,
                last_chunk: &last_chunk,
            };
            lod::build_levels(&mut out, mesh, &origins)?;
        }
        Ok(out)
    }

    /// Number of triangles.
    pub fn triangle_count(&self) -> usize {
        self.source_triangle.len()
    }

    /// See [`mark_visible`].
    pub fn mark_visible(
        &self,
        lod: Option<&LodView>,
        frustum: Option<&Frustum>,
        visible: &mut Vec<bool>,
    ) -> CullStats {
        mark_visible(&self.chunks, &self.lod, lod, frustum, visible)
    }
}

/// Triangles per cluster (the last of a chunk may have fewer): the unit
/// of both renderers' occlusion culls within a chunk.
pub const CLUSTER_TRIS: usize = 256;

// A cluster's number within its chunk fits `u8`.
const _: () = assert!(MAX_CHUNK_TRIS / CLUSTER_TRIS <= 256);

/// A run of [`CLUSTER_TRIS`] consecutive triangles of one chunk (a
/// contiguous range of the index buffer), with the chunk-local range of
/// vertices they use and their bounds.
#[derive(Debug, Clone)]
pub struct Cluster {
    /// Chunk-local triangle numbers.
    pub triangles: Range<usize>,
    /// Chunk-local vertex numbers: every vertex of these triangles lies in
    /// this range.
    pub vertices: Range<usize>,
    /// Bounds of those triangles' vertices, world frame.
    pub bounds: Aabb,
    /// The plane all its triangles lie in, facing their front
    /// ([`FrontPlane`]); `None` when they do not share one.
    pub plane: Option<FrontPlane>,
}

/// Largest distance of a vertex from its cluster's plane, meters, for the
/// cluster to count as flat ([`FrontPlane`]).
pub const PLANE_TOL_M: f64 = 1e-4;

/// Smallest cosine between a triangle's normal and its cluster's plane's
/// for the cluster to count as flat.
const PLANE_COS_MIN: f64 = 0.9999;

/// A camera counts as behind a flat cluster only when it is behind its
/// plane by at least this share of its distance to the cluster's farthest
/// point (the sine of the grazing angle, about 3 degrees), so that every
/// triangle is clockwise on the image by a margin that rounding does not
/// turn over.
pub const BEHIND_SIN_MIN: f64 = 0.05;

/// The plane of a flat cluster, `normal . p = offset_m`, the unit `normal`
/// pointing to the side from which every triangle of the cluster is
/// counter-clockwise (its front). A camera behind it sees only back faces:
/// with back faces culled, the cluster can be skipped whole, before its
/// vertices are transformed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrontPlane {
    /// Unit normal, world frame.
    pub normal: [f64; 3],
    /// Offset along the normal, meters.
    pub offset_m: f64,
}

impl FrontPlane {
    /// The plane of triangles `tris` (vertex indices into `positions`),
    /// when they all lie within [`PLANE_TOL_M`] of one and their normals
    /// (counter-clockwise) agree within [`PLANE_COS_MIN`]; triangles of no
    /// area are checked for their vertices only.
    pub fn fit(positions: &[[f32; 3]], tris: &[u32]) -> Option<Self> {
        let at = |i: u32| positions.get(i as usize).map(|p| p.map(f64::from));
        let cross = |t: &[u32]| -> Option<[f64; 3]> {
            let (a, b, c) = (at(t[0])?, at(t[1])?, at(t[2])?);
            let (u, v) = (sub(b, a), sub(c, a));
            Some([
                u[1] * v[2] - u[2] * v[1],
                u[2] * v[0] - u[0] * v[2],
                u[0] * v[1] - u[1] * v[0],
            ])
        };
        // The largest triangle gives the normal.
        let mut best = ([0.0; 3], 0.0);
        for t in tris.chunks_exact(3) {
            let n = cross(t)?;
            let len = dot(n, n).sqrt();
            if len > best.1 {
                best = (n, len);
            }
        }
        if best.1 <= 0.0 {
            return None;
        }
        let normal = best.0.map(|x| x / best.1);
        let offset_m = dot(normal, at(*tris.first()?)?);
        for t in tris.chunks_exact(3) {
            let n = cross(t)?;
            let len = dot(n, n).sqrt();
            if len > 0.0 && dot(n, normal) < PLANE_COS_MIN * len {
                return None;
            }
            for &i in t {
                if (dot(normal, at(i)?) - offset_m).abs() > PLANE_TOL_M {
                    return None;
                }
            }
        }
        Some(Self { normal, offset_m })
    }

    /// Whether a camera at `eye_m` is behind the plane by the margin
    /// [`BEHIND_SIN_MIN`] of its distance to the farthest corner of
    /// `bounds` (the cluster's box): then every triangle of the cluster is
    /// a back face on its image.
    pub fn is_behind(&self, bounds: &Aabb, eye_m: [f64; 3]) -> bool {
        let behind_m = self.offset_m - dot(self.normal, eye_m);
        if behind_m <= 0.0 {
            return false;
        }
        let far: [f64; 3] = std::array::from_fn(|k| {
            let (lo, hi) = (f64::from(bounds.min_m[k]), f64::from(bounds.max_m[k]));
            (eye_m[k] - lo).abs().max((eye_m[k] - hi).abs())
        });
        behind_m >= BEHIND_SIN_MIN * dot(far, far).sqrt()
    }
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// The clusters of `chunk` of `mesh`, in triangle order.
pub fn clusters(mesh: &ChunkedMesh, chunk: &MeshChunk) -> Vec<Cluster> {
    let first_vertex = chunk.vertices.start as usize;
    let (t0, t1) = (chunk.triangles.start as usize, chunk.triangles.end as usize);
    let indices = mesh.indices.get(3 * t0..3 * t1).unwrap_or(&[]);
    indices
        .chunks(3 * CLUSTER_TRIS)
        .enumerate()
        .map(|(k, run)| {
            let mut bounds = Aabb {
                min_m: [f32::INFINITY; 3],
                max_m: [f32::NEG_INFINITY; 3],
            };
            let (mut lo, mut hi) = (usize::MAX, 0);
            for &i in run {
                let p = mesh.positions.get(i as usize).copied().unwrap_or([0.0; 3]);
                for a in 0..3 {
                    bounds.min_m[a] = bounds.min_m[a].min(p[a]);
                    bounds.max_m[a] = bounds.max_m[a].max(p[a]);
                }
                let local = (i as usize).saturating_sub(first_vertex);
                lo = lo.min(local);
                hi = hi.max(local + 1);
            }
            let first = k * CLUSTER_TRIS;
            Cluster {
                triangles: first..first + run.len() / 3,
                vertices: lo.min(hi)..hi,
                bounds,
                plane: FrontPlane::fit(&mesh.positions, run),
            }
        })
        .collect()
}

/// Sets `visible[i]` for every chunk `i` (`visible` is resized to the chunk
/// count, without allocating after the first call): see [`LodTable::mark`]
/// (without coarse copies or without a view: each chunk, when it passes
/// `frustum`, or always when `frustum` is `None`).
pub fn mark_visible(
    chunks: &[MeshChunk],
    table: &LodTable,
    view: Option<&LodView>,
    frustum: Option<&Frustum>,
    visible: &mut Vec<bool>,
) -> CullStats {
    table.mark(chunks, view, frustum, visible)
}

/// Splits `order[range]` at the median centroid on the longest axis of the
/// centroids' bounds until every part holds at most [`MAX_CHUNK_TRIS`]
/// triangles; calls `leaf` with each part, in tree order. Ties are broken by
/// triangle number, so the split does not depend on the sort algorithm.
fn split(
    order: &mut [u32],
    range: Range<usize>,
    centroids: &[[f32; 3]],
    leaf: &mut impl FnMut(Range<usize>),
) {
    let mut stack = vec![range];
    while let Some(range) = stack.pop() {
        if range.len() <= MAX_CHUNK_TRIS {
            leaf(range);
            continue;
        }
        let tris = &mut order[range.clone()];
        let mut bounds = Aabb::EMPTY;
        for &t in tris.iter() {
            bounds.add(centroids[t as usize]);
        }
        let extent = [0, 1, 2].map(|k| bounds.max_m[k] - bounds.min_m[k]);
        let axis = if extent[0] >= extent[1] && extent[0] >= extent[2] {
            0
        } else if extent[1] >= extent[2] {
            1
        } else {
            2
        };
        let mid = tris.len() / 2;
        tris.select_nth_unstable_by(mid, |&a, &b| {
            centroids[a as usize][axis]
                .total_cmp(&centroids[b as usize][axis])
                .then(a.cmp(&b))
        });
        let split_at = range.start + mid;
        // Popped in reverse: the low half first.
        stack.push(split_at..range.end);
        stack.push(range.start..split_at);
    }
}

#[cfg(test)]
#[allow(clippy::expect_used, clippy::unwrap_used)]
mod tests {
    use super::*;
    use crate::geometry::{PinholeCamera, Pose};
    use crate::map::MeshGroup;

    /// An `n x n` grid of quads on the plane z = `z`, spanning x, y in
    /// `[-half, half]`.
    fn grid(n: usize, half: f32, z: f32) -> Mesh {
        let mut mesh = Mesh::default();
        for j in 0..=n {
            for i in 0..=n {
                let s = |k: usize| -half + 2.0 * half * k as f32 / n as f32;
                mesh.positions.push([s(i), s(j), z]);
                mesh.gray.push((i + j) as f32);
            }
        }
        let at = |i: usize, j: usize| (j * (n + 1) + i) as u32;
        for j in 0..n {
            for i in 0..n {
                mesh.indices
                    .extend([at(i, j), at(i + 1, j), at(i + 1, j + 1)]);
                mesh.indices
                    .extend([at(i, j), at(i + 1, j + 1), at(i, j + 1)]);
            }
        }
        mesh
    }

    #[test]
    fn chunks_partition_the_triangles_and_keep_them_intact() {
        let mut mesh = grid(100, 5.0, 2.0);
        // Two groups, the first not starting at 0: a third kind, ungrouped.
        let n = mesh.indices.len() as u32;
        mesh.groups = vec![
            MeshGroup {
                first_index: 300,
                index_count: n / 2 - 300 - (n / 2) % 3,
                texture: None,
            },
            MeshGroup {
                first_index: n / 2 - (n / 2) % 3,
                index_count: n - (n / 2 - (n / 2) % 3),
                texture: None,
            },
        ];
        let chunked = ChunkedMesh::build(&mesh).unwrap();
        let tris = mesh.indices.len() / 3;
        assert_eq!(chunked.triangle_count(), tris);
        let mut seen = vec![false; tris];
        let mut next_tri = 0;
        let mut next_vertex = 0;
        for chunk in &chunked.chunks {
            assert!(chunk.triangle_count() <= MAX_CHUNK_TRIS);
            assert_eq!(chunk.triangles.start, next_tri);
            assert_eq!(chunk.vertices.start, next_vertex);
            next_tri = chunk.triangles.end;
            next_vertex = chunk.vertices.end;
            for t in chunk.triangles.clone() {
                let src = chunked.source_triangle[t as usize] as usize;
                assert!(!std::mem::replace(&mut seen[src], true));
                let group = mesh
                    .groups
                    .iter()
                    .position(|g| {
                        let first = g.first_index as usize / 3;
                        (first..first + g.index_count as usize / 3).contains(&src)
                    })
                    .map_or(NO_GROUP, |g| g as u32);
                assert_eq!(chunk.group, group);
                for k in 0..3 {
                    let v = chunked.indices[3 * t as usize + k];
                    assert!(chunk.vertices.contains(&v), "vertex outside its chunk");
                    let p = chunked.positions[v as usize];
                    let orig = mesh.indices[3 * src + k] as usize;
                    assert_eq!(p, mesh.positions[orig]);
                    assert_eq!(chunked.gray[v as usize], mesh.gray[orig]);
                    for a in 0..3 {
                        assert!(chunk.bounds.min_m[a] <= p[a] && p[a] <= chunk.bounds.max_m[a]);
                    }
                }
            }
        }
        assert!(seen.iter().all(|&s| s));
        // Groups in order, ungrouped last.
        let groups: Vec<u32> = chunked.chunks.iter().map(|c| c.group).collect();
        assert!(groups.windows(2).all(|w| w[0] <= w[1]), "{groups:?}");
        assert_eq!(groups.last(), Some(&NO_GROUP));
        // Compact: 20k triangles on 10 x 10 m give chunks well under the grid.
        let widest = chunked
            .chunks
            .iter()
            .map(|c| {
                (c.bounds.max_m[0] - c.bounds.min_m[0]).max(c.bounds.max_m[1] - c.bounds.min_m[1])
            })
            .fold(0.0f32, f32::max);
        assert!(widest < 6.0, "widest chunk {widest} m");
    }

    #[test]
    fn mark_visible_counts_chunks_and_triangles() {
        let mut mesh = grid(60, 5.0, 2.0);
        // Far enough behind that the first split separates the planes.
        let behind = grid(60, 5.0, -20.0);
        let base = mesh.positions.len() as u32;
        mesh.positions.extend(&behind.positions);
        mesh.gray.extend(&behind.gray);
        mesh.indices.extend(behind.indices.iter().map(|i| i + base));
        let chunked = ChunkedMesh::build(&mesh).unwrap();
        let cam = PinholeCamera::new(64, 48, 50.0, 50.0, 31.5, 23.5);
        let f = Frustum::new(&Pose::identity(), &cam, 0.05);
        let mut visible = Vec::new();
        let all = chunked.mark_visible(None, None, &mut visible);
        assert_eq!(all.visible_chunks, all.chunks);
        assert_eq!(all.visible_triangles, mesh.indices.len() / 3);
        let stats = chunked.mark_visible(None, Some(&f), &mut visible);
        assert_eq!(stats.chunks, chunked.chunks.len());
        assert!(stats.visible_chunks > 0);
        // The plane behind the camera is half the mesh: all of it culled.
        assert!(stats.visible_fraction() <= 0.5, "{stats:?}");
        for (chunk, &v) in chunked.chunks.iter().zip(&visible) {
            if chunk.bounds.max_m[2] < 0.0 {
                assert!(!v, "chunk behind the camera kept");
            }
        }
    }

    #[test]
    fn a_flat_cluster_has_a_front_plane_and_is_behind_it_only_by_a_margin() {
        // Counter-clockwise seen from +z: the front faces up.
        let mesh = grid(4, 1.0, 2.0);
        let plane = FrontPlane::fit(&mesh.positions, &mesh.indices).expect("flat");
        assert!((plane.normal[2] - 1.0).abs() < 1e-12, "{plane:?}");
        assert!((plane.offset_m - 2.0).abs() < 1e-6, "{plane:?}");
        let bounds = Aabb {
            min_m: [-1.0, -1.0, 2.0],
            max_m: [1.0, 1.0, 2.0],
        };
        assert!(plane.is_behind(&bounds, [0.0, 0.0, 0.0]));
        assert!(!plane.is_behind(&bounds, [0.0, 0.0, 4.0]));
        assert!(!plane.is_behind(&bounds, [0.3, 0.2, 2.0]));
        // 5 cm below the plane, 10 m away: a grazing view, under the margin.
        assert!(!plane.is_behind(&bounds, [10.0, 0.0, 1.95]));
        assert!(plane.is_behind(&bounds, [10.0, 0.0, 1.0]));
        // One triangle wound the other way, or a vertex 1 mm off the plane:
        // no plane.
        let mut flipped = mesh.indices.clone();
        flipped.swap(0, 1);
        assert!(FrontPlane::fit(&mesh.positions, &flipped).is_none());
        let mut bent = mesh.positions.clone();
        bent[7][2] += 1e-3;
        assert!(FrontPlane::fit(&bent, &mesh.indices).is_none());
        // A chunk's clusters of the flat grid get the plane.
        let chunked = ChunkedMesh::build(&mesh).expect("chunks");
        let chunk = chunked.chunks.first().expect("a chunk");
        assert!(clusters(&chunked, chunk).iter().all(|c| c.plane.is_some()));
    }
}
