//! Mesh assembly for the synthetic scene: subdivided rectangles with
//! per-vertex shading and uv mapping, collected into one group per texture.

use crate::map::{Mesh, MeshGroup};

/// Edge length of the cells inside a surface patch or box face, meters.
pub(super) const CELL_M: f64 = 0.125;

/// A planar rectangle in the world: `origin + s * u_axis + t * v_axis` for
/// `s` in `0..u_len_m`, `t` in `0..v_len_m` (axes unit length).
#[derive(Debug, Clone, Copy)]
pub(super) struct Face {
    /// Corner where `s = t = 0`.
    pub origin: [f64; 3],
    /// Unit direction of `s` (texture x).
    pub u_axis: [f64; 3],
    /// Unit direction of `t` (texture y, down on walls).
    pub v_axis: [f64; 3],
    /// Extent along `u_axis`.
    pub u_len_m: f64,
    /// Extent along `v_axis`.
    pub v_len_m: f64,
    /// Unit normal facing the visible side.
    pub normal: [f64; 3],
}

impl Face {
    /// World point at `(s, t)`.
    pub fn point(&self, s: f64, t: f64) -> [f64; 3] {
        [
            self.origin[0] + s * self.u_axis[0] + t * self.v_axis[0],
            self.origin[1] + s * self.u_axis[1] + t * self.v_axis[1],
            self.origin[2] + s * self.u_axis[2] + t * self.v_axis[2],
        ]
    }
}

/// Maps face coordinates (meters) to texture uv: `uv = offset + st * scale`.
#[derive(Debug, Clone, Copy)]
pub(super) struct UvMap {
    /// uv at `s = t = 0`.
    pub offset: [f64; 2],
    /// uv per meter along `s` and `t`.
    pub scale: [f64; 2],
}

/// Collects triangles per texture and emits a [`Mesh`].
pub(super) struct MeshBuilder {
    mesh: Mesh,
    buckets: Vec<Vec<u32>>,
    /// Cell edge of [`MeshBuilder::face`], meters.
    cell_m: f64,
}

impl MeshBuilder {
    /// A builder for meshes using up to `texture_count` textures, whole
    /// faces cut into cells of about [`CELL_M`].
    pub fn new(texture_count: usize) -> Self {
        Self::with_cell(texture_count, CELL_M)
    }

    /// As [`MeshBuilder::new`], whole faces cut into cells of about
    /// `cell_m` (denser tessellation for large-map benchmarks).
    pub fn with_cell(texture_count: usize, cell_m: f64) -> Self {
        Self {
            mesh: Mesh::default(),
            buckets: vec![Vec::new(); texture_count],
            cell_m,
        }
    }

    /// The cell edge of [`MeshBuilder::face`], meters.
    pub fn cell_m(&self) -> f64 {
        self.cell_m
    }

    /// Appends a finished `mesh` (groups on this builder's texture numbers)
    /// with every position mapped through `world_from_local`; gray and uv
    /// are copied as they are.
    pub fn append(&mut self, mesh: &Mesh, world_from_local: &dyn Fn([f64; 3]) -> [f64; 3]) {
        let base = self.mesh.positions.len() as u32;
        for p in &mesh.positions {
            let q = world_from_local(p.map(f64::from));
            self.mesh.positions.push(q.map(|v| v as f32));
        }
        self.mesh.gray.extend_from_slice(&mesh.gray);
        self.mesh.uvs.extend_from_slice(&mesh.uvs);
        for group in &mesh.groups {
            let Some(bucket) = group.texture.and_then(|t| self.buckets.get_mut(t as usize)) else {
                continue;
            };
            let first = group.first_index as usize;
            let Some(indices) = mesh.indices.get(first..first + group.index_count as usize) else {
                continue;
            };
            bucket.extend(indices.iter().map(|i| i + base));
        }
    }

    /// Adds the part `[s0, s1] x [t0, t1]` of `face` as an `ns x nt` grid of
    /// quads (two triangles each) on `texture`. Vertex gray is
    /// `shade(point) * 255`.
    #[allow(clippy::too_many_arguments)]
    pub fn grid(
        &mut self,
        face: &Face,
        s: [f64; 2],
        t: [f64; 2],
        cells: [usize; 2],
        texture: usize,
        uv: UvMap,
        shade: &dyn Fn([f64; 3]) -> f64,
    ) {
        let [ns, nt] = [cells[0].max(1), cells[1].max(1)];
        let base = self.mesh.positions.len() as u32;
        for j in 0..=nt {
            let tt = t[0] + (t[1] - t[0]) * j as f64 / nt as f64;
            for i in 0..=ns {
                let ss = s[0] + (s[1] - s[0]) * i as f64 / ns as f64;
                let p = face.point(ss, tt);
                self.mesh
                    .positions
                    .push([p[0] as f32, p[1] as f32, p[2] as f32]);
                self.mesh.gray.push((shade(p) * 255.0) as f32);
                self.mesh.uvs.push([
                    (uv.offset[0] + ss * uv.scale[0]) as f32,
                    (uv.offset[1] + tt * uv.scale[1]) as f32,
                ]);
            }
        }
        let Some(bucket) = self.buckets.get_mut(texture) else {
            return;
        };
        // Counter-clockwise seen from the visible side: `u x v` along the
        // normal keeps the grid's order, else it is reversed, so that every
        // triangle's front faces where `face.normal` says the surface is seen
        // from (renderers that cull back faces draw only that side).
        let [u, v, n] = [face.u_axis, face.v_axis, face.normal];
        let u_cross_v = [
            u[1] * v[2] - u[2] * v[1],
            u[2] * v[0] - u[0] * v[2],
            u[0] * v[1] - u[1] * v[0],
        ];
        let flip = u_cross_v[0] * n[0] + u_cross_v[1] * n[1] + u_cross_v[2] * n[2] < 0.0;
        let row = ns as u32 + 1;
        for j in 0..nt as u32 {
            for i in 0..ns as u32 {
                let a = base + j * row + i;
                let (b, c, d) = (a + 1, a + row + 1, a + row);
                if flip {
                    bucket.extend_from_slice(&[a, c, b, a, d, c]);
                } else {
                    bucket.extend_from_slice(&[a, b, c, a, c, d]);
                }
            }
        }
    }

    /// Adds a whole face subdivided into cells of about the builder's cell
    /// edge ([`CELL_M`] unless built [`MeshBuilder::with_cell`]).
    pub fn face(
        &mut self,
        face: &Face,
        texture: usize,
        uv: UvMap,
        shade: &dyn Fn([f64; 3]) -> f64,
    ) {
        let cells = [
            (face.u_len_m / self.cell_m).ceil() as usize,
            (face.v_len_m / self.cell_m).ceil() as usize,
        ];
        self.grid(
            face,
            [0.0, face.u_len_m],
            [0.0, face.v_len_m],
            cells,
            texture,
            uv,
            shade,
        );
    }

    /// The mesh, one group per non-empty texture bucket, in texture order.
    /// Textures are left empty for the caller to fill.
    pub fn finish(mut self) -> Mesh {
        for (texture, bucket) in self.buckets.into_iter().enumerate() {
            if bucket.is_empty() {
                continue;
            }
            self.mesh.groups.push(MeshGroup {
                first_index: self.mesh.indices.len() as u32,
                index_count: bucket.len() as u32,
                texture: Some(texture as u32),
            });
            self.mesh.indices.extend(bucket);
        }
        self.mesh
    }
}
