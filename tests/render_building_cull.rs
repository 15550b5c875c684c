//! Culling never drops a visible triangle, at the scale of a building:
//! renders of the `building` preset's floor (22 rooms, a corridor, about
//! 5.9 M map triangles, built in memory from a fixed seed) from 50 poses
//! spread through its rooms, doorways and corridor are the same, bit for
//! bit, with the chunk cull (view frustum cut at the far limit) and
//! without it (every chunk drawn, the far limit applied per pixel only):
//! on the CPU rasterizer from all 50, on the wgpu renderer (lavapipe where
//! it is installed) from 12 of them. Every tenth pose (every fourth of
//! wgpu's) is compared again with back faces culled in both renders
//! (`[render] cull_back_faces`): the chunk cull still changes nothing.

#![allow(clippy::expect_used, clippy::unwrap_used)]

use std::sync::Arc;

use nalgebra::Translation3;
use star::geometry::look::camera_rotation;
use star::geometry::{PinholeCamera, Pose};
use star::render::cpu::CpuRenderer;
use star::render::gpu::{self, AdapterPreference, GpuRenderer};
use star::render::select::DEFAULT_FAR_M;
use star::render::{RenderedView, Renderer};
use star::synth::preset::Preset;
use star::synth::sequence::preset_scene;
use star::synth::SplitMix64;

/// 50 poses through the building: at every room's corridor point, door,
/// inside point and loop, in turn, looking every way (up to 20 degrees up
/// or down), some along the corridor where it is longest.
fn poses(scene: &star::synth::Scene) -> Vec<Pose> {
    let plan = scene.plan.as_ref().expect("a building");
    let routes = plan.routes();
    let mut rng = SplitMix64::new(22);
    let mut out = Vec::new();
    let mut i = 0;
    while out.len() < 50 {
        let r = &routes[i % routes.len()];
        let points = [
            r.corridor_m,
            r.door_m,
            r.inside_m,
            r.loop_m[0],
            r.loop_m[1],
            r.loop_m[2],
        ];
        let p = points[(i / routes.len() + i) % points.len()];
        let along_corridor = i % 7 == 0;
        let p = if along_corridor { r.corridor_m } else { p };
        // Along the corridor: toward its farther end.
        let middle_x = 0.5 * (plan.corridor_min_m[0] + plan.corridor_max_m[0]);
        let yaw = if along_corridor {
            if p[0] < middle_x {
                0.0
            } else {
                std::f64::consts::PI
            }
        } else {
            rng.range(-std::f64::consts::PI, std::f64::consts::PI)
        };
        let pitch = rng.range(-20f64, 20.0).to_radians();
        let z = rng.range(0.8, 2.0);
        out.push(Pose::from_parts(
            Translation3::new(p[0], p[1], z),
            camera_rotation(yaw, pitch, 0.0),
        ));
        i += 1;
    }
    out
}

fn gpu_renderer(mesh: &Arc<star::map::Mesh>) -> Option<GpuRenderer> {
    match GpuRenderer::new(Arc::clone(mesh), AdapterPreference::Software) {
        Ok(r) => Some(r),
        Err(e) if gpu::lavapipe_installed() => {
            panic!("lavapipe is installed but no wgpu adapter works: {e}")
        }
        Err(e) => {
            eprintln!("SKIPPED (wgpu part): no wgpu adapter and no lavapipe: {e}");
            None
        }
    }
}

