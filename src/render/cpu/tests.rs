//! Tests of the CPU renderer: request and mesh errors, determinism across
//! thread counts, and depth on analytic planes. Scene tests (cube, occlusion,
//! clipping, textures) are in `tests_scenes.rs`.

use std::sync::Arc;

use nalgebra::{Point3, Translation3, UnitQuaternion, Vector3};

use super::*;
use crate::map::{GrayTexture, MeshGroup};
use crate::render::NO_DEPTH;

/// A small camera for the tests (pixel centers at integers).
pub(super) fn camera() -> PinholeCamera {
    PinholeCamera::new(160, 128, 105.0, 100.0, 79.5, 63.5)
}

/// Appends a quad `a b c d` (in order around it) as a `n x n` grid of
/// quads, two triangles each, with gray `gray` and uv over `[0,1]^2`
/// (u along a->b, v along a->d).
pub(super) fn add_quad(mesh: &mut Mesh, corners: [Vector3<f64>; 4], gray: f32, n: usize) {
    let [a, b, _c, d] = corners;
    let base = mesh.positions.len() as u32;
    for j in 0..=n {
        for i in 0..=n {
            let (s, t) = (i as f64 / n as f64, j as f64 / n as f64);
            // Bilinear patch through the four corners.
            let p = a * ((1.0 - s) * (1.0 - t))
                + b * (s * (1.0 - t))
                + corners[2] * (s * t)
                + d * ((1.0 - s) * t);
            mesh.positions.push([p.x as f32, p.y as f32, p.z as f32]);
            mesh.gray.push(gray);
            mesh.uvs.push([s as f32, t as f32]);
        }
    }
    let first = mesh.indices.len() as u32;
    let at = |i: usize, j: usize| base + (j * (n + 1) + i) as u32;
    for j in 0..n {
        for i in 0..n {
            mesh.indices
                .extend([at(i, j), at(i + 1, j), at(i + 1, j + 1)]);
            mesh.indices
                .extend([at(i, j), at(i + 1, j + 1), at(i, j + 1)]);
        }
    }
    mesh.groups.push(MeshGroup {
        first_index: first,
        index_count: mesh.indices.len() as u32 - first,
        texture: None,
    });
}

/// A pose from a camera position and a rotation (axis-angle).
pub(super) fn pose(t: [f64; 3], axis_angle: [f64; 3]) -> Pose {
    Pose::from_parts(
        Translation3::new(t[0], t[1], t[2]),
        UnitQuaternion::from_scaled_axis(Vector3::from(axis_angle)),
    )
}

/// Renders `mesh` at `world_from_camera`.
pub(super) fn render(mesh: &Mesh, world_from_camera: &Pose, cam: &PinholeCamera) -> RenderedView {
    let mut r = CpuRenderer::new(Arc::new(mesh.clone())).expect("valid mesh");
    let mut out = RenderedView::for_camera(cam);
    r.render(world_from_camera, cam, &mut out).expect("render");
    out
}

/// The ray through pixel `(u, v)` in the camera frame, with z = 1.
pub(super) fn ray(cam: &PinholeCamera, u: usize, v: usize) -> Vector3<f64> {
    Vector3::new(
        (u as f64 - cam.cx) / cam.fx,
        (v as f64 - cam.cy) / cam.fy,
        1.0,
    )
}

/// A plane through `p0` with normal `n`, in the world frame, as a large
/// subdivided quad (side `2 * half`).
fn plane_mesh(p0: Vector3<f64>, n: Vector3<f64>, half: f64, gray: f32, subdiv: usize) -> Mesh {
    let n = n.normalize();
    let e1 = n.cross(&Vector3::new(0.3, 1.0, 0.1)).normalize();
    let e2 = n.cross(&e1);
    let mut mesh = Mesh::default();
    let c = |s: f64, t: f64| p0 + e1 * (s * half) + e2 * (t * half);
    add_quad(
        &mut mesh,
        [c(-1., -1.), c(1., -1.), c(1., 1.), c(-1., 1.)],
        gray,
        subdiv,
    );
    mesh
}

