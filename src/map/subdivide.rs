//! Uniform 1-to-4 subdivision of a [`Mesh`], to make large meshes with the
//! same surface for renderer benchmarks (200k, 1M triangles).
//!
//! Takes a mesh and a minimum triangle count; gives out a new mesh whose
//! every triangle is split at its edge midpoints (gray and uv interpolated
//! linearly) as many times as needed. The surface, bounds, groups and
//! textures are unchanged; edge midpoints are shared so the mesh stays
//! watertight where it was.

use std::collections::HashMap;

use super::{Mesh, MeshGroup};

/// Splits every triangle into 4 (at edge midpoints) until the mesh has at
/// least `min_triangles` triangles. Returns a copy when it already has.
pub fn subdivide(mesh: &Mesh, min_triangles: usize) -> Mesh {
    let mut out = mesh.clone();
    while out.triangle_count() < min_triangles && out.triangle_count() > 0 {
        out = subdivide_once(&out);
    }
    out
}

/// One round of 1-to-4 subdivision.
fn subdivide_once(mesh: &Mesh) -> Mesh {
    let mut out = Mesh {
        positions: mesh.positions.clone(),
        gray: mesh.gray.clone(),
        uvs: mesh.uvs.clone(),
        indices: Vec::with_capacity(mesh.indices.len() * 4),
        groups: Vec::with_capacity(mesh.groups.len()),
        textures: mesh.textures.clone(),
    };
    let mut midpoints: HashMap<(u32, u32), u32> = HashMap::with_capacity(mesh.indices.len());
    let n = mesh.positions.len();
    let attr = |v: &Vec<f32>, i: u32| v.get(i as usize).copied().unwrap_or(0.0);
    let uv = |i: u32| mesh.uvs.get(i as usize).copied().unwrap_or([0.0, 0.0]);
    let mut midpoint = |out: &mut Mesh, a: u32, b: u32| -> u32 {
        let key = (a.min(b), a.max(b));
        *midpoints.entry(key).or_insert_with(|| {
            let (pa, pb) = (mesh.positions[a as usize], mesh.positions[b as usize]);
            out.positions.push([
                0.5 * (pa[0] + pb[0]),
                0.5 * (pa[1] + pb[1]),
                0.5 * (pa[2] + pb[2]),
            ]);
            out.gray
                .push(0.5 * (attr(&mesh.gray, a) + attr(&mesh.gray, b)));
            let (ua, ub) = (uv(a), uv(b));
            out.uvs.push([0.5 * (ua[0] + ub[0]), 0.5 * (ua[1] + ub[1])]);
            (out.positions.len() - 1) as u32
        })
    };
    let groups: Vec<MeshGroup> = if mesh.groups.is_empty() {
        vec![MeshGroup {
            first_index: 0,
            index_count: mesh.indices.len() as u32,
            texture: None,
        }]
    } else {
        mesh.groups.clone()
    };
    for group in groups {
        let first_index = out.indices.len() as u32;
        let start = group.first_index as usize;
        let end = (start + group.index_count as usize).min(mesh.indices.len());
        for tri in mesh.indices.get(start..end).unwrap_or(&[]).chunks_exact(3) {
            let (a, b, c) = (tri[0], tri[1], tri[2]);
            if [a, b, c].iter().any(|&i| i as usize >= n) {
                continue; // invalid triangle: dropped (validate() reports it)
            }
            let ab = midpoint(&mut out, a, b);
            let bc = midpoint(&mut out, b, c);
            let ca = midpoint(&mut out, c, a);
            out.indices
                .extend_from_slice(&[a, ab, ca, ab, b, bc, ca, bc, c, ab, bc, ca]);
        }
        out.groups.push(MeshGroup {
            first_index,
            index_count: out.indices.len() as u32 - first_index,
            texture: group.texture,
        });
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn area(mesh: &Mesh) -> f64 {
        mesh.indices
            .chunks_exact(3)
            .map(|t| {
                let p = |i: u32| {
                    let q = mesh.positions[i as usize];
                    nalgebra::Vector3::new(q[0] as f64, q[1] as f64, q[2] as f64)
                };
                0.5 * (p(t[1]) - p(t[0])).cross(&(p(t[2]) - p(t[0]))).norm()
            })
            .sum()
    }

    fn tetra() -> Mesh {
        Mesh {
            positions: vec![
                [0.0, 0.0, 0.0],
                [2.0, 0.0, 0.0],
                [0.0, 3.0, 0.0],
                [0.0, 0.0, 1.5],
            ],
            gray: vec![0.0, 100.0, 200.0, 255.0],
            uvs: vec![[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]],
            indices: vec![0, 1, 2, 0, 1, 3, 1, 2, 3, 0, 2, 3],
            groups: vec![
                MeshGroup {
                    first_index: 0,
                    index_count: 6,
                    texture: None,
                },
                MeshGroup {
                    first_index: 6,
                    index_count: 6,
                    texture: Some(0),
                },
            ],
            textures: vec![crate::map::GrayTexture {
                width: 1,
                height: 1,
                texels: vec![1.0],
            }],
        }
    }

    #[test]
    fn surface_and_bounds_are_unchanged() {
        let mesh = tetra();
        let fine = subdivide(&mesh, 1000);
        assert_eq!(fine.triangle_count(), 4 * 4usize.pow(4));
        assert!(fine.validate().is_ok());
        assert!((area(&fine) - area(&mesh)).abs() < 1e-4 * area(&mesh));
        assert_eq!(fine.bounds(), mesh.bounds());
        assert_eq!(fine.groups.len(), 2);
        assert_eq!(fine.groups[1].texture, Some(0));
        assert_eq!(fine.groups[1].index_count, 6 * 256);
        // Shared midpoints: a closed tetrahedron stays closed (V - E + F = 2).
        let v = fine.positions.len() as i64;
        let f = fine.triangle_count() as i64;
        assert_eq!(v - 3 * f / 2 + f, 2);
    }

    #[test]
    fn attributes_are_interpolated() {
        let fine = subdivide(&tetra(), 5);
        // Midpoint of vertices 0 and 1: gray 50, uv (0.5, 0).
        let i = fine
            .positions
            .iter()
            .position(|p| *p == [1.0, 0.0, 0.0])
            .unwrap();
        assert_eq!(fine.gray[i], 50.0);
        assert_eq!(fine.uvs[i], [0.5, 0.0]);
    }

    #[test]
    fn already_large_enough_is_a_copy() {
        let mesh = tetra();
        assert_eq!(subdivide(&mesh, 4), mesh);
    }
}
