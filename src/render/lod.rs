//! Levels of detail of a chunked mesh: coarser copies of groups of its
//! chunks, drawn instead of them where the camera cannot tell the
//! difference.
//!
//! Owns [`LodTable`] (built once with the chunks, [`build_levels`]) and the
//! per-render choice ([`LodView`], [`LodTable::mark`]). A scanned map (a
//! TSDF mesh, vertex-colored, 1-2 cm triangles) has millions of triangles
//! smaller than a pixel wherever the camera looks down a corridor, and
//! every one costs a vertex transform and a setup; at the database's
//! 160x128 thumbnails almost all of them do. A textured map cut into small
//! cells (the `building` preset's 3.7 cm) has as many, on surfaces that are
//! flat and mapped affinely, where far fewer triangles draw the same image.
//!
//! **The coarse copies.** The chunks of one mesh group are the leaves of a
//! binary tree of median splits ([`super::chunks`]), each node a contiguous
//! run of chunks. In a vertex-colored group the nodes 2, 4 and 6 levels
//! above the deepest leaves (4, 16 and 64 chunks) get one coarse copy each;
//! in a textured group each chunk gets one, at the finest cell (see below).
//! A copy is simplified by vertex
//! clustering (Rossignac and Borrel): the node's vertices are pooled in
//! cubic cells of 2, 4 and 8 times the median edge (of the vertex-colored
//! triangles, or of the textured ones), each cell's vertices become one
//! vertex at their mean position, mean gray and mean texture coordinates,
//! and the triangles that collapse are dropped. A vertex the node shares
//! with a chunk outside it is never moved, so a coarse copy meets its
//! neighbors, fine or coarse, at exactly the same border: no crack opens
//! between levels. In a textured copy the vertices on an open edge (a
//! wall's outline, a doorway's edge) stay too, and only vertices whose
//! normals face the same way share a cell, so faces that meet without
//! sharing vertices are not pooled together. A copy is kept only with at
//! most [`KEEP_RATIO`] of the node's triangles and at most
//! [`MAX_COARSE_TRIS`]. Coarse chunks are appended after the fine ones in
//! [`super::chunks::ChunkedMesh::chunks`]; each coarse triangle carries the
//! mesh number of the first triangle that made it, for the renderers'
//! depth tie-break.
//!
//! **Each copy's error** ([`LodNode::error_m`]), meters on the surface. A
//! vertex-colored copy's appearance is in its vertices, averaged over a
//! cell: its error is the cell. A textured copy's appearance is in the
//! texture, which a flat surface with an affine mapping keeps exactly
//! whatever its triangles: its error is measured ([`textured_error_m`]:
//! each fine vertex's distance from the coarse triangles at its cell, and
//! the shift of the texture there), and is its cell where the shading
//! (the vertex gray that modulates the texture) changed by more than
//! [`GRAY_TOLERANCE`].
//!
//! A textured copy of error 0 is drawn near the camera too, so its grain
//! is what the frustum and occlusion culls work with: copies of 4 chunks
//! made the culls' boxes 4 times larger and a floor's keyframe slower than
//! copies of one chunk; copies of one chunk at 4 and 8 times the median
//! edge lost shading detail (their error is their cell) and gained
//! nothing.
//!
//! **The choice.** A render draws, for each run of chunks, the coarsest
//! copy whose error, at the copy's box's nearest point to the camera, spans
//! at most `max_px` pixels (`[render] lod_max_px`), else the chunks
//! themselves, node by node down the tree; the frustum test is then made on
//! what was chosen. The choice depends only on the pose, the camera and the
//! map, never on the culls, so a culled render stays identical to an
//! unculled one, and both renderers choose alike. A vertex-colored copy's
//! vertex moves by less than a cell (its mean stays inside the cell), so an
//! outline moves by less than `max_px` pixels, and a surface's depth by
//! less than a cell. A textured copy of error 0 is drawn at every
//! distance.

use std::collections::HashMap;
use std::ops::Range;

use super::chunks::{
    Aabb, ChunkedMesh, CullStats, MeshChunk, CLUSTER_TRIS, MAX_CHUNK_TRIS, NO_GROUP,
};
use super::frustum::Frustum;
use crate::geometry::{PinholeCamera, Pose};
use crate::map::Mesh;

/// Number of coarse levels.
pub const LEVELS: usize = 3;

/// Cell size of coarse level `l` (0-based) in median edges.
const CELL_EDGES: [f32; LEVELS] = [2.0, 4.0, 8.0];

/// Tree levels above the deepest leaves of the nodes of coarse level `l`.
const NODE_HEIGHT: [usize; LEVELS] = [2, 4, 6];

/// A copy is kept only with at most this share of its node's triangles.
pub const KEEP_RATIO: f32 = 0.5;

/// Most triangles in a coarse copy: 256 clusters (a cluster's number
/// within its chunk fits `u8`).
pub const MAX_COARSE_TRIS: usize = 256 * CLUSTER_TRIS;

/// Triangles sampled for the median edge.
const EDGE_SAMPLES: usize = 100_000;

/// A level-of-detail cell limit as the renderers keep it, pixels: `px`
/// when a finite number of at least 0, else 0 (full detail).
pub fn cell_limit_px(px: f32) -> f32 {
    if px.is_finite() {
        px.max(0.0)
    } else {
        0.0
    }
}

/// One coarse copy: of which chunks, at which level, where, and how far
/// from them it may stray.
#[derive(Debug, Clone, PartialEq)]
pub struct LodNode {
    /// The fine chunks it replaces (a contiguous run).
    pub chunks: Range<u32>,
    /// Its level, 0..[`LEVELS`].
    pub level: u8,
    /// Its chunk number in [`ChunkedMesh::chunks`].
    pub coarse: u32,
    /// How far the copy's image may stray from the chunks', meters on the
    /// surface: the level's cell for an untextured copy, the measured
    /// error for a textured one ([`textured_error_m`]).
    pub error_m: f32,
}

/// Which chunks are coarse copies of which. See the module docs.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct LodTable {
    /// The chunks of full detail: `chunks[..fine_chunks]`.
    pub fine_chunks: usize,
    /// Cell size of each level, meters (0 when there are no coarse copies).
    pub cell_m: [f32; LEVELS],
    /// The coarse copies by first chunk, the largest run first.
    pub nodes: Vec<LodNode>,
}

/// What one render needs to choose levels: where the camera is and how
/// large a meter is on its image.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LodView {
    position_m: [f32; 3],
    /// Largest focal length, pixels.
    focal_px: f32,
    /// Largest cell on the image, pixels.
    max_px: f32,
}

