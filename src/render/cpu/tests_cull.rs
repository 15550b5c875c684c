//! Tests of the chunk cull in the CPU renderer: it never changes a pixel
//! (renders with and without it are bit-identical from many random poses),
//! it skips the chunks behind the camera, and depth ties are won in mesh
//! order whatever order the chunks are drawn in.

#![allow(clippy::expect_used, clippy::unwrap_used)]

use std::sync::Arc;

use nalgebra::Vector3;

use super::tests::{add_quad, camera, pose};
use super::*;
use crate::render::chunks::MAX_CHUNK_TRIS;

/// An 8 x 6 x 3 m room (z up, corner at the origin) of finely split walls,
/// floor and ceiling, with a few boxes on the floor and a thin slab exactly
/// coplanar with part of one wall (depth ties).
fn room() -> Mesh {
    let mut mesh = Mesh::default();
    let v = |x: f64, y: f64, z: f64| Vector3::new(x, y, z);
    let (w, d, h) = (8.0, 6.0, 3.0);
    // Floor, ceiling, four walls.
    add_quad(
        &mut mesh,
        [v(0., 0., 0.), v(w, 0., 0.), v(w, d, 0.), v(0., d, 0.)],
        90.0,
        96,
    );
    add_quad(
        &mut mesh,
        [v(0., 0., h), v(0., d, h), v(w, d, h), v(w, 0., h)],
        200.0,
        64,
    );
    add_quad(
        &mut mesh,
        [v(0., 0., 0.), v(0., 0., h), v(w, 0., h), v(w, 0., 0.)],
        140.0,
        80,
    );
    add_quad(
        &mut mesh,
        [v(w, 0., 0.), v(w, 0., h), v(w, d, h), v(w, d, 0.)],
        160.0,
        80,
    );
    add_quad(
        &mut mesh,
        [v(w, d, 0.), v(w, d, h), v(0., d, h), v(0., d, 0.)],
        120.0,
        80,
    );
    add_quad(
        &mut mesh,
        [v(0., d, 0.), v(0., d, h), v(0., 0., h), v(0., 0., 0.)],
        180.0,
        80,
    );
    // The part of the first wall under x < 4 again, gray 60: ties with the
    // wall on every pixel it covers (the wall comes first in mesh order).
    add_quad(
        &mut mesh,
        [v(0., 0., 0.), v(0., 0., h), v(4., 0., h), v(4., 0., 0.)],
        60.0,
        20,
    );
    for (x, y, s) in [(2.0, 2.0, 0.6), (5.5, 4.0, 1.0), (6.5, 1.2, 0.4)] {
        let (x1, y1) = (x + s, y + s);
        add_quad(
            &mut mesh,
            [v(x, y, s), v(x1, y, s), v(x1, y1, s), v(x, y1, s)],
            30.0,
            6,
        );
        add_quad(
            &mut mesh,
            [v(x, y, 0.), v(x, y, s), v(x1, y, s), v(x1, y, 0.)],
            230.0,
            6,
        );
        add_quad(
            &mut mesh,
            [v(x1, y, 0.), v(x1, y, s), v(x1, y1, s), v(x1, y1, 0.)],
            70.0,
            6,
        );
    }
    mesh
}

/// A camera pose at `position` looking along world +x turned by `yaw` about
/// z and raised by `pitch` (z up world; camera x right, y down).
fn looking(position: [f64; 3], yaw: f64, pitch: f64) -> Pose {
    // Camera z forward along +x of the world at yaw 0, pitch 0.
    let base = nalgebra::UnitQuaternion::from_matrix(&nalgebra::Matrix3::new(
        0.0, 0.0, 1.0, //
        -1.0, 0.0, 0.0, //
        0.0, -1.0, 0.0,
    ));
    let turn = nalgebra::UnitQuaternion::from_euler_angles(0.0, 0.0, yaw)
        * nalgebra::UnitQuaternion::from_euler_angles(0.0, -pitch, 0.0);
    Pose::from_parts(
        nalgebra::Translation3::new(position[0], position[1], position[2]),
        turn * base,
    )
}

