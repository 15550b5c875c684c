//! Issue 23, the flight log and the plots, end to end on the `star`
//! binary over the 60-frame synthetic sequence (`star synth --preset
//! realistic --seed 3`, made once per test process):
//!
//! - `star localize --record` and `star run --record` write a `frames.csv`
//!   with one row per frame processed, a TUM `trajectory.txt` with one pose
//!   per pose output, and every Nth camera frame as a PNG;
//! - a free-space floor above the free space (a full disk) stops
//!   recording with a warning, and the run's own trajectory still comes out
//!   complete;
//! - a record folder that cannot be created fails at start, naming it;
//! - `star eval --plot` writes a PNG of the requested size that is not
//!   blank, and `--frames` prints the log's counts.

#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;

use std::path::Path;
use std::time::{Duration, Instant};

use common::star_cli::{config, dataset, spawn, star, trajectory_lines};

/// A run that has not ended by then is stuck.
const GUARD: Duration = Duration::from_secs(180);

/// Frames of [`dataset`].
const FRAMES: usize = 60;

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

/// The number after `key ` in a summary line of `stdout`.
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

/// Data lines of a CSV (the header excluded).
fn csv_rows(path: &Path) -> usize {
    std::fs::read_to_string(path)
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
        .lines()
        .skip(1)
        .filter(|l| !l.trim().is_empty())
        .count()
}

fn pngs(dir: &Path) -> usize {
    std::fs::read_dir(dir)
        .map(|entries| {
            entries
                .flatten()
                .filter(|e| e.path().extension().is_some_and(|x| x == "png"))
                .count()
        })
        .unwrap_or(0)
}

#[test]
fn localize_record_writes_one_row_per_frame_and_every_nth_frame() {
    let dir = tempfile::tempdir().unwrap();
    let (est, rec) = (dir.path().join("est.txt"), dir.path().join("rec"));
    let o = star(&[
        "--log",
        "warn",
        "localize",
        dataset().to_str().unwrap(),
        "-o",
        est.to_str().unwrap(),
        "--record",
        rec.to_str().unwrap(),
        "--record-every",
        "7",
        "--record-views",
    ]);
    let (out, err) = (text(&o.stdout), text(&o.stderr));
    assert!(o.status.success(), "stdout:\n{out}\nstderr:\n{err}");
    let frames = figure(&out, "frames");
    assert_eq!(frames, FRAMES, "{out}");
    assert_eq!(
        csv_rows(&rec.join("frames.csv")),
        frames,
        "one row per frame processed"
    );
    let tracked = figure(&out, "tracked");
    assert!(tracked > FRAMES / 2, "{out}");
    assert_eq!(trajectory_lines(&rec.join("trajectory.txt")), tracked);
    assert_eq!(trajectory_lines(&est), tracked);
    // Frames 0, 7, ..., 56: nine pictures, and a view strip for each one
    // that had a pose.
    assert_eq!(pngs(&rec.join("frames")), FRAMES.div_ceil(7));
    let views = pngs(&rec.join("views"));
    assert!(
        (1..=FRAMES.div_ceil(7)).contains(&views),
        "{views} view strips"
    );
    let frame0 = image::open(rec.join("frames/000000.png")).unwrap();
    let strip = image::open(rec.join("views/000000.png")).unwrap();
    assert_eq!(strip.height(), frame0.height());
    assert!(
        strip.width() > 4 * frame0.width(),
        "four panels side by side"
    );
    assert!(out.contains("dropped rows 0"), "{out}");

    // `star eval` reads the log back.
    let o = star(&[
        "eval",
        dataset().join("groundtruth.txt").to_str().unwrap(),
        est.to_str().unwrap(),
        "--frames",
        rec.to_str().unwrap(),
    ]);
    let out = text(&o.stdout);
    assert!(o.status.success(), "{out}\n{}", text(&o.stderr));
    assert!(
        out.contains(&format!("frames {FRAMES}  tracking {tracked}")),
        "{out}"
    );
    assert!(out.contains(&format!("poses sent {tracked}")), "{out}");
}

#[test]
fn run_record_writes_one_row_per_frame_processed() {
    let _cleanup = common::Cleanup(common::prefix("flightlog"));
    let dir = tempfile::tempdir().unwrap();
    let cfg = config(dir.path(), "flightlog", "[record]\nevery_n_frames = 20\n");
    let rec = dir.path().join("rec");
    let src = format!("replay:{}", dataset().display());
    let mut run = spawn(&[
        "--log",
        "warn",
        "run",
        "--config",
        cfg.to_str().unwrap(),
        "--source",
        &src,
        "--record",
        rec.to_str().unwrap(),
    ]);
    let (status, _) = run.wait_timeout(GUARD, Instant::now());
    let err = run.drain_log();
    let out = run.stdout();
    assert!(status.success(), "stdout:\n{out}\nstderr:\n{err}");
    let processed = figure(&out, "frames processed");
    let tracked = figure(&out, "tracked");
    assert!(processed > 0 && tracked > 0, "{out}");
    assert_eq!(
        csv_rows(&rec.join("frames.csv")),
        processed,
        "one row per frame processed"
    );
    assert_eq!(trajectory_lines(&rec.join("trajectory.txt")), tracked);
    assert!(pngs(&rec.join("frames")) >= 1);
    let rows = star::output::read_frames_log(&rec).expect("frames.csv reads back");
    let sent = rows.iter().filter(|r| r.pose_sent).count();
    assert_eq!(sent, tracked);
    // MAVLink is off in this config: the MAVLink columns stay empty.
    assert!(rows
        .iter()
        .all(|r| r.mavlink_send_ns.is_none() && r.timesync_offset_ns.is_none()));
}