impl LodView {
    /// The choice for `camera` at `world_from_camera` with cells of at
    /// most `max_px` pixels; `None` (full detail everywhere) when `max_px`
    /// is not a positive number.
    pub fn new(world_from_camera: &Pose, camera: &PinholeCamera, max_px: f32) -> Option<Self> {
        let t = world_from_camera.translation.vector;
        let focal_px = camera.fx.abs().max(camera.fy.abs()) as f32;
        (max_px > 0.0 && max_px.is_finite() && focal_px > 0.0 && focal_px.is_finite()).then_some(
            Self {
                position_m: [t.x as f32, t.y as f32, t.z as f32],
                focal_px,
                max_px,
            },
        )
    }

    /// Distance from the camera to the nearest point of `bounds`, meters.
    fn distance_m(&self, bounds: &Aabb) -> f32 {
        let mut d2 = 0.0f32;
        for k in 0..3 {
            let p = self.position_m[k];
            let gap = (bounds.min_m[k] - p).max(p - bounds.max_m[k]).max(0.0);
            d2 += gap * gap;
        }
        d2.sqrt()
    }

    /// Whether an error of `error_m` spans at most `max_px` pixels at the
    /// nearest point of `bounds`.
    fn fits(&self, error_m: f32, bounds: &Aabb) -> bool {
        error_m * self.focal_px <= self.max_px * self.distance_m(bounds)
    }
}

impl LodTable {
    /// The table of a mesh without coarse copies: `fine_chunks` chunks.
    pub fn fine_only(fine_chunks: usize) -> Self {
        Self {
            fine_chunks,
            cell_m: [0.0; LEVELS],
            nodes: Vec::new(),
        }
    }

    /// Number of coarse copies.
    pub fn coarse_chunks(&self) -> usize {
        self.nodes.len()
    }

    /// Sets `visible[i]` for every chunk `i` of `chunks` (resized to their
    /// count, without allocating after the first call): for each run of
    /// fine chunks, the coarsest copy `view` allows, else each chunk
    /// itself (every fine chunk without a view), marked when it passes
    /// `frustum` (always when `None`); every other chunk is not. The
    /// counts are of the fine chunks and of what was chosen.
    pub fn mark(
        &self,
        chunks: &[MeshChunk],
        view: Option<&LodView>,
        frustum: Option<&Frustum>,
        visible: &mut Vec<bool>,
    ) -> CullStats {
        visible.resize(chunks.len(), false);
        visible.fill(false);
        let fine = self.fine_chunks.min(chunks.len());
        let mut stats = CullStats {
            chunks: fine,
            ..CullStats::default()
        };
        let mut mark = |c: usize, stats: &mut CullStats| {
            let Some(chunk) = chunks.get(c) else {
                return;
            };
            let seen = frustum.is_none_or(|f| f.intersects(&chunk.bounds));
            if let Some(v) = visible.get_mut(c) {
                *v = seen;
            }
            if seen {
                stats.visible_chunks += 1;
                stats.visible_triangles += chunk.triangle_count();
            }
        };
        let mut next_node = 0;
        let mut i = 0;
        while i < fine {
            while self
                .nodes
                .get(next_node)
                .is_some_and(|n| (n.chunks.start as usize) < i)
            {
                next_node += 1;
            }
            let chosen = view.and_then(|view| {
                self.nodes[next_node.min(self.nodes.len())..]
                    .iter()
                    .take_while(|n| n.chunks.start as usize == i)
                    .find(|n| {
                        chunks
                            .get(n.coarse as usize)
                            .is_some_and(|c| view.fits(n.error_m, &c.bounds))
                    })
            });
            match chosen {
                Some(n) => {
                    mark(n.coarse as usize, &mut stats);
                    i = (n.chunks.end as usize).max(i + 1);
                }
                None => {
                    mark(i, &mut stats);
                    i += 1;
                }
            }
        }
        stats.triangles = chunks
            .iter()
            .take(fine)
            .map(MeshChunk::triangle_count)
            .sum();
        stats
    }
}

/// Position of vertex `i` of `chunked`, meters (the origin if out of range).
fn position_m(chunked: &ChunkedMesh, i: u32) -> [f32; 3] {
    chunked
        .positions
        .get(i as usize)
        .copied()
        .unwrap_or([0.0; 3])
}

/// Whether the chunks of `group` are untextured (their appearance is in
/// their vertices' gray).
fn untextured(mesh: &Mesh, group: u32) -> bool {
    if group == NO_GROUP {
        return mesh.groups.is_empty();
    }
    mesh.groups
        .get(group as usize)
        .is_some_and(|g| g.texture.is_none())
}

/// Whether the chunks of `group` sample a texture.
fn textured(mesh: &Mesh, group: u32) -> bool {
    group != NO_GROUP
        && mesh
            .groups
            .get(group as usize)
            .is_some_and(|g| g.texture.is_some())
}

/// Median edge length of the untextured (`want_textured` false) or
/// textured triangles of `chunked` (sampled), meters; `None` when there
/// are none.
fn median_edge_m(chunked: &ChunkedMesh, mesh: &Mesh, want_textured: bool) -> Option<f32> {
    let of_kind = |c: &&MeshChunk| {
        if want_textured {
            textured(mesh, c.group)
        } else {
            untextured(mesh, c.group)
        }
    };
    let tris: usize = chunked
        .chunks
        .iter()
        .filter(of_kind)
        .map(MeshChunk::triangle_count)
        .sum();
    if tris == 0 {
        return None;
    }
    let stride = tris.div_ceil(EDGE_SAMPLES).max(1);
    let mut edges = Vec::with_capacity(3 * (tris / stride + 1));
    let mut k = 0usize;
    for chunk in chunked.chunks.iter().filter(of_kind) {
        for t in chunk.triangles.clone() {
            k += 1;
            if k % stride != 0 {
                continue;
            }
            let Some(tri) = chunked.indices.get(3 * t as usize..3 * t as usize + 3) else {
                continue;
            };
            let p = |i: u32| position_m(chunked, i);
            let (a, b, c) = (p(tri[0]), p(tri[1]), p(tri[2]));
            for (u, v) in [(a, b), (b, c), (c, a)] {
                let d =
                    ((u[0] - v[0]).powi(2) + (u[1] - v[1]).powi(2) + (u[2] - v[2]).powi(2)).sqrt();
                if d.is_finite() && d > 0.0 {
                    edges.push(d);
                }
            }
        }
    }
    if edges.is_empty() {
        return None;
    }
    let mid = edges.len() / 2;
    let (_, m, _) = edges.select_nth_unstable_by(mid, f32::total_cmp);
    Some(*m)
}