#[test]
fn cull_never_changes_the_image() {
    let mesh = Arc::new(room());
    let cam = camera();
    let mut culled = CpuRenderer::with_threads(Arc::clone(&mesh), 2).unwrap();
    let mut full = CpuRenderer::with_threads(Arc::clone(&mesh), 2).unwrap();
    full.set_frustum_cull(false);
    let (mut a, mut b) = (
        RenderedView::for_camera(&cam),
        RenderedView::for_camera(&cam),
    );
    let mut state = 11u64;
    let mut rnd = || {
        state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    let (mut skipped, mut hits) = (0usize, 0usize);
    for k in 0..120 {
        // Mostly inside the room, some outside it and some on a wall.
        let p = [rnd() * 10.0 - 1.0, rnd() * 8.0 - 1.0, rnd() * 4.0 - 0.5];
        let world_from_camera = if k % 3 == 0 {
            pose(p, [rnd() * 6.0 - 3.0, rnd() * 6.0 - 3.0, rnd() * 6.0 - 3.0])
        } else {
            looking(p, rnd() * 6.3, rnd() - 0.5)
        };
        culled.render(&world_from_camera, &cam, &mut a).unwrap();
        full.render(&world_from_camera, &cam, &mut b).unwrap();
        assert!(a.gray.data() == b.gray.data(), "gray differs at pose {k}");
        assert!(
            a.depth_m.data() == b.depth_m.data(),
            "depth differs at pose {k}"
        );
        let stats = culled.cull_stats();
        assert_eq!(full.cull_stats().visible_chunks, stats.chunks);
        skipped += stats.chunks - stats.visible_chunks;
        hits += a.depth_m.data().iter().filter(|&&z| z > 0.0).count();
    }
    // The comparison means something: views saw the room, and chunks were
    // skipped.
    assert!(hits > 120 * 160 * 128 / 4, "{hits} pixels hit");
    assert!(skipped > 120, "{skipped} chunks skipped in 120 renders");
}

#[test]
fn chunks_behind_the_camera_are_skipped() {
    let mesh = Arc::new(room());
    let cam = camera();
    let mut r = CpuRenderer::with_threads(Arc::clone(&mesh), 1).unwrap();
    let mut out = RenderedView::for_camera(&cam);
    // In the middle of the room, looking along +x at the x = 8 wall.
    r.render(&looking([4.0, 3.0, 1.5], 0.0, 0.0), &cam, &mut out)
        .unwrap();
    let stats = r.cull_stats();
    assert_eq!(stats.triangles, mesh.triangle_count());
    assert!(stats.chunks >= mesh.triangle_count() / MAX_CHUNK_TRIS);
    let behind = r
        .chunked
        .chunks
        .iter()
        .filter(|c| c.bounds.max_m[0] < 3.9)
        .count();
    assert!(behind > 0);
    // No chunk wholly behind the camera (x < 4) is drawn.
    for (chunk, &drawn) in r.chunked.chunks.iter().zip(&r.visible) {
        if chunk.bounds.max_m[0] < 3.9 {
            assert!(!drawn, "chunk {:?} behind the camera drawn", chunk.bounds);
        }
    }
    assert!(stats.visible_chunks + behind <= stats.chunks, "{stats:?}");
    assert!(stats.visible_fraction() < 0.6, "{stats:?}");
    // And the view is complete: every pixel sees the room.
    assert!(out.depth_m.data().iter().all(|&z| z > 0.0));
}

#[test]
fn depth_ties_are_won_in_mesh_order() {
    // Two identical quads (tied on every pixel), gray 50 first in the mesh,
    // gray 250 second, with groups listing the second first: the chunks of
    // the second are drawn first, and must still lose the ties.
    let mut mesh = Mesh::default();
    let corners = [
        Vector3::new(-3.0, -3.0, 2.0),
        Vector3::new(3.0, -3.0, 2.0),
        Vector3::new(3.0, 3.0, 2.0),
        Vector3::new(-3.0, 3.0, 2.0),
    ];
    add_quad(&mut mesh, corners, 50.0, 50);
    add_quad(&mut mesh, corners, 250.0, 50);
    assert!(mesh.triangle_count() > 2 * MAX_CHUNK_TRIS);
    mesh.groups.reverse();
    let mesh = Arc::new(mesh);
    let r = CpuRenderer::new(Arc::clone(&mesh)).unwrap();
    assert_eq!(
        r.chunked.source_triangle.first().copied(),
        Some(mesh.triangle_count() as u32 / 2),
        "the second quad's chunks come first"
    );
    let cam = camera();
    let out = super::tests::render(&mesh, &Pose::identity(), &cam);
    assert!(out.depth_m.data().iter().all(|&z| z == 2.0));
    assert!(
        out.gray.data().iter().all(|&g| (g - 50.0).abs() < 1e-3),
        "a pixel shows the second quad"
    );
}

/// Two rooms of [`room`]'s kind side by side along x (the second shifted
/// by 8.2 m), joined by a doorway cut into the wall between them: the
/// building's case of a room seen through a door, with the far room's
/// walls, floor and boxes hidden behind the wall around the door.
fn two_rooms() -> Mesh {
    let mut mesh = room();
    let second = room();
    let base = mesh.positions.len() as u32;
    let first_index = mesh.indices.len() as u32;
    mesh.positions
        .extend(second.positions.iter().map(|p| [p[0] + 8.2, p[1], p[2]]));
    mesh.gray.extend(second.gray.iter().map(|g| 255.0 - g));
    mesh.uvs.extend(&second.uvs);
    mesh.indices.extend(second.indices.iter().map(|i| i + base));
    for g in &second.groups {
        mesh.groups.push(crate::map::MeshGroup {
            first_index: g.first_index + first_index,
            ..*g
        });
    }
    // Cut the door (y 2.5..3.5 m, z below 2.2 m) out of both faces of the
    // wall between the rooms (x = 8 of the first, x = 8.2 of the second):
    // drop their triangles whose centroid lies in the opening.
    let p = mesh.positions.clone();
    let mut kept = Vec::new();
    let mut groups = Vec::new();
    for g in &mesh.groups {
        let start = kept.len() as u32;
        let range = g.first_index as usize..(g.first_index + g.index_count) as usize;
        for t in mesh.indices[range].chunks_exact(3) {
            let c =
                |k: usize| (p[t[0] as usize][k] + p[t[1] as usize][k] + p[t[2] as usize][k]) / 3.0;
            let in_wall = (c(0) - 8.0).abs() < 1e-3 || (c(0) - 8.2).abs() < 1e-3;
            if in_wall && (2.5..3.5).contains(&c(1)) && c(2) < 2.2 {
                continue;
            }
            kept.extend_from_slice(t);
        }
        groups.push(crate::map::MeshGroup {
            first_index: start,
            index_count: kept.len() as u32 - start,
            ..*g
        });
    }
    mesh.indices = kept;
    mesh.groups = groups;
    mesh
}

/// The first batch of a render is what the previous one saw when its
/// camera was near: along walks through two rooms joined by a door (small
/// steps and turns, with jumps back and about-turns in place), renders
/// with every cull are the same, bit for bit, as without any.
#[test]
fn cull_after_nearby_renders_never_changes_the_image() {
    let mesh = Arc::new(two_rooms());
    let cam = camera();
    let mut culled = CpuRenderer::with_threads(Arc::clone(&mesh), 2).unwrap();
    let mut full = CpuRenderer::with_threads(Arc::clone(&mesh), 2).unwrap();
    full.set_frustum_cull(false);
    let (mut a, mut b) = (
        RenderedView::for_camera(&cam),
        RenderedView::for_camera(&cam),
    );
    let mut state = 7u64;
    let mut rnd = || {
        state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    let (mut hidden, mut hits) = (0usize, 0usize);
    let (mut x, mut y, mut yaw) = (1.0, 3.0, 0.0);
    for k in 0..200 {
        if k % 40 == 0 {
            // Back to the first room's far corner.
            (x, y) = (1.0 + rnd(), 2.0 + 2.0 * rnd());
        }
        // Toward the door and through it, with some wandering.
        x += 0.1 + 0.15 * rnd();
        y += 0.2 * (rnd() - 0.5);
        yaw += 0.3 * (rnd() - 0.5);
        if k % 17 == 0 {
            // An about-turn in place.
            yaw += std::f64::consts::PI;
        }
        let (x1, y1) = (x.min(15.5), y.clamp(2.6, 3.4));
        let world_from_camera = looking([x1, y1, 1.0 + rnd()], yaw, 0.4 * (rnd() - 0.5));
        culled.render(&world_from_camera, &cam, &mut a).unwrap();
        full.render(&world_from_camera, &cam, &mut b).unwrap();
        assert!(a.gray.data() == b.gray.data(), "gray differs at pose {k}");
        assert!(
            a.depth_m.data() == b.depth_m.data(),
            "depth differs at pose {k}"
        );
        let stats = culled.cull_stats();
        hidden += stats.visible_triangles - culled.binned_triangles().min(stats.visible_triangles);
        hits += a.depth_m.data().iter().filter(|&&z| z > 0.0).count();
    }
    assert!(hits > 200 * 160 * 128 / 2, "{hits} pixels hit");
    assert!(hidden > 0, "nothing was culled");
}
