//! The wgpu renderer on analytic meshes: exact depth of planes, pixel-center
//! conventions, occlusion, near clipping, textures, readback padding and the
//! pipelined submit/collect path.
//!
//! These run for real on Mesa's lavapipe where it is installed; finding no
//! adapter there is a failure, never a skip.

#![allow(clippy::expect_used, clippy::unwrap_used)]

use std::sync::Arc;

use nalgebra::{Translation3, UnitQuaternion};
use star::geometry::{PinholeCamera, Pose};
use star::map::{GrayTexture, Mesh, MeshGroup};
use star::render::gpu::{self, AdapterPreference, GpuRenderer};
use star::render::{RenderedView, Renderer, NO_DEPTH};

/// A GPU renderer for `mesh`: the software adapter (lavapipe), else a
/// hardware one. `None` only when no adapter exists and lavapipe is not
/// installed; with lavapipe installed, failing to get one panics.
fn gpu_renderer(mesh: Mesh) -> Option<GpuRenderer> {
    let mesh = Arc::new(mesh);
    let software = GpuRenderer::new(Arc::clone(&mesh), AdapterPreference::Software);
    usable(software.or_else(|e| {
        GpuRenderer::new(mesh, AdapterPreference::Hardware).map_err(|h| format!("{e}; {h}"))
    }))
}

/// The renderer, or `None` (skip, said out loud) only where lavapipe is
/// not installed.
fn usable(result: Result<GpuRenderer, String>) -> Option<GpuRenderer> {
    match result {
        Ok(r) => Some(r),
        Err(e) if gpu::lavapipe_installed() => {
            panic!("lavapipe is installed but no wgpu adapter works: {e}")
        }
        Err(e) => {
            eprintln!("SKIPPED: no wgpu adapter and no lavapipe on this machine: {e}");
            None
        }
    }
}

/// Appends a quad (two triangles) with uniform vertex gray and the given uvs.
fn push_quad(mesh: &mut Mesh, corners: [[f32; 3]; 4], gray: f32, uvs: [[f32; 2]; 4]) {
    let base = mesh.positions.len() as u32;
    mesh.positions.extend(corners);
    mesh.gray.extend([gray; 4]);
    mesh.uvs.extend(uvs);
    mesh.indices
        .extend([base, base + 1, base + 2, base, base + 2, base + 3]);
}

/// A fronto-parallel rectangle `x0..x1, y0..y1` at depth `z` (camera = world).
fn rect(mesh: &mut Mesh, x: (f32, f32), y: (f32, f32), z: f32, gray: f32) {
    let corners = [[x.0, y.0, z], [x.1, y.0, z], [x.1, y.1, z], [x.0, y.1, z]];
    push_quad(mesh, corners, gray, [[0.0, 0.0]; 4]);
}

/// Closes a mesh built with `push_quad` into one untextured group.
fn one_group(mut mesh: Mesh) -> Mesh {
    mesh.groups = vec![MeshGroup {
        first_index: 0,
        index_count: mesh.indices.len() as u32,
        texture: None,
    }];
    mesh
}

fn render(r: &mut GpuRenderer, pose: &Pose, camera: &PinholeCamera) -> RenderedView {
    let mut out = RenderedView::for_camera(camera);
    r.render(pose, camera, &mut out).expect("render");
    out
}

#[test]
fn software_adapter_is_listed_when_lavapipe_is_installed() {
    let adapters = gpu::list_adapters();
    for a in &adapters {
        eprintln!("adapter: {a} class {:?} rank {}", a.class, a.rank);
    }
    if gpu::lavapipe_installed() {
        assert!(
            adapters
                .iter()
                .any(|a| a.class == gpu::AdapterClass::Software),
            "lavapipe installed but not listed: {adapters:?}"
        );
    }
    // Auto takes a hardware adapter, never a software one.
    let hardware = adapters
        .iter()
        .any(|a| a.class == gpu::AdapterClass::Hardware);
    assert_eq!(gpu::auto_choice(&adapters).is_some(), hardware);
}

