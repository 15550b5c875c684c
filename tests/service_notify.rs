//! The service's sd_notify traffic, received on a fake `$NOTIFY_SOCKET`:
//! READY=1, STATUS=, and WATCHDOG=1 only while the loop makes progress.
//!
//! One test in this binary, because it sets process-wide environment variables.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::os::unix::net::UnixDatagram;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use star::service::{Service, ServiceState};

/// Collects the datagrams that arrive within `window`, while `during` runs
/// every 10 ms.
fn collect(socket: &UnixDatagram, window: Duration, mut during: impl FnMut()) -> Vec<String> {
    let mut out = Vec::new();
    let end = Instant::now() + window;
    let mut buf = [0u8; 4096];
    while Instant::now() < end {
        during();
        if let Ok(n) = socket.recv(&mut buf) {
            out.push(String::from_utf8_lossy(&buf[..n]).into_owned());
        }
    }
    out
}

fn pings(messages: &[String]) -> usize {
    messages
        .iter()
        .filter(|m| m.lines().any(|l| l == "WATCHDOG=1"))
        .count()
}

#[test]
fn notify_ready_status_and_progress_gated_watchdog() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("notify.sock");
    let socket = UnixDatagram::bind(&path).unwrap();
    socket
        .set_read_timeout(Some(Duration::from_millis(10)))
        .unwrap();
    std::env::set_var("NOTIFY_SOCKET", &path);
    // WatchdogSec=0.2s: pings every 100 ms while fed.
    std::env::set_var("WATCHDOG_USEC", "200000");
    std::env::remove_var("WATCHDOG_PID");

    let shutdown = Arc::new(AtomicBool::new(false));
    let svc = Service::start(shutdown.clone()).unwrap();
    svc.ready();
    let first = collect(&socket, Duration::from_millis(100), || {});
    let ready = first
        .iter()
        .find(|m| m.contains("READY=1"))
        .expect("READY=1 sent");
    assert!(ready.contains("STATUS=waiting"), "{ready}");

    // Fed: pings come.
    let dog = svc.watchdog();
    let status = svc.status();
    status.set_state(ServiceState::Tracking);
    status.keyframe_created(star::clock::monotonic_now_ns());
    let fed = collect(&socket, Duration::from_millis(1300), || {
        dog.feed();
        status.frame_done();
        std::thread::sleep(Duration::from_millis(10));
    });
    assert!(pings(&fed) >= 3, "pings while fed: {fed:?}");
    let line = fed
        .iter()
        .find(|m| m.starts_with("STATUS=tracking"))
        .expect("a STATUS line while tracking");
    assert!(line.contains(" fps, keyframe age "), "{line}");

    // Hung: after at most one ping already earned, none.
    let _settle = collect(&socket, Duration::from_millis(300), || {});
    let hung = collect(&socket, Duration::from_millis(500), || {});
    assert_eq!(pings(&hung), 0, "no pings without progress: {hung:?}");

    // Progress again: pings resume.
    let resumed = collect(&socket, Duration::from_millis(500), || {
        dog.feed();
        std::thread::sleep(Duration::from_millis(10));
    });
    assert!(pings(&resumed) >= 1, "pings resume: {resumed:?}");

    // The shutdown flag ends the service thread; stop() says STOPPING=1.
    shutdown.store(true, Ordering::Relaxed);
    svc.stop();
    let last = collect(&socket, Duration::from_millis(100), || {});
    assert!(last.iter().any(|m| m.contains("STOPPING=1")), "{last:?}");
}
