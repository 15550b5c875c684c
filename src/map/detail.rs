//! How fine a map's appearance is: the spacing, in meters, of the samples
//! its colors are interpolated between ([`Mesh::detail_spacing_m`]).
//!
//! A scanned map (TSDF fusion, marching cubes) stores one color per vertex,
//! a voxel apart: between vertices its appearance is a linear blend, and
//! detail finer than the voxel is gone. A textured map holds detail down to
//! its texels. With `[reloc] gate_at_map_detail`, relocalization's
//! verification reads only the pyramid levels whose pixels are no finer
//! than the map holds (see `track::Keyframe::gate_level`): a camera image
//! at full resolution has detail a 2 cm map cannot, and a true pose then
//! correlates as poorly there as a wrong one.

use super::Mesh;

/// Triangles looked at, at most (evenly strided over the mesh).
const MAX_SAMPLED_TRIANGLES: usize = 200_000;

/// Vertex colors of a triangle that differ by less than this (gray levels)
/// make a flat surface: it claims no blur and holds no detail to compare.
const FLAT_GRAY_SPAN: f32 = 1.0;

impl Mesh {
    /// The median, over triangles that carry appearance, of the spacing of
    /// their color samples, meters: for a textured triangle, the side of
    /// one texel on the surface (`sqrt(surface area / texel area)`); for a
    /// vertex-colored one whose vertex colors differ, its mean edge length.
    /// Flat-colored triangles (one gray over the triangle) and degenerate
    /// ones do not count. Returns 0 when no triangle counts (nothing to
    /// blur). Looks at up to 200 000 triangles, evenly strided.
    pub fn detail_spacing_m(&self) -> f32 {
        let triangles = self.triangle_count();
        if triangles == 0 {
            return 0.0;
        }
        let stride = triangles.div_ceil(MAX_SAMPLED_TRIANGLES);
        let mut spacings: Vec<f32> = Vec::with_capacity(triangles / stride + 1);
        let whole = [super::MeshGroup {
            first_index: 0,
            index_count: self.indices.len() as u32,
            texture: None,
        }];
        let groups: &[super::MeshGroup] = if self.groups.is_empty() {
            &whole
        } else {
            &self.groups
        };
        for group in groups {
            let first = group.first_index as usize / 3;
            let count = group.index_count as usize / 3;
            let texture = group
                .texture
                .and_then(|t| self.textures.get(t as usize))
                .filter(|t| t.width > 0 && t.height > 0);
            // Keep the stride's phase across groups.
            let start = first.div_ceil(stride) * stride;
            for t in (start..first + count).step_by(stride) {
                let Some(tri) = self.indices.get(3 * t..3 * t + 3) else {
                    break;
                };
                let ids = [tri[0] as usize, tri[1] as usize, tri[2] as usize];
                let Some(spacing) = self.triangle_spacing_m(ids, texture) else {
                    continue;
                };
                spacings.push(spacing);
            }
        }
        if spacings.is_empty() {
            return 0.0;
        }
        let mid = spacings.len() / 2;
        *spacings.select_nth_unstable_by(mid, f32::total_cmp).1
    }

    /// One triangle's sample spacing ([`Self::detail_spacing_m`]); `None`
    /// when it carries no appearance or is degenerate.
    fn triangle_spacing_m(
        &self,
        ids: [usize; 3],
        texture: Option<&super::GrayTexture>,
    ) -> Option<f32> {
        let p = |i: usize| self.positions.get(i).map(|p| glam::Vec3::from_array(*p));
        let (a, b, c) = (p(ids[0])?, p(ids[1])?, p(ids[2])?);
        let area_m2 = 0.5 * (b - a).cross(c - a).length();
        if !(area_m2 > 0.0) {
            return None;
        }
        match texture {
            Some(tex) => {
                let uv = |i: usize| self.uvs.get(i).map(|u| glam::Vec2::from_array(*u));
                let (ua, ub, uc) = (uv(ids[0])?, uv(ids[1])?, uv(ids[2])?);
                let texels =
                    0.5 * (ub - ua).perp_dot(uc - ua).abs() * tex.width as f32 * tex.height as f32;
                (texels > 0.0).then(|| (area_m2 / texels).sqrt())
            }
            None => {
                let gray = |i: usize| self.gray.get(i).copied();
                let g = [gray(ids[0])?, gray(ids[1])?, gray(ids[2])?];
                let span = g.iter().fold(f32::MIN, |m, &v| m.max(v))
                    - g.iter().fold(f32::MAX, |m, &v| m.min(v));
                (span >= FLAT_GRAY_SPAN)
                    .then(|| ((b - a).length() + (c - b).length() + (a - c).length()) / 3.0)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::map::{GrayTexture, MeshGroup};

    /// A square of `n x n` cells, `side_m` on a side, two triangles each,
    /// vertex grays alternating (a checker of vertices) unless `flat`.
    fn grid(n: usize, side_m: f32, flat: bool) -> Mesh {
        let step = side_m / n as f32;
        let mut mesh = Mesh::default();
        for j in 0..=n {
            for i in 0..=n {
                mesh.positions.push([i as f32 * step, j as f32 * step, 0.0]);
                let odd = (i + j) % 2 == 1;
                mesh.gray.push(if flat || !odd { 100.0 } else { 160.0 });
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
    fn a_vertex_colored_mesh_is_as_fine_as_its_edges() {
        // Cells of 2 cm: edges 2, 2 and 2.83 cm, a mean of 2.28 cm.
        let spacing = grid(50, 1.0, false).detail_spacing_m();
        assert!((spacing - 0.0228).abs() < 0.0005, "{spacing}");
        let finer = grid(100, 1.0, false).detail_spacing_m();
        assert!((finer - 0.0114).abs() < 0.0003, "{finer}");
    }

    #[test]
    fn flat_colored_triangles_claim_no_blur() {
        assert_eq!(grid(4, 8.0, true).detail_spacing_m(), 0.0);
        assert_eq!(Mesh::default().detail_spacing_m(), 0.0);
    }

    #[test]
    fn a_textured_mesh_is_as_fine_as_its_texels() {
        // One 2 m square, two triangles, the whole of a 400 x 400 texture:
        // a texel is 5 mm on the wall, however large the triangles are.
        let mut mesh = grid(1, 2.0, true);
        mesh.uvs = vec![[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]];
        mesh.groups = vec![MeshGroup {
            first_index: 0,
            index_count: 6,
            texture: Some(0),
        }];
        mesh.textures = vec![GrayTexture {
            width: 400,
            height: 400,
            texels: vec![128.0; 400 * 400],
        }];
        let spacing = mesh.detail_spacing_m();
        assert!((spacing - 0.005).abs() < 1e-5, "{spacing}");
    }
}