#[test]
fn tilted_plane_depth_is_exact_everywhere() {
    // The plane z = 2 + 0.5 x, far wider than the view.
    let mut mesh = Mesh::default();
    let z = |x: f32| 2.0 + 0.5 * x;
    let corners = [
        [-3.0, -9.0, z(-3.0)],
        [3.0, -9.0, z(3.0)],
        [3.0, 9.0, z(3.0)],
        [-3.0, 9.0, z(-3.0)],
    ];
    push_quad(&mut mesh, corners, 100.0, [[0.0, 0.0]; 4]);
    let Some(mut r) = gpu_renderer(one_group(mesh)) else {
        return;
    };
    let camera = PinholeCamera::new(96, 64, 80.0, 80.0, 47.5, 31.5);
    let out = render(&mut r, &Pose::identity(), &camera);
    let mut worst = 0.0f64;
    for v in 0..64 {
        for u in 0..96 {
            let xn = (f64::from(u) - camera.cx) / camera.fx;
            let expected = 2.0 / (1.0 - 0.5 * xn);
            let d = f64::from(out.depth_m.get(u as usize, v as usize).expect("in image"));
            worst = worst.max((d - expected).abs() / expected);
            let g = out.gray.get(u as usize, v as usize).expect("in image");
            assert!((g - 100.0).abs() < 1e-3, "gray {g} at ({u},{v})");
        }
    }
    assert!(worst < 1e-5, "worst relative depth error {worst}");
}

#[test]
fn silhouette_follows_integer_pixel_centers() {
    // At z = 1 with fx = fy = 100, cx = cy = 31.5: u = 100 x + 31.5.
    // Edges at u = 9.7 and 20.3 (v = 5.7 and 12.2) cover pixel centers
    // 10..=20 (6..=12) and nothing else. A half-pixel error would change this.
    let camera = PinholeCamera::new(64, 48, 100.0, 100.0, 31.5, 31.5);
    let x = ((9.7 - 31.5) / 100.0, (20.3 - 31.5) / 100.0);
    let y = ((5.7 - 31.5) / 100.0, (12.2 - 31.5) / 100.0);
    let mut mesh = Mesh::default();
    rect(&mut mesh, x, y, 1.0, 200.0);
    let Some(mut r) = gpu_renderer(one_group(mesh)) else {
        return;
    };
    let out = render(&mut r, &Pose::identity(), &camera);
    for v in 0..48 {
        for u in 0..64 {
            let inside = (10..=20).contains(&u) && (6..=12).contains(&v);
            let d = out.depth_m.get(u, v).expect("in image");
            assert_eq!(RenderedView::is_hit(d), inside, "pixel ({u},{v}) depth {d}");
            if inside {
                assert!((d - 1.0).abs() < 1e-6);
            } else {
                assert_eq!(out.gray.get(u, v), Some(0.0));
                assert_eq!(d, NO_DEPTH);
            }
        }
    }
}

#[test]
fn nearer_surface_wins_in_either_draw_order() {
    let camera = PinholeCamera::new(40, 30, 30.0, 30.0, 19.5, 14.5);
    for near_first in [true, false] {
        let mut mesh = Mesh::default();
        let far = |m: &mut Mesh| rect(m, (-9.0, 9.0), (-9.0, 9.0), 5.0, 50.0);
        let near = |m: &mut Mesh| rect(m, (-0.2, 0.2), (-0.2, 0.2), 1.0, 150.0);
        if near_first {
            near(&mut mesh);
            far(&mut mesh);
        } else {
            far(&mut mesh);
            near(&mut mesh);
        }
        let Some(mut r) = gpu_renderer(one_group(mesh)) else {
            return;
        };
        let out = render(&mut r, &Pose::identity(), &camera);
        let center = (out.depth_m.get(20, 15), out.gray.get(20, 15));
        assert_eq!(center, (Some(1.0), Some(150.0)), "near_first {near_first}");
        let corner = (out.depth_m.get(1, 1), out.gray.get(1, 1));
        assert_eq!(corner, (Some(5.0), Some(50.0)), "near_first {near_first}");
    }
}

