//! Steady-state CPU rendering does not allocate: a counting global
//! allocator watches every thread (the renderer's pool included) while the
//! renderer draws a sequence of poses it has already drawn once.
//!
//! The one allocation that remains is rayon's: handing a render to the pool
//! (`ThreadPool::install`) pushes one job onto the pool's injector queue,
//! a linked list of 63-slot blocks, so one ~1.5 KB block is allocated every
//! 63 renders. With 48 renders per check at most one block boundary is
//! crossed.

#![allow(clippy::expect_used, clippy::unwrap_used)]

mod common;

use std::sync::Arc;

use common::counting_alloc::{
    start_counting_all_threads, stop_counting_all_threads, CountingAlloc,
};
use nalgebra::{Translation3, UnitQuaternion, Vector3};
use star::geometry::{PinholeCamera, Pose};
use star::map::{GrayTexture, Mesh, MeshGroup};
use star::render::cpu::CpuRenderer;
use star::render::{RenderedView, Renderer};

#[global_allocator]
static GLOBAL: CountingAlloc = CountingAlloc;

/// A textured 10 x 10 m floor at y = 1.5 and a wall at z = 4, as grids of
/// 40 x 40 quads (6400 triangles): enough for several setup chunks.
fn scene() -> Mesh {
    let mut mesh = Mesh {
        textures: vec![GrayTexture {
            width: 8,
            height: 8,
            texels: (0..64).map(|i| (i * 4) as f32).collect(),
        }],
        ..Mesh::default()
    };
    let n = 40usize;
    let mut add = |corner: Vector3<f32>, du: Vector3<f32>, dv: Vector3<f32>| {
        let base = mesh.positions.len() as u32;
        for j in 0..=n {
            for i in 0..=n {
                let (s, t) = (i as f32 / n as f32, j as f32 / n as f32);
                let p = corner + du * s + dv * t;
                mesh.positions.push([p.x, p.y, p.z]);
                mesh.gray.push(200.0);
                mesh.uvs.push([s * 5.0, t * 5.0]);
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
    };
    add(
        Vector3::new(-5.0, 1.5, -5.0),
        Vector3::new(10.0, 0.0, 0.0),
        Vector3::new(0.0, 0.0, 10.0),
    );
    add(
        Vector3::new(-5.0, -1.5, 4.0),
        Vector3::new(10.0, 0.0, 0.0),
        Vector3::new(0.0, 3.0, 0.0),
    );
    mesh.groups.push(MeshGroup {
        first_index: 0,
        index_count: mesh.indices.len() as u32,
        texture: Some(0),
    });
    mesh
}

#[test]
fn steady_state_render_does_not_allocate() {
    let camera = PinholeCamera::new(320, 256, 210.0, 210.0, 159.5, 127.5);
    let poses: Vec<Pose> = (0..16)
        .map(|k| {
            let yaw = 0.1 * k as f64 - 0.8;
            Pose::from_parts(
                Translation3::new(0.2 * k as f64 - 1.5, 0.5, -1.0),
                UnitQuaternion::from_axis_angle(&Vector3::y_axis(), yaw),
            )
        })
        .collect();
    for threads in [1, 2] {
        let mut renderer =
            CpuRenderer::with_threads(Arc::new(scene()), threads).expect("valid mesh");
        let mut out = RenderedView::for_camera(&camera);
        // Warm-up: scratch grows to its working size.
        for p in &poses {
            renderer.render(p, &camera, &mut out).expect("render");
        }
        start_counting_all_threads();
        for _ in 0..3 {
            for p in &poses {
                renderer.render(p, &camera, &mut out).expect("render");
            }
        }
        let allocations = stop_counting_all_threads();
        let hits = out.depth_m.data().iter().filter(|&&d| d > 0.0).count();
        assert!(hits > 10_000, "the scene should fill the view, {hits} hits");
        assert!(
            allocations <= 1,
            "{threads} threads: {allocations} allocations in 48 steady-state renders \
             (expected at most one rayon injector block)"
        );
    }
}
