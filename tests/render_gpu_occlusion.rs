//! The wgpu renderer's occlusion cull never changes the image: a walk
//! through a 4-room floor of the `building` preset (built in memory from
//! seed 1), from the corridor through each door, round the room and back,
//! in steps of 0.3 m, with an about-turn in place every tenth pose (so
//! that the first pass, what the previous render kept, is sometimes
//! stale) is rendered by wgpu (lavapipe where installed) with the frustum
//! and occlusion culls and with no cull at all: gray and depth must be
//! identical bit for bit. It also checks that the cull ran in two passes
//! with the previous render's clusters first, and that it drew fewer
//! triangles than the frustum alone would have.

#![allow(clippy::expect_used, clippy::unwrap_used)]

use std::sync::Arc;

use nalgebra::Translation3;
use star::geometry::look::camera_rotation;
use star::geometry::{PinholeCamera, Pose};
use star::render::gpu::{self, AdapterPreference, GpuRenderer};
use star::render::select::DEFAULT_FAR_M;
use star::render::{RenderedView, Renderer};
use star::synth::preset::Preset;
use star::synth::sequence::preset_scene;

/// Step along the walk, meters.
const STEP_M: f64 = 0.3;
/// The walk is shifted this far off the plan's lines, meters: its points
/// lie in the planes of walls and door frames, and a camera in such a
/// plane sees the wall edge-on, as zero-area triangles that lavapipe may
/// still rasterize into a pixel at an extrapolated depth (0.755 m, on a
/// wall 8.4 m away), which no cull can reproduce (`render::gpu::occlusion`).
const OFF_PLANE_M: [f64; 2] = [0.0123, 0.0071];

/// The walk: per room, corridor point, door, inside point, the loop and
/// back, at eye height, looking where it goes, swaying 20 degrees either
/// side; every tenth pose turned about.
fn walk(scene: &star::synth::Scene) -> Vec<Pose> {
    let plan = scene.plan.as_ref().expect("a building");
    let mut out = Vec::new();
    for r in plan.routes() {
        let points = [
            r.corridor_m,
            r.door_m,
            r.inside_m,
            r.loop_m[0],
            r.loop_m[1],
            r.loop_m[2],
            r.inside_m,
            r.door_m,
            r.corridor_m,
        ];
        for pair in points.windows(2) {
            let (a, b) = (pair[0], pair[1]);
            let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
            let length = dx.hypot(dy);
            let heading = dy.atan2(dx);
            let steps = (length / STEP_M).ceil().max(1.0) as usize;
            for s in 0..steps {
                let t = s as f64 / steps as f64;
                let n = out.len();
                let sway = (n as f64 * 0.7).sin() * 20f64.to_radians();
                let about = if n % 10 == 9 {
                    std::f64::consts::PI
                } else {
                    0.0
                };
                // camera_rotation's yaw 0 looks along +x.
                out.push(Pose::from_parts(
                    Translation3::new(
                        a[0] + t * dx + OFF_PLANE_M[0],
                        a[1] + t * dy + OFF_PLANE_M[1],
                        1.4,
                    ),
                    camera_rotation(heading + sway + about, -5f64.to_radians(), 0.0),
                ));
            }
        }
    }
    out
}

/// The `building` preset with 4 rooms, seed 1.
fn four_rooms() -> (Preset, star::synth::Scene) {
    let mut preset = Preset::by_name("building").unwrap();
    if let Some(spec) = preset.scene.building.as_mut() {
        spec.rooms = 4;
    }
    let scene = preset_scene(&preset, 1);
    (preset, scene)
}

fn renderer(mesh: &Arc<star::map::Mesh>) -> Option<GpuRenderer> {
    match GpuRenderer::new(Arc::clone(mesh), AdapterPreference::Software) {
        Ok(r) => Some(r),
        Err(e) if gpu::lavapipe_installed() => {
            panic!("lavapipe is installed but no wgpu adapter works: {e}")
        }
        Err(e) => {
            eprintln!("SKIPPED: no wgpu adapter and no lavapipe: {e}");
            None
        }
    }
}

