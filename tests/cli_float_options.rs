//! Probes of issue 24's float options: `star camera --speed 1e-6` ignored
//! SIGTERM and `--speed 1e-300` played at full speed; `star track
//! --idle-exit-s 1e20` panicked converting to a Duration. Each bad value is
//! now refused at start, naming the option, its bounds and the value, and
//! nothing panics.

#![allow(clippy::expect_used, clippy::unwrap_used)] // test code: a failed step should panic

mod common;

use common::star_cli::{dataset, star};

fn refused(args: &[&str], option: &str, value_shown: &str) {
    let out = star(args);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{args:?} was accepted");
    assert_ne!(out.status.code(), Some(101), "{args:?} panicked: {stderr}");
    assert!(!stderr.contains("panicked"), "{args:?}: {stderr}");
    assert!(
        stderr.contains(option) && stderr.contains("must be within"),
        "{args:?}: the error should name {option} and its bounds: {stderr}"
    );
    assert!(
        stderr.contains(value_shown),
        "{args:?}: the error should show the value as {value_shown}: {stderr}"
    );
}

#[test]
fn replay_speeds_out_of_bounds_are_refused() {
    let source = format!("replay:{}", dataset().display());
    let dir = tempfile::tempdir().expect("tmp");
    let config = dir.path().join("star.toml");
    std::fs::write(&config, "# built-in defaults\n").expect("config");
    let config = config.to_str().unwrap();
    for (speed, shown) in [
        ("1e-6", "1e-6"),
        ("1e-300", "1e-300"),
        ("-1", "-1"),
        ("0", "0"),
        ("NaN", "NaN"),
        ("inf", "inf"),
        ("1e300", "1e300"),
    ] {
        let speed_arg = format!("--speed={speed}");
        refused(
            &[
                "--log", "error", "camera", "--config", config, "--source", &source, &speed_arg,
            ],
            "--speed",
            shown,
        );
        refused(
            &[
                "--log",
                "error",
                "replay",
                &speed_arg,
                dataset().to_str().unwrap(),
                "--to",
                "/dev/video99",
            ],
            "--speed",
            shown,
        );
    }
}

#[test]
fn idle_exit_times_out_of_bounds_are_refused() {
    let dir = tempfile::tempdir().expect("tmp");
    let config = dir.path().join("star.toml");
    let mesh = dataset().join("map").join("map.obj");
    std::fs::write(
        &config,
        format!("[map]\nmesh = {:?}\n", mesh.display().to_string()),
    )
    .expect("config");
    for (idle, shown) in [
        ("1e20", "1e20"),
        ("0", "0"),
        ("-3", "-3"),
        ("NaN", "NaN"),
        ("inf", "inf"),
    ] {
        let idle_arg = format!("--idle-exit-s={idle}");
        refused(
            &[
                "--log",
                "error",
                "track",
                "--config",
                config.to_str().unwrap(),
                &idle_arg,
            ],
            "--idle-exit-s",
            shown,
        );
    }
}
