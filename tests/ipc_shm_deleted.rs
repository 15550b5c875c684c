//! Issue 24, IPC: iceoryx2's files deleted from `/dev/shm` while the
//! tracker runs (a cleanup script, a careless `rm`). The processes attached
//! keep their mappings, but nobody could open the services again: a
//! restarted camera failed with `HangsInCreation`. Now the restarted camera
//! removes what is left and creates the services anew, the silent tracker
//! notices it was left on the old ones and re-attaches, and frames flow.

#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;

use std::time::{Duration, Instant};

use common::star_cli::{config, dataset, spawn};

const START: Duration = Duration::from_secs(90);
const GUARD: Duration = Duration::from_secs(60);

#[test]
fn a_camera_restarted_after_shm_files_were_deleted_reaches_the_tracker() {
    let dir = tempfile::tempdir().unwrap();
    let tag = "shmdel";
    let prefix = common::prefix(tag);
    let _cleanup = common::Cleanup(prefix.clone());
    let cfg = config(dir.path(), tag, "");
    let cfg = cfg.to_str().unwrap();
    let mut track = spawn(&["--log", "info", "track", "--config", cfg]);
    assert!(track.wait_for("tracker ready", START), "tracker not ready");
    let src = format!("replay:{}", dataset().display());
    let camera = |frames: &str| {
        let mut camera = spawn(&[
            "--log", "info", "camera", "--config", cfg, "--source", &src, "--frames", frames,
        ]);
        let (status, _) = camera.wait_timeout(GUARD, Instant::now());
        let log = camera.drain_log();
        assert!(status.success(), "camera failed: {log}");
        log
    };
    camera("20");
    assert!(
        track.wait_for("tracking", Duration::from_secs(20)),
        "no tracking"
    );

    let mut deleted = Vec::new();
    for entry in std::fs::read_dir("/dev/shm").unwrap().flatten() {
        if entry.file_name().to_string_lossy().starts_with(&prefix) {
            std::fs::remove_file(entry.path()).unwrap();
            deleted.push(entry.file_name());
        }
    }
    assert!(!deleted.is_empty(), "no shared-memory files with {prefix}");
    println!("deleted {deleted:?}");

    let log = camera("20");
    assert!(
        track.wait_for("camera frames resumed", Duration::from_secs(20)),
        "the tracker never saw the new camera; camera log:\n{log}\ntracker log:\n{}",
        track.drain_log()
    );
    let (status, _) = track.signal_and_wait(libc::SIGTERM, GUARD);
    let out = track.stdout();
    let err = track.drain_log();
    assert!(status.success(), "{status}\n{out}\n{err}");
    assert!(
        log.contains("created anew") && err.contains("re-attaching"),
        "the recovery was not logged:\n{err}\n{log}"
    );
    // Frames from the second camera (a new publisher) reached the loop.
    let restarts: u64 = out
        .split("camera restarts ")
        .nth(1)
        .and_then(|s| s.split_whitespace().next())
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| panic!("no restart count in {out}"));
    assert!(
        restarts >= 1,
        "the second camera's frames did not arrive\n{out}"
    );
}
