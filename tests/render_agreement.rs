//! Agreement of the wgpu renderer (on lavapipe here) with the CPU
//! rasterizer, the reference, on textured indoor scenes at 640x512:
//! - depth within 0.1 % relative on >= 99 % of the pixels both cover;
//! - gray within 2 levels on >= 98 % of the pixels, edges excepted;
//! - silhouettes within 1 px: every pixel covered by one renderer only has
//!   a pixel covered by the other within 1 px.
//!
//! Finding no wgpu adapter where lavapipe is installed is a failure.

#![allow(clippy::expect_used, clippy::unwrap_used)]

mod common;

use std::sync::Arc;

use nalgebra::{Matrix3, Rotation3, Translation3, UnitQuaternion, Vector3};
use star::config::CameraConfig;
use star::geometry::{PinholeCamera, Pose};
use star::map::Mesh;
use star::render::cpu::CpuRenderer;
use star::render::gpu::{self, AdapterPreference, GpuRenderer};
use star::render::{RenderedView, Renderer};

use common::room::textured_room;

/// Agreement figures of one or more views.
#[derive(Debug, Default, Clone, Copy)]
struct Agreement {
    /// Pixels both renderers cover.
    both: usize,
    /// Of those, pixels with depth within 0.1 %.
    depth_ok: usize,
    /// Pixels away from edges (both or neither covered, no discontinuity).
    interior: usize,
    /// Of those, pixels with gray within 2 levels.
    gray_ok: usize,
    /// Pixels covered by exactly one renderer.
    coverage_differs: usize,
    /// Of those, pixels with no pixel of the other renderer within 1 px.
    silhouette_far: usize,
    /// Largest relative depth difference on common pixels.
    max_depth_rel: f32,
    /// Largest gray difference on non-edge pixels.
    max_gray: f32,
}

impl Agreement {
    fn add(&mut self, o: Agreement) {
        self.both += o.both;
        self.depth_ok += o.depth_ok;
        self.interior += o.interior;
        self.gray_ok += o.gray_ok;
        self.coverage_differs += o.coverage_differs;
        self.silhouette_far += o.silhouette_far;
        self.max_depth_rel = self.max_depth_rel.max(o.max_depth_rel);
        self.max_gray = self.max_gray.max(o.max_gray);
    }
    fn depth_frac(&self) -> f64 {
        self.depth_ok as f64 / self.both.max(1) as f64
    }
    fn gray_frac(&self) -> f64 {
        self.gray_ok as f64 / self.interior.max(1) as f64
    }
}

fn hit(view: &RenderedView, x: i64, y: i64) -> Option<f32> {
    if x < 0 || y < 0 {
        return None;
    }
    view.depth_m
        .get(x as usize, y as usize)
        .filter(|&d| RenderedView::is_hit(d))
}

/// True when pixel (x, y) of `view` is next to a silhouette or a depth
/// discontinuity (> 2 % between 8-neighbours).
fn is_edge(view: &RenderedView, x: i64, y: i64) -> bool {
    let center = hit(view, x, y);
    for dy in -1..=1 {
        for dx in -1..=1 {
            let (nx, ny) = (x + dx, y + dy);
            if nx < 0
                || ny < 0
                || nx >= view.depth_m.width() as i64
                || ny >= view.depth_m.height() as i64
            {
                continue;
            }
            match (center, hit(view, nx, ny)) {
                (Some(a), Some(b)) if (a - b).abs() > 0.02 * a.min(b) => return true,
                (Some(_), None) | (None, Some(_)) => return true,
                _ => {}
            }
        }
    }
    false
}

fn compare(gpu: &RenderedView, cpu: &RenderedView) -> Agreement {
    let (w, h) = (gpu.depth_m.width() as i64, gpu.depth_m.height() as i64);
    let mut a = Agreement::default();
    for y in 0..h {
        for x in 0..w {
            let (g, c) = (hit(gpu, x, y), hit(cpu, x, y));
            match (g, c) {
                (Some(dg), Some(dc)) => {
                    a.both += 1;
                    a.max_depth_rel = a.max_depth_rel.max((dg - dc).abs() / dc);
                    if (dg - dc).abs() <= 1e-3 * dc {
                        a.depth_ok += 1;
                    }
                }
                (Some(_), None) | (None, Some(_)) => {
                    a.coverage_differs += 1;
                    let other = if g.is_some() { cpu } else { gpu };
                    let near =
                        (-1..=1).any(|dy| (-1..=1).any(|dx| hit(other, x + dx, y + dy).is_some()));
                    if !near {
                        a.silhouette_far += 1;
                    }
                }
                (None, None) => {}
            }
            if g.is_some() == c.is_some() && !is_edge(gpu, x, y) && !is_edge(cpu, x, y) {
                a.interior += 1;
                let (gg, gc) = (
                    gpu.gray.get(x as usize, y as usize),
                    cpu.gray.get(x as usize, y as usize),
                );
                if let (Some(gg), Some(gc)) = (gg, gc) {
                    a.max_gray = a.max_gray.max((gg - gc).abs());
                    if (gg - gc).abs() <= 2.0 {
                        a.gray_ok += 1;
                    }
                }
            }
        }
    }
    a
}

