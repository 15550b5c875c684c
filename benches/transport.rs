//! Frame transport latency, publish to receive, for 640x512 and 1280x1024
//! gray frames: iceoryx2 zero-copy (this crate's `FramePublisher` /
//! `FrameSubscriber`, subscriber blocked on the frame event) against the
//! same frames copied through a Unix stream socket. Prints p50, p99 and max
//! in microseconds and the socket/transport ratio. A figure, not a test.
//!
//! Run: `cargo bench --bench transport` (or `cargo test --bench transport`
//! for a quick unoptimized run). `STAR_BENCH_FRAMES` sets the frame count.

#![allow(clippy::expect_used, clippy::unwrap_used)] // test code: a failed step should panic

use std::io::{Read, Write};
use std::ops::ControlFlow;
use std::os::unix::net::UnixStream;
use std::sync::{Arc, Barrier};
use std::time::Duration;

use star::camera::monotonic_now_ns;
use star::ipc::{create_node, FrameEvent, FrameHeader, FramePublisher, FrameSubscriber};

/// Time between frames: long enough that the receiver is idle and blocked
/// when the next frame is sent, as with a real camera.
const PERIOD: Duration = Duration::from_micros(1000);

fn frames() -> usize {
    std::env::var("STAR_BENCH_FRAMES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(2000)
}

fn iceoryx_latencies_ns(width: u32, height: u32, n: usize) -> Vec<u64> {
    let prefix = format!("stbench{}_", std::process::id());
    let config = Arc::new(
        star::ipc::load_iceoryx_config(std::path::Path::new("/nonexistent"), Some(&prefix))
            .expect("config"),
    );
    let ready = Arc::new(Barrier::new(2));
    let rx = {
        let (config, ready) = (config.clone(), ready.clone());
        std::thread::spawn(move || {
            let node = create_node("bench-rx", &config).expect("node");
            let mut subscriber = FrameSubscriber::new(&node).expect("subscriber");
            let mut latencies = Vec::with_capacity(n);
            let mut touched = 0u64;
            ready.wait();
            subscriber
                .run(Duration::from_secs(2), |event| match event {
                    FrameEvent::Frame(view) => {
                        latencies.push(monotonic_now_ns().saturating_sub(view.header.capture_ns));
                        touched += u64::from(view.pixels[view.pixels.len() - 1]);
                        if latencies.len() >= n {
                            ControlFlow::Break(())
                        } else {
                            ControlFlow::Continue(())
                        }
                    }
                    FrameEvent::Silent => ControlFlow::Break(()),
                })
                .expect("run");
            std::hint::black_box(touched);
            (latencies, subscriber.stats())
        })
    };
    let tx = std::thread::spawn(move || {
        let node = create_node("bench-tx", &config).expect("node");
        let mut publisher = FramePublisher::new(&node).expect("publisher");
        ready.wait();
        std::thread::sleep(Duration::from_millis(50));
        for i in 0..n + 20 {
            publisher
                .publish_with(|slot| {
                    *slot.header = FrameHeader::gray8(0, width, height);
                    slot.pixels[..(width * height) as usize].fill(i as u8);
                    slot.header.capture_ns = monotonic_now_ns();
                    Ok::<(), ()>(())
                })
                .expect("publish");
            std::thread::sleep(PERIOD);
        }
    });
    tx.join().expect("publisher");
    let (latencies, stats) = rx.join().expect("subscriber");
    if stats.dropped > 0 {
        println!(
            "  (iceoryx2: {} frames dropped by the receiver)",
            stats.dropped
        );
    }
    latencies
}

fn socket_latencies_ns(width: u32, height: u32, n: usize) -> Vec<u64> {
    let size = std::mem::size_of::<FrameHeader>() + (width * height) as usize;
    let (mut a, mut b) = UnixStream::pair().expect("socket pair");
    let rx = std::thread::spawn(move || {
        let mut buf = vec![0u8; size];
        let mut latencies = Vec::with_capacity(n);
        for _ in 0..n {
            b.read_exact(&mut buf).expect("read");
            let stamp = u64::from_le_bytes(buf[8..16].try_into().expect("8 bytes"));
            latencies.push(monotonic_now_ns().saturating_sub(stamp));
        }
        std::hint::black_box(buf[size - 1]);
        latencies
    });
    let mut buf = vec![0u8; size];
    for i in 0..n {
        buf[48..].fill(i as u8);
        // Same offset as FrameHeader::capture_ns.
        buf[8..16].copy_from_slice(&monotonic_now_ns().to_le_bytes());
        a.write_all(&buf).expect("write");
        std::thread::sleep(PERIOD);
    }
    rx.join().expect("socket receiver")
}

fn percentile_us(sorted: &[u64], p: f64) -> f64 {
    let i = ((sorted.len() as f64 - 1.0) * p).round() as usize;
    sorted[i.min(sorted.len() - 1)] as f64 / 1e3
}

/// Removes this run's iceoryx2 files (prefix `stbench<pid>_`).
fn remove_bench_resources() {
    let prefix = format!("stbench{}_", std::process::id());
    for dir in ["/dev/shm", "/tmp/iceoryx2/nodes", "/tmp/iceoryx2/services"] {
        for entry in std::fs::read_dir(dir).into_iter().flatten().flatten() {
            if entry.file_name().to_string_lossy().starts_with(&prefix) {
                let _ = std::fs::remove_file(entry.path());
            }
        }
    }
}

fn main() {
    // cargo bench passes `--bench`; a filter argument is ignored.
    let n = frames();
    println!("frame transport latency, publish -> receive, {n} frames per case, {PERIOD:?} apart");
    println!(
        "{:>10} {:>10} {:>9} {:>9} {:>9}   {:>14}",
        "size", "transport", "p50 us", "p99 us", "max us", "socket/iceoryx2"
    );
    for (w, h) in [(640u32, 512u32), (1280, 1024)] {
        let mut iox = iceoryx_latencies_ns(w, h, n);
        let mut uds = socket_latencies_ns(w, h, n);
        iox.sort_unstable();
        uds.sort_unstable();
        if iox.is_empty() || uds.is_empty() {
            println!("{w}x{h}: no samples");
            continue;
        }
        let size = format!("{w}x{h}");
        let (i50, i99) = (percentile_us(&iox, 0.5), percentile_us(&iox, 0.99));
        let (u50, u99) = (percentile_us(&uds, 0.5), percentile_us(&uds, 0.99));
        println!(
            "{size:>10} {:>10} {i50:>9.1} {i99:>9.1} {:>9.1}",
            "iceoryx2",
            percentile_us(&iox, 1.0)
        );
        println!(
            "{size:>10} {:>10} {u50:>9.1} {u99:>9.1} {:>9.1}   p50 {:.1}x, p99 {:.1}x",
            "unix sock",
            percentile_us(&uds, 1.0),
            u50 / i50,
            u99 / i99
        );
    }
    remove_bench_resources();
}
