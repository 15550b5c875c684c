//! Issue 24, exit status and blocking reads: a run whose source failed (a
//! replay frame missing, truncated, of the wrong size, or a FIFO that would
//! block the reader forever) or that tracked nothing exits non-zero, at
//! once, with a message naming the file and saying why.

#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use common::star_cli::{config, dataset_copy, spawn};

/// A run that has not ended by then is stuck (a FIFO read, a sleep).
const GUARD: Duration = Duration::from_secs(120);
/// The frame the tests break (frames before it track).
const BROKEN: usize = 5;

/// Runs `star ARGS` with the hang guard; returns (success, stdout, stderr).
fn run_guarded(args: &[&str]) -> (bool, String, String) {
    let mut run = spawn(args);
    let (status, _) = run.wait_timeout(GUARD, Instant::now());
    let err = run.drain_log();
    (status.success(), run.stdout(), err)
}

fn star_run(dir: &Path, tag: &str, ds: &Path, extra: &[&str]) -> (bool, String, String) {
    let _cleanup = common::Cleanup(common::prefix(tag));
    let cfg = config(dir, tag, "");
    let src = format!("replay:{}", ds.display());
    let mut args = vec![
        "--log",
        "warn",
        "run",
        "--config",
        cfg.to_str().unwrap(),
        "--source",
        &src,
    ];
    args.extend_from_slice(extra);
    run_guarded(&args)
}

fn localize(dir: &Path, ds: &Path) -> (bool, String, String) {
    let est = dir.join("est.txt");
    run_guarded(&[
        "--log",
        "warn",
        "localize",
        ds.to_str().unwrap(),
        "--max-frames",
        "10",
        "-o",
        est.to_str().unwrap(),
    ])
}

/// Replaces a frame file (already removed) with something broken.
type Breaker<'a> = Box<dyn Fn(&Path) + 'a>;

/// A copy of the dataset whose frame [`BROKEN`] is replaced by `breaker`.
fn broken(dir: &Path, breaker: impl Fn(&Path)) -> (PathBuf, PathBuf) {
    let (ds, frames) = dataset_copy(dir, |_, t| t);
    let frame = frames[BROKEN].clone();
    std::fs::remove_file(&frame).unwrap();
    breaker(&frame);
    (ds, frame)
}

fn expect_failure(what: &str, result: &(bool, String, String), needles: &[&str]) {
    let (ok, out, err) = result;
    assert!(!ok, "{what}: exited 0\nstdout:\n{out}\nstderr:\n{err}");
    for needle in needles {
        assert!(
            err.contains(needle),
            "{what}: stderr does not say `{needle}`:\n{err}"
        );
    }
}

#[test]
fn a_fifo_frame_is_refused_naming_it() {
    let dir = tempfile::tempdir().unwrap();
    let (ds, fifo) = broken(dir.path(), |path| {
        let c = std::ffi::CString::new(path.to_str().unwrap()).unwrap();
        // SAFETY: mkfifo with a valid C string.
        assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o644) }, 0);
    });
    let fifo = fifo.to_str().unwrap();
    expect_failure(
        "star localize",
        &localize(dir.path(), &ds),
        &[fifo, "FIFO, not a regular file"],
    );
    expect_failure(
        "star run",
        &star_run(dir.path(), "fiforun", &ds, &[]),
        &[fifo, "FIFO, not a regular file", "camera source failed"],
    );
}

#[test]
fn missing_truncated_and_wrong_size_frames_fail_the_run() {
    let dir = tempfile::tempdir().unwrap();
    let original = common::star_cli::dataset()
        .join(&common::star_cli::frame_lines(common::star_cli::dataset())[BROKEN].1);
    let cases: [(&str, Breaker, &str); 3] = [
        ("missing", Box::new(|_: &Path| {}), "missing file"),
        (
            "truncated",
            Box::new(|path: &Path| {
                let bytes = std::fs::read(&original).unwrap();
                std::fs::write(path, &bytes[..bytes.len() / 2]).unwrap();
            }),
            "cannot decode",
        ),
        (
            "wrong size",
            Box::new(|path: &Path| {
                image::GrayImage::from_pixel(32, 24, image::Luma([128]))
                    .save(path)
                    .unwrap();
            }),
            "32x24",
        ),
    ];
    for (i, (what, breaker, says)) in cases.iter().enumerate() {
        let sub = dir.path().join(format!("case{i}"));
        std::fs::create_dir_all(&sub).unwrap();
        let (ds, frame) = broken(&sub, breaker);
        let frame = frame.to_str().unwrap();
        expect_failure(
            &format!("star run, {what} frame"),
            &star_run(&sub, &format!("bad{i}"), &ds, &[]),
            &[frame, says, "camera source failed"],
        );
        expect_failure(
            &format!("star localize, {what} frame"),
            &localize(&sub, &ds),
            &[frame, "could not be used"],
        );
    }
}

#[test]
fn every_frame_missing_or_nothing_tracked_fails() {
    let dir = tempfile::tempdir().unwrap();
    let (ds, frames) = dataset_copy(dir.path(), |_, t| t);
    let none = dir.path().join("none");
    std::fs::create_dir_all(&none).unwrap();
    let (empty, empty_frames) = dataset_copy(&none, |_, t| t);
    for f in &empty_frames {
        std::fs::remove_file(f).unwrap();
    }
    let first = empty_frames[0].to_str().unwrap();
    expect_failure(
        "star run, every frame missing",
        &star_run(&none, "nofr", &empty, &[]),
        &[first, "missing file"],
    );
    expect_failure(
        "star localize, every frame missing",
        &localize(&none, &empty),
        &[first, "could not be used"],
    );
    // Every frame is there, but the start pose is far outside the room:
    // the start is never verified and nothing is tracked.
    assert!(frames.iter().all(|f| f.exists()));
    let far = star_run(
        dir.path(),
        "far",
        &ds,
        &["--init-pose", "40 40 40 0 0 0 1", "--frames", "20"],
    );
    expect_failure("star run from a wrong start", &far, &["tracked nothing"]);
}