/// Marks in `open` (one flag per mesh vertex) the mesh vertices on an open
/// edge of fine chunks `chunks`: an edge only one of their triangles has
/// (a wall's outline, a doorway's edge, the seam where two faces meet
/// without sharing vertices). `edges` is scratch.
fn mark_open_edges(
    chunked: &ChunkedMesh,
    chunks: Range<usize>,
    origins: &VertexOrigins,
    open: &mut [bool],
    edges: &mut Vec<u64>,
) {
    edges.clear();
    let source = |i: u32| {
        origins
            .vertex_source
            .get(i as usize)
            .copied()
            .unwrap_or(u32::MAX)
    };
    for chunk in chunked.chunks.get(chunks).unwrap_or(&[]) {
        let Some(indices) = chunked
            .indices
            .get(chunk.index_range().start as usize..chunk.index_range().end as usize)
        else {
            continue;
        };
        for tri in indices.chunks_exact(3) {
            let m = [source(tri[0]), source(tri[1]), source(tri[2])];
            for (a, b) in [(m[0], m[1]), (m[1], m[2]), (m[2], m[0])] {
                edges.push(u64::from(a.min(b)) << 32 | u64::from(a.max(b)));
            }
        }
    }
    edges.sort_unstable();
    let mut i = 0;
    while i < edges.len() {
        let mut j = i + 1;
        while j < edges.len() && edges[j] == edges[i] {
            j += 1;
        }
        if j - i == 1 {
            for v in [edges[i] >> 32, edges[i] & u64::from(u32::MAX)] {
                if let Some(flag) = open.get_mut(v as usize) {
                    *flag = true;
                }
            }
        }
        i = j;
    }
}

/// The nodes of the split tree of a group of `triangles` triangles whose
/// leaves are chunks `first..` ([`super::chunks`]: halves by count until at
/// most [`MAX_CHUNK_TRIS`]), as (chunks, height above the deepest leaf),
/// in depth-first order, parents first; and the number of leaves.
fn split_tree(triangles: usize, first: usize) -> (Vec<(Range<usize>, usize)>, usize) {
    // (triangles, depth) of each leaf, in order, then nodes by leaf runs.
    fn walk(
        n: usize,
        depth: usize,
        leaves: &mut Vec<usize>,
        nodes: &mut Vec<(usize, usize, usize)>,
    ) {
        if n <= MAX_CHUNK_TRIS {
            leaves.push(depth);
            return;
        }
        let at = nodes.len();
        let start = leaves.len();
        nodes.push((start, 0, depth));
        walk(n / 2, depth + 1, leaves, nodes);
        walk(n - n / 2, depth + 1, leaves, nodes);
        nodes[at].1 = leaves.len();
    }
    let (mut leaves, mut nodes) = (Vec::new(), Vec::new());
    if triangles > 0 {
        walk(triangles, 0, &mut leaves, &mut nodes);
    }
    let deepest = leaves.iter().copied().max().unwrap_or(0);
    let out = nodes
        .into_iter()
        .map(|(a, b, depth)| (first + a..first + b, deepest.saturating_sub(depth)))
        .collect();
    (out, leaves.len())
}

/// One cluster of vertices: sums of their attributes, and their count.
#[derive(Debug, Clone, Copy, Default)]
struct Pool {
    position_m: [f64; 3],
    gray: f64,
    uv: [f64; 2],
    count: u32,
}

impl Pool {
    fn add(&mut self, position_m: [f32; 3], gray: f32, uv: [f32; 2]) {
        for k in 0..3 {
            self.position_m[k] += f64::from(position_m[k]);
        }
        self.gray += f64::from(gray);
        self.uv[0] += f64::from(uv[0]);
        self.uv[1] += f64::from(uv[1]);
        self.count += 1;
    }

    /// Mean position, gray and texture coordinates.
    fn mean(&self) -> ([f64; 3], f64, [f64; 2]) {
        let n = f64::from(self.count.max(1));
        (
            self.position_m.map(|x| x / n),
            self.gray / n,
            self.uv.map(|x| x / n),
        )
    }
}

/// Scratch of one node's simplification, reused from node to node.
#[derive(Default)]
struct Scratch {
    /// Cell (and, on a textured copy, normal class) of each pooled vertex
    /// -> its cluster.
    cells: HashMap<[i32; 4], u32>,
    /// Mesh vertex of each fixed vertex -> its cluster.
    fixed: HashMap<u32, u32>,
    /// Per node-local vertex, its cluster.
    cluster_of: Vec<u32>,
    /// Per cluster, its sums.
    sum: Vec<Pool>,
    /// Per node-local vertex, its area-weighted normal (textured copies).
    normal: Vec<[f64; 3]>,
    /// Per cluster, where its members start in `members` (and one past).
    member_start: Vec<u32>,
    /// Node-local vertices, cluster by cluster.
    members: Vec<u32>,
    /// Open-edge scratch ([`mark_open_edges`]).
    edges: Vec<u64>,
    /// Per cluster, its vertex number in the output, or `u32::MAX`.
    emitted: Vec<u32>,
    /// Coarse triangles seen (sorted cluster triples).
    seen: std::collections::HashSet<[u32; 3]>,
    /// The coarse triangles, as clusters, with their source triangle.
    triangles: Vec<([u32; 3], u32)>,
}

/// Where each copied vertex comes from: `vertex_source[v]`, the mesh
/// vertex that chunked vertex `v` copies; `first_chunk[m]` and
/// `last_chunk[m]`, the first and last chunk using mesh vertex `m`.
pub struct VertexOrigins<'a> {
    /// Per chunked vertex, its mesh vertex.
    pub vertex_source: &'a [u32],
    /// Per mesh vertex, the first chunk that uses it.
    pub first_chunk: &'a [u32],
    /// Per mesh vertex, the last chunk that uses it.
    pub last_chunk: &'a [u32],
}

