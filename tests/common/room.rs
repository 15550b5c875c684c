//! The room meshes of the renderer tests and benchmarks:
//! - [`room`]: an 8 x 3 x 6 m textured room with furniture (y down), its
//!   faces split into a given number of quads, and [`poses`] inside it, for
//!   the renderer benchmarks;
//! - [`textured_room`]: a 6 x 5 x 3 m room of single quads with four
//!   textures and two boxes (z up), for the GPU/CPU agreement test;
//! - [`twin_map`]: a mesh built twice, the copy shifted and shaded, for
//!   the look-alike tests ([`copy_map`]: the copy turned as well).
//!
//! The benchmarks include this file on its own
//! (`#[path = "../tests/common/room.rs"] mod room;`), so it depends on
//! nothing else in `tests/common`.

// Each includer uses only some of the fixtures.
#![allow(dead_code)]

use nalgebra::{Translation3, UnitQuaternion, Vector3};
use star::geometry::Pose;
use star::map::{GrayTexture, Mesh, MeshGroup};

/// Appends an axis-aligned box `[lo, hi]` as 6 quads of `n x n` cells.
fn add_box(mesh: &mut Mesh, lo: [f32; 3], hi: [f32; 3], n: usize, gray: f32, texture: Option<u32>) {
    let c = |i: usize| -> [f32; 3] {
        [
            if i & 1 != 0 { hi[0] } else { lo[0] },
            if i & 2 != 0 { hi[1] } else { lo[1] },
            if i & 4 != 0 { hi[2] } else { lo[2] },
        ]
    };
    let faces = [
        [0, 1, 3, 2],
        [4, 5, 7, 6],
        [0, 1, 5, 4],
        [2, 3, 7, 6],
        [0, 2, 6, 4],
        [1, 3, 7, 5],
    ];
    let first = mesh.indices.len() as u32;
    for (f, face) in faces.iter().enumerate() {
        let [a, b, _, d] = face.map(c);
        let base = mesh.positions.len() as u32;
        for j in 0..=n {
            for i in 0..=n {
                let (s, t) = (i as f32 / n as f32, j as f32 / n as f32);
                let p: [f32; 3] =
                    std::array::from_fn(|k| a[k] + s * (b[k] - a[k]) + t * (d[k] - a[k]));
                mesh.positions.push(p);
                mesh.gray
                    .push(gray * (0.8 + 0.04 * f as f32) * (0.9 + 0.1 * s));
                let span = [
                    (b[0] - a[0]).abs() + (b[1] - a[1]).abs() + (b[2] - a[2]).abs(),
                    (d[0] - a[0]).abs() + (d[1] - a[1]).abs() + (d[2] - a[2]).abs(),
                ];
                mesh.uvs.push([s * span[0] * 0.5, t * span[1] * 0.5]);
            }
        }
        let at = |i: usize, j: usize| base + (j * (n + 1) + i) as u32;
        for j in 0..n {
            for i in 0..n {
                mesh.indices
                    .extend([at(i, j), at(i + 1, j), at(i + 1, j + 1)]);
                mesh.indices
                    .extend([at(i, j), at(i + 1, j + 1), at(i, j + 1)]);
            }
        }
    }
    mesh.groups.push(MeshGroup {
        first_index: first,
        index_count: mesh.indices.len() as u32 - first,
        texture,
    });
}

/// An 8 x 3 x 6 m room (y down, floor at y = 1.5) with textured walls
/// (`wall_cells^2` quads a side) and eight pieces of furniture
/// (`box_cells^2` quads a side).
pub fn room(wall_cells: usize, box_cells: usize) -> Mesh {
    let size = 256u32;
    let texels = (0..size * size)
        .map(|i| {
            let (x, y) = ((i % size) as f32, (i / size) as f32);
            let brick = if ((x / 32.0) as u32 + (y / 16.0) as u32) % 2 == 0 {
                170.0
            } else {
                110.0
            };
            brick + 40.0 * (x * 0.31).sin() * (y * 0.17).cos()
        })
        .collect();
    let mut mesh = Mesh {
        textures: vec![GrayTexture {
            width: size,
            height: size,
            texels,
        }],
        ..Mesh::default()
    };
    add_box(
        &mut mesh,
        [-4.0, -1.5, -3.0],
        [4.0, 1.5, 3.0],
        wall_cells,
        255.0,
        Some(0),
    );
    for k in 0..8 {
        let x = -3.2 + 0.9 * k as f32;
        let z = if k % 2 == 0 { -2.4 } else { 2.0 };
        let h = 0.4 + 0.15 * k as f32;
        add_box(
            &mut mesh,
            [x, 1.5 - h, z],
            [x + 0.6, 1.5, z + 0.5],
            box_cells,
            60.0 + 20.0 * k as f32,
            None,
        );
    }
    mesh
}

/// Eight poses inside [`room`], looking around at walls, corners and
/// furniture.
pub fn poses() -> Vec<Pose> {
    (0..8)
        .map(|k| {
            let yaw = k as f64 * std::f64::consts::TAU / 8.0 + 0.3;
            let t = Translation3::new(1.2 * (k as f64).cos(), 0.2, 0.8 * (k as f64).sin());
            let r = UnitQuaternion::from_axis_angle(&Vector3::y_axis(), yaw)
                * UnitQuaternion::from_axis_angle(&Vector3::x_axis(), 0.15);
            Pose::from_parts(t, r)
        })
        .collect()
}

