//! Transport guarantees in one process: the newest frame wins and drops are
//! counted, inconsistent headers are rejected on both sides, a publisher
//! restart is detected, and poses round-trip.

#![allow(clippy::expect_used, clippy::unwrap_used)] // test code: a failed step should panic

mod common;
use common as common_ipc;

use star::geometry::Pose;
use star::ipc::services::open_frame_service;
use star::ipc::{
    create_node, FrameHeader, FramePublisher, FrameSubscriber, PoseMsg, PosePublisher,
    PoseSubscriber, PublishError, TrackingState,
};

fn publish_gray(publisher: &mut FramePublisher, width: u32, height: u32, value: u8) -> u64 {
    publisher
        .publish_with(|slot| {
            *slot.header = FrameHeader::gray8(0, width, height);
            slot.pixels[..(width * height) as usize].fill(value);
            Ok::<(), ()>(())
        })
        .expect("publish")
}

#[test]
fn slow_consumer_gets_newest_frame_and_drops_are_counted() {
    let _cleanup = common_ipc::Cleanup(common_ipc::prefix("slow"));
    let config = common_ipc::isolated_config("slow");
    let node = create_node("test-slow", &config).expect("node");
    let mut subscriber = FrameSubscriber::new(&node).expect("subscriber");
    let mut publisher = FramePublisher::new(&node).expect("publisher");

    assert_eq!(publish_gray(&mut publisher, 64, 32, 1), 0);
    let first = subscriber.take_latest().expect("receive").expect("frame 0");
    assert_eq!(first.view().expect("valid").header.sequence, 0);
    drop(first);

    for i in 1..=10u8 {
        publish_gray(&mut publisher, 64, 32, i);
    }
    let newest = subscriber.take_latest().expect("receive").expect("newest");
    let view = newest.view().expect("valid");
    assert_eq!(view.header.sequence, 10);
    assert!(view.pixels.iter().all(|&p| p == 10), "pixels read in place");
    drop(newest);
    assert!(
        subscriber.take_latest().expect("receive").is_none(),
        "nothing queued"
    );
    let stats = subscriber.stats();
    assert_eq!(stats.received, 2);
    assert_eq!(stats.dropped, 9);
    assert_eq!(stats.rejected, 0);
}

#[test]
fn inconsistent_headers_are_rejected_and_counted() {
    let _cleanup = common_ipc::Cleanup(common_ipc::prefix("reject"));
    let config = common_ipc::isolated_config("reject");
    let node = create_node("test-reject", &config).expect("node");
    let mut subscriber = FrameSubscriber::new(&node).expect("subscriber");
    let mut publisher = FramePublisher::new(&node).expect("publisher");

    // The publisher refuses to send a bad header.
    let err = publisher
        .publish_with(|slot| {
            *slot.header = FrameHeader::gray8(0, 0, 10);
            Ok::<(), ()>(())
        })
        .expect_err("zero width");
    assert!(matches!(err, PublishError::Rejected(_)));
    assert_eq!(publisher.stats().rejected, 1);
    assert_eq!(publisher.stats().published, 0);

    // A foreign publisher that skips validation: the subscriber rejects.
    // The service admits one publisher, so the checked one steps aside.
    drop(publisher);
    let raw = open_frame_service(&node)
        .expect("service")
        .publisher_builder()
        .create()
        .expect("raw publisher");
    for bad in [
        {
            let mut h = FrameHeader::gray8(0, 64, 32);
            h.pixel_format = 0x1234_5678;
            h
        },
        FrameHeader::gray8(1, 0, 32),
        FrameHeader::gray8(2, 100_000, 100_000),
    ] {
        let mut sample = raw.loan_uninit().expect("loan");
        // SAFETY: shared-memory bytes are initialized; all bit patterns are valid.
        let frame = unsafe { sample.payload_mut().assume_init_mut() };
        frame.header = bad;
        // SAFETY: as above.
        unsafe { sample.assume_init() }.send().expect("send");
        assert!(subscriber.take_latest().expect("receive").is_none());
    }
    assert_eq!(subscriber.stats().rejected, 3);

    drop(raw);
    let mut publisher = FramePublisher::new(&node).expect("publisher again");
    publish_gray(&mut publisher, 8, 8, 5);
    assert!(subscriber.take_latest().expect("receive").is_some());
}