#[test]
fn a_full_disk_stops_recording_but_not_tracking() {
    let dir = tempfile::tempdir().unwrap();
    // A floor of 10^18 bytes: above the free space of any disk.
    let cfg = dir.path().join("star.toml");
    std::fs::write(&cfg, "[record]\nmin_free_mb = 1e12\n").unwrap();
    let (est, rec) = (dir.path().join("est.txt"), dir.path().join("rec"));
    let o = star(&[
        "--log",
        "warn",
        "localize",
        dataset().to_str().unwrap(),
        "--config",
        cfg.to_str().unwrap(),
        "-o",
        est.to_str().unwrap(),
        "--record",
        rec.to_str().unwrap(),
    ]);
    let (out, err) = (text(&o.stdout), text(&o.stderr));
    assert!(o.status.success(), "stdout:\n{out}\nstderr:\n{err}");
    assert!(
        err.contains("WARN") && err.contains("record.min_free_mb"),
        "no free-space warning:\n{err}"
    );
    assert!(out.contains("flight log stopped early"), "{out}");
    // Nothing was recorded...
    assert!(!rec.join("frames.csv").exists());
    assert_eq!(pngs(&rec.join("frames")), 0);
    // ...and the run itself was complete: every frame processed, every
    // tracked pose written.
    assert_eq!(figure(&out, "frames"), FRAMES, "{out}");
    let tracked = figure(&out, "tracked");
    assert!(tracked > FRAMES / 2, "{out}");
    assert_eq!(trajectory_lines(&est), tracked);
    assert!(
        out.contains(&format!("{FRAMES} rows not recorded")),
        "{out}"
    );
}

#[test]
fn a_record_folder_that_cannot_be_created_fails_at_start() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("a_file");
    std::fs::write(&file, "not a folder").unwrap();
    let rec = file.join("rec");
    let est = dir.path().join("est.txt");
    let o = star(&[
        "--log",
        "warn",
        "localize",
        dataset().to_str().unwrap(),
        "-o",
        est.to_str().unwrap(),
        "--record",
        rec.to_str().unwrap(),
    ]);
    let err = text(&o.stderr);
    assert!(!o.status.success(), "{err}");
    assert!(
        err.contains("--record") && err.contains(rec.to_str().unwrap()),
        "the error names the folder: {err}"
    );
    assert!(!est.exists(), "failed before the run");
}

#[test]
fn eval_plot_writes_a_png_of_the_requested_size() {
    let dir = tempfile::tempdir().unwrap();
    let est = dir.path().join("est.txt");
    let o = star(&[
        "--log",
        "warn",
        "localize",
        dataset().to_str().unwrap(),
        "-o",
        est.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let plot = dir.path().join("plot.png");
    let o = star(&[
        "eval",
        dataset().join("groundtruth.txt").to_str().unwrap(),
        est.to_str().unwrap(),
        "--plot",
        plot.to_str().unwrap(),
        "--plot-size",
        "900x500",
    ]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let image = image::open(&plot).expect("a PNG").to_rgb8();
    assert_eq!(image.dimensions(), (900, 500));
    // Not blank: the estimate's red, the rotation error's blue, text and
    // axes in black, the truth in gray.
    let count = |rgb: [u8; 3]| image.pixels().filter(|p| p.0 == rgb).count();
    assert!(count([214, 39, 40]) > 200, "estimate/translation red");
    assert!(count([31, 119, 180]) > 100, "rotation blue");
    assert!(count([0, 0, 0]) > 500, "axes and text");
    let white = count([255, 255, 255]);
    assert!(white < 900 * 500 * 98 / 100, "{white} white pixels");

    // A bad size is refused, naming it.
    let o = star(&[
        "eval",
        dataset().join("groundtruth.txt").to_str().unwrap(),
        est.to_str().unwrap(),
        "--plot",
        plot.to_str().unwrap(),
        "--plot-size",
        "900by500",
    ]);
    assert!(!o.status.success());
    assert!(text(&o.stderr).contains("900by500"), "{}", text(&o.stderr));
}

/// Without the `rerun` feature, `--rerun` is refused at start, saying how
/// to get it (with it, `tests/rerun_log.rs` runs it).
#[cfg(not(feature = "rerun"))]
#[test]
fn rerun_without_the_feature_is_refused_naming_it() {
    let dir = tempfile::tempdir().unwrap();
    let est = dir.path().join("est.txt");
    let o = star(&[
        "localize",
        dataset().to_str().unwrap(),
        "-o",
        est.to_str().unwrap(),
        "--rerun",
        "save:x.rrd",
    ]);
    let err = text(&o.stderr);
    assert!(!o.status.success(), "{err}");
    assert!(err.contains("--features rerun"), "{err}");
    let o = star(&["localize", dataset().to_str().unwrap(), "--rerun", "udp:x"]);
    assert!(text(&o.stderr).contains("expected save:FILE.rrd or connect:"));
}
