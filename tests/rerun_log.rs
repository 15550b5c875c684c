//! Issue 23, the live view (cargo feature `rerun`): a short
//! `star localize --rerun save:FILE.rrd` run writes a recording that
//! Rerun's own decoder reads back, with every entity the module documents
//! and as many rows as frames, pictures and tracked poses.

#![cfg(feature = "rerun")]
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;

use common::star_cli::{dataset, star};

fn figure(stdout: &str, key: &str) -> usize {
    let at = stdout
        .find(&format!("{key} "))
        .unwrap_or_else(|| panic!("no `{key}` in:\n{stdout}"));
    stdout[at + key.len() + 1..]
        .split_whitespace()
        .next()
        .and_then(|w| w.parse().ok())
        .unwrap_or_else(|| panic!("no number after `{key}` in:\n{stdout}"))
}

#[test]
fn localize_rerun_save_writes_a_recording_with_the_entities_and_counts() {
    let dir = tempfile::tempdir().unwrap();
    let (est, rrd) = (dir.path().join("est.txt"), dir.path().join("x.rrd"));
    let o = star(&[
        "--log",
        "warn",
        "localize",
        dataset().to_str().unwrap(),
        "-o",
        est.to_str().unwrap(),
        "--rerun",
        &format!("save:{}", rrd.display()),
        "--rerun-every",
        "10",
    ]);
    let out = String::from_utf8_lossy(&o.stdout).into_owned();
    assert!(
        o.status.success(),
        "{out}\n{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let frames = figure(&out, "frames");
    let tracked = figure(&out, "tracked");
    assert_eq!(frames, 60, "{out}");
    assert!(out.contains("refused log calls 0"), "{out}");

    let counts = star::output::rerun_log::read_rrd_counts(&rrd).expect("read the recording");
    eprintln!("{counts:#?}");
    let count = |entity: &str| counts.get(entity).copied().unwrap_or(0);
    for scalar in [
        "inlier_ratio",
        "correlation",
        "iterations",
        "track_ms",
        "keyframe_age_ms",
        "state",
    ] {
        assert_eq!(count(&format!("/scalars/{scalar}")), frames, "{scalar}");
    }
    // Once: the map, the truth, the pinhole.
    assert_eq!(count("/world/map"), 1);
    assert_eq!(count("/world/ground_truth"), 1);
    // Every tracked frame's pose.
    assert_eq!(count("/world/camera"), tracked);
    // Pictures at frames 0, 10, ..., 50; the warped frame, the residual and
    // the points for those with a pose.
    let pictures = frames.div_ceil(10);
    assert_eq!(count("/frame/camera"), pictures);
    assert_eq!(count("/frame/keyframe"), pictures);
    let posed = count("/frame/residual");
    assert!((1..=pictures).contains(&posed), "{posed} residual pictures");
    assert_eq!(count("/frame/warped"), posed);
    assert_eq!(count("/world/points"), posed);
    // The camera image in 3D: the pinhole once and each picture.
    assert_eq!(count("/world/camera/image"), 1 + pictures);
    // The trajectory at each picture and at the end; the state changes.
    assert!(count("/world/trajectory") >= 2);
    assert!(count("/events") >= 1);
}