/// A deterministic texture: stripes, blobs and fine noise.
fn texture(seed: u32, size: u32) -> GrayTexture {
    let mut state = seed.wrapping_mul(2_654_435_761).wrapping_add(1);
    let texels = (0..size * size)
        .map(|i| {
            state ^= state << 13;
            state ^= state >> 17;
            state ^= state << 5;
            let (x, y) = ((i % size) as f32, (i / size) as f32);
            let stripes = if ((x / 16.0) as u32 + (y / 24.0) as u32) % 2 == 0 {
                170.0
            } else {
                70.0
            };
            let blob = 40.0 * ((x * 0.11 + seed as f32).sin() * (y * 0.07).cos());
            let noise = (state % 32) as f32;
            (stripes + blob + noise).clamp(0.0, 255.0)
        })
        .collect();
    GrayTexture {
        width: size,
        height: size,
        texels,
    }
}

/// A textured 6 x 5 x 3 m room (world z up) with two textured boxes.
pub fn textured_room() -> Mesh {
    let mut mesh = Mesh::default();
    let quad = |mesh: &mut Mesh, c: [[f32; 3]; 4], texture: u32, gray: f32| {
        let base = mesh.positions.len() as u32;
        let first_index = mesh.indices.len() as u32;
        let (w, h) = {
            let d = |a: [f32; 3], b: [f32; 3]| {
                ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
            };
            (d(c[0], c[1]), d(c[1], c[2]))
        };
        mesh.positions.extend(c);
        mesh.gray.extend([gray, gray * 0.9, gray, gray * 0.95]);
        // 1.5 m of surface per texture repeat.
        let (u, v) = (w / 1.5, h / 1.5);
        mesh.uvs.extend([[0.0, 0.0], [u, 0.0], [u, v], [0.0, v]]);
        mesh.indices
            .extend([base, base + 1, base + 2, base, base + 2, base + 3]);
        mesh.groups.push(MeshGroup {
            first_index,
            index_count: 6,
            texture: Some(texture),
        });
    };
    let (x, y, z) = (6.0, 5.0, 3.0);
    quad(
        &mut mesh,
        [[0.0, 0.0, 0.0], [x, 0.0, 0.0], [x, y, 0.0], [0.0, y, 0.0]],
        0,
        255.0,
    );
    quad(
        &mut mesh,
        [[0.0, 0.0, z], [x, 0.0, z], [x, y, z], [0.0, y, z]],
        1,
        230.0,
    );
    quad(
        &mut mesh,
        [[0.0, 0.0, 0.0], [x, 0.0, 0.0], [x, 0.0, z], [0.0, 0.0, z]],
        2,
        255.0,
    );
    quad(
        &mut mesh,
        [[x, 0.0, 0.0], [x, y, 0.0], [x, y, z], [x, 0.0, z]],
        3,
        200.0,
    );
    quad(
        &mut mesh,
        [[x, y, 0.0], [0.0, y, 0.0], [0.0, y, z], [x, y, z]],
        2,
        180.0,
    );
    quad(
        &mut mesh,
        [[0.0, y, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, z], [0.0, y, z]],
        3,
        255.0,
    );
    for (cx, cy, s, hgt) in [(4.0f32, 1.5f32, 0.4f32, 1.0f32), (2.0, 3.5, 0.3, 1.6)] {
        let p = |dx: f32, dy: f32, zz: f32| [cx + dx, cy + dy, zz];
        for (a, b) in [
            ((-s, -s), (s, -s)),
            ((s, -s), (s, s)),
            ((s, s), (-s, s)),
            ((-s, s), (-s, -s)),
        ] {
            quad(
                &mut mesh,
                [
                    p(a.0, a.1, 0.0),
                    p(b.0, b.1, 0.0),
                    p(b.0, b.1, hgt),
                    p(a.0, a.1, hgt),
                ],
                1,
                210.0,
            );
        }
        quad(
            &mut mesh,
            [p(-s, -s, hgt), p(s, -s, hgt), p(s, s, hgt), p(-s, s, hgt)],
            0,
            160.0,
        );
    }
    mesh.textures = (0..4).map(|i| texture(i + 1, 128)).collect();
    mesh
}

/// `mesh` and a copy of it `offset_x_m` along x: two rooms the same to the
/// last vertex, as the rooms of one design in a building. `shade` gives the
/// copy's vertex gray from the original's position and gray (a look-alike
/// copy: the same shell, something painted otherwise, or lit otherwise).
pub fn twin_map(
    mesh: &star::map::Mesh,
    offset_x_m: f32,
    shade: impl Fn([f32; 3], f32) -> f32,
) -> star::map::Mesh {
    copy_map(mesh, |p| [p[0] + offset_x_m, p[1], p[2]], shade)
}

/// `mesh` and a copy of it whose vertex at `p` stands at `place(p)` (a
/// rigid motion: a copy moved, or turned and moved), its gray given by
/// `shade` as in [`twin_map`].
pub fn copy_map(
    mesh: &star::map::Mesh,
    place: impl Fn([f32; 3]) -> [f32; 3],
    shade: impl Fn([f32; 3], f32) -> f32,
) -> star::map::Mesh {
    let mut twin = mesh.clone();
    let n_vertices = mesh.positions.len() as u32;
    let n_indices = mesh.indices.len() as u32;
    twin.positions
        .extend(mesh.positions.iter().map(|&p| place(p)));
    twin.gray.extend(
        mesh.positions
            .iter()
            .zip(&mesh.gray)
            .map(|(&p, &g)| shade(p, g)),
    );
    if !mesh.uvs.is_empty() {
        twin.uvs.extend_from_slice(&mesh.uvs);
    }
    twin.indices
        .extend(mesh.indices.iter().map(|i| i + n_vertices));
    twin.groups
        .extend(mesh.groups.iter().map(|g| star::map::MeshGroup {
            first_index: g.first_index + n_indices,
            ..*g
        }));
    twin
}