#[test]
fn fronto_parallel_plane_has_exact_depth() {
    let cam = camera();
    for (d, world_from_camera) in [
        (2.0, Pose::identity()),
        (3.25, pose([1.0, -2.0, 0.5], [0.4, -1.1, 0.7])),
        (0.75, pose([-3.0, 0.2, 8.0], [2.0, 0.3, -0.2])),
    ] {
        // The plane z = d of the camera frame, in the world frame.
        let p0 = world_from_camera * Point3::new(0.0, 0.0, d);
        let n = world_from_camera.rotation * Vector3::z();
        let mesh = plane_mesh(p0.coords, n, 3.0 * d, 140.0, 7);
        let out = render(&mesh, &world_from_camera, &cam);
        for (&z, &g) in out.depth_m.data().iter().zip(out.gray.data()) {
            // Exact up to the f32 rounding of the world-to-camera transform.
            assert!((z - d as f32).abs() <= 1e-5 * d as f32, "depth {z} != {d}");
            assert!((g - 140.0).abs() < 1e-3, "gray {g}");
        }
    }
    // Camera frame = world frame: exactly d.
    let mesh = plane_mesh(Vector3::new(0.0, 0.0, 2.5), Vector3::z(), 50.0, 99.0, 3);
    let out = render(&mesh, &Pose::identity(), &cam);
    assert!(out.depth_m.data().iter().all(|&z| z == 2.5));
}

#[test]
fn tilted_plane_has_analytic_depth() {
    let cam = camera();
    let world_from_camera = pose([0.5, 1.0, -1.0], [0.2, 0.3, -0.1]);
    // Plane in the camera frame: through (0.2, -0.1, 3) with a tilted normal.
    let p0_c = Vector3::new(0.2, -0.1, 3.0);
    let n_c = Vector3::new(0.5, -0.4, 1.0).normalize();
    let mesh = plane_mesh(
        (world_from_camera * Point3::from(p0_c)).coords,
        world_from_camera.rotation * n_c,
        30.0,
        77.0,
        9,
    );
    let out = render(&mesh, &world_from_camera, &cam);
    let mut hits = 0;
    for v in 0..cam.height as usize {
        for u in 0..cam.width as usize {
            let r = ray(&cam, u, v);
            let z_true = n_c.dot(&p0_c) / n_c.dot(&r);
            let z = out.depth_m.get(u, v).expect("in image") as f64;
            assert!(
                ((z - z_true) / z_true).abs() < 1e-4,
                "pixel ({u}, {v}): depth {z}, analytic {z_true}"
            );
            hits += 1;
        }
    }
    assert_eq!(hits, 160 * 128);
}

