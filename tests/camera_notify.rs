//! `star camera` talks to systemd like the tracker does
//! (`star-camera.service` is `Type=notify` with `WatchdogSec=`): READY=1
//! once its publisher is up, and WATCHDOG=1 while its loop turns.

#![allow(clippy::expect_used, clippy::unwrap_used)] // test code: a failed step should panic

mod common;
use common as common_ipc;

use std::os::unix::net::UnixDatagram;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

#[test]
fn camera_sends_ready_and_watchdog() {
    let _cleanup = common_ipc::Cleanup(common_ipc::prefix("camnotify"));
    let tmp = tempfile::tempdir().expect("tmp");
    let config =
        common_ipc::write_isolated_configs(tmp.path(), "camnotify", "[camera]\nfps = 50.0\n");
    let socket_path = tmp.path().join("notify.sock");
    let socket = UnixDatagram::bind(&socket_path).expect("notify socket");
    socket
        .set_read_timeout(Some(Duration::from_millis(50)))
        .unwrap();
    let mut camera = Command::new(env!("CARGO_BIN_EXE_star"))
        .args([
            "camera",
            "--source",
            "pattern:64x48",
            "--frames",
            "100",
            "--config",
        ])
        .arg(&config)
        .env("NOTIFY_SOCKET", &socket_path)
        .env("WATCHDOG_USEC", "400000")
        .env_remove("WATCHDOG_PID")
        .env("RUST_LOG", "warn")
        .stdout(Stdio::null())
        .stderr(Stdio::inherit())
        .spawn()
        .expect("spawn star camera");
    let mut messages = Vec::new();
    let mut buf = [0u8; 4096];
    // A hang guard: 100 frames at 50 Hz take 2 s.
    let end = Instant::now() + Duration::from_secs(30);
    while Instant::now() < end {
        if let Ok(n) = socket.recv(&mut buf) {
            messages.push(String::from_utf8_lossy(&buf[..n]).into_owned());
        }
        if camera.try_wait().expect("wait").is_some() {
            break;
        }
    }
    let status = camera.wait().expect("camera exits");
    assert!(status.success(), "star camera failed: {status}");
    let ready = messages
        .iter()
        .position(|m| m.lines().any(|l| l == "READY=1"));
    let ready = ready.unwrap_or_else(|| panic!("no READY=1 in {messages:?}"));
    let pings = messages[ready..]
        .iter()
        .filter(|m| m.lines().any(|l| l == "WATCHDOG=1"))
        .count();
    // 2 s of frames with a 0.4 s watchdog: pings every 0.2 s.
    assert!(
        pings >= 3,
        "{pings} watchdog pings after READY=1: {messages:?}"
    );
}