#[test]
fn occlusion_cull_never_changes_the_wgpu_image() {
    let (preset, scene) = four_rooms();
    let poses = walk(&scene);
    assert!(poses.len() > 60, "a walk of {} poses", poses.len());
    let mesh = Arc::new(scene.map.clone());
    let camera: PinholeCamera = preset.camera.pinhole();
    let Some(mut culled) = renderer(&mesh) else {
        return;
    };
    let mut full = renderer(&mesh).unwrap();
    full.set_frustum_cull(false);
    let far = Some(DEFAULT_FAR_M);
    culled.set_far_m(far);
    full.set_far_m(far);
    let (mut a, mut b) = (
        RenderedView::for_camera(&camera),
        RenderedView::for_camera(&camera),
    );
    let mut in_frustum = 0u64;
    for (k, pose) in poses.iter().enumerate() {
        culled.render(pose, &camera, &mut a).unwrap();
        full.render(pose, &camera, &mut b).unwrap();
        in_frustum += culled.cull_stats().visible_triangles as u64;
        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert!(
            bits(a.gray.data()) == bits(b.gray.data())
                && bits(a.depth_m.data()) == bits(b.depth_m.data()),
            "pose {k} ({pose:?}): the occlusion cull changed the image"
        );
        assert!(
            a.depth_m.data().iter().any(|&d| d > 0.0),
            "pose {k} sees nothing"
        );
    }
    let stats = culled.occlusion_stats();
    eprintln!(
        "{} poses, {in_frustum} triangles in the frustum; occlusion cull: {stats:?}",
        poses.len()
    );
    assert!(stats.renders > 0, "the occlusion cull never ran: {stats:?}");
    assert!(
        stats.coherent_renders * 2 > stats.renders,
        "most renders of a walk start from the previous one's clusters: {stats:?}"
    );
    assert!(
        stats.passes > stats.renders,
        "some renders were drawn in two passes: {stats:?}"
    );
    assert!(
        stats.triangles_drawn < in_frustum,
        "the occlusion cull drew {} triangles, the frustum held {in_frustum}",
        stats.triangles_drawn
    );
}

#[test]
fn a_timed_occlusion_cull_switches_modes_without_changing_the_image() {
    use star::render::gpu::cull_timing::BLOCK;
    let (preset, scene) = four_rooms();
    // A trial (a block with the cull, one without) and a few renders after
    // its decision.
    let poses: Vec<Pose> = walk(&scene).into_iter().take(2 * BLOCK + 6).collect();
    let mesh = Arc::new(scene.map.clone());
    let camera: PinholeCamera = preset.camera.pinhole();
    let Some(mut timed) = renderer(&mesh) else {
        return;
    };
    let mut full = renderer(&mesh).unwrap();
    full.set_frustum_cull(false);
    let far = Some(DEFAULT_FAR_M);
    timed.set_far_m(far);
    full.set_far_m(far);
    timed.set_occlusion_timed();
    let (mut a, mut b) = (
        RenderedView::for_camera(&camera),
        RenderedView::for_camera(&camera),
    );
    for (k, pose) in poses.iter().enumerate() {
        if k == 2 * BLOCK {
            // The trial ends with the render before this one.
            let d = timed
                .cull_decision()
                .expect("a trial of two blocks has finished");
            assert!(d.with_cull_s > 0.0 && d.frustum_only_s > 0.0, "{d:?}");
        } else if k < 2 * BLOCK {
            assert!(timed.cull_decision().is_none(), "render {k}: decided early");
        }
        timed.render(pose, &camera, &mut a).unwrap();
        full.render(pose, &camera, &mut b).unwrap();
        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert!(
            bits(a.gray.data()) == bits(b.gray.data())
                && bits(a.depth_m.data()) == bits(b.depth_m.data()),
            "pose {k} ({pose:?}): the timed cull changed the image"
        );
    }
    eprintln!("timed on this adapter: {:?}", timed.cull_decision());
    // The block without the cull ran: the cull's own count is short of the
    // renders by at least that block.
    let stats = timed.occlusion_stats();
    assert!(
        stats.renders + BLOCK as u64 <= poses.len() as u64,
        "{} renders, {} with the cull",
        poses.len(),
        stats.renders
    );
}