/// Appends coarse copies of the chunks of `chunked` (built from
/// `mesh`, chunks in split-tree order per group) and fills its
/// [`LodTable`]. Fails only when the copies no longer fit `u32` indices.
pub fn build_levels(
    chunked: &mut ChunkedMesh,
    mesh: &Mesh,
    origins: &VertexOrigins,
) -> Result<(), super::RenderError> {
    let fine = chunked.chunks.len();
    let fine_tris = chunked.source_triangle.len();
    chunked.lod = LodTable::fine_only(fine);
    let cells = |edge_m: Option<f32>| edge_m.map(|e| CELL_EDGES.map(|k| k * e));
    let cell_plain = cells(median_edge_m(chunked, mesh, false));
    let cell_textured = if chunked.uvs.is_empty() {
        None
    } else {
        cells(median_edge_m(chunked, mesh, true))
    };
    let Some(cell_m) = cell_plain.or(cell_textured) else {
        return Ok(());
    };
    // Per mesh vertex: on an open edge of a textured group.
    let mut open = if cell_textured.is_some() {
        vec![false; origins.first_chunk.len()]
    } else {
        Vec::new()
    };
    let mut nodes = Vec::new();
    let mut scratch = Scratch::default();
    let mut textured_errors = Vec::new();
    let mut level_tris = [0usize; LEVELS];
    let mut start = 0;
    while start < fine {
        let group = chunked.chunks[start].group;
        let end = start
            + chunked.chunks[start..]
                .iter()
                .position(|c| c.group != group)
                .unwrap_or(fine - start);
        let run = start..end;
        start = end;
        let is_textured = textured(mesh, group);
        let Some(group_cells) = (if is_textured {
            cell_textured
        } else if untextured(mesh, group) {
            cell_plain
        } else {
            None
        }) else {
            continue;
        };
        if is_textured {
            let mut edges = std::mem::take(&mut scratch.edges);
            mark_open_edges(chunked, run.clone(), origins, &mut open, &mut edges);
            scratch.edges = edges;
        }
        let triangles: usize = chunked.chunks[run.clone()]
            .iter()
            .map(MeshChunk::triangle_count)
            .sum();
        let (tree, leaves) = split_tree(triangles, run.start);
        if leaves != run.len() {
            // Not the tree the chunks were split by: leave the group whole.
            tracing::warn!(
                group,
                leaves,
                chunks = run.len(),
                "level of detail: chunk tree mismatch"
            );
            continue;
        }
        // A textured copy is of one chunk, at the finest level: its error
        // is measured, so it may be drawn near, where the culls need the
        // chunks' grain (see the module docs).
        let tree: Vec<(Range<usize>, usize)> = if is_textured {
            run.clone().map(|c| (c..c + 1, NODE_HEIGHT[0])).collect()
        } else {
            tree
        };
        for (chunks, height) in tree {
            let Some(level) = NODE_HEIGHT.iter().position(|&h| h == height) else {
                continue;
            };

            let node_tris: usize = chunked.chunks[chunks.clone()]
                .iter()
                .map(MeshChunk::triangle_count)
                .sum();
            let made = simplify(
                chunked,
                chunks.clone(),
                group_cells[level],
                (origins, is_textured.then_some(open.as_slice())),
                &mut scratch,
            );
            if made == 0 || made > MAX_COARSE_TRIS || made as f32 > KEEP_RATIO * node_tris as f32 {
                continue;
            }
            let error_m = if is_textured {
                let e = textured_error_m(chunked, chunks.clone(), group_cells[level], &mut scratch);
                textured_errors.push(e);
                e
            } else {
                group_cells[level]
            };
            let number = chunked.chunks.len();
            if number >= u32::MAX as usize {
                return Err(super::RenderError::InvalidMesh {
                    field: "indices",
                    index: number,
                    reason: "too many chunks with levels of detail".to_string(),
                });
            }
            emit(chunked, group, &mut scratch)?;
            level_tris[level] += made;
            nodes.push(LodNode {
                chunks: chunks.start as u32..chunks.end as u32,
                level: level as u8,
                coarse: number as u32,
                error_m,
            });
        }
    }
    // By first chunk, the largest run first (parents come before their
    // children in depth-first order already; sort to be sure).
    nodes.sort_by_key(|n| {
        (
            n.chunks.start,
            std::cmp::Reverse(n.chunks.end),
            std::cmp::Reverse(n.level),
        )
    });
    textured_errors.sort_by(f32::total_cmp);
    let textured_median_error_m = textured_errors.get(textured_errors.len() / 2).copied();
    tracing::info!(
        fine_triangles = fine_tris,
        coarse_triangles = ?level_tris,
        cell_m = ?cell_plain,
        textured_cell_m = ?cell_textured,
        textured_copies = textured_errors.len(),
        textured_median_error_m = ?textured_median_error_m,
        "levels of detail built"
    );
    if !nodes.is_empty() {
        chunked.lod = LodTable {
            fine_chunks: fine,
            cell_m,
            nodes,
        };
    }
    Ok(())
}

/// Clusters the vertices of fine chunks `chunks` in cells of `cell_m`
/// into `s` and lists the coarse triangles that survive; gives their
/// number. With `open` (a textured copy: one flag per mesh vertex, see
/// [`mark_open_edges`]) the vertices on open edges stay where they are, as
/// the node's border does, and only vertices whose normals face the same
/// way ([`normal_class`]) share a cell, so faces that meet at an edge
/// without sharing vertices are pooled apart.
fn simplify(
    chunked: &ChunkedMesh,
    chunks: Range<usize>,
    cell_m: f32,
    (origins, open): (&VertexOrigins, Option<&[bool]>),
    s: &mut Scratch,
) -> usize {
    s.cells.clear();
    s.fixed.clear();
    s.cluster_of.clear();
    s.sum.clear();
    s.seen.clear();
    s.triangles.clear();
    let (Some(first), Some(last)) = (
        chunked.chunks.get(chunks.start),
        chunked.chunks.get(chunks.end.saturating_sub(1)),
    ) else {
        return 0;
    };
    let vertices = first.vertices.start as usize..last.vertices.end as usize;
    let triangles = first.triangles.start as usize..last.triangles.end as usize;
    let (a, b) = (chunks.start as u32, chunks.end as u32);
    let v0 = vertices.start;
    if open.is_some() {
        vertex_normals(chunked, vertices.clone(), triangles.clone(), &mut s.normal);
    }
    for v in vertices {
        let p = chunked.positions.get(v).copied().unwrap_or([0.0; 3]);
        let gray = chunked.gray.get(v).copied().unwrap_or(0.0);
        let uv = chunked.uvs.get(v).copied().unwrap_or([0.0; 2]);
        let m = origins.vertex_source.get(v).copied().unwrap_or(u32::MAX);
        let inside = origins.first_chunk.get(m as usize).is_some_and(|&c| c >= a)
            && origins.last_chunk.get(m as usize).is_some_and(|&c| c < b)
            && open.is_none_or(|o| o.get(m as usize) == Some(&false));
        let class = if open.is_some() {
            normal_class(s.normal.get(v - v0).copied().unwrap_or_default())
        } else {
            0
        };
        let [x, y, z] = p.map(|x| (x / cell_m).floor() as i32);
        let key = [x, y, z, class];
        let existing = if inside {
            s.cells.get(&key).copied()
        } else {
            s.fixed.get(&m).copied()
        };
        let cluster = match existing {
            Some(k) => k,
            None => {
                s.sum.push(Pool::default());
                let k = (s.sum.len() - 1) as u32;
                if inside {
                    s.cells.insert(key, k);
                } else {
                    s.fixed.insert(m, k);
                }
                k
            }
        };
        if let Some(sum) = s.sum.get_mut(cluster as usize) {
            if inside || sum.count == 0 {
                sum.add(p, gray, uv);
            }
        }
        s.cluster_of.push(cluster);
    }
    for t in triangles {
        let Some(tri) = chunked.indices.get(3 * t..3 * t + 3) else {
            continue;
        };
        let cluster = |i: u32| {
            s.cluster_of
                .get((i as usize).wrapping_sub(v0))
                .copied()
                .unwrap_or(u32::MAX)
        };
        let k = [cluster(tri[0]), cluster(tri[1]), cluster(tri[2])];
        if k.contains(&u32::MAX) || k[0] == k[1] || k[1] == k[2] || k[0] == k[2] {
            continue;
        }
        let mut key = k;
        key.sort_unstable();
        if s.seen.insert(key) {
            let source = chunked.source_triangle.get(t).copied().unwrap_or(0);
            s.triangles.push((k, source));
        }
    }
    s.triangles.len()
}

