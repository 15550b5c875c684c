//! Issue 24, IPC: one publisher per service. A second `star camera` or a
//! second tracker on the same iceoryx2 prefix is refused with an error
//! naming the process that holds the service; cameras that replace each
//! other (a flip-flop of publishers) never move the tracker's
//! `reset_counter`, which only an accepted relocalization moves.

#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;

use std::time::{Duration, Instant};

use common::star_cli::{config, dataset, frame_lines, spawn};
use star::ipc::{create_node, load_iceoryx_config, PoseSubscriber};

const START: Duration = Duration::from_secs(90);
const GUARD: Duration = Duration::from_secs(60);

fn refused(args: &[&str], holder_pid: u32, holder_node: &str) {
    let mut second = spawn(args);
    let (status, _) = second.wait_timeout(GUARD, Instant::now());
    let err = second.drain_log();
    assert!(!status.success(), "the second one ran: {err}");
    for needle in [
        "already has its publisher",
        holder_node,
        &format!("pid {holder_pid}"),
    ] {
        assert!(err.contains(needle), "no `{needle}` in:\n{err}");
    }
}

#[test]
fn a_second_camera_is_refused_naming_the_first() {
    let dir = tempfile::tempdir().unwrap();
    let tag = "twocams";
    let _cleanup = common::Cleanup(common::prefix(tag));
    let cfg = common::write_isolated_configs(dir.path(), tag, "");
    let cfg = cfg.to_str().unwrap();
    let args = [
        "--log",
        "info",
        "camera",
        "--config",
        cfg,
        "--source",
        "pattern:64x48",
    ];
    let mut first = spawn(&args);
    assert!(first.wait_for("camera process started", START), "no camera");
    refused(&args, first.child.id(), "star-camera");
    let (status, _) = first.signal_and_wait(libc::SIGTERM, GUARD);
    assert!(status.success(), "the first camera is unharmed: {status}");
}

#[test]
fn a_second_tracker_is_refused_and_camera_flip_flops_are_no_relocalization() {
    let dir = tempfile::tempdir().unwrap();
    let tag = "twotrk";
    let _cleanup = common::Cleanup(common::prefix(tag));
    let cfg = config(dir.path(), tag, "");
    let cfg = cfg.to_str().unwrap();
    let mut track = spawn(&["--log", "info", "track", "--config", cfg]);
    assert!(track.wait_for("tracker ready", START), "tracker not ready");
    refused(
        &["--log", "warn", "track", "--config", cfg],
        track.child.id(),
        "star-track",
    );

    // Four cameras replace each other, each playing the next 15 frames of
    // the sequence: the scene is continuous, only the publisher changes.
    // The start's verification is the one accepted relocalization (no
    // database: no other can be accepted), so reset_counter keeps the value
    // of the first tracked pose to the end.
    let iox = load_iceoryx_config(&dir.path().join("iceoryx2.toml"), None).unwrap();
    let node = create_node("test-poses", &iox).unwrap();
    let poses = PoseSubscriber::new(&node).unwrap();
    let lines = frame_lines(dataset());
    let (mut received, mut tracking) = (0, 0);
    let mut counter_at_start = None;
    for (round, slice) in lines.chunks(15).enumerate() {
        let ds = dir.path().join(format!("slice{round}"));
        std::fs::create_dir_all(ds.join("rgb")).unwrap();
        let mut list = String::new();
        for (t, rel) in slice {
            std::os::unix::fs::symlink(dataset().join(rel), ds.join(rel)).unwrap();
            list.push_str(&format!("{t} {rel}\n"));
        }
        std::fs::write(ds.join("rgb.txt"), list).unwrap();
        let src = format!("replay:{}", ds.display());
        let mut camera = spawn(&["--log", "warn", "camera", "--config", cfg, "--source", &src]);
        // Read the poses while the camera plays (the buffer holds 4), and
        // for a moment after it ended.
        let started = Instant::now();
        let mut ended_at: Option<Instant> = None;
        while ended_at.is_none_or(|t| t.elapsed() < Duration::from_millis(300)) {
            if ended_at.is_none() {
                if let Some(status) = camera.child.try_wait().unwrap() {
                    assert!(status.success(), "camera {round}: {}", camera.drain_log());
                    ended_at = Some(Instant::now());
                }
                assert!(started.elapsed() < GUARD, "camera {round} did not end");
            }
            let Some(pose) = poses.wait_next(Duration::from_millis(20)).unwrap() else {
                continue;
            };
            received += 1;
            if pose.tracking_state() != Some(star::ipc::TrackingState::Tracking) {
                continue;
            }
            tracking += 1;
            let start = *counter_at_start.get_or_insert(pose.reset_counter);
            assert_eq!(
                pose.reset_counter, start,
                "camera {round}: a new publisher moved reset_counter"
            );
        }
    }
    let (status, _) = track.signal_and_wait(libc::SIGTERM, GUARD);
    let out = track.stdout();
    println!("{received} poses, {tracking} tracking; {out}");
    assert!(status.success(), "{status}: {out}");
    assert!(
        received >= 40 && tracking > 0,
        "{received} poses, {tracking} tracking"
    );
    let restarts: u64 = out
        .split("camera restarts ")
        .nth(1)
        .and_then(|s| s.split_whitespace().next())
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| panic!("no restart count in {out}"));
    assert!(restarts >= 3, "{out}");
}