#[test]
fn output_is_identical_for_any_thread_count() {
    // Many overlapping random triangles, some crossing the near plane.
    let mut mesh = Mesh::default();
    let mut state = 7u64;
    let mut rnd = || {
        state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    for _ in 0..20_000 {
        let c = Vector3::new(rnd() * 8.0 - 4.0, rnd() * 6.0 - 3.0, rnd() * 8.0 - 0.5);
        for _ in 0..3 {
            let p = c + Vector3::new(rnd() - 0.5, rnd() - 0.5, rnd() - 0.5) * 1.5;
            mesh.positions.push([p.x as f32, p.y as f32, p.z as f32]);
            mesh.gray.push((rnd() * 255.0) as f32);
            mesh.uvs.push([0.0, 0.0]);
            mesh.indices.push(mesh.positions.len() as u32 - 1);
        }
    }
    mesh.groups.push(MeshGroup {
        first_index: 0,
        index_count: mesh.indices.len() as u32,
        texture: None,
    });
    let mesh = Arc::new(mesh);
    let cam = camera();
    let world_from_camera = pose([0.1, 0.0, -0.2], [0.05, -0.1, 0.02]);
    let outputs: Vec<RenderedView> = [1, 2, 3, 5]
        .iter()
        .map(|&n| {
            let mut r = CpuRenderer::with_threads(mesh.clone(), n).expect("renderer");
            assert_eq!(r.threads(), n);
            let mut out = RenderedView::for_camera(&cam);
            r.render(&world_from_camera, &cam, &mut out)
                .expect("render");
            // A second render into the same buffers gives the same image.
            let first = out.clone();
            r.render(&world_from_camera, &cam, &mut out)
                .expect("render");
            assert_eq!(first.gray.data(), out.gray.data());
            out
        })
        .collect();
    let hits = outputs[0]
        .depth_m
        .data()
        .iter()
        .filter(|&&z| z > 0.0)
        .count();
    assert!(
        hits > 1000,
        "the scene should cover the image, got {hits} hits"
    );
    for o in &outputs[1..] {
        assert_eq!(o.gray.data(), outputs[0].gray.data());
        assert_eq!(o.depth_m.data(), outputs[0].depth_m.data());
    }
}

#[test]
fn empty_pixels_have_no_depth_and_zero_gray() {
    let cam = camera();
    // A small quad in the middle of the view.
    let mut mesh = Mesh::default();
    let q = |x: f64, y: f64| Vector3::new(x, y, 2.0);
    add_quad(
        &mut mesh,
        [q(-0.2, -0.2), q(0.2, -0.2), q(0.2, 0.2), q(-0.2, 0.2)],
        200.0,
        1,
    );
    let out = render(&mesh, &Pose::identity(), &cam);
    assert_eq!(out.depth_m.get(0, 0), Some(NO_DEPTH));
    assert_eq!(out.gray.get(0, 0), Some(0.0));
    assert_eq!(out.depth_m.get(80, 64), Some(2.0));
    assert_eq!(out.gray.get(80, 64).map(|g| g.round()), Some(200.0));
    // An empty mesh renders nothing.
    let out = render(&Mesh::default(), &Pose::identity(), &cam);
    assert!(out.depth_m.data().iter().all(|&z| z == NO_DEPTH));
}

#[test]
fn bad_requests_are_errors() {
    let cam = camera();
    let mut mesh = Mesh::default();
    let q = |x: f64, y: f64| Vector3::new(x, y, 2.0);
    add_quad(
        &mut mesh,
        [q(-1.0, -1.0), q(1.0, -1.0), q(1.0, 1.0), q(-1.0, 1.0)],
        50.0,
        1,
    );
    let mut r = CpuRenderer::new(Arc::new(mesh)).expect("valid");
    let mut out = RenderedView::for_camera(&cam);
    let mut nan_pose = Pose::identity();
    nan_pose.translation.vector.x = f64::NAN;
    assert!(matches!(
        r.render(&nan_pose, &cam, &mut out),
        Err(RenderError::NotFinite("pose"))
    ));
    let mut small = RenderedView::new(10, 10);
    assert!(matches!(
        r.render(&Pose::identity(), &cam, &mut small),
        Err(RenderError::TargetSize { found_w: 10, .. })
    ));
    let mut bad_cam = cam;
    bad_cam.fx = f64::INFINITY;
    assert!(matches!(
        r.render(&Pose::identity(), &bad_cam, &mut out),
        Err(RenderError::NotFinite("intrinsics"))
    ));
    assert_eq!(r.name(), "cpu");
}

fn triangle_mesh() -> Mesh {
    Mesh {
        positions: vec![[0.0, 0.0, 1.0], [1.0, 0.0, 1.0], [0.0, 1.0, 1.0]],
        gray: vec![10.0; 3],
        uvs: vec![[0.0, 0.0]; 3],
        indices: vec![0, 1, 2],
        groups: vec![MeshGroup {
            first_index: 0,
            index_count: 3,
            texture: None,
        }],
        textures: vec![],
    }
}

fn mesh_error(mesh: Mesh) -> (&'static str, usize) {
    match CpuRenderer::new(Arc::new(mesh)) {
        Err(RenderError::InvalidMesh { field, index, .. }) => (field, index),
        other => panic!("expected InvalidMesh, got {other:?}"),
    }
}

#[test]
fn bad_meshes_are_errors() {
    assert!(CpuRenderer::new(Arc::new(triangle_mesh())).is_ok());
    let mut m = triangle_mesh();
    m.indices[2] = 3;
    assert_eq!(mesh_error(m), ("indices", 2));
    let mut m = triangle_mesh();
    m.indices.push(0);
    assert_eq!(mesh_error(m).0, "indices");
    let mut m = triangle_mesh();
    m.positions[1][2] = f32::NAN;
    assert_eq!(mesh_error(m), ("positions", 1));
    let mut m = triangle_mesh();
    m.gray.pop();
    assert_eq!(mesh_error(m).0, "gray");
    let mut m = triangle_mesh();
    m.groups[0].texture = Some(0);
    assert_eq!(mesh_error(m), ("groups", 0));
    let mut m = triangle_mesh();
    m.groups[0].index_count = 6;
    assert_eq!(mesh_error(m), ("groups", 0));
    let mut m = triangle_mesh();
    m.groups.push(m.groups[0]);
    assert_eq!(mesh_error(m), ("groups", 1));
    let mut m = triangle_mesh();
    m.textures.push(GrayTexture {
        width: 2,
        height: 2,
        texels: vec![0.0; 3],
    });
    assert_eq!(mesh_error(m), ("textures", 0));
    // No uvs is fine without textures; no groups means untextured.
    let mut m = triangle_mesh();
    m.uvs.clear();
    m.groups.clear();
    assert!(CpuRenderer::new(Arc::new(m)).is_ok());
}