/// Both renderers of `mesh`; panics if lavapipe is installed but unusable.
fn renderers(mesh: Arc<Mesh>, unorm8: bool) -> Option<(GpuRenderer, CpuRenderer)> {
    let cpu = CpuRenderer::new(Arc::clone(&mesh)).expect("cpu renderer");
    let gpu = if unorm8 {
        GpuRenderer::new_with_unorm8_textures(mesh, AdapterPreference::Software)
    } else {
        GpuRenderer::new(Arc::clone(&mesh), AdapterPreference::Software)
            .or_else(|_| GpuRenderer::new(mesh, AdapterPreference::Hardware))
    };
    match gpu {
        Ok(g) => Some((g, cpu)),
        Err(e) if gpu::lavapipe_installed() => panic!("lavapipe installed but unusable: {e}"),
        Err(e) => {
            eprintln!("SKIPPED: no wgpu adapter and no lavapipe: {e}");
            None
        }
    }
}

/// `world_from_camera` at `position` looking along `yaw`/`pitch` (radians),
/// world z up.
fn look(position: [f64; 3], yaw: f64, pitch: f64) -> Pose {
    let forward = Vector3::new(
        yaw.cos() * pitch.cos(),
        yaw.sin() * pitch.cos(),
        pitch.sin(),
    );
    let right = forward.cross(&Vector3::z()).normalize();
    let down = forward.cross(&right);
    let rotation = Rotation3::from_matrix_unchecked(Matrix3::from_columns(&[right, down, forward]));
    Pose::from_parts(
        Translation3::new(position[0], position[1], position[2]),
        UnitQuaternion::from_rotation_matrix(&rotation),
    )
}

fn assert_agreement(label: &str, total: Agreement) {
    eprintln!(
        "{label}: depth within 0.1 % on {:.6} of {} common pixels (max rel. {:.2e}); gray within 2 \
         on {:.6} of {} non-edge pixels (max {:.3}); coverage differs on {} pixels, {} farther \
         than 1 px",
        total.depth_frac(),
        total.both,
        total.max_depth_rel,
        total.gray_frac(),
        total.interior,
        total.max_gray,
        total.coverage_differs,
        total.silhouette_far
    );
    assert!(total.both > 0, "{label}: nothing rendered");
    assert!(
        total.depth_frac() >= 0.99,
        "{label}: depth agreement {total:?}"
    );
    assert!(
        total.gray_frac() >= 0.98,
        "{label}: gray agreement {total:?}"
    );
    assert_eq!(total.silhouette_far, 0, "{label}: silhouettes {total:?}");
}

fn run_views(label: &str, mesh: Arc<Mesh>, poses: &[Pose], unorm8: bool) {
    let Some((mut gpu, mut cpu)) = renderers(mesh, unorm8) else {
        return;
    };
    let camera: PinholeCamera = CameraConfig::default().intrinsics;
    let mut out_gpu = RenderedView::for_camera(&camera);
    let mut out_cpu = RenderedView::for_camera(&camera);
    let mut total = Agreement::default();
    for pose in poses {
        gpu.render(pose, &camera, &mut out_gpu).expect("gpu render");
        cpu.render(pose, &camera, &mut out_cpu).expect("cpu render");
        total.add(compare(&out_gpu, &out_cpu));
    }
    assert_agreement(
        &format!("{label} [{:?} textures]", gpu.texture_format()),
        total,
    );
}

fn room_poses() -> Vec<Pose> {
    vec![
        look([1.0, 1.0, 1.5], 0.3, -0.1),
        look([5.0, 4.0, 1.2], -2.6, -0.2),
        look([3.0, 2.5, 2.0], 1.2, -0.6),
        look([1.5, 4.0, 0.8], -0.8, 0.15),
        look([3.0, 0.8, 1.4], 1.9, 0.0),
        look([4.8, 2.5, 1.0], 3.1, -0.35),
    ]
}

