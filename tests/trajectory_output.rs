//! Probes of issue 24's trajectory rows: `--trajectory` into a missing
//! directory used to fail only after the whole run, losing it; SIGKILL
//! mid-flight used to leave no trajectory file (about 300 poses lost). The
//! path is now created at start, and poses are streamed to the file and
//! flushed each second, so a killed run loses at most a second.

#![allow(clippy::expect_used, clippy::unwrap_used)] // test code: a failed step should panic

mod common;

use std::time::{Duration, Instant};

use common::star_cli::{config, dataset, spawn, star};

/// Data lines of a TUM trajectory file (0 when it does not exist).
fn poses_in(path: &std::path::Path) -> usize {
    std::fs::read_to_string(path)
        .unwrap_or_default()
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .count()
}

#[test]
fn a_trajectory_into_a_missing_directory_fails_at_start() {
    let dir = tempfile::tempdir().expect("tmp");
    let cfg = config(dir.path(), "trajmissing", "");
    let missing = dir.path().join("no").join("such").join("est.txt");
    let src = format!("replay:{}", dataset().display());
    let started = Instant::now();
    let out = star(&[
        "--log",
        "info",
        "run",
        "--config",
        cfg.to_str().unwrap(),
        "--source",
        &src,
        "--trajectory",
        missing.to_str().unwrap(),
    ]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success(),
        "a run into a missing directory succeeded"
    );
    assert!(
        stderr.contains("--trajectory") && stderr.contains("no/such/est.txt"),
        "the error should name the option and the path: {stderr}"
    );
    assert!(
        !stderr.contains("tracker ready"),
        "the tracker started before the path was checked: {stderr}"
    );
    eprintln!("refused after {:?}", started.elapsed());
}

#[test]
fn sigkill_loses_at_most_a_second_of_poses() {
    let dir = tempfile::tempdir().expect("tmp");
    // 0.2x: a frame every 0.1 s, so the run is still going when killed.
    let cfg = config(dir.path(), "trajkill", "[camera]\nreplay_speed = 0.2\n");
    let est = dir.path().join("est.txt");
    let src = format!("replay:{}", dataset().display());
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
    assert!(
        run.wait_for("tracker ready", Duration::from_secs(120)),
        "star run not ready"
    );
    // The file gets its first poses within a second of the first pose.
    let end = Instant::now() + Duration::from_secs(60);
    while poses_in(&est) == 0 {
        assert!(Instant::now() < end, "no pose reached the file");
        std::thread::sleep(Duration::from_millis(20));
    }
    let kept_s = 3.0;
    std::thread::sleep(Duration::from_secs_f64(kept_s));
    unsafe {
        // SAFETY: a plain kill(2) of our own child.
        libc::kill(run.child.id() as i32, libc::SIGKILL);
    }
    let status = run.child.wait().expect("wait");
    assert!(!status.success(), "killed by SIGKILL");
    // At 10 frames/s, at least 10 * kept_s poses were made after the file
    // got its first; at most a second of them (10) may be lost, plus a
    // margin of 5 for frames a loaded machine took late.
    let written = poses_in(&est);
    let made_at_least = (10.0 * kept_s) as usize;
    assert!(
        written + 10 + 5 >= made_at_least,
        "{written} poses in the file after SIGKILL, at least {made_at_least} made"
    );
    assert!(
        written < 60,
        "{written} poses: more than the dataset's 60 frames"
    );
}

/// Stamps of a TUM trajectory file, seconds.
fn stamps_in(path: &std::path::Path) -> Vec<f64> {
    std::fs::read_to_string(path)
        .unwrap_or_default()
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .filter_map(|l| l.split_whitespace().next()?.parse().ok())
        .collect()
}

/// `[keyframe] hold_for_next_frame` in the service (`star run`): each pose
/// goes out with the next frame, at its own stamp, and the last frame,
/// which no frame confirms, is not sent.
#[test]
fn the_service_holds_each_pose_for_the_next_frame() {
    let dir = tempfile::tempdir().expect("tmp");
    let src = format!("replay:{}", dataset().display());
    // 0.5x: the tracker keeps up with every frame.
    let run = |tag: &str, extra: &str| {
        let cfg = config(
            dir.path(),
            tag,
            &format!("{extra}\n[camera]\nreplay_speed = 0.5\n"),
        );
        let est = dir.path().join(format!("{tag}.txt"));
        let out = star(&[
            "--log",
            "info",
            "run",
            "--config",
            cfg.to_str().unwrap(),
            "--source",
            &src,
            "--trajectory",
            est.to_str().unwrap(),
            "--idle-exit-s",
            "1",
        ]);
        let stdout = String::from_utf8_lossy(&out.stdout).to_string();
        assert!(
            out.status.success(),
            "{tag}: {stdout}\n{}",
            String::from_utf8_lossy(&out.stderr)
        );
        (stamps_in(&est), stdout)
    };
    let (plain, plain_out) = run("holdoff", "");
    let (held, held_out) = run("holdon", "[keyframe]\nhold_for_next_frame = true\n");
    assert!(plain.len() >= 50, "the plain run tracked: {plain_out}");
    assert!(
        !plain_out.contains("held for the next frame"),
        "{plain_out}"
    );
    let line = held_out
        .lines()
        .find(|l| l.contains("poses held for the next frame"))
        .unwrap_or_else(|| panic!("no hold line: {held_out}"));
    let withheld: usize = line
        .rsplit(": ")
        .next()
        .and_then(|r| r.split_whitespace().next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("cannot read {line}"));
    assert!(withheld >= 1, "the last frame is never confirmed: {line}");
    // Every pose goes out at a frame's own stamp, in order; never the
    // stream's last frame, which no frame follows.
    let frames = common::star_cli::frame_lines(dataset());
    let stamps: Vec<f64> = frames.iter().map(|(t, _)| t.parse().unwrap()).collect();
    assert!(held.len() >= 40, "the held run tracked: {held_out}");
    assert!(
        held.iter()
            .all(|s| stamps.iter().any(|t| (t - s).abs() < 1e-6)),
        "a pose at a stamp that is no frame's"
    );
    assert!(held.windows(2).all(|w| w[0] < w[1]), "poses out of order");
    let last = *stamps.last().expect("frames");
    assert!(
        held.iter().all(|s| (s - last).abs() > 1e-6),
        "the last frame's pose went out without a frame after it"
    );
    // The summary counts what went out: the poses in the file.
    let counts: Vec<u64> = held_out
        .lines()
        .find(|l| l.starts_with("track: frames processed"))
        .unwrap_or_else(|| panic!("no summary: {held_out}"))
        .split_whitespace()
        .filter_map(|w| w.parse().ok())
        .collect();
    let (processed, tracked, lost) = (counts[0], counts[1], counts[2]);
    assert_eq!(tracked as usize, held.len(), "{held_out}");
    assert_eq!(
        tracked + lost,
        processed,
        "every frame released once: {held_out}"
    );
}