#[test]
fn pose_moves_the_view_and_misses_give_no_depth() {
    let mut mesh = Mesh::default();
    rect(&mut mesh, (-1.0, 1.0), (-1.0, 1.0), 0.0, 80.0); // the plane z = 0 of the world
    let Some(mut r) = gpu_renderer(one_group(mesh)) else {
        return;
    };
    let camera = PinholeCamera::new(32, 32, 20.0, 20.0, 15.5, 15.5);
    // Camera 3 m behind the plane, looking along +z: depth 3 at the center.
    let behind = Pose::from_parts(
        Translation3::new(0.0, 0.0, -3.0),
        UnitQuaternion::identity(),
    );
    let out = render(&mut r, &behind, &camera);
    let d = out.depth_m.get(15, 15).expect("center");
    assert!((d - 3.0).abs() < 1e-5, "depth {d}");
    // Turned around (yaw 180 deg), it sees nothing.
    let away = Pose::from_parts(
        Translation3::new(0.0, 0.0, -3.0),
        UnitQuaternion::from_euler_angles(0.0, std::f64::consts::PI, 0.0),
    );
    let out = render(&mut r, &away, &camera);
    assert!(out.depth_m.data().iter().all(|&d| d == NO_DEPTH));
    assert!(out.gray.data().iter().all(|&g| g == 0.0));
}

#[test]
fn surfaces_closer_than_the_near_plane_are_clipped() {
    let mut mesh = Mesh::default();
    rect(&mut mesh, (-1.0, 1.0), (-1.0, 1.0), 0.03, 90.0);
    let Some(mut r) = gpu_renderer(one_group(mesh)) else {
        return;
    };
    let camera = PinholeCamera::new(16, 16, 10.0, 10.0, 7.5, 7.5);
    let out = render(&mut r, &Pose::identity(), &camera);
    assert!(out.depth_m.data().iter().all(|&d| d == NO_DEPTH));
}

fn check_texture(unorm8: bool) {
    // A 4x2 texture on a plane at z = 1; u runs 0..2 across the quad so the
    // texture repeats twice; vertex gray 127.5 halves it.
    let texels = vec![0.0, 100.0, 200.0, 40.0, 255.0, 10.0, 60.0, 120.0];
    let texture = GrayTexture {
        width: 4,
        height: 2,
        texels: texels.clone(),
    };
    let mut mesh = Mesh::default();
    let c = [
        [-1.0, -1.0, 1.0],
        [1.0, -1.0, 1.0],
        [1.0, 1.0, 1.0],
        [-1.0, 1.0, 1.0],
    ];
    let uv = [[0.0, 0.0], [2.0, 0.0], [2.0, 1.0], [0.0, 1.0]];
    push_quad(&mut mesh, c, 127.5, uv);
    mesh.groups = vec![MeshGroup {
        first_index: 0,
        index_count: 6,
        texture: Some(0),
    }];
    mesh.textures = vec![texture];
    let r = if unorm8 {
        usable(
            GpuRenderer::new_with_unorm8_textures(Arc::new(mesh), AdapterPreference::Software)
                .map_err(|e| e.to_string()),
        )
    } else {
        gpu_renderer(mesh)
    };
    let Some(mut r) = r else {
        return;
    };
    let format = r.texture_format();
    assert!(!unorm8 || format == gpu::TextureFormat::Unorm8);
    // x in [-1, 1] maps to u in [0, 64): camera fx = 32, cx = 31.5 puts
    // x = -1 at u = -0.5 (the left image edge) and x = 1 at 63.5.
    let camera = PinholeCamera::new(64, 32, 32.0, 32.0, 31.5, 15.5);
    let out = render(&mut r, &Pose::identity(), &camera);
    let texel = |x: i64, y: i64| texels[(y.rem_euclid(2) * 4 + x.rem_euclid(4)) as usize];
    let mut worst = 0.0f32;
    for v in 0..32usize {
        for u in 0..64usize {
            // Surface point of this pixel center, then uv, then bilinear.
            let x = (u as f32 - 31.5) / 32.0;
            let y = (v as f32 - 15.5) / 32.0;
            let (tu, tv) = ((x + 1.0), (y + 1.0) / 2.0);
            let (px, py) = (tu * 4.0 - 0.5, tv * 2.0 - 0.5);
            let (x0, y0) = (px.floor(), py.floor());
            let (fx, fy) = (px - x0, py - y0);
            let (x0, y0) = (x0 as i64, y0 as i64);
            let top = texel(x0, y0) * (1.0 - fx) + texel(x0 + 1, y0) * fx;
            let bottom = texel(x0, y0 + 1) * (1.0 - fx) + texel(x0 + 1, y0 + 1) * fx;
            let expected = (top * (1.0 - fy) + bottom * fy) * 127.5 / 255.0;
            let g = out.gray.get(u, v).expect("in image");
            worst = worst.max((g - expected).abs());
        }
    }
    // Float32 is exact up to the sampler's subtexel precision; Unorm8 also
    // rounds the filter weights to 8 bits (integer texels here).
    let bound = if format == gpu::TextureFormat::Float32 {
        0.05
    } else {
        1.0
    };
    eprintln!("{format:?}: worst gray error {worst}");
    assert!(worst < bound, "{format:?}: worst gray error {worst}");
}