#[test]
fn textured_room_agrees_with_cpu_rasterizer() {
    run_views(
        "textured room",
        Arc::new(textured_room()),
        &room_poses(),
        false,
    );
}

#[test]
fn textured_room_agrees_with_unorm8_textures() {
    run_views(
        "textured room",
        Arc::new(textured_room()),
        &room_poses(),
        true,
    );
}

/// Up to ten free-space poses of `scene`, looking around the room.
fn scene_poses(scene: &star::synth::Scene) -> Vec<Pose> {
    let (lo, hi) = (scene.free_min_m, scene.free_max_m);
    (0..40)
        .map(|i| {
            let f = |k: usize, a: f64| lo[k] + (hi[k] - lo[k]) * ((i as f64 * a).fract());
            [f(0, 0.37), f(1, 0.61), f(2, 0.23)]
        })
        .enumerate()
        .filter(|(_, p)| scene.is_free(*p, 0.3))
        .take(10)
        .map(|(i, p)| look(p, i as f64 * 0.9, -0.3 + 0.12 * (i % 5) as f64))
        .collect()
}

#[test]
fn default_scene_agrees_with_cpu_rasterizer() {
    let scene = star::synth::default_scene();
    let poses = scene_poses(&scene);
    assert!(poses.len() >= 5, "only {} free poses", poses.len());
    // The map has holes (unmapped space renders as no depth); the truth has
    // occluders: both must agree.
    run_views(
        "default scene map",
        Arc::new(scene.map.clone()),
        &poses,
        false,
    );
    run_views(
        "default scene truth",
        Arc::new(scene.truth.clone()),
        &poses,
        false,
    );
}

#[test]
fn subdivided_default_scene_agrees_with_cpu_rasterizer() {
    let scene = star::synth::default_scene();
    let poses = scene_poses(&scene);
    let mesh = star::map::subdivide(&scene.map, 200_000);
    let label = format!("default scene map, {} triangles", mesh.triangle_count());
    run_views(&label, Arc::new(mesh), &poses[..3], false);
}

/// An untextured wall of `nx x nz` quads, 40 m long and 2.4 m high, from
/// 3 to 43 m along +x and slanting from y = -8 to -4 m, gray varying along
/// it (as a scan's vertex color).
fn receding_wall(nx: usize, nz: usize) -> Mesh {
    let mut mesh = Mesh::default();
    for j in 0..=nz {
        for i in 0..=nx {
            let (u, v) = (i as f32 / nx as f32, j as f32 / nz as f32);
            mesh.positions
                .push([3.0 + 40.0 * u, -8.0 + 4.0 * u, 2.4 * v]);
            mesh.gray
                .push(120.0 + 60.0 * (u * 37.0).sin() * (v * 11.0).cos());
        }
    }
    let at = |i: usize, j: usize| (j * (nx + 1) + i) as u32;
    for j in 0..nz {
        for i in 0..nx {
            mesh.indices
                .extend([at(i, j), at(i + 1, j), at(i + 1, j + 1)]);
            mesh.indices
                .extend([at(i, j), at(i + 1, j + 1), at(i, j + 1)]);
        }
    }
    mesh
}

/// Renders `mesh` with levels of detail at 2 px on both renderers from
/// three poses along the receding wall; asserts that the CPU rasterizer
/// drew fewer than `1 / reduction` of the mesh's triangles at each and
/// that the two renders agree (`what` names the case). Skips without a
/// wgpu adapter.
fn levels_agree(mesh: Mesh, reduction: usize, what: &str) {
    let mesh = Arc::new(mesh);
    let lod_px = 2.0;
    let mut cpu = CpuRenderer::with_lod(Arc::clone(&mesh), lod_px).expect("cpu renderer");
    let mut gpu = match GpuRenderer::new_configured(
        Arc::clone(&mesh),
        AdapterPreference::Software,
        0,
        lod_px,
    ) {
        Ok(g) => g,
        Err(e) if gpu::lavapipe_installed() => panic!("lavapipe installed but unusable: {e}"),
        Err(e) => {
            eprintln!("SKIPPED: no wgpu adapter and no lavapipe: {e}");
            return;
        }
    };
    assert!(cpu.coarse_chunks() > 0, "no coarse copies built");
    let camera: PinholeCamera = CameraConfig::default().intrinsics;
    let mut out_gpu = RenderedView::for_camera(&camera);
    let mut out_cpu = RenderedView::for_camera(&camera);
    let mut total = Agreement::default();
    for (x, yaw) in [(0.0, 0.1), (-2.0, 0.25), (1.0, 0.0)] {
        let pose = look([x, -6.0, 1.2], yaw, 0.0);
        gpu.render(&pose, &camera, &mut out_gpu)
            .expect("gpu render");
        cpu.render(&pose, &camera, &mut out_cpu)
            .expect("cpu render");
        let stats = cpu.cull_stats();
        assert!(
            reduction * stats.visible_triangles < mesh.triangle_count(),
            "{what}: the coarse copies drew {} of {} triangles",
            stats.visible_triangles,
            mesh.triangle_count()
        );
        total.add(compare(&out_gpu, &out_cpu));
    }
    assert_agreement(what, total);
}

