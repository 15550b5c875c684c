//! `MavlinkHandle::publish` is on the tracking hot path: it must not allocate.
//! A counting global allocator counts this thread's allocations only (the
//! link's own threads allocate as they please).

#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;

use std::sync::atomic::AtomicBool;
use std::sync::Arc;

use common::counting_alloc::{start_counting, stop_counting, CountingAlloc};
use star::clock::monotonic_now_ns;
use star::geometry::Pose;
use star::mavlink_io::{MavlinkConfig, MavlinkLink, PoseSample};

#[global_allocator]
static GLOBAL: CountingAlloc = CountingAlloc;

#[test]
fn publish_does_not_allocate() {
    let peer = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
    let config = MavlinkConfig {
        connection: format!("udpout:{}", peer.local_addr().unwrap()),
        ..MavlinkConfig::default()
    };
    let link = MavlinkLink::spawn(&config, Arc::new(AtomicBool::new(false))).unwrap();
    let sample = PoseSample {
        capture_ns: 0,
        world_from_camera: Pose::translation(1.0, 2.0, 3.0),
        covariance_6x6: [[0.0; 6]; 6],
        reset_counter: 0,
        quality_percent: 90,
        tracking: true,
    };
    // Warm up (first use of thread-locals, the mutex, the condvar).
    link.publish(sample);
    start_counting();
    for k in 0..2000u64 {
        link.publish(PoseSample {
            capture_ns: monotonic_now_ns() + k,
            tracking: k % 7 != 0,
            ..sample
        });
        let _ = link.stats();
    }
    let allocations = stop_counting();
    assert_eq!(
        allocations, 0,
        "publish/stats allocated {allocations} times"
    );
    // The link did take samples from the mailbox.
    let end = std::time::Instant::now() + std::time::Duration::from_secs(5);
    loop {
        let s = link.stats();
        let taken = s.vision_position_estimate_sent
            + s.poses_dropped_rate
            + s.poses_dropped_link
            + s.poses_dropped_lost
            + s.poses_dropped_clock
            + s.poses_dropped_spacing;
        if taken > 0 {
            break;
        }
        assert!(
            std::time::Instant::now() < end,
            "the link never took a sample: {s:?}"
        );
        std::thread::sleep(std::time::Duration::from_millis(5));
    }
    assert!(link.shutdown());
}
