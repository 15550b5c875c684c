//! Issue 24, signals: a stop signal ends every `star` process within a
//! second in every state (the spec's figure, so this test times it: printed,
//! and asserted at 1.0 s), and SIGHUP, SIGQUIT and SIGUSR1 stop as
//! gracefully as SIGTERM, the trajectory file holding every pose produced.
//!
//! The states: the tracker starting; the tracker waiting for a camera;
//! `star run` in a two-hour
//! gap between replay stamps; `star run` and `star camera` replaying at
//! 0.01x (a frame every 2 s). The processes run one at a time, so the
//! figures are not inflated by each other on a small machine.

#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;

use std::path::Path;
use std::time::Duration;

use common::star_cli::{config, dataset_copy, spawn, trajectory_lines, Running};

/// Most of a run's start (map load, first keyframe) on a loaded machine.
const START: Duration = Duration::from_secs(90);
/// The spec: exit within 1 s of the signal.
const EXIT_LIMIT: Duration = Duration::from_millis(1000);
/// Past this the process is stuck; the test kills it and fails.
const GUARD: Duration = Duration::from_secs(20);

/// Frames 30.. are moved two hours later: the replay tracks 30 frames and
/// then waits in the gap.
fn gap_dataset(dir: &Path) -> std::path::PathBuf {
    dataset_copy(dir, |i, t| if i < 30 { t } else { t + 7200.0 }).0
}

fn assert_quick_exit(what: &str, run: &mut Running, signal: i32) -> String {
    let (status, took) = run.signal_and_wait(signal, GUARD);
    let log = run.drain_log();
    println!(
        "{what}: exited {:.3} s after signal {signal} ({status})",
        took.as_secs_f64()
    );
    assert!(
        took <= EXIT_LIMIT,
        "{what}: exit took {:.3} s after signal {signal} (limit {:.1} s); stderr:\n{log}",
        took.as_secs_f64(),
        EXIT_LIMIT.as_secs_f64()
    );
    log
}

#[test]
fn sigterm_ends_every_state_within_a_second() {
    let dir = tempfile::tempdir().unwrap();
    let tag = "sigstates";
    let _cleanup = common::Cleanup(common::prefix(tag));
    let cfg = config(dir.path(), tag, "");
    let cfg = cfg.to_str().unwrap();

    // 0. The tracker starting (map, renderer, first keyframe): the start
    // stops between its steps.
    let mut starting = spawn(&["--log", "info", "track", "--config", cfg]);
    // The map is loaded after the handlers are installed; the renderer and
    // the first keyframe come next.
    assert!(starting.wait_for("mesh loaded", START), "no map loaded");
    assert_quick_exit("star track, starting", &mut starting, libc::SIGTERM);
    assert!(
        starting
            .child
            .try_wait()
            .unwrap()
            .is_some_and(|s| s.success()),
        "a tracker stopped while starting exits 0"
    );

    // 1. The tracker waiting for a camera that never comes.
    let mut track = spawn(&["--log", "info", "track", "--config", cfg]);
    assert!(track.wait_for("tracker ready", START), "tracker not ready");
    std::thread::sleep(Duration::from_millis(300));
    assert_quick_exit("star track, waiting for frames", &mut track, libc::SIGTERM);
    assert!(
        track.child.try_wait().unwrap().is_some_and(|s| s.success()),
        "an idle tracker stopped by SIGTERM exits 0"
    );

    // 2. `star run` in a long gap between replay stamps.
    let gap = gap_dataset(dir.path());
    let est = dir.path().join("gap_est.txt");
    let src = format!("replay:{}", gap.display());
    let mut run = spawn(&[
        "--log",
        "info",
        "run",
        "--config",
        cfg,
        "--source",
        &src,
        "--trajectory",
        est.to_str().unwrap(),
    ]);
    assert!(run.wait_for("tracker ready", START), "star run not ready");
    assert!(
        run.wait_for("no camera frames", Duration::from_secs(30)),
        "star run never reached the gap; stderr:\n{}",
        run.drain_log()
    );
    assert_quick_exit("star run, in a gap of the replay", &mut run, libc::SIGTERM);
    let out = run.stdout();
    assert!(out.contains("track: wrote"), "{out}");
    assert!(trajectory_lines(&est) > 0, "{out}");

    // 3. `star run` replaying at 0.01x: a frame every 2 s.
    let slow = format!("{cfg}.slow.toml");
    let text = std::fs::read_to_string(cfg).unwrap();
    std::fs::write(&slow, format!("[camera]\nreplay_speed = 0.01\n{text}")).unwrap();
    let src = format!("replay:{}", common::star_cli::dataset().display());
    let mut run = spawn(&["--log", "info", "run", "--config", &slow, "--source", &src]);
    assert!(run.wait_for("camera opened", START), "slow run not started");
    std::thread::sleep(Duration::from_millis(700));
    assert_quick_exit("star run, replay at 0.01x", &mut run, libc::SIGTERM);

    // 4. `star camera` alone, replaying at 0.01x.
    let mut camera = spawn(&[
        "--log", "info", "camera", "--config", &slow, "--source", &src,
    ]);
    assert!(
        camera.wait_for("camera opened", START),
        "camera not started"
    );
    std::thread::sleep(Duration::from_millis(700));
    assert_quick_exit("star camera, replay at 0.01x", &mut camera, libc::SIGTERM);
    assert!(
        camera
            .child
            .try_wait()
            .unwrap()
            .is_some_and(|s| s.success()),
        "star camera stopped by SIGTERM exits 0"
    );
}

