//! Levels of detail of a chunked mesh: coarser copies of its untextured
//! chunks, drawn instead of the chunk where the camera is too far away to
//! tell the difference.
//!
//! Owns [`LodTable`] (built once with the chunks, [`build_levels`]) and the
//! per-render choice ([`LodView`], [`LodTable::choose`]). A scanned map (a
//! TSDF mesh, vertex-colored, 1-2 cm triangles) has millions of triangles
//! smaller than a pixel wherever the camera looks down a corridor, and
//! every one costs a vertex transform and a setup; at the database's
//! 160x128 thumbnails almost all of them do.
//!
//! **The coarse copies.** Each untextured chunk is simplified by vertex
//! clustering (Rossignac and Borrel): its vertices are pooled in cubic
//! cells of [`LEVELS`] sizes (2, 4 and 8 times the median edge of the
//! untextured triangles), each cell's vertices become one vertex at their
//! mean position and mean gray, and the triangles that collapse are
//! dropped. A vertex the chunk shares with another chunk is never moved,
//! so a coarse chunk meets its neighbors, fine or coarse, at exactly the
//! same border: no crack opens between levels. A level is kept for a chunk
//! only when it has at most [`KEEP_RATIO`] of the triangles of the finer
//! level kept before it. Coarse chunks are appended after the fine ones in
//! [`super::chunks::ChunkedMesh::chunks`]; each coarse triangle carries the
//! mesh number of the first triangle that made it, for the renderers'
//! depth tie-break. Textured chunks have no coarse copy: their appearance
//! is in the texture, which a mean vertex cannot keep, and their triangles
//! are not the scan's fine ones.
//!
//! **The choice.** A render draws, for each fine chunk, its coarsest level
//! whose cell, at the chunk box's nearest point to the camera, spans at most
//! `max_px` pixels (`[render] lod_max_px`); the frustum test is then made
//! on the chosen copy. The choice depends only on the pose, the camera and
//! the chunk, never on the culls, so a culled render stays identical to an
//! unculled one, and both renderers choose alike. A vertex moves by less
//! than a cell (its mean stays inside the cell), so an outline moves by
//! less than `max_px` pixels, and a surface's depth by less than a cell.

use std::collections::HashMap;

use super::chunks::{Aabb, ChunkedMesh, MeshChunk, NO_GROUP};
use crate::geometry::{PinholeCamera, Pose};
use crate::map::Mesh;

/// Number of coarse levels.
pub const LEVELS: usize = 3;

/// Cell size of coarse level `l` (0-based) in median edges: 2, 4, 8.
const CELL_EDGES: [f32; LEVELS] = [2.0, 4.0, 8.0];

/// A level is kept for a chunk only with at most this share of the
/// triangles of the level before it (the fine chunk for the first).
pub const KEEP_RATIO: f32 = 0.75;

/// No coarse copy at this level.
pub const NONE: u32 = u32::MAX;

/// Triangles sampled for the median edge.
const EDGE_SAMPLES: usize = 100_000;

/// Which chunks are coarse copies of which. See the module docs.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct LodTable {
    /// The chunks of full detail: `chunks[..fine_chunks]`.
    pub fine_chunks: usize,
    /// Cell size of each level, meters (0 when there are no coarse copies).
    pub cell_m: [f32; LEVELS],
    /// Per fine chunk, the chunk number of its copy at each level, or
    /// [`NONE`]; empty when no chunk has one.
    pub coarse: Vec<[u32; LEVELS]>,
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
}

impl LodTable {
    /// The table of a mesh without coarse copies: `fine_chunks` chunks.
    pub fn fine_only(fine_chunks: usize) -> Self {
        Self {
            fine_chunks,
            cell_m: [0.0; LEVELS],
            coarse: Vec::new(),
        }
    }

    /// Number of coarse copies.
    pub fn coarse_chunks(&self) -> usize {
        self.coarse.iter().flatten().filter(|&&c| c != NONE).count()
    }

