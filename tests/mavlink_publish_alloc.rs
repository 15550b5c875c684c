//! `MavlinkHandle::publish` is on the tracking hot path: it must not allocate.
//! A counting global allocator counts this thread's allocations only (the
//! link's own threads allocate as they please).

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;

use star::clock::monotonic_now_ns;
use star::geometry::Pose;
use star::mavlink_io::{MavlinkConfig, MavlinkLink, PoseSample};

thread_local! {
    static ALLOCATIONS: Cell<u64> = const { Cell::new(0) };
}

struct Counting;

// SAFETY: forwards to the system allocator; only adds a thread-local count.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let _ = ALLOCATIONS.try_with(|c| c.set(c.get() + 1));
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        let _ = ALLOCATIONS.try_with(|c| c.set(c.get() + 1));
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

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
    let before = ALLOCATIONS.with(Cell::get);
    for k in 0..2000u64 {
        link.publish(PoseSample {
            capture_ns: monotonic_now_ns() + k,
            tracking: k % 7 != 0,
            ..sample
        });
        let _ = link.stats();
    }
    let after = ALLOCATIONS.with(Cell::get);
    assert_eq!(
        after - before,
        0,
        "publish/stats allocated {} times",
        after - before
    );
    // The link did take samples from the mailbox.
    let end = std::time::Instant::now() + std::time::Duration::from_secs(5);
    loop {
        let s = link.stats();
        let taken = s.vision_position_estimate_sent
            + s.poses_dropped_rate
            + s.poses_dropped_link
            + s.poses_dropped_lost
            + s.poses_dropped_clock;
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