#[test]
fn hup_quit_and_usr1_stop_gracefully_with_the_trajectory_flushed() {
    let dir = tempfile::tempdir().unwrap();
    let gap = gap_dataset(dir.path());
    let src = format!("replay:{}", gap.display());
    for (name, signal) in [
        ("SIGHUP", libc::SIGHUP),
        ("SIGQUIT", libc::SIGQUIT),
        ("SIGUSR1", libc::SIGUSR1),
    ] {
        let tag = format!("sig{signal}");
        let _cleanup = common::Cleanup(common::prefix(&tag));
        let cfg = config(dir.path(), &tag, "");
        let est = dir.path().join(format!("est_{signal}.txt"));
        let mut run = spawn(&[
            "--log",
            "info",
            "run",
            "--config",
            cfg.to_str().unwrap(),
            "--source",
            &src,
            "--trajectory",
            est.to_str().unwrap(),
        ]);
        assert!(run.wait_for("tracker ready", START), "{name}: not ready");
        assert!(
            run.wait_for("no camera frames", Duration::from_secs(30)),
            "{name}: never reached the gap; stderr:\n{}",
            run.drain_log()
        );
        let log = assert_quick_exit(&format!("star run, {name}"), &mut run, signal);
        let status = run.child.try_wait().unwrap().unwrap();
        let out = run.stdout();
        assert!(status.success(), "{name}: {status}\n{out}\n{log}");
        // "track: frames processed N  tracked T (..)" and "wrote W poses".
        let tracked: usize = out
            .split("tracked ")
            .nth(1)
            .and_then(|s| s.split_whitespace().next())
            .and_then(|s| s.parse().ok())
            .unwrap_or_else(|| panic!("{name}: no tracked count in {out}"));
        let wrote: usize = out
            .split("wrote ")
            .nth(1)
            .and_then(|s| s.split_whitespace().next())
            .and_then(|s| s.parse().ok())
            .unwrap_or_else(|| panic!("{name}: no pose count in {out}"));
        let lines = trajectory_lines(&est);
        println!("{name}: tracked {tracked}, wrote {wrote}, file holds {lines}");
        assert!(tracked > 0, "{name}: {out}");
        assert_eq!(wrote, tracked, "{name}: {out}");
        assert_eq!(lines, tracked, "{name}: the file lost poses\n{out}");
    }
}
