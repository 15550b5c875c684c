//! Steady-state tracking makes no heap allocation: a counting global
//! allocator watches the tracking thread through 240 frames of a moving
//! camera, keyframe swaps included.

mod common;

use std::sync::Arc;

use common::counting_alloc::{start_counting, stop_counting, CountingAlloc};
use nalgebra::{Translation3, UnitQuaternion};
use star::config::{KeyframeConfig, TrackerConfig};
use star::geometry::{PinholeCamera, Pose};
use star::localizer::{Localizer, TrackState};
use star::map::{GrayTexture, Mesh, MeshGroup};
use star::render::cpu::CpuRenderer;
use star::render::{RenderedView, Renderer};

#[global_allocator]
static GLOBAL: CountingAlloc = CountingAlloc;

/// A 6 x 6 m textured wall at z = 3 m, facing the camera.
fn wall() -> Mesh {
    let n = 512u32;
    let mut texels = Vec::with_capacity((n * n) as usize);
    for y in 0..n {
        for x in 0..n {
            let (u, v) = (x as f32 / n as f32, y as f32 / n as f32);
            let g = 128.0
                + 60.0 * (40.0 * u + 4.0 * (9.0 * v).sin()).sin() * (31.0 * v).cos()
                + 40.0 * (((u * 17.0).floor() + (v * 13.0).floor()) % 2.0 - 0.5);
            texels.push(g.clamp(0.0, 255.0));
        }
    }
    Mesh {
        positions: vec![
            [-3.0, -3.0, 3.0],
            [3.0, -3.0, 3.0],
            [3.0, 3.0, 3.0],
            [-3.0, 3.0, 3.0],
        ],
        gray: vec![255.0; 4],
        uvs: vec![[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]],
        indices: vec![0, 1, 2, 0, 2, 3],
        groups: vec![MeshGroup {
            first_index: 0,
            index_count: 6,
            texture: Some(0),
        }],
        textures: vec![GrayTexture {
            width: n,
            height: n,
            texels,
        }],
    }
}

fn pose_at(i: usize) -> Pose {
    let t = i as f64 * 0.02;
    Pose::from_parts(
        Translation3::new(0.3 * t.sin(), 0.1 * (1.3 * t).sin(), 0.2 * (0.7 * t).sin()),
        UnitQuaternion::from_euler_angles(0.03 * t.cos(), 0.05 * (0.9 * t).sin(), 0.02 * t),
    )
}

#[test]
fn steady_state_tracking_does_not_allocate() {
    let camera = PinholeCamera::new(320, 256, 210.0, 210.0, 159.5, 127.5);
    let mesh = Arc::new(wall());
    let mut images = Vec::new();
    let mut truth_renderer = CpuRenderer::new(mesh.clone()).expect("valid mesh");
    let mut view = RenderedView::for_camera(&camera);
    for i in 0..260 {
        truth_renderer
            .render(&pose_at(i), &camera, &mut view)
            .expect("render");
        images.push(view.gray.to_u8());
    }
    let tracker = TrackerConfig {
        pyramid_levels: 3,
        max_points: 3000,
        ..TrackerConfig::default()
    };
    let policy = KeyframeConfig {
        max_interval_s: 0.2,
        ..KeyframeConfig::default()
    };
    let renderer = Box::new(CpuRenderer::new(mesh).expect("valid mesh"));
    let mut localizer =
        Localizer::start(renderer, &camera, &tracker, &policy, pose_at(0), 1_000_000)
            .expect("start");
    let period_ns = 20_000_000u64;
    // Warm-up: the first frames fill lazily initialized state (thread-locals
    // of the channels, the first keyframe swap).
    for (i, img) in images.iter().enumerate().take(20) {
        let out = localizer
            .process_frame(
                img.data(),
                320,
                256,
                320,
                1_000_000 + (i as u64 + 1) * period_ns,
            )
            .expect("frame");
        assert_eq!(out.state, TrackState::Tracking, "frame {i}");
    }
    let keyframes_before = localizer.stats().keyframes;
    start_counting();
    let mut max_err_m: f64 = 0.0;
    for (i, img) in images.iter().enumerate().skip(20) {
        let out = localizer
            .process_frame(
                img.data(),
                320,
                256,
                320,
                1_000_000 + (i as u64 + 1) * period_ns,
            )
            .expect("frame");
        if let Some(p) = out.world_from_camera {
            max_err_m = max_err_m.max((pose_at(i).inverse() * p).translation.vector.norm());
        }
        assert_eq!(
            out.state,
            TrackState::Tracking,
            "frame {i}: {:?} kf {} age {}",
            out.quality,
            out.keyframe_id,
            out.keyframe_age_s
        );
        // Give the render thread time so keyframes really swap during the run.
        std::thread::sleep(std::time::Duration::from_millis(2));
    }
    let allocations = stop_counting();
    let swaps = localizer.stats().keyframes - keyframes_before;
    assert!(
        swaps >= 3,
        "only {swaps} keyframe swaps during the counted frames"
    );
    assert!(max_err_m < 0.01, "tracking error {max_err_m} m");
    assert_eq!(
        allocations, 0,
        "{allocations} allocations in 240 tracked frames"
    );
}