#[test]
fn levels_of_detail_agree_with_cpu_rasterizer() {
    // 288 k triangles (3.3 by 2 cm): beyond a few meters the camera sees
    // them at the coarse levels.
    levels_agree(
        receding_wall(1200, 120),
        2,
        "receding wall, levels of detail",
    );
}

#[test]
fn textured_levels_of_detail_agree_with_cpu_rasterizer() {
    // The receding wall with shading that varies slowly and a texture
    // mapped affinely along it: flat, so its coarse copies are exact and
    // drawn at every distance (`render::lod`), by both renderers alike.
    let mut mesh = receding_wall(1200, 120);
    for (p, g) in mesh.positions.iter().zip(mesh.gray.iter_mut()) {
        *g = 150.0 + 0.5 * p[0];
    }
    mesh.uvs = mesh
        .positions
        .iter()
        .map(|p| [(p[0] - 3.0) / 2.0, p[2] / 2.0])
        .collect();
    mesh.textures = vec![star::map::GrayTexture {
        width: 64,
        height: 64,
        texels: (0..64 * 64)
            .map(|k: usize| 60.0 + (k * 7919 % 173) as f32)
            .collect(),
    }];
    mesh.groups = vec![star::map::MeshGroup {
        first_index: 0,
        index_count: mesh.indices.len() as u32,
        texture: Some(0),
    }];
    levels_agree(mesh, 3, "textured receding wall, levels of detail");
}

/// The receding wall and, above it, its copy wound the other way: with back
/// faces culled exactly one of the two is drawn, by both renderers alike;
/// with both sides drawn, both.
#[test]
fn back_faces_are_culled_alike_by_both_renderers() {
    let lower = receding_wall(80, 8);
    let mut mesh = lower.clone();
    let base = mesh.positions.len() as u32;
    mesh.positions
        .extend(lower.positions.iter().map(|p| [p[0], p[1], p[2] + 2.4]));
    mesh.gray.extend_from_slice(&lower.gray);
    mesh.indices.extend(
        lower
            .indices
            .chunks_exact(3)
            .flat_map(|t| [t[0] + base, t[2] + base, t[1] + base]),
    );
    let mesh = Arc::new(mesh);
    let Some((mut gpu, mut cpu)) = renderers(Arc::clone(&mesh), false) else {
        return;
    };
    let camera: PinholeCamera = CameraConfig::default().intrinsics;
    let mut out_gpu = RenderedView::for_camera(&camera);
    let mut out_cpu = RenderedView::for_camera(&camera);
    let covered = |v: &RenderedView, upper: bool| {
        v.depth_m
            .data()
            .iter()
            .enumerate()
            .filter(|(i, d)| {
                RenderedView::is_hit(**d) && ((*i / camera.width as usize) < 256) == upper
            })
            .count()
    };
    let pose = look([0.0, -6.0, 2.4], 0.1, 0.0);
    cpu.render(&pose, &camera, &mut out_cpu)
        .expect("cpu render");
    let (upper_both, lower_both) = (covered(&out_cpu, true), covered(&out_cpu, false));
    assert!(
        upper_both > 20_000 && lower_both > 20_000,
        "{upper_both} {lower_both}"
    );
    cpu.set_cull_back_faces(true);
    gpu.set_cull_back_faces(true);
    cpu.render(&pose, &camera, &mut out_cpu)
        .expect("cpu render");
    gpu.render(&pose, &camera, &mut out_gpu)
        .expect("gpu render");
    let (upper, lower) = (covered(&out_cpu, true), covered(&out_cpu, false));
    // One wall is gone whole, the other is as it was.
    assert!(
        (upper == 0 && lower == lower_both) || (lower == 0 && upper == upper_both),
        "culled: upper {upper} of {upper_both}, lower {lower} of {lower_both}"
    );
    assert_agreement("back faces culled", compare(&out_gpu, &out_cpu));
}
