//! Map holes: round patches of the map mesh removed, as a real scan misses
//! surfaces (glass, dark or shiny objects, unscanned corners).
//!
//! Takes a mesh and a [`HoleSpec`]; gives a new mesh. Triangles longer
//! than `max_edge_m` are first split on a regular barycentric grid so holes
//! have round edges. Then hole centers are drawn on the surface
//! (area-weighted), each with a radius in `radius_m`, and every triangle
//! whose centroid lies within a hole is removed, until `fraction` of the
//! surface area is gone.

use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};
use serde::Serialize;

use super::derive_seed;
use crate::map::{Mesh, MeshGroup};

/// Exact map-hole parameters of a preset.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct HoleSpec {
    /// Fraction of the surface area removed (0 = no holes).
    pub fraction: f64,
    /// Range of hole radii, m.
    pub radius_m: (f64, f64),
    /// Triangles are split until no edge is longer than this, m.
    pub max_edge_m: f64,
}

type V3 = [f32; 3];

fn sub(a: V3, b: V3) -> V3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn len(a: V3) -> f32 {
    (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt()
}

fn area(a: V3, b: V3, c: V3) -> f64 {
    let (u, v) = (sub(b, a), sub(c, a));
    let cross = [
        u[1] * v[2] - u[2] * v[1],
        u[2] * v[0] - u[0] * v[2],
        u[0] * v[1] - u[1] * v[0],
    ];
    0.5 * len(cross) as f64
}

/// Splits every triangle with an edge longer than `max_edge_m` into `n^2`
/// triangles on a barycentric grid (`n` = longest edge / `max_edge_m`,
/// rounded up), interpolating gray and uv. Groups and textures are kept.
pub fn refine(mesh: &Mesh, max_edge_m: f32) -> Mesh {
    let mut out = Mesh {
        textures: mesh.textures.clone(),
        ..Mesh::default()
    };
    for g in &mesh.groups {
        let first_index = out.indices.len() as u32;
        let range = g.first_index as usize..(g.first_index + g.index_count) as usize;
        for tri in mesh.indices.get(range).unwrap_or(&[]).chunks_exact(3) {
            let [a, b, c] = [tri[0] as usize, tri[1] as usize, tri[2] as usize];
            let (pa, pb, pc) = (mesh.positions[a], mesh.positions[b], mesh.positions[c]);
            let longest = len(sub(pb, pa)).max(len(sub(pc, pb))).max(len(sub(pa, pc)));
            let n = if max_edge_m > 0.0 {
                ((longest / max_edge_m).ceil() as usize).clamp(1, 256)
            } else {
                1
            };
            // Vertex (i, j) = a + i/n (b - a) + j/n (c - a), i + j <= n.
            let mut id = vec![vec![0u32; n + 1]; n + 1];
            for i in 0..=n {
                for j in 0..=n - i {
                    let (s, t) = (i as f32 / n as f32, j as f32 / n as f32);
                    let w = [1.0 - s - t, s, t];
                    let mix3 = |p: [V3; 3]| -> V3 {
                        std::array::from_fn(|k| w[0] * p[0][k] + w[1] * p[1][k] + w[2] * p[2][k])
                    };
                    id[i][j] = out.positions.len() as u32;
                    out.positions.push(mix3([pa, pb, pc]));
                    out.gray
                        .push(w[0] * mesh.gray[a] + w[1] * mesh.gray[b] + w[2] * mesh.gray[c]);
                    let (ua, ub, uc) = (mesh.uvs[a], mesh.uvs[b], mesh.uvs[c]);
                    out.uvs.push(std::array::from_fn(|k| {
                        w[0] * ua[k] + w[1] * ub[k] + w[2] * uc[k]
                    }));
                }
            }
            for i in 0..n {
                for j in 0..n - i {
                    out.indices.extend([id[i][j], id[i + 1][j], id[i][j + 1]]);
                    if i + j + 2 <= n {
                        out.indices
                            .extend([id[i + 1][j], id[i + 1][j + 1], id[i][j + 1]]);
                    }
                }
            }
        }
        out.groups.push(MeshGroup {
            first_index,
            index_count: out.indices.len() as u32 - first_index,
            texture: g.texture,
        });
    }
    out
}

/// Removes about `spec.fraction` of `mesh`'s surface area in round holes,
/// deterministically from `seed`. Returns the damaged mesh and the fraction
/// of area actually removed.
pub fn punch_holes(mesh: &Mesh, spec: &HoleSpec, seed: u64) -> (Mesh, f64) {
    if !(spec.fraction > 0.0) {
        return (mesh.clone(), 0.0);
    }
    let fine = refine(mesh, spec.max_edge_m as f32);
    let tris: Vec<[u32; 3]> = fine
        .indices
        .chunks_exact(3)
        .map(|t| [t[0], t[1], t[2]])
        .collect();
    let pos = |i: u32| fine.positions[i as usize];
    let areas: Vec<f64> = tris
        .iter()
        .map(|t| area(pos(t[0]), pos(t[1]), pos(t[2])))
        .collect();
    let centroids: Vec<V3> = tris
        .iter()
        .map(|t| std::array::from_fn(|k| (pos(t[0])[k] + pos(t[1])[k] + pos(t[2])[k]) / 3.0))
        .collect();
    let total: f64 = areas.iter().sum();
    let mut cumulative = Vec::with_capacity(areas.len());
    areas.iter().fold(0.0, |acc, a| {
        cumulative.push(acc + a);
        acc + a
    });
    let mut removed = vec![false; tris.len()];
    let mut removed_area = 0.0;
    let mut rng = StdRng::seed_from_u64(derive_seed(seed, 0x401e));
    let (r_lo, r_hi) = spec.radius_m;
    for _ in 0..100_000 {
        if removed_area >= spec.fraction * total || total <= 0.0 {
            break;
        }
        let pick = rng.random_range(0.0..total);
        let center = centroids[cumulative
            .partition_point(|&c| c < pick)
            .min(tris.len() - 1)];
        let r = if r_hi > r_lo {
            rng.random_range(r_lo..r_hi)
        } else {
            r_lo
        } as f32;
        for (k, c) in centroids.iter().enumerate() {
            if !removed[k] && len(sub(*c, center)) <= r {
                removed[k] = true;
                removed_area += areas[k];
            }
        }
    }
    let mut out = Mesh {
        positions: fine.positions.clone(),
        gray: fine.gray.clone(),
        uvs: fine.uvs.clone(),
        textures: fine.textures.clone(),
        ..Mesh::default()
    };
    for g in &fine.groups {
        let first_index = out.indices.len() as u32;
        let (t0, t1) = (
            (g.first_index / 3) as usize,
            ((g.first_index + g.index_count) / 3) as usize,
        );
        for k in (t0..t1).filter(|&k| !removed[k]) {
            out.indices.extend(tris[k]);
        }
        let index_count = out.indices.len() as u32 - first_index;
        if index_count > 0 {
            out.groups.push(MeshGroup {
                first_index,
                index_count,
                texture: g.texture,
            });
        }
    }
    (
        out,
        if total > 0.0 {
            removed_area / total
        } else {
            0.0
        },
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 4 x 3 m wall made of two triangles, vertex gray 0..255 along x.
    fn wall() -> Mesh {
        Mesh {
            positions: vec![
                [0.0, 0.0, 0.0],
                [4.0, 0.0, 0.0],
                [4.0, 0.0, 3.0],
                [0.0, 0.0, 3.0],
            ],
            gray: vec![0.0, 255.0, 255.0, 0.0],
            uvs: vec![[0.0, 1.0], [1.0, 1.0], [1.0, 0.0], [0.0, 0.0]],
            indices: vec![0, 1, 2, 0, 2, 3],
            groups: vec![MeshGroup {
                first_index: 0,
                index_count: 6,
                texture: None,
            }],
            textures: vec![],
        }
    }

    fn total_area(m: &Mesh) -> f64 {
        m.indices
            .chunks_exact(3)
            .map(|t| {
                area(
                    m.positions[t[0] as usize],
                    m.positions[t[1] as usize],
                    m.positions[t[2] as usize],
                )
            })
            .sum()
    }

    #[test]
    fn refine_keeps_surface_and_interpolates() {
        let fine = refine(&wall(), 0.25);
        fine.validate().expect("valid mesh");
        assert!(fine.triangle_count() >= 2 * 20 * 20);
        assert!((total_area(&fine) - 12.0).abs() < 1e-3);
        for (p, g) in fine.positions.iter().zip(&fine.gray) {
            assert!((g - p[0] / 4.0 * 255.0).abs() < 1e-3, "gray follows x");
        }
        let unchanged = refine(&wall(), 10.0);
        assert_eq!(unchanged.triangle_count(), 2);
    }

    #[test]
    fn holes_remove_about_the_requested_fraction() {
        let spec = HoleSpec {
            fraction: 0.1,
            radius_m: (0.2, 0.5),
            max_edge_m: 0.1,
        };
        let (holed, removed) = punch_holes(&wall(), &spec, 3);
        holed.validate().expect("valid mesh");
        assert!((0.1..0.2).contains(&removed), "removed {removed}");
        let left = total_area(&holed) / 12.0;
        assert!((left - (1.0 - removed)).abs() < 1e-3);
        let (again, _) = punch_holes(&wall(), &spec, 3);
        assert_eq!(again, holed, "seeded");
        let (none, zero) = punch_holes(
            &wall(),
            &HoleSpec {
                fraction: 0.0,
                ..spec
            },
            3,
        );
        assert_eq!((none, zero), (wall(), 0.0));
    }
}