#[test]
fn culling_never_drops_a_visible_triangle_of_the_building() {
    let preset = Preset::by_name("building").unwrap();
    let scene = preset_scene(&preset, 1);
    assert!(scene.map.triangle_count() >= 5_000_000);
    let poses = poses(&scene);
    let mesh = Arc::new(scene.map.clone());
    let camera: PinholeCamera = preset.camera.pinhole();

    let mut culled = CpuRenderer::new(Arc::clone(&mesh)).unwrap();
    let mut full = CpuRenderer::new(Arc::clone(&mesh)).unwrap();
    full.set_frustum_cull(false);
    let far = Some(DEFAULT_FAR_M);
    let (mut a, mut b) = (
        RenderedView::for_camera(&camera),
        RenderedView::for_camera(&camera),
    );
    let mut drawn = 0.0;
    let mut beyond_far = 0;
    for (k, pose) in poses.iter().enumerate() {
        // Every pose with the configured default far limit, every fifth
        // also without one.
        let limits: &[Option<f64>] = if k % 5 == 0 { &[far, None] } else { &[far] };
        for &limit in limits {
            culled.set_far_m(limit);
            full.set_far_m(limit);
            let what = format!("pose {k} ({pose:?}), far {limit:?}");
            assert_same(
                (&mut culled, &mut full),
                pose,
                &camera,
                (&mut a, &mut b),
                &what,
            );
            let stats = culled.cull_stats();
            assert_eq!(full.cull_stats().visible_chunks, stats.chunks);
            drawn += stats.visible_fraction();
        }
        if k % 10 == 0 {
            let what = format!("pose {k}");
            assert_same_back_faces_culled(
                (&mut culled, &mut full),
                pose,
                &camera,
                (&mut a, &mut b),
                &what,
            );
        }
        let hits = a.depth_m.data().iter().filter(|&&d| d > 0.0).count();
        assert!(
            hits > a.depth_m.data().len() / 2,
            "pose {k} sees mostly nothing"
        );
        beyond_far += usize::from(b.depth_m.data().iter().any(|&d| d > DEFAULT_FAR_M as f32));
    }
    // The cull did cut: a few percent of the building per view.
    assert!(drawn / 60.0 < 0.25, "mean share drawn {}", drawn / 60.0);
    // Some poses look down the corridor past the far limit (without it).
    assert!(beyond_far > 0, "no pose sees beyond the far limit");

    // wgpu: the same comparison from 12 poses, at the preset's size.
    let Some(mut culled) = gpu_renderer(&mesh) else {
        return;
    };
    let mut full = gpu_renderer(&mesh).unwrap();
    full.set_frustum_cull(false);
    for (k, pose) in poses.iter().enumerate().step_by(4).take(12) {
        for limit in [far, None] {
            culled.set_far_m(limit);
            full.set_far_m(limit);
            let what = format!("wgpu, pose {k}, far {limit:?}");
            assert_same(
                (&mut culled, &mut full),
                pose,
                &camera,
                (&mut a, &mut b),
                &what,
            );
        }
        if k % 16 == 0 {
            let what = format!("wgpu, pose {k}");
            assert_same_back_faces_culled(
                (&mut culled, &mut full),
                pose,
                &camera,
                (&mut a, &mut b),
                &what,
            );
        }
    }
}

/// Renders `pose` with the culled and the unculled renderer; the images
/// must be the same, bit for bit (`what` names the case).
fn assert_same(
    (culled, full): (&mut dyn Renderer, &mut dyn Renderer),
    pose: &Pose,
    camera: &PinholeCamera,
    (a, b): (&mut RenderedView, &mut RenderedView),
    what: &str,
) {
    culled.render(pose, camera, a).unwrap();
    full.render(pose, camera, b).unwrap();
    assert!(
        a.gray.data() == b.gray.data() && a.depth_m.data() == b.depth_m.data(),
        "{what}: the cull changed the image"
    );
}

/// [`assert_same`] with back faces culled in both renders.
fn assert_same_back_faces_culled(
    (culled, full): (&mut dyn Renderer, &mut dyn Renderer),
    pose: &Pose,
    camera: &PinholeCamera,
    views: (&mut RenderedView, &mut RenderedView),
    what: &str,
) {
    culled.set_cull_back_faces(true);
    full.set_cull_back_faces(true);
    let what = format!("{what}, back faces culled");
    assert_same((&mut *culled, &mut *full), pose, camera, views, &what);
    culled.set_cull_back_faces(false);
    full.set_cull_back_faces(false);
}