#[test]
fn texture_is_bilinear_with_repeat_and_modulated_by_vertex_gray() {
    check_texture(false);
}

#[test]
fn unorm8_textures_agree_within_a_gray_level() {
    check_texture(true);
}

#[test]
fn odd_sizes_read_back_without_row_padding() {
    // Width 37: 148 bytes per row, padded to 256 in staging.
    let mut mesh = Mesh::default();
    rect(&mut mesh, (0.0, 9.0), (-9.0, 9.0), 2.0, 30.0); // right half
    let Some(mut r) = gpu_renderer(one_group(mesh)) else {
        return;
    };
    let camera = PinholeCamera::new(37, 23, 20.0, 20.0, 18.0, 11.0);
    let out = render(&mut r, &Pose::identity(), &camera);
    for v in 0..23 {
        for u in 0..37 {
            let hit = RenderedView::is_hit(out.depth_m.get(u, v).expect("in"));
            // x = 0 is at u = 18 exactly: the top-left rule may take it or not.
            if u != 18 {
                assert_eq!(hit, u > 18, "pixel ({u},{v})");
            }
        }
    }
}

#[test]
fn pipelined_renders_match_single_renders() {
    let mut mesh = Mesh::default();
    rect(&mut mesh, (-2.0, 2.0), (-2.0, 2.0), 0.0, 120.0);
    rect(&mut mesh, (-0.5, 0.5), (-0.5, 0.5), -0.5, 220.0);
    let Some(mut r) = gpu_renderer(one_group(mesh)) else {
        return;
    };
    let camera = PinholeCamera::new(48, 40, 40.0, 40.0, 23.5, 19.5);
    let pose =
        |x: f64| Pose::from_parts(Translation3::new(x, 0.1, -3.0), UnitQuaternion::identity());
    let single: Vec<RenderedView> = [0.0, 0.3, -0.4]
        .iter()
        .map(|&x| render(&mut r, &pose(x), &camera))
        .collect();
    // Two in flight at once; a third must wait for a free staging buffer.
    let a = r.submit(&pose(0.0), &camera).expect("submit a");
    let b = r.submit(&pose(0.3), &camera).expect("submit b");
    assert!(matches!(
        r.submit(&pose(-0.4), &camera),
        Err(gpu::GpuError::Busy)
    ));
    let mut out_a = RenderedView::for_camera(&camera);
    let mut out_b = RenderedView::for_camera(&camera);
    r.collect(a, &mut out_a).expect("collect a");
    let c = r.submit(&pose(-0.4), &camera).expect("submit c");
    r.collect(b, &mut out_b).expect("collect b");
    let mut out_c = RenderedView::for_camera(&camera);
    r.collect(c, &mut out_c).expect("collect c");
    for (piped, one) in [out_a, out_b, out_c].iter().zip(&single) {
        assert_eq!(piped.depth_m, one.depth_m);
        assert_eq!(piped.gray, one.gray);
    }
    assert_ne!(single[0].depth_m, single[1].depth_m, "poses differ");
}

#[test]
fn injected_failure_fails_the_render_not_the_process() {
    let mut mesh = Mesh::default();
    rect(&mut mesh, (-1.0, 1.0), (-1.0, 1.0), 2.0, 10.0);
    let Some(mut r) = gpu_renderer(one_group(mesh)) else {
        return;
    };
    let camera = PinholeCamera::new(16, 16, 10.0, 10.0, 7.5, 7.5);
    r.inject_failure_after(1);
    let mut out = RenderedView::for_camera(&camera);
    assert!(r.render(&Pose::identity(), &camera, &mut out).is_ok());
    let err = r
        .render(&Pose::identity(), &camera, &mut out)
        .expect_err("injected");
    assert!(err.to_string().contains("injected"), "{err}");
}
