//! Uniform subdivision of a [`Mesh`], to make large meshes with the same
//! surface for renderer benchmarks (200k, 1M triangles).
//!
//! Takes a mesh and a minimum triangle count; gives out a new mesh whose
//! every triangle is split into `n x n` similar triangles (each edge cut into
//! `n` equal segments, gray and uv interpolated linearly), with the smallest
//! `n` that reaches the count. `n = 2` is the classic 1-to-4 midpoint split
//! and `n = 2^k` equals `k` rounds of it; other `n` land closer to the target
//! (a 27k-triangle room gives 242k for 200k, not 430k). The surface, bounds,
//! groups and textures are unchanged; edge points are shared between
//! neighbouring triangles so the mesh stays watertight where it was.

use std::collections::HashMap;

use super::{Mesh, MeshGroup};

/// Largest number of triangles [`subdivide`] produces.
pub const MAX_SUBDIVIDED_TRIANGLES: usize = 64 << 20;

/// Splits every triangle into `n x n` (smallest `n` with at least
/// `min_triangles` in all, capped at [`MAX_SUBDIVIDED_TRIANGLES`]). Returns a
/// copy when the mesh already has enough. Triangles with out-of-range
/// indices are dropped ([`Mesh::validate`] reports them).
pub fn subdivide(mesh: &Mesh, min_triangles: usize) -> Mesh {
    let count = mesh.triangle_count();
    if count == 0 || count >= min_triangles {
        return mesh.clone();
    }
    let target = min_triangles.min(MAX_SUBDIVIDED_TRIANGLES) as f64;
    let mut n = ((target / count as f64).sqrt().ceil() as usize).max(1);
    while n > 1 && count * n * n > MAX_SUBDIVIDED_TRIANGLES {
        n -= 1;
    }
    split(mesh, n)
}

/// Interpolation weights and source vertices of a new vertex.
type Blend = [(u32, f64); 3];

/// Splits every triangle into `n x n`.
fn split(mesh: &Mesh, n: usize) -> Mesh {
    let vertex_count = mesh.positions.len();
    let has_uvs = mesh.uvs.len() == vertex_count;
    let mut out = Mesh {
        positions: mesh.positions.clone(),
        gray: mesh.gray.clone(),
        uvs: mesh.uvs.clone(),
        indices: Vec::with_capacity(mesh.indices.len() * n * n),
        groups: Vec::with_capacity(mesh.groups.len().max(1)),
        textures: mesh.textures.clone(),
    };
    let push = |out: &mut Mesh, blend: Blend| -> u32 {
        let mut p = [0.0f64; 3];
        let (mut g, mut uv) = (0.0f64, [0.0f64; 2]);
        for (i, w) in blend {
            let i = i as usize;
            for (acc, &c) in p.iter_mut().zip(&mesh.positions[i]) {
                *acc += w * f64::from(c);
            }
            g += w * f64::from(mesh.gray.get(i).copied().unwrap_or(0.0));
            if has_uvs {
                uv[0] += w * f64::from(mesh.uvs[i][0]);
                uv[1] += w * f64::from(mesh.uvs[i][1]);
            }
        }
        out.positions.push([p[0] as f32, p[1] as f32, p[2] as f32]);
        out.gray.push(g as f32);
        if has_uvs {
            out.uvs.push([uv[0] as f32, uv[1] as f32]);
        }
        (out.positions.len() - 1) as u32
    };
    // The n - 1 inner points of each edge, keyed by (low, high) vertex and
    // stored from low to high.
    let mut edges: HashMap<(u32, u32), u32> = HashMap::with_capacity(mesh.indices.len());
    let nf = n as f64;
    let mut edge_point = |out: &mut Mesh, from: u32, to: u32, k: usize| -> u32 {
        let (lo, hi) = (from.min(to), from.max(to));
        let first = *edges.entry((lo, hi)).or_insert_with(|| {
            let first = out.positions.len() as u32;
            for step in 1..n {
                let t = step as f64 / nf;
                push(&mut *out, [(lo, 1.0 - t), (hi, t), (hi, 0.0)]);
            }
            first
        });
        let step = if from == lo { k } else { n - k };
        first + step as u32 - 1
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
    // Grid point (i, j) of triangle (a, b, c) is a + (b - a) i/n + (c - a) j/n.
    let mut grid: Vec<u32> = vec![0; (n + 1) * (n + 1)];
    for group in groups {
        let first_index = out.indices.len() as u32;
        let start = group.first_index as usize;
        let end = (start + group.index_count as usize).min(mesh.indices.len());
        for tri in mesh.indices.get(start..end).unwrap_or(&[]).chunks_exact(3) {
            let (a, b, c) = (tri[0], tri[1], tri[2]);
            if [a, b, c].iter().any(|&i| i as usize >= vertex_count) {
                continue;
            }
            for j in 0..=n {
                for i in 0..=n - j {
                    grid[j * (n + 1) + i] = match (i, j) {
                        (0, 0) => a,
                        (i, 0) if i == n => b,
                        (0, j) if j == n => c,
                        (i, 0) => edge_point(&mut out, a, b, i),
                        (0, j) => edge_point(&mut out, a, c, j),
                        (i, j) if i + j == n => edge_point(&mut out, b, c, j),
                        (i, j) => {
                            let (wi, wj) = (i as f64 / nf, j as f64 / nf);
                            push(&mut out, [(a, 1.0 - wi - wj), (b, wi), (c, wj)])
                        }
                    };
                }
            }
            let at = |i: usize, j: usize| grid[j * (n + 1) + i];
            for j in 0..n {
                for i in 0..n - j {
                    out.indices
                        .extend_from_slice(&[at(i, j), at(i + 1, j), at(i, j + 1)]);
                    if i + j + 1 < n {
                        out.indices.extend_from_slice(&[
                            at(i + 1, j),
                            at(i + 1, j + 1),
                            at(i, j + 1),
                        ]);
                    }
                }
            }
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
        // n = ceil(sqrt(1000 / 4)) = 16 segments per edge.
        assert_eq!(fine.triangle_count(), 4 * 16 * 16);
        assert!(fine.validate().is_ok());
        assert!((area(&fine) - area(&mesh)).abs() < 1e-4 * area(&mesh));
        assert_eq!(fine.bounds(), mesh.bounds());
        assert_eq!(fine.groups.len(), 2);
        assert_eq!(fine.groups[1].texture, Some(0));
        assert_eq!(fine.groups[1].index_count, 6 * 256);
        // Odd n too, and a target that is not a square multiple.
        let odd = subdivide(&mesh, 4 * 9 - 3);
        assert_eq!(odd.triangle_count(), 4 * 9);
        assert!((area(&odd) - area(&mesh)).abs() < 1e-4 * area(&mesh));
        let v = odd.positions.len() as i64;
        let f = odd.triangle_count() as i64;
        assert_eq!(v - 3 * f / 2 + f, 2);
        // Shared midpoints: a closed tetrahedron stays closed (V - E + F = 2).
        let v = fine.positions.len() as i64;
        let f = fine.triangle_count() as i64;
        assert_eq!(v - 3 * f / 2 + f, 2);
    }

    #[test]
    fn attributes_are_interpolated() {
        let fine = subdivide(&tetra(), 5);
        assert_eq!(fine.triangle_count(), 16);
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