#[test]
fn publisher_restart_is_detected_without_counting_drops() {
    let _cleanup = common_ipc::Cleanup(common_ipc::prefix("restart"));
    let config = common_ipc::isolated_config("restart");
    let node = create_node("test-restart", &config).expect("node");
    let mut subscriber = FrameSubscriber::new(&node).expect("subscriber");
    let mut publisher = FramePublisher::new(&node).expect("publisher");
    for _ in 0..5 {
        publish_gray(&mut publisher, 8, 8, 1);
    }
    assert!(subscriber.take_latest().expect("receive").is_some());
    drop(publisher);
    let mut publisher = FramePublisher::new(&node).expect("new publisher");
    publish_gray(&mut publisher, 8, 8, 2);
    let frame = subscriber.take_latest().expect("receive").expect("frame");
    assert_eq!(frame.view().expect("valid").header.sequence, 0);
    drop(frame);
    let stats = subscriber.stats();
    assert_eq!(stats.publisher_changes, 1);
    assert_eq!(stats.dropped, 0);
}

#[test]
fn poses_round_trip() {
    let _cleanup = common_ipc::Cleanup(common_ipc::prefix("pose"));
    let config = common_ipc::isolated_config("pose");
    let node = create_node("test-pose", &config).expect("node");
    let subscriber = PoseSubscriber::new(&node).expect("subscriber");
    let publisher = PosePublisher::new(&node).expect("publisher");
    let mut msg = PoseMsg::new(
        123,
        4,
        &Pose::translation(1.0, 2.0, 3.0),
        TrackingState::Relocalized,
    );
    msg.reset_counter = 2;
    publisher.publish(&msg).expect("publish");
    let got = subscriber
        .wait_next(std::time::Duration::from_secs(2))
        .expect("receive")
        .expect("pose");
    assert_eq!(got, msg);
    assert_eq!(got.tracking_state(), Some(TrackingState::Relocalized));
    assert!(subscriber.try_next().expect("receive").is_none());
}

/// A camera that fails: every third frame is corrupt, and after five good
/// frames the device "disconnects".
struct FlakyCamera {
    frames: u32,
}

impl star::camera::FrameSource for FlakyCamera {
    fn describe(&self) -> String {
        "flaky test camera".into()
    }

    fn next_frame(
        &mut self,
        slot: &mut star::ipc::FrameSlot<'_>,
    ) -> Result<(), star::camera::CameraError> {
        self.frames += 1;
        if self.frames > 5 {
            return Err(star::camera::CameraError::Disconnected {
                device: "flaky".into(),
                reason: "unplugged".into(),
            });
        }
        if self.frames % 3 == 0 {
            return Err(star::camera::CameraError::BadFrame {
                device: "flaky".into(),
                reason: "corrupt".into(),
            });
        }
        *slot.header = FrameHeader::gray8(0, 16, 8);
        Ok(())
    }
}

#[test]
fn failing_camera_is_reconnected_and_bad_frames_skipped() {
    use star::camera::{run_camera, RunnerSettings};
    let _cleanup = common_ipc::Cleanup(common_ipc::prefix("flaky"));
    let config = common_ipc::isolated_config("flaky");
    let node = create_node("test-flaky", &config).expect("node");
    let mut publisher = FramePublisher::new(&node).expect("publisher");
    let mut opens = 0;
    let summary = run_camera(
        || {
            opens += 1;
            if opens == 2 {
                // The device is briefly absent after the disconnect.
                return Err(star::camera::CameraError::Open {
                    device: "flaky".into(),
                    reason: "no such device".into(),
                });
            }
            Ok(Box::new(FlakyCamera { frames: 0 }))
        },
        &mut publisher,
        &|| false,
        &RunnerSettings {
            initial_backoff: std::time::Duration::from_millis(1),
            max_frames: Some(10),
            ..RunnerSettings::default()
        },
    )
    .expect("run");
    // Sessions publish frames 1, 2, 4, 5 (frame 3 is skipped) until frame 6
    // disconnects: 4 + 4 + 2 = 10 over three sessions.
    assert_eq!(summary.stats.published, 10);
    assert_eq!(
        summary.opens, 3,
        "successful opens; one failed attempt between"
    );
    assert_eq!(opens, 4);
    assert_eq!(summary.skipped, 2);
    assert_eq!(
        summary.stats.source_errors,
        2 + 2,
        "2 corrupt frames, 2 disconnects"
    );
}