    /// The chunk to draw for fine chunk `fine` (with box `bounds`): its
    /// coarsest copy whose cell spans at most `view.max_px` pixels at the
    /// box's nearest point, else `fine` itself (also without a view).
    pub fn choose(&self, fine: usize, bounds: &Aabb, view: Option<&LodView>) -> usize {
        let (Some(view), Some(levels)) = (view, self.coarse.get(fine)) else {
            return fine;
        };
        let distance_m = view.distance_m(bounds);
        for l in (0..LEVELS).rev() {
            let chunk = levels[l];
            if chunk != NONE && self.cell_m[l] * view.focal_px <= view.max_px * distance_m {
                return chunk as usize;
            }
        }
        fine
    }
}

/// Whether fine chunk `chunk` of `mesh` may get coarse copies: untextured.
fn untextured(mesh: &Mesh, chunk: &MeshChunk) -> bool {
    if chunk.group == NO_GROUP {
        return mesh.groups.is_empty();
    }
    mesh.groups
        .get(chunk.group as usize)
        .is_some_and(|g| g.texture.is_none())
}

/// Median edge length of the untextured triangles of `chunked` (sampled),
/// meters; `None` when there are none.
fn median_edge_m(chunked: &ChunkedMesh, mesh: &Mesh) -> Option<f32> {
    let tris: usize = chunked
        .chunks
        .iter()
        .filter(|c| untextured(mesh, c))
        .map(MeshChunk::triangle_count)
        .sum();
    if tris == 0 {
        return None;
    }
    let stride = tris.div_ceil(EDGE_SAMPLES).max(1);
    let mut edges = Vec::with_capacity(3 * (tris / stride + 1));
    let mut k = 0usize;
    for chunk in chunked.chunks.iter().filter(|c| untextured(mesh, c)) {
        for t in chunk.triangles.clone() {
            k += 1;
            if k % stride != 0 {
                continue;
            }
            let Some(tri) = chunked.indices.get(3 * t as usize..3 * t as usize + 3) else {
                continue;
            };
            let p = |i: u32| {
                chunked
                    .positions
                    .get(i as usize)
                    .copied()
                    .unwrap_or([0.0; 3])
            };
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

/// Scratch of one chunk's simplification, reused from chunk to chunk.
#[derive(Default)]
struct Scratch {
    /// Cell of each pooled vertex -> its cluster.
    cells: HashMap<[i32; 3], u32>,
    /// Per chunk-local vertex, its cluster.
    cluster_of: Vec<u32>,
    /// Per cluster: summed position, gray and count, and whether it is a
    /// shared (fixed) vertex.
    sum: Vec<([f64; 3], f64, u32)>,
    /// Per cluster, its vertex number in the output, or [`NONE`].
    emitted: Vec<u32>,
    /// Coarse triangles seen (sorted cluster triples).
    seen: std::collections::HashSet<[u32; 3]>,
    /// The coarse triangles, as clusters, with their source triangle.
    triangles: Vec<([u32; 3], u32)>,
}

/// Appends coarse copies of the untextured chunks of `chunked` (built from
/// `mesh`) and fills its [`LodTable`]. `vertex_source[v]` is the mesh
/// vertex that chunked vertex `v` copies; `shared[m]` whether mesh vertex
/// `m` lies in more than one chunk. Fails only when the copies no longer
/// fit `u32` indices.
pub fn build_levels(
    chunked: &mut ChunkedMesh,
    mesh: &Mesh,
    vertex_source: &[u32],
    shared: &[bool],
) -> Result<(), super::RenderError> {
    let fine = chunked.chunks.len();
    chunked.lod = LodTable::fine_only(fine);
    let Some(edge_m) = median_edge_m(chunked, mesh) else {
        return Ok(());
    };
    let cell_m = CELL_EDGES.map(|k| k * edge_m);
    let mut coarse = vec![[NONE; LEVELS]; fine];
    let mut scratch = Scratch::default();
    for c in 0..fine {
        let Some(chunk) = chunked.chunks.get(c).cloned() else {
            break;
        };
        if !untextured(mesh, &chunk) {
            continue;
        }
        let mut kept_tris = chunk.triangle_count();
        for l in 0..LEVELS {
            let made = simplify(
                chunked,
                &chunk,
                cell_m[l],
                vertex_source,
                shared,
                &mut scratch,
            );
            if made == 0 || made as f32 > KEEP_RATIO * kept_tris as f32 {
                continue;
            }
            let number = chunked.chunks.len();
            if number >= NONE as usize {
                return Err(super::RenderError::InvalidMesh {
                    field: "indices",
                    index: number,
                    reason: "too many chunks with levels of detail".to_string(),
                });
            }
            emit(chunked, &chunk, &mut scratch)?;
            coarse[c][l] = number as u32;
            kept_tris = made;
        }
    }
    if coarse.iter().flatten().any(|&n| n != NONE) {
        chunked.lod = LodTable {
            fine_chunks: fine,
            cell_m,
            coarse,
        };
    }
    Ok(())
}

/// Clusters `chunk`'s vertices in cells of `cell_m` into `scratch` and
/// lists the coarse triangles that survive; gives their number.
fn simplify(
    chunked: &ChunkedMesh,
    chunk: &MeshChunk,
    cell_m: f32,
    vertex_source: &[u32],
    shared: &[bool],
    s: &mut Scratch,
) -> usize {
    s.cells.clear();
    s.cluster_of.clear();
    s.sum.clear();
    s.seen.clear();
    s.triangles.clear();
    let v0 = chunk.vertices.start as usize;
    for v in chunk.vertices.clone() {
        let v = v as usize;
        let p = chunked.positions.get(v).copied().unwrap_or([0.0; 3]);
        let gray = f64::from(chunked.gray.get(v).copied().unwrap_or(0.0));
        let fixed = vertex_source
            .get(v)
            .and_then(|&m| shared.get(m as usize))
            .copied()
            .unwrap_or(true);
        let new_cluster = |s: &mut Scratch| {
            s.sum.push(([0.0; 3], 0.0, 0));
            (s.sum.len() - 1) as u32
        };
        let cluster = if fixed {
            new_cluster(s)
        } else {
            let key = p.map(|x| (x / cell_m).floor() as i32);
            match s.cells.get(&key) {
                Some(&k) => k,
                None => {
                    let k = new_cluster(s);
                    s.cells.insert(key, k);
                    k
                }
            }
        };
        if let Some(sum) = s.sum.get_mut(cluster as usize) {
            for k in 0..3 {
                sum.0[k] += f64::from(p[k]);
            }
            sum.1 += gray;
            sum.2 += 1;
        }
        s.cluster_of.push(cluster);
    }
    for t in chunk.triangles.clone() {
        let Some(tri) = chunked.indices.get(3 * t as usize..3 * t as usize + 3) else {
            continue;
        };
        let cluster = |i: u32| {
            s.cluster_of
                .get((i as usize).wrapping_sub(v0))
                .copied()
                .unwrap_or(NONE)
        };
        let k = [cluster(tri[0]), cluster(tri[1]), cluster(tri[2])];
        if k.contains(&NONE) || k[0] == k[1] || k[1] == k[2] || k[0] == k[2] {
            continue;
        }
        let mut key = k;
        key.sort_unstable();
        if s.seen.insert(key) {
            let source = chunked
                .source_triangle
                .get(t as usize)
                .copied()
                .unwrap_or(0);
            s.triangles.push((k, source));
        }
    }
    s.triangles.len()
}

/// Appends the coarse chunk in `scratch` (from [`simplify`] on `chunk`).
fn emit(
    chunked: &mut ChunkedMesh,
    chunk: &MeshChunk,
    s: &mut Scratch,
) -> Result<(), super::RenderError> {
    s.emitted.clear();
    s.emitted.resize(s.sum.len(), NONE);
    let first_tri = chunked.source_triangle.len() as u32;
    let first_vertex = chunked.positions.len();
    let has_uvs = !chunked.uvs.is_empty();
    let mut bounds = Aabb::EMPTY;
    for &(tri, source) in &s.triangles {
        for k in tri {
            let Some(slot) = s.emitted.get_mut(k as usize) else {
                continue;
            };
            if *slot == NONE {
                let n = chunked.positions.len();
                if n >= NONE as usize {
                    return Err(super::RenderError::InvalidMesh {
                        field: "indices",
                        index: n,
                        reason: "vertices: more than 2^32 with levels of detail".to_string(),
                    });
                }
                *slot = n as u32;
                let (p, gray, count) = s.sum.get(k as usize).copied().unwrap_or_default();
                let count = f64::from(count.max(1));
                let p = p.map(|x| (x / count) as f32);
                bounds.add(p);
                chunked.positions.push(p);
                chunked.gray.push((gray / count) as f32);
                if has_uvs {
                    chunked.uvs.push([0.0; 2]);
                }
            }
            chunked.indices.push(*slot);
        }
        chunked.source_triangle.push(source);
    }
    chunked.chunks.push(MeshChunk {
        triangles: first_tri..chunked.source_triangle.len() as u32,
        vertices: first_vertex as u32..chunked.positions.len() as u32,
        group: chunk.group,
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
    fn untextured_chunks_get_coarser_copies_with_their_borders_intact() {
        let mesh = wall(200, 10.0, 5.0); // 80k triangles, 10 cm edges
        let plain = ChunkedMesh::build(&mesh).unwrap();
        assert_eq!(plain.lod.coarse_chunks(), 0);
        let c = ChunkedMesh::build_with_levels(&mesh, true).unwrap();
        let fine = c.lod.fine_chunks;
        assert_eq!(fine, plain.chunks.len());
        // The fine part is untouched.
        assert_eq!(c.chunks[..fine], plain.chunks[..]);
        assert_eq!(
            c.indices[..plain.indices.len()],
            plain.indices[..],
            "fine indices"
        );
        assert!((c.lod.cell_m[0] - 0.2).abs() < 1e-3, "{:?}", c.lod.cell_m);
        assert!(c.lod.coarse_chunks() >= fine, "{:?}", c.lod);
        for (f, levels) in c.lod.coarse.iter().enumerate() {
            let fine_chunk = &c.chunks[f];
            let mut before = fine_chunk.triangle_count();
            // The fine chunk's border: vertices also in another chunk.
            let border: std::collections::HashSet<[u32; 3]> = c.chunks[..fine]
                .iter()
                .enumerate()
                .filter(|&(o, _)| o != f)
                .flat_map(|(_, o)| {
                    c.positions[o.vertices.start as usize..o.vertices.end as usize].iter()
                })
                .map(|p| p.map(f32::to_bits))
                .collect();
            let own: std::collections::HashSet<[u32; 3]> = c.positions
                [fine_chunk.vertices.start as usize..fine_chunk.vertices.end as usize]
                .iter()
                .map(|p| p.map(f32::to_bits))
                .filter(|p| border.contains(p))
                .collect();
            for &n in levels.iter().filter(|&&n| n != NONE) {
                let chunk = &c.chunks[n as usize];
                assert_eq!(chunk.group, fine_chunk.group);
                assert!(chunk.triangle_count() as f32 <= KEEP_RATIO * before as f32);
                before = chunk.triangle_count();
                let coarse: std::collections::HashSet<[u32; 3]> = c.positions
                    [chunk.vertices.start as usize..chunk.vertices.end as usize]
                    .iter()
                    .map(|p| p.map(f32::to_bits))
                    .collect();
                for p in &c.positions[chunk.vertices.start as usize..chunk.vertices.end as usize] {
                    for k in 0..3 {
                        assert!(
                            fine_chunk.bounds.min_m[k] <= p[k]
                                && p[k] <= fine_chunk.bounds.max_m[k]
                        );
                    }
                }
                // Every border vertex of the fine chunk is still there, exactly.
                assert!(own.is_subset(&coarse), "a border vertex moved");
                for t in chunk.triangles.clone() {
                    for k in 0..3 {
                        let v = c.indices[3 * t as usize + k];
                        assert!(chunk.vertices.contains(&v));
                    }
                    let src = c.source_triangle[t as usize] as usize;
                    assert!(src < mesh.triangle_count());
                }
            }
        }
    }

    #[test]
    fn textured_chunks_have_no_coarse_copy() {
        let mut mesh = wall(100, 5.0, 5.0);
        mesh.uvs = vec![[0.5, 0.5]; mesh.positions.len()];
        mesh.textures = vec![GrayTexture {
            width: 1,
            height: 1,
            texels: vec![1.0],
        }];
        mesh.groups = vec![MeshGroup {
            first_index: 0,
            index_count: mesh.indices.len() as u32,
            texture: Some(0),
        }];
        let c = ChunkedMesh::build_with_levels(&mesh, true).unwrap();
        assert_eq!(c.lod.coarse_chunks(), 0);
        assert_eq!(c.chunks.len(), c.lod.fine_chunks);
        // An untextured group of the same mesh does get them.
        mesh.groups[0].texture = None;
        let c = ChunkedMesh::build_with_levels(&mesh, true).unwrap();
        assert!(c.lod.coarse_chunks() > 0);
        assert_eq!(c.uvs.len(), c.positions.len(), "uvs kept per vertex");
    }

    #[test]
    fn the_level_follows_the_cells_size_on_the_image() {
        let mesh = wall(200, 10.0, 5.0);
        let c = ChunkedMesh::build_with_levels(&mesh, true).unwrap();
        let camera = PinholeCamera::new(640, 512, 420.0, 420.0, 319.5, 255.5);
        let (f, levels) = c
            .lod
            .coarse
            .iter()
            .enumerate()
            .find(|(_, l)| l.iter().all(|&n| n != NONE))
            .expect("a chunk with every level");
        let bounds = c.chunks[f].bounds;
        assert_eq!(c.lod.choose(f, &bounds, None), f, "no view: full detail");
        let at = |d: f32| {
            // A camera `d` m from the box, beside it along -y.
            let mut pose = looking_along_y(0.0);
            pose.translation.vector = Vector3::new(
                f64::from((bounds.min_m[0] + bounds.max_m[0]) / 2.0),
                f64::from(bounds.min_m[1] - d),
                f64::from((bounds.min_m[2] + bounds.max_m[2]) / 2.0),
            );
            LodView::new(&pose, &camera, 2.0).unwrap()
        };
        // Cells of 0.2, 0.4, 0.8 m: 2 px at 42, 84, 168 m.
        assert_eq!(c.lod.choose(f, &bounds, Some(&at(10.0))), f);
        assert_eq!(
            c.lod.choose(f, &bounds, Some(&at(50.0))),
            levels[0] as usize
        );
        assert_eq!(
            c.lod.choose(f, &bounds, Some(&at(100.0))),
            levels[1] as usize
        );
        assert_eq!(
            c.lod.choose(f, &bounds, Some(&at(200.0))),
            levels[2] as usize
        );
        assert!(LodView::new(&looking_along_y(0.0), &camera, 0.0).is_none());
        assert!(LodView::new(&looking_along_y(0.0), &camera, f32::NAN).is_none());
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
        let mesh = Arc::new(mesh);
        for x_m in [-3.0, 0.0, 2.5] {
            let pose = looking_along_y(x_m);
            let culled = render(&mesh, &pose, 2.0, true);
            let whole = render(&mesh, &pose, 2.0, false);
            assert_eq!(culled.depth_m.data(), whole.depth_m.data(), "x = {x_m}");
            assert_eq!(culled.gray.data(), whole.gray.data(), "x = {x_m}");
        }
    }
}
