//! `[keyframe] far_m`: tracking keyframes are drawn to their own far limit,
//! the start pose (drawn as a relocalization candidate) to the renderer's.
//! Data from `star synth --preset ideal` with a fixed seed; the CPU
//! rasterizer.

#![allow(clippy::expect_used, clippy::unwrap_used)] // test code: a failed step should panic

mod common;

use std::path::Path;
use std::sync::Arc;

use star::config::Config;
use star::dataset::Dataset;
use star::localizer::{Localizer, TrackState};
use star::render::cpu::CpuRenderer;
use star::render::NO_DEPTH;
use star::track::Keyframe;

const FRAMES: usize = 120;

/// The keyframe far limit under test, meters: short of the room's far
/// walls, so that it shows in every keyframe.
const KEYFRAME_FAR_M: f32 = 2.5;

fn synth(out: &Path) {
    common::star_cli::synth_no_depth(out, "ideal", 21, FRAMES);
}

/// The deepest pixel drawn, meters.
fn deepest_m(keyframe: &Keyframe) -> f32 {
    keyframe
        .depth_m()
        .data()
        .iter()
        .filter(|&&d| d != NO_DEPTH && d.is_finite())
        .fold(0.0, |a, &d| a.max(d))
}

#[test]
fn tracking_keyframes_stop_at_their_far_limit_and_the_start_pose_sees_the_renderers() {
    let tmp = tempfile::tempdir().expect("tmp");
    synth(tmp.path());
    let dataset = Dataset::open(tmp.path()).expect("open");
    let mesh = star::map::load_obj(&tmp.path().join("map/map.obj")).expect("map");
    let mut renderer = CpuRenderer::new(Arc::new(mesh)).expect("renderer");
    renderer.set_far_m(Some(30.0));
    let mut config = Config::default();
    config.keyframe.far_m = KEYFRAME_FAR_M;
    config.keyframe.validate().expect("a valid [keyframe]");
    let truth = dataset.ground_truth.as_ref().expect("gt");
    let stamp_ns = |i: usize| (dataset.frames[i].timestamp_s * 1e9).round() as u64;
    let mut localizer = Localizer::start(
        Box::new(renderer),
        dataset.camera(),
        &config.tracker,
        &config.keyframe,
        truth.poses[0],
        stamp_ns(0),
    )
    .expect("start");

    // The start pose is drawn as a candidate: to the renderer's 30 m, the
    // room's far walls included.
    let start_deepest_m = deepest_m(localizer.keyframe());
    assert!(
        start_deepest_m > KEYFRAME_FAR_M + 0.5,
        "the start keyframe reaches {start_deepest_m} m"
    );

    let mut tracking_keyframes = 0;
    let mut last_id = localizer.keyframe().id;
    for i in 1..dataset.frames.len() {
        let frame = dataset.load_frame(i).expect("frame");
        let (w, h) = (frame.width(), frame.height());
        let out = localizer
            .process_frame(frame.data(), w, h, w, stamp_ns(i))
            .expect("frame processed");
        assert_eq!(out.state, TrackState::Tracking, "frame {i}");
        let keyframe = localizer.keyframe();
        if keyframe.id != last_id {
            last_id = keyframe.id;
            tracking_keyframes += 1;
            let deepest = deepest_m(keyframe);
            assert!(
                deepest <= KEYFRAME_FAR_M + 1e-3,
                "keyframe {last_id} reaches {deepest} m, beyond its {KEYFRAME_FAR_M} m"
            );
            assert!(deepest > 1.0, "keyframe {last_id} is empty");
        }
    }
    assert!(
        tracking_keyframes >= 2,
        "only {tracking_keyframes} keyframes were rendered while tracking"
    );
}
