//! Steady-state tracking makes no heap allocation: a counting global
//! allocator watches the tracking thread through 240 frames of a moving
//! camera, keyframe swaps included.

mod common;

use std::sync::Arc;

use common::counting_alloc::{start_counting, stop_counting, CountingAlloc};
use common::wall::wall;
use nalgebra::{Translation3, UnitQuaternion};
use star::config::{KeyframeConfig, TrackerConfig};
use star::geometry::{PinholeCamera, Pose};
use star::localizer::{Localizer, TrackState};
use star::render::cpu::CpuRenderer;
use star::render::{RenderedView, Renderer};

#[global_allocator]
static GLOBAL: CountingAlloc = CountingAlloc;

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
