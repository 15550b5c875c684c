//! Steady-state frame transport allocates nothing: a counting global
//! allocator counts heap allocations made on the publishing thread and on
//! the receiving thread (which blocks on the frame event) after a warm-up.
//!
//! iceoryx2 0.10 itself allocates one small `Rc` per loaned sample
//! (`Publisher::loan_uninit` -> `ChunkMutSharedState::new`), freed again when
//! the sample is sent. The publisher check therefore pins that cost exactly:
//! one allocation per frame, nothing from star's code. The receiving side
//! must not allocate at all.

#![allow(clippy::expect_used, clippy::unwrap_used)] // test code: a failed step should panic

mod common;
use common as common_ipc;

use std::ops::ControlFlow;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Barrier};
use std::time::Duration;

use star::camera::pattern::PatternSource;
use star::camera::FrameSource;
use star::ipc::{create_node, FrameEvent, FramePublisher, FrameSubscriber};

use common::counting_alloc::{start_counting, stop_counting, CountingAlloc};

#[global_allocator]
static GLOBAL: CountingAlloc = CountingAlloc;

const WARMUP_FRAMES: u64 = 30;
const COUNTED_FRAMES: u64 = 300;

#[test]
fn steady_state_publish_and_receive_do_not_allocate() {
    let _cleanup = common_ipc::Cleanup(common_ipc::prefix("noalloc"));
    let config = Arc::new(common_ipc::isolated_config("noalloc"));
    let ready = Arc::new(Barrier::new(2));
    let done = Arc::new(AtomicBool::new(false));

    let receiver = {
        let (config, ready, done) = (config.clone(), ready.clone(), done.clone());
        std::thread::spawn(move || {
            let node = create_node("test-noalloc-rx", &config).expect("node");
            // Polling around the predicted arrival is on, as in `star track`,
            // so both ways of waiting run under the counter.
            let mut subscriber = FrameSubscriber::new(&node)
                .expect("subscriber")
                .with_spin(Duration::from_micros(250));
            ready.wait();
            let mut frames = 0u64;
            let mut first_sequence = None;
            let mut checksum = 0u64;
            let mut counted_allocs = 0u64;
            subscriber
                .run(Duration::from_millis(100), |event| {
                    if let FrameEvent::Frame(view) = event {
                        frames += 1;
                        first_sequence.get_or_insert(view.header.sequence);
                        checksum += u64::from(view.pixels[view.pixels.len() / 2]);
                        if frames == WARMUP_FRAMES {
                            start_counting();
                        }
                    }
                    if done.load(Ordering::SeqCst) {
                        counted_allocs = stop_counting();
                        return ControlFlow::Break(());
                    }
                    ControlFlow::Continue(())
                })
                .expect("run");
            (
                frames,
                first_sequence,
                checksum,
                counted_allocs,
                subscriber.stats(),
            )
        })
    };

    let publisher = {
        let (config, ready) = (config.clone(), ready.clone());
        std::thread::spawn(move || {
            let node = create_node("test-noalloc-tx", &config).expect("node");
            let mut publisher = FramePublisher::new(&node).expect("publisher");
            let mut source = PatternSource::new(640, 512, 2000.0).expect("pattern");
            ready.wait();
            for i in 0..WARMUP_FRAMES + COUNTED_FRAMES {
                if i == WARMUP_FRAMES {
                    start_counting();
                }
                publisher
                    .publish_with(|slot| source.next_frame(slot))
                    .expect("publish");
            }
            (stop_counting(), publisher.stats())
        })
    };

    let (tx_allocs, tx_stats) = publisher.join().expect("publisher thread");
    std::thread::sleep(Duration::from_millis(200));
    done.store(true, Ordering::SeqCst);
    let (frames, first_sequence, checksum, rx_allocs, rx_stats) =
        receiver.join().expect("receiver thread");

    assert_eq!(tx_stats.published, WARMUP_FRAMES + COUNTED_FRAMES);
    assert!(
        frames > WARMUP_FRAMES + COUNTED_FRAMES / 2,
        "received {frames}"
    );
    assert!(checksum > 0);
    assert_eq!(rx_stats.rejected, 0);
    assert!(
        rx_stats.polled > 0,
        "the polling path never ran, so it went uncounted: {rx_stats:?}"
    );
    // Frames sent before the subscriber's first one are not drops: the
    // connection is made on the first send.
    let first_sequence = first_sequence.expect("frames arrived");
    assert!(first_sequence < WARMUP_FRAMES);
    assert_eq!(
        rx_stats.received + rx_stats.dropped,
        tx_stats.published - first_sequence,
        "every frame after the first is either received or counted as dropped"
    );
    assert_eq!(
        tx_allocs, COUNTED_FRAMES,
        "publishing thread: expected exactly iceoryx2's one Rc per loan, nothing more"
    );
    assert_eq!(rx_allocs, 0, "receiving thread allocated in steady state");
}