/// Area-weighted normals of `vertices` of `chunked` from `triangles`
/// (whose vertices all lie in that range) into `out`, one per vertex.
fn vertex_normals(
    chunked: &ChunkedMesh,
    vertices: Range<usize>,
    triangles: Range<usize>,
    out: &mut Vec<[f64; 3]>,
) {
    let v0 = vertices.start;
    out.clear();
    out.resize(vertices.len(), [0.0; 3]);
    let p = |i: u32| position_m(chunked, i).map(f64::from);
    for t in triangles {
        let Some(tri) = chunked.indices.get(3 * t..3 * t + 3) else {
            continue;
        };
        let n = cross(sub(p(tri[1]), p(tri[0])), sub(p(tri[2]), p(tri[0])));
        for &i in tri {
            if let Some(acc) = out.get_mut((i as usize).wrapping_sub(v0)) {
                for k in 0..3 {
                    acc[k] += n[k];
                }
            }
        }
    }
}

/// Which of the six axis directions `normal` is nearest (0..6), or 6
/// without a direction.
fn normal_class(normal: [f64; 3]) -> i32 {
    let axis = (0..3)
        .max_by(|&i, &j| normal[i].abs().total_cmp(&normal[j].abs()))
        .unwrap_or(0);
    match normal[axis] {
        x if x > 0.0 => 2 * axis as i32,
        x if x < 0.0 => 2 * axis as i32 + 1,
        _ => 6,
    }
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// Largest difference, in gray levels of 0..=255, between a fine vertex's
/// gray and the coarse triangle's interpolated gray for which a textured
/// copy is judged by its shape and texture coordinates alone; beyond it
/// the copy has lost shading detail, and its error is at least its cell.
const GRAY_TOLERANCE: f64 = 4.0;

/// How far the textured copy in `s` (from [`simplify`] of fine chunks
/// `chunks`) may stray from them on the image, meters on the surface: for
/// every coarse triangle and every fine vertex pooled into one of its
/// corners, the larger of the vertex's distance from the triangle's plane
/// and the shift of the texture there (the difference between the
/// vertex's texture coordinates and the triangle's, at the vertex's
/// place on the plane, as a distance along the surface). A flat surface
/// with one affine texture mapping (walls and floors cut into cells) has
/// copies of error 0; an edge or a texture seam pooled into one cell
/// shows as an error of its size. A triangle that lost its area or its
/// texture mapping, or shading that changed by more than
/// [`GRAY_TOLERANCE`], makes the error at least `cell_m`.
fn textured_error_m(
    chunked: &ChunkedMesh,
    chunks: Range<usize>,
    cell_m: f32,
    s: &mut Scratch,
) -> f32 {
    let Some(first) = chunked.chunks.get(chunks.start) else {
        return f32::INFINITY;
    };
    let v0 = first.vertices.start as usize;
    // Members of each cluster.
    let n = s.sum.len();
    s.member_start.clear();
    s.member_start.resize(n + 1, 0);
    for &k in &s.cluster_of {
        if let Some(c) = s.member_start.get_mut(k as usize + 1) {
            *c += 1;
        }
    }
    for k in 0..n {
        s.member_start[k + 1] += s.member_start[k];
    }
    s.members.clear();
    s.members.resize(s.cluster_of.len(), 0);
    let mut cursor: Vec<u32> = s.member_start[..n].to_vec();
    for (local, &k) in s.cluster_of.iter().enumerate() {
        if let Some(at) = cursor.get_mut(k as usize) {
            if let Some(slot) = s.members.get_mut(*at as usize) {
                *slot = local as u32;
            }
            *at += 1;
        }
    }
    let mut worst = 0.0f64;
    let mut lost_detail = false;
    for &(tri, _) in &s.triangles {
        let [(m0, g0, w0), (m1, g1, w1), (m2, g2, w2)] =
            tri.map(|k| s.sum.get(k as usize).copied().unwrap_or_default().mean());
        let (e1, e2) = (sub(m1, m0), sub(m2, m0));
        let normal = cross(e1, e2);
        let area2 = dot(normal, normal);
        let (a11, a12, a22) = (dot(e1, e1), dot(e1, e2), dot(e2, e2));
        let (d1, d2) = (
            [w1[0] - w0[0], w1[1] - w0[1]],
            [w2[0] - w0[0], w2[1] - w0[1]],
        );
        let uv_det = d1[0] * d2[1] - d1[1] * d2[0];
        let uv_scale = d1[0] * d1[0] + d1[1] * d1[1] + d2[0] * d2[0] + d2[1] * d2[1];
        if !(area2 > 1e-12 * (a11 + a22).powi(2) && uv_det.abs() > 1e-9 * uv_scale) {
            lost_detail = true;
            continue;
        }
        let unit = normal.map(|x| x / area2.sqrt());
        for k in tri {
            let at = s.member_start.get(k as usize).copied().unwrap_or(0) as usize;
            let to = s.member_start.get(k as usize + 1).copied().unwrap_or(0) as usize;
            for &local in s.members.get(at..to).unwrap_or(&[]) {
                let v = v0 + local as usize;
                let p = chunked
                    .positions
                    .get(v)
                    .copied()
                    .unwrap_or([0.0; 3])
                    .map(f64::from);
                let uv = chunked
                    .uvs
                    .get(v)
                    .copied()
                    .unwrap_or([0.0; 2])
                    .map(f64::from);
                let gray = f64::from(chunked.gray.get(v).copied().unwrap_or(0.0));
                let r = sub(p, m0);
                let off_plane_m = dot(unit, r).abs();
                // Barycentric coordinates of the point on the plane.
                let (b1, b2) = (dot(e1, r), dot(e2, r));
                let det = a11 * a22 - a12 * a12;
                let (bs, bt) = ((a22 * b1 - a12 * b2) / det, (a11 * b2 - a12 * b1) / det);
                let du = uv[0] - (w0[0] + bs * d1[0] + bt * d2[0]);
                let dv = uv[1] - (w0[1] + bs * d1[1] + bt * d2[1]);
                // The texture-coordinate error as a step on the surface.
                let (sa, sb) = (
                    (du * d2[1] - dv * d2[0]) / uv_det,
                    (d1[0] * dv - d1[1] * du) / uv_det,
                );
                let step = [0, 1, 2].map(|c| sa * e1[c] + sb * e2[c]);
                let shift_m = dot(step, step).sqrt();
                let gray_off = (gray - (g0 + bs * (g1 - g0) + bt * (g2 - g0))).abs();
                if !(gray_off <= GRAY_TOLERANCE) {
                    lost_detail = true;
                }
                let e = off_plane_m.max(shift_m);
                worst = if e.is_finite() {
                    worst.max(e)
                } else {
                    f64::INFINITY
                };
            }
        }
    }
    let worst = worst as f32;
    if lost_detail {
        worst.max(cell_m)
    } else {
        worst
    }
}

/// Appends the coarse chunk in `s` (from [`simplify`]) of mesh group
/// `group`.
fn emit(chunked: &mut ChunkedMesh, group: u32, s: &mut Scratch) -> Result<(), super::RenderError> {
    s.emitted.clear();
    s.emitted.resize(s.sum.len(), u32::MAX);
    let first_tri = chunked.source_triangle.len() as u32;
    let first_vertex = chunked.positions.len();
    let has_uvs = !chunked.uvs.is_empty();
    let mut bounds = Aabb::EMPTY;
    for &(tri, source) in &s.triangles {
        for k in tri {
            let Some(slot) = s.emitted.get_mut(k as usize) else {
                continue;
            };
            if *slot == u32::MAX {
                let n = chunked.positions.len();
                if n >= u32::MAX as usize {
                    return Err(super::RenderError::InvalidMesh {
                        field: "indices",
                        index: n,
                        reason: "vertices: more than 2^32 with levels of detail".to_string(),
                    });
                }
                *slot = n as u32;
                let (p, gray, uv) = s.sum.get(k as usize).copied().unwrap_or_default().mean();
                let p = p.map(|x| x as f32);
                bounds.add(p);
                chunked.positions.push(p);
                chunked.gray.push(gray as f32);
                if has_uvs {
                    chunked.uvs.push(uv.map(|x| x as f32));
                }
            }
            chunked.indices.push(*slot);
        }
        chunked.source_triangle.push(source);
    }
    chunked.chunks.push(MeshChunk {
        triangles: first_tri..chunked.source_triangle.len() as u32,
        vertices: first_vertex as u32..chunked.positions.len() as u32,
        group,
        bounds,
    });
    Ok(())
}

#[cfg(test)]
#[allow(clippy::expect_used, clippy::unwrap_used)]
mod tests {
    use super::*;
    use crate::map::{GrayTexture, MeshGroup};
    use crate::render::cpu::CpuRenderer;
    use crate::render::{RenderedView, Renderer};
    use nalgebra::{Translation3, UnitQuaternion, Vector3};
    use std::sync::Arc;

    /// A wall: an `n x n` grid of quads on the plane y = `y_m`, x and z in
    /// `[-half, half]` (z up), gray varying smoothly.
    fn wall(n: usize, half_m: f32, y_m: f32) -> Mesh {
        let mut mesh = Mesh::default();
        for j in 0..=n {
            for i in 0..=n {
                let s = |k: usize| -half_m + 2.0 * half_m * k as f32 / n as f32;
                mesh.positions.push([s(i), y_m, s(j)]);
                mesh.gray
                    .push(100.0 + 50.0 * ((i as f32 * 0.05).sin() + (j as f32 * 0.07).cos()));
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

    /// A camera at the origin looking along +y (world z up).
    fn looking_along_y(x_m: f64) -> Pose {
        // Camera optical frame: x right, y down, z forward.
        let r = nalgebra::Matrix3::new(1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, -1.0, 0.0);
        let rotation = UnitQuaternion::from_matrix(&r);
        Pose::from_parts(Translation3::from(Vector3::new(x_m, 0.0, 0.0)), rotation)
    }

    #[test]
    fn the_tree_is_the_one_the_chunks_were_split_by() {
        // 10 000 triangles: 5000 | 5000, each 2500 | 2500: four leaves.
        let (nodes, leaves) = split_tree(10_000, 7);
        assert_eq!(leaves, 4);
        assert_eq!(nodes, vec![(7..11, 2), (7..9, 1), (9..11, 1)]);
        let (nodes, leaves) = split_tree(MAX_CHUNK_TRIS, 0);
        assert_eq!((nodes.len(), leaves), (0, 1));
        assert_eq!(split_tree(0, 0), (vec![], 0));
        let mesh = wall(200, 10.0, 5.0);
        let c = ChunkedMesh::build(&mesh).unwrap();
        assert_eq!(split_tree(mesh.triangle_count(), 0).1, c.chunks.len());
    }

    #[test]
    fn untextured_chunks_get_coarser_copies_with_their_borders_intact() {
        let mesh = wall(400, 10.0, 5.0); // 320k triangles, 5 cm edges
        let plain = ChunkedMesh::build(&mesh).unwrap();
        assert_eq!(plain.lod.coarse_chunks(), 0);
        let c = ChunkedMesh::build_with_levels(&mesh, true).unwrap();
        let fine = c.lod.fine_chunks;
        assert_eq!(fine, plain.chunks.len());
        // The fine part is untouched.
        assert_eq!(c.chunks[..fine], plain.chunks[..]);
        assert_eq!(c.indices[..plain.indices.len()], plain.indices[..]);
        assert!((c.lod.cell_m[0] - 0.1).abs() < 1e-3, "{:?}", c.lod.cell_m);
        // 128 chunks: 32 nodes of 4, 8 of 16, 2 of 64.
        assert_eq!(fine, 128);
        let per_level = |l: u8| c.lod.nodes.iter().filter(|n| n.level == l).count();
        assert_eq!([per_level(0), per_level(1), per_level(2)], [32, 8, 2]);
        let bits = |p: &[f32; 3]| p.map(f32::to_bits);
        for node in &c.lod.nodes {
            let run = node.chunks.start as usize..node.chunks.end as usize;
            let chunk = &c.chunks[node.coarse as usize];
            let fine_tris: usize = c.chunks[run.clone()]
                .iter()
                .map(MeshChunk::triangle_count)
                .sum();
            assert!(chunk.triangle_count() as f32 <= KEEP_RATIO * fine_tris as f32);
            // Its border: the vertices its chunks share with other chunks.
            let outside: std::collections::HashSet<[u32; 3]> = c.chunks[..fine]
                .iter()
                .enumerate()
                .filter(|(o, _)| !run.contains(o))
                .flat_map(|(_, o)| {
                    c.positions[o.vertices.start as usize..o.vertices.end as usize].iter()
                })
                .map(bits)
                .collect();
            let inside = || {
                c.chunks[run.clone()].iter().flat_map(|o| {
                    c.positions[o.vertices.start as usize..o.vertices.end as usize].iter()
                })
            };
            let border: std::collections::HashSet<[u32; 3]> =
                inside().map(bits).filter(|p| outside.contains(p)).collect();
            let coarse: std::collections::HashSet<[u32; 3]> = c.positions
                [chunk.vertices.start as usize..chunk.vertices.end as usize]
                .iter()
                .map(bits)
                .collect();
            assert!(!border.is_empty() || run.len() == fine);
            assert!(border.is_subset(&coarse), "a border vertex moved");
            let mut lo = [f32::INFINITY; 3];
            let mut hi = [f32::NEG_INFINITY; 3];
            for p in inside() {
                for k in 0..3 {
                    lo[k] = lo[k].min(p[k]);
                    hi[k] = hi[k].max(p[k]);
                }
            }
            for k in 0..3 {
                assert!(lo[k] <= chunk.bounds.min_m[k] && chunk.bounds.max_m[k] <= hi[k]);
            }
            for t in chunk.triangles.clone() {
                for k in 0..3 {
                    assert!(chunk.vertices.contains(&c.indices[3 * t as usize + k]));
                }
                assert!((c.source_triangle[t as usize] as usize) < mesh.triangle_count());
            }
        }
    }

    /// `mesh` with one texture (a 64 x 64 pattern) mapped affinely,
    /// `uv = (x, z) / 4 m`, and one group.
    fn textured(mut mesh: Mesh) -> Mesh {
        mesh.uvs = mesh
            .positions
            .iter()
            .map(|p| [p[0] / 4.0, p[2] / 4.0])
            .collect();
        mesh.textures = vec![GrayTexture {
            width: 64,
            height: 64,
            texels: (0..64 * 64)
                .map(|k| 40.0 + ((k * 7919 % 211) as f32))
                .collect(),
        }];
        mesh.groups = vec![MeshGroup {
            first_index: 0,
            index_count: mesh.indices.len() as u32,
            texture: Some(0),
        }];
        mesh
    }

    #[test]
    fn a_flat_textured_wall_has_exact_copies_drawn_at_any_distance() {
        let mut mesh = wall(400, 10.0, 5.0);
        mesh.gray.fill(200.0);
        let mesh = textured(mesh);
        let c = ChunkedMesh::build_with_levels(&mesh, true).unwrap();
        let fine = c.lod.fine_chunks;
        assert_eq!(c.lod.nodes.len(), fine, "a copy of every chunk");
        for node in &c.lod.nodes {
            assert!(node.error_m < 1e-4, "{node:?}");
            // The copy keeps the texture mapping: uv = (x, z) / 4 m.
            let chunk = &c.chunks[node.coarse as usize];
            for v in chunk.vertices.start as usize..chunk.vertices.end as usize {
                let (p, uv) = (c.positions[v], c.uvs[v]);
                assert!((uv[0] - p[0] / 4.0).abs() < 1e-5 && (uv[1] - p[2] / 4.0).abs() < 1e-5);
                assert!((p[1] - 5.0).abs() < 1e-5, "on the wall's plane");
            }
        }
        // 1 m in front of the wall: the copies, not the fine chunks.
        let camera = PinholeCamera::new(640, 512, 420.0, 420.0, 319.5, 255.5);
        let mut pose = looking_along_y(0.0);
        pose.translation.vector = Vector3::new(0.0, 4.0, 0.0);
        let view = LodView::new(&pose, &camera, 2.0).unwrap();
        let mut visible = Vec::new();
        let stats = c.lod.mark(&c.chunks, Some(&view), None, &mut visible);
        assert!(visible[..fine].iter().all(|&v| !v));
        assert!(
            3 * stats.visible_triangles < mesh.triangle_count(),
            "{stats:?}"
        );
    }

    #[test]
    fn a_textured_copy_that_bends_or_loses_shading_has_an_error() {
        // Folded along x = 1.3 m (off the chunks' median splits), at
        // y = 5.03 m (off the cells' borders): two planes meeting at a
        // crease.
        let mut bent = wall(400, 10.0, 5.03);
        bent.gray.fill(200.0);
        for p in &mut bent.positions {
            p[1] += 0.3 * (p[0] - 1.3).abs();
        }
        let c = ChunkedMesh::build_with_levels(&textured(bent), true).unwrap();
        let crosses = |n: &LodNode| {
            let b = &c.chunks[n.coarse as usize].bounds;
            b.min_m[0] < 1.29 && b.max_m[0] > 1.31
        };
        let (across, beside): (Vec<&LodNode>, Vec<&LodNode>) =
            c.lod.nodes.iter().partition(|n| crosses(n));
        assert!(!across.is_empty() && !beside.is_empty());
        for n in across {
            assert!(n.error_m > 0.004, "the crease: {n:?}");
        }
        for n in beside {
            assert!(n.error_m < 1e-4, "a flat part: {n:?}");
        }
        // Shading that changes from vertex to vertex: each copy is judged
        // by its cell, as an untextured one.
        let mut speckled = wall(400, 10.0, 5.0);
        for (k, g) in speckled.gray.iter_mut().enumerate() {
            *g = if k % 2 == 0 { 120.0 } else { 160.0 };
        }
        let c = ChunkedMesh::build_with_levels(&textured(speckled), true).unwrap();
        assert!(!c.lod.nodes.is_empty());
        for n in &c.lod.nodes {
            assert!(n.error_m >= 0.1 * (1 << n.level) as f32 * 0.999, "{n:?}");
        }
    }

    #[test]
    fn a_textured_render_with_exact_copies_matches_the_full_one() {
        let mut mesh = wall(400, 10.0, 5.0);
        mesh.gray.fill(200.0);
        let mesh = Arc::new(textured(mesh));
        // Obliquely, 1-15 m from the wall, its outline in view.
        let mut pose = looking_along_y(0.0);
        pose.translation.vector = Vector3::new(-6.0, 1.0, 0.5);
        let full = render(&mesh, &pose, 0.0, true);
        let coarse = render(&mesh, &pose, 2.0, true);
        let (w, h) = (full.depth_m.width(), full.depth_m.height());
        let (mut hits, mut mask_off, mut depth_off, mut gray_off) = (0, 0, 0, 0);
        for y in 0..h {
            for x in 0..w {
                let (a, b) = (
                    full.depth_m.get(x, y).unwrap_or(0.0),
                    coarse.depth_m.get(x, y).unwrap_or(0.0),
                );
                let (ha, hb) = (RenderedView::is_hit(a), RenderedView::is_hit(b));
                if ha != hb {
                    mask_off += 1;
                    continue;
                }
                if !ha {
                    continue;
                }
                hits += 1;
                if (a - b).abs() > 1e-4 * a {
                    depth_off += 1;
                }
                let (ga, gb) = (
                    full.gray.get(x, y).unwrap_or(0.0),
                    coarse.gray.get(x, y).unwrap_or(0.0),
                );
                if (ga - gb).abs() > 1.0 {
                    gray_off += 1;
                }
            }
        }
        assert!(hits > 30_000, "the wall fills most of the view: {hits}");
        assert_eq!(mask_off, 0, "the same pixels covered");
        assert_eq!(depth_off, 0, "the same depth");
        assert!(
            gray_off * 1000 < hits,
            "{gray_off} of {hits} off by a gray level"
        );
    }

    #[test]
    fn the_level_follows_the_cells_size_on_the_image() {
        let mesh = wall(400, 10.0, 5.0);
        let c = ChunkedMesh::build_with_levels(&mesh, true).unwrap();
        let camera = PinholeCamera::new(640, 512, 420.0, 420.0, 319.5, 255.5);
        let mut visible = Vec::new();
        // A camera `d` m in front of the wall, looking at it.
        let drawn = |d: f64, visible: &mut Vec<bool>| {
            let mut pose = looking_along_y(0.0);
            pose.translation.vector = Vector3::new(0.0, 5.0 - d, 0.0);
            let view = LodView::new(&pose, &camera, 2.0).unwrap();
            let stats = c.lod.mark(&c.chunks, Some(&view), None, visible);
            let levels: Vec<usize> = visible
                .iter()
                .enumerate()
                .filter(|(_, &v)| v)
                .map(|(i, _)| {
                    c.lod
                        .nodes
                        .iter()
                        .find(|n| n.coarse as usize == i)
                        .map_or(0, |n| 1 + n.level as usize)
                })
                .collect();
            (stats, levels)
        };
        // Cells of 0.1, 0.2, 0.4 m are 2 px at 21, 42, 84 m.
        let (near, levels) = drawn(5.0, &mut visible);
        assert!(levels.iter().all(|&l| l == 0), "{levels:?}");
        assert_eq!(near.visible_triangles, mesh.triangle_count());
        for (d, level) in [(30.0, 1), (60.0, 2), (200.0, 3)] {
            let (stats, levels) = drawn(d, &mut visible);
            assert!(levels.iter().all(|&l| l == level), "{d} m: {levels:?}");
            assert!(stats.visible_triangles < mesh.triangle_count() / 2);
            assert_eq!(stats.triangles, mesh.triangle_count());
            // Every fine chunk is covered exactly once.
            let mut covered = vec![0; c.lod.fine_chunks];
            for (i, _) in visible.iter().enumerate().filter(|(_, &v)| v) {
                let run = c
                    .lod
                    .nodes
                    .iter()
                    .find(|n| n.coarse as usize == i)
                    .map_or(i..i + 1, |n| n.chunks.start as usize..n.chunks.end as usize);
                for f in run {
                    covered[f] += 1;
                }
            }
            assert!(covered.iter().all(|&n| n == 1), "{d} m");
        }
        // Without a view, or a size of 0: full detail.
        let stats = c.lod.mark(&c.chunks, None, None, &mut visible);
        assert_eq!(stats.visible_triangles, mesh.triangle_count());
        assert!(visible[c.lod.fine_chunks..].iter().all(|&v| !v));
        assert!(LodView::new(&looking_along_y(0.0), &camera, 0.0).is_none());
        assert!(LodView::new(&looking_along_y(0.0), &camera, f32::NAN).is_none());
        for (px, kept) in [(2.5, 2.5), (0.0, 0.0), (-1.0, 0.0), (f32::NAN, 0.0)] {
            assert_eq!(cell_limit_px(px), kept, "{px}");
        }
        assert_eq!(cell_limit_px(f32::INFINITY), 0.0);
    }

    /// Renders `mesh` from `pose` with the level of detail at `max_px`.
    fn render(mesh: &Arc<Mesh>, pose: &Pose, max_px: f32, cull: bool) -> RenderedView {
        let camera = PinholeCamera::new(320, 256, 210.0, 210.0, 159.5, 127.5);
        let mut r = CpuRenderer::with_lod(Arc::clone(mesh), 2.0).unwrap();
        r.set_lod_max_px(max_px);
        r.set_frustum_cull(cull);
        let mut out = RenderedView::for_camera(&camera);
        r.render(pose, &camera, &mut out).unwrap();
        out
    }

    #[test]
    fn a_coarse_render_has_no_cracks_and_stays_near_the_full_one() {
        // A wall of 2 cm triangles 4-30 m away, seen obliquely: its near
        // chunks fine, the far ones at every level, side by side.
        let mut mesh = wall(1000, 10.0, 0.0);
        for p in &mut mesh.positions {
            // Turn it to recede: y from 4 m (x = -10) to 30 m (x = 10).
            let t = (p[0] + 10.0) / 20.0;
            *p = [p[0] * 0.3, 4.0 + 26.0 * t, p[2] * 0.3];
        }
        let mesh = Arc::new(mesh);
        let pose = looking_along_y(0.0);
        let full = render(&mesh, &pose, 0.0, true);
        let coarse = render(&mesh, &pose, 2.0, true);
        let (w, h) = (full.depth_m.width(), full.depth_m.height());
        let depth = |v: &RenderedView, x: usize, y: usize| v.depth_m.get(x, y).unwrap_or(0.0);
        let hit = |v: &RenderedView, x: usize, y: usize| RenderedView::is_hit(depth(v, x, y));
        let (mut holes, mut covered, mut depth_off) = (0, 0, 0);
        for y in 2..h - 2 {
            for x in 2..w - 2 {
                // Inside the full render's wall, 2 px from its outline.
                let inside = (0..5).all(|dy| (0..5).all(|dx| hit(&full, x + dx - 2, y + dy - 2)));
                if !inside {
                    continue;
                }
                covered += 1;
                if !hit(&coarse, x, y) {
                    holes += 1;
                    continue;
                }
                let (a, b) = (depth(&full, x, y), depth(&coarse, x, y));
                if (a - b).abs() > 0.01 * a {
                    depth_off += 1;
                }
            }
        }
        assert!(covered > 10_000, "the wall fills the view: {covered}");
        assert_eq!(holes, 0, "cracks between levels");
        assert_eq!(depth_off, 0, "depth within 1 %");
        // And it drew fewer triangles.
        let camera = PinholeCamera::new(320, 256, 210.0, 210.0, 159.5, 127.5);
        let mut counts = [0usize; 2];
        for (k, px) in [0.0, 2.0].into_iter().enumerate() {
            let mut r = CpuRenderer::with_lod(Arc::clone(&mesh), 2.0).unwrap();
            r.set_lod_max_px(px);
            let mut out = RenderedView::for_camera(&camera);
            r.render(&pose, &camera, &mut out).unwrap();
            counts[k] = r.cull_stats().visible_triangles;
        }
        assert!(4 * counts[1] < counts[0], "{counts:?}");
    }

    #[test]
    fn culling_does_not_change_a_render_with_levels_of_detail() {
        let mut mesh = wall(600, 10.0, 0.0);
        for p in &mut mesh.positions {
            let t = (p[0] + 10.0) / 20.0;
            *p = [p[0] * 0.5, 4.0 + 40.0 * t, p[2] * 0.3];
        }
        // Vertex-colored, and textured (whose copies are exact, drawn near
        // too).
        for mesh in [Arc::new(mesh.clone()), Arc::new(textured(mesh))] {
            for x_m in [-3.0, 0.0, 2.5] {
                let pose = looking_along_y(x_m);
                let culled = render(&mesh, &pose, 2.0, true);
                let whole = render(&mesh, &pose, 2.0, false);
                assert_eq!(culled.depth_m.data(), whole.depth_m.data(), "x = {x_m}");
                assert_eq!(culled.gray.data(), whole.gray.data(), "x = {x_m}");
            }
        }
    }
}
