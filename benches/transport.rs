//! Frame transport latency, publish to receive, for 640x512 and 1280x1024
//! gray frames: iceoryx2 zero-copy (this crate's `FramePublisher` /
//! `FrameSubscriber`, blocked on the frame event as the tracker is by
//! default) against the same frames copied through a Unix stream socket.
//! Prints p50, p99 and max in microseconds, the socket/transport ratio, and
//! the same transport polling around each frame's predicted arrival
//! (`ipc.spin_us`). A figure, not a test.
//!
//! Run: `cargo bench --bench transport` (or `cargo test --bench transport`
//! for a quick unoptimized run). `STAR_BENCH_FRAMES` sets the frame count,
//! `STAR_BENCH_PERIOD_US` the time between frames (default 1000 µs),
//! `STAR_BENCH_SPIN_US` the polling half-window (default 250 µs; the
//! shipped `ipc.spin_us` is 0, polling off), `STAR_BENCH_CPU=N` pins both
//! iceoryx2 threads to CPU N, and `STAR_BENCH_VERBOSE=1` also prints the
//! subscriber's counters and how long the publisher's own publish call
//! took (from the stamp to its return: the send and the event's
//! notification), which splits the latency between the two sides.

#![allow(clippy::expect_used, clippy::unwrap_used)] // test code: a failed step should panic

use std::io::{Read, Write};
use std::ops::ControlFlow;
use std::os::unix::net::UnixStream;
use std::sync::{Arc, Barrier};
use std::time::Duration;

use star::clock::monotonic_now_ns;
use star::ipc::{create_node, FrameEvent, FrameHeader, FramePublisher, FrameSubscriber};

fn env_or(name: &str, default: u64) -> u64 {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

/// Time between frames: long enough that the receiver is idle when the next
/// frame is sent, as with a real camera.
fn period() -> Duration {
    Duration::from_micros(env_or("STAR_BENCH_PERIOD_US", 1000))
}

/// Frames due on a fixed schedule, as a camera's clock sets them (a
/// relative sleep would add each wake-up's lateness to the period).
struct Schedule {
    next_ns: u64,
    period_ns: u64,
}

impl Schedule {
    fn start() -> Self {
        Self {
            next_ns: monotonic_now_ns(),
            period_ns: period().as_nanos() as u64,
        }
    }

    fn sleep_until_next(&mut self) {
        self.next_ns += self.period_ns;
        let now = monotonic_now_ns();
        if self.next_ns > now {
            std::thread::sleep(Duration::from_nanos(self.next_ns - now));
        }
    }
}

/// Pins the calling thread to `STAR_BENCH_CPU` when it is set.
fn pin_from_env() {
    let Some(cpu) = std::env::var("STAR_BENCH_CPU")
        .ok()
        .and_then(|v| v.parse::<usize>().ok())
    else {
        return;
    };
    // SAFETY: a zeroed cpu_set_t is a valid empty set; CPU_SET writes
    // within it; sched_setaffinity reads it.
    unsafe {
        let mut set: libc::cpu_set_t = std::mem::zeroed();
        libc::CPU_SET(cpu, &mut set);
        if libc::sched_setaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &set) != 0 {
            eprintln!("STAR_BENCH_CPU={cpu}: {}", std::io::Error::last_os_error());
        }
    }
}

fn iceoryx_latencies_ns(width: u32, height: u32, n: usize, spin: Duration) -> Vec<u64> {
    let prefix = format!("stbench{}_", std::process::id());
    let config = Arc::new(
        star::ipc::load_iceoryx_config(std::path::Path::new("/nonexistent"), Some(&prefix))
            .expect("config"),
    );
    let ready = Arc::new(Barrier::new(2));
    let rx = {
        let (config, ready) = (config.clone(), ready.clone());
        std::thread::spawn(move || {
            pin_from_env();
            let node = create_node("bench-rx", &config).expect("node");
            let mut subscriber = FrameSubscriber::new(&node)
                .expect("subscriber")
                .with_spin(spin);
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
        pin_from_env();
        let node = create_node("bench-tx", &config).expect("node");
        let mut publisher = FramePublisher::new(&node).expect("publisher");
        ready.wait();
        std::thread::sleep(Duration::from_millis(50));
        let mut schedule = Schedule::start();
        let mut send_ns = Vec::with_capacity(n + 20);
        for i in 0..n + 20 {
            let mut stamp = 0;
            publisher
                .publish_with(|slot| {
                    *slot.header = FrameHeader::gray8(0, width, height);
                    slot.pixels[..(width * height) as usize].fill(i as u8);
                    stamp = monotonic_now_ns();
                    slot.header.capture_ns = stamp;
                    Ok::<(), ()>(())
                })
                .expect("publish");
            send_ns.push(monotonic_now_ns() - stamp);
            schedule.sleep_until_next();
        }
        if std::env::var_os("STAR_BENCH_VERBOSE").is_some() {
            send_ns.sort_unstable();
            println!(
                "  (publisher: stamp to publish returned p50 {:.1} us, p99 {:.1} us)",
                percentile_us(&send_ns, 0.5),
                percentile_us(&send_ns, 0.99)
            );
        }
    });
    tx.join().expect("publisher");
    let (latencies, stats) = rx.join().expect("subscriber");
    if std::env::var_os("STAR_BENCH_VERBOSE").is_some() {
        println!("  (iceoryx2: {stats:?})");
    }
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
    let mut schedule = Schedule::start();
    for i in 0..n {
        buf[48..].fill(i as u8);
        // Same offset as FrameHeader::capture_ns.
        buf[8..16].copy_from_slice(&monotonic_now_ns().to_le_bytes());
        a.write_all(&buf).expect("write");
        schedule.sleep_until_next();
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
    let n = env_or("STAR_BENCH_FRAMES", 2000) as usize;
    let spin = Duration::from_micros(env_or("STAR_BENCH_SPIN_US", 250));
    println!(
        "frame transport latency, publish -> receive, {n} frames per case, {:?} apart",
        period()
    );
    println!(
        "{:>10} {:>10} {:>9} {:>9} {:>9}   {:>14}",
        "size", "transport", "p50 us", "p99 us", "max us", "socket/iceoryx2"
    );
    for (w, h) in [(640u32, 512u32), (1280, 1024)] {
        let mut iox = iceoryx_latencies_ns(w, h, n, Duration::ZERO);
        let mut polled = iceoryx_latencies_ns(w, h, n, spin);
        let mut uds = socket_latencies_ns(w, h, n);
        iox.sort_unstable();
        polled.sort_unstable();
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
        if !polled.is_empty() {
            println!(
                "{size:>10} {:>10} {:>9.1} {:>9.1} {:>9.1}   (iceoryx2 polling ±{spin:?}, ipc.spin_us)",
                "polled",
                percentile_us(&polled, 0.5),
                percentile_us(&polled, 0.99),
                percentile_us(&polled, 1.0)
            );
        }
    }
    remove_bench_resources();
}
