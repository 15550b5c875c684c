//! The Aravis source against Aravis's built-in fake camera (the "Fake"
//! interface, enabled in process through `arv_enable_interface`): Mono8
//! frames of the configured size with monotonic capture times, first read
//! directly, then through the publish loop and the transport.

#![allow(clippy::expect_used, clippy::unwrap_used)] // test code: a failed step should panic
#![cfg(feature = "aravis")]

mod common;
use common as common_ipc;

use star::camera::aravis::{AravisSource, FAKE_CAMERA_ID};
use star::camera::{
    open_source, run_camera, FrameSource, RunnerSettings, SourceSettings, SourceUri,
};
use star::clock::monotonic_now_ns;
use star::ipc::{create_node, Frame, FramePublisher, FrameSlot, FrameSubscriber};

fn settings() -> SourceSettings {
    SourceSettings {
        width: 320,
        height: 240,
        fps: 50.0,
        buffers: 4,
        exposure_us: Some(2000.0),
        gain_db: Some(1.0),
        ..SourceSettings::default()
    }
}

#[test]
fn fake_camera_frames_direct_and_through_transport() {
    // Direct reads.
    let mut source = AravisSource::open(FAKE_CAMERA_ID, &settings()).expect("open fake camera");
    eprintln!("opened {}", source.describe());
    let mut frame = Frame::boxed_zeroed();
    let mut last_ns = 0;
    for _ in 0..5 {
        source
            .next_frame(&mut FrameSlot::from_frame(&mut frame))
            .expect("frame");
        let view = frame.view().expect("valid header");
        assert_eq!((view.header.width, view.header.height), (320, 240));
        assert!(view.header.capture_ns > last_ns, "capture times increase");
        assert!(
            view.header.capture_ns <= monotonic_now_ns(),
            "capture time is not in the future"
        );
        assert!(
            (view.header.exposure_us - 2000.0).abs() < 1.0,
            "{}",
            view.header.exposure_us
        );
        last_ns = view.header.capture_ns;
    }
    let distinct = {
        let mut seen = [false; 256];
        frame
            .view()
            .expect("valid")
            .pixels
            .iter()
            .for_each(|&p| seen[p as usize] = true);
        seen.iter().filter(|s| **s).count()
    };
    assert!(
        distinct > 4,
        "the fake camera draws a pattern, found {distinct} gray levels"
    );
    drop(source);

    // Through the publish loop (the code path of `star camera --source aravis:fake`).
    let _cleanup = common_ipc::Cleanup(common_ipc::prefix("aravis"));
    let config = common_ipc::isolated_config("aravis");
    let node = create_node("test-aravis", &config).expect("node");
    let mut subscriber = FrameSubscriber::new(&node).expect("subscriber");
    let mut publisher = FramePublisher::new(&node).expect("publisher");
    let uri = SourceUri::parse("aravis:fake").expect("uri");
    let settings = settings();
    let summary = run_camera(
        || open_source(&uri, &settings),
        &mut publisher,
        &|| false,
        &RunnerSettings {
            max_frames: Some(3),
            ..RunnerSettings::default()
        },
    )
    .expect("run");
    assert_eq!(summary.stats.published, 3);
    assert_eq!(summary.opens, 1);
    let received = subscriber.take_latest().expect("receive").expect("a frame");
    let view = received.view().expect("valid");
    assert_eq!(view.header.sequence, 2, "newest of the three");
    assert_eq!((view.header.width, view.header.height), (320, 240));
}
