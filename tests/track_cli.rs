//! `star track` as a process: bad config or map exits non-zero naming the
//! problem; SIGTERM while tracking exits cleanly (status 0, final stats
//! printed); the poses of the real tracker on a short synthetic sequence
//! reach a pymavlink autopilot stand-in with sane fields (reset_counter,
//! covariance, usec).

#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use serde_json::Value;

use common::star_cli::{dataset, spawn_logged as spawn, star, STAR};

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

#[test]
fn missing_config_exits_non_zero_naming_it() {
    let o = star(&["track", "--config", "/nonexistent/star.toml"]);
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("/nonexistent/star.toml"),
        "{}",
        stderr(&o)
    );
}

#[test]
fn invalid_config_and_missing_map_are_named() {
    let dir = tempfile::tempdir().unwrap();
    let bad = dir.path().join("bad.toml");
    std::fs::write(&bad, "[tracker]\npyramid_levelz = 3\n").unwrap();
    let o = star(&["track", "--config", bad.to_str().unwrap()]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("pyramid_levelz"), "{}", stderr(&o));

    let no_map = dir.path().join("nomap.toml");
    std::fs::write(&no_map, "[map]\nmesh = \"/nonexistent/map.obj\"\n").unwrap();
    let o = star(&["track", "--config", no_map.to_str().unwrap()]);
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("/nonexistent/map.obj"),
        "{}",
        stderr(&o)
    );

    let bad_pose = dir.path().join("pose.toml");
    std::fs::write(
        &bad_pose,
        "[tracker]\ninit_pose = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]\n",
    )
    .unwrap();
    let o = star(&["track", "--config", bad_pose.to_str().unwrap()]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("tracker.init_pose"), "{}", stderr(&o));
}

/// Star config for [`dataset`] with an isolated iceoryx2 prefix and
/// `mavlink` as its `[mavlink]` section.
fn configs(dir: &Path, tag: &str, mavlink: &str) -> PathBuf {
    common::star_cli::config_with_mavlink(dir, tag, "", mavlink)
}

fn wait_for(rx: &mpsc::Receiver<String>, needle: &str, timeout: Duration) -> bool {
    let end = Instant::now() + timeout;
    while let Some(left) = end.checked_duration_since(Instant::now()) {
        match rx.recv_timeout(left) {
            Ok(line) if line.contains(needle) => return true,
            Ok(_) => {}
            Err(_) => return false,
        }
    }
    false
}

#[test]
fn sigterm_while_tracking_exits_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    let tag = "sigterm";
    let _cleanup = common::Cleanup(common::prefix(tag));
    let config = configs(dir.path(), tag, "enabled = false");
    let cfg = config.to_str().unwrap();
    let (mut track, track_log) = spawn(&["--log", "info", "track", "--config", cfg]);
    assert!(
        wait_for(&track_log, "tracker ready", Duration::from_secs(60)),
        "tracker did not become ready"
    );
    let src = format!("replay:{}", dataset().display());
    let (mut camera, _camera_log) = spawn(&["camera", "--config", cfg, "--source", &src, "--loop"]);
    assert!(
        wait_for(&track_log, "tracking", Duration::from_secs(20)),
        "tracker never tracked"
    );
    std::thread::sleep(Duration::from_millis(500));
    // SAFETY: signalling our own child.
    unsafe { libc::kill(track.id() as i32, libc::SIGTERM) };
    // The deadline only keeps a tracker that ignores SIGTERM from hanging
    // the test; how fast it exits is not checked here.
    let end = Instant::now() + Duration::from_secs(30);
    let status = loop {
        if let Some(s) = track.try_wait().unwrap() {
            break s;
        }
        assert!(Instant::now() < end, "tracker did not exit after SIGTERM");
        std::thread::sleep(Duration::from_millis(10));
    };
    let _ = camera.kill();
    let _ = camera.wait();
    assert!(status.success(), "exit status {status}");
    let mut out = String::new();
    std::io::Read::read_to_string(&mut track.stdout.take().unwrap(), &mut out).unwrap();
    assert!(out.contains("track: frames processed"), "{out}");
}

#[test]
fn tracker_poses_decode_in_pymavlink() {
    let Some(python) = common::venv_tool("python") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let tag = "pymav";
    let _cleanup = common::Cleanup(common::prefix(tag));
    let port = std::net::UdpSocket::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let rx_out = dir.path().join("rx.jsonl");
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("hil_tests/mavlink_receiver.py");
    let mut receiver = Command::new(python)
        .arg(script)
        .args(["--listen", &format!("udpin:127.0.0.1:{port}")])
        .args(["--duration", "60"])
        .arg("--out")
        .arg(&rx_out)
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    let mut line = String::new();
    BufReader::new(receiver.stdout.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    assert_eq!(line.trim(), "ready");
    let config = configs(
        dir.path(),
        tag,
        &format!("connection = \"udpout:127.0.0.1:{port}\""),
    );
    let cfg = config.to_str().unwrap();
    let (mut track, track_log) = spawn(&[
        "--log",
        "info",
        "track",
        "--config",
        cfg,
        "--idle-exit-s",
        "1",
    ]);
    assert!(wait_for(
        &track_log,
        "tracker ready",
        Duration::from_secs(60)
    ));
    let src = format!("replay:{}", dataset().display());
    let camera = Command::new(STAR)
        .args(["camera", "--config", cfg, "--source", &src])
        .output()
        .unwrap();
    assert!(camera.status.success(), "camera: {}", stderr(&camera));
    let status = track.wait().unwrap();
    assert!(status.success());
    // SAFETY: signalling our own child (it writes its summary on SIGTERM).
    unsafe { libc::kill(receiver.id() as i32, libc::SIGTERM) };
    receiver.wait().unwrap();
    let records: Vec<Value> = std::fs::read_to_string(&rx_out)
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    let vpe: Vec<&Value> = records
        .iter()
        .filter(|r| r["kind"] == "rx" && r["type"] == "VISION_POSITION_ESTIMATE")
        .collect();
    // The rate is checked by the HIL nominal scenario; here other tests may
    // share the two cores, so frames can be dropped.
    assert!(vpe.len() >= 30, "{} poses of 60 frames", vpe.len());
    let mut last_usec = 0u64;
    for r in &vpe {
        let f = &r["fields"];
        assert_eq!(f["reset_counter"], 0, "{r}");
        let usec = f["usec"].as_u64().unwrap();
        assert!(usec > last_usec, "usec not increasing: {r}");
        last_usec = usec;
        let cov: Vec<f64> = f["covariance"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_f64().unwrap_or(f64::NAN))
            .collect();
        assert_eq!(cov.len(), 21);
        assert!(cov.iter().all(|v| v.is_finite()), "{r}");
        for d in [0, 6, 11, 15, 18, 20] {
            assert!(cov[d] > 0.0, "diagonal {d} not positive: {r}");
        }
        for k in ["x", "y", "z", "roll", "pitch", "yaw"] {
            assert!(f[k].as_f64().unwrap().is_finite(), "{r}");
        }
    }
    let summary = records.iter().find(|r| r["kind"] == "summary").unwrap();
    assert_eq!(summary["bad_data"], 0, "{summary}");
}

#[test]
fn star_run_tracks_a_replay_and_writes_the_trajectory() {
    let dir = tempfile::tempdir().unwrap();
    let tag = "run";
    let _cleanup = common::Cleanup(common::prefix(tag));
    let config = configs(dir.path(), tag, "enabled = false");
    let est = dir.path().join("est.txt");
    let src = format!("replay:{}", dataset().display());
    let o = star(&[
        "run",
        "--config",
        config.to_str().unwrap(),
        "--source",
        &src,
        "--trajectory",
        est.to_str().unwrap(),
    ]);
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{out}\n{}", stderr(&o));
    assert!(out.contains("camera: frames published 60"), "{out}");
    let o = star(&[
        "eval",
        dataset().join("groundtruth.txt").to_str().unwrap(),
        est.to_str().unwrap(),
    ]);
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{text}");
    // "matched N of M estimate poses": most frames tracked, dataset stamps.
    let matched: usize = text
        .split("matched ")
        .nth(1)
        .and_then(|s| s.split_whitespace().next())
        .and_then(|s| s.parse().ok())
        .unwrap_or(0);
    assert!(matched >= 40, "{text}");
    let ate_rmse_m: f64 = text
        .lines()
        .find(|l| l.starts_with("ATE translation"))
        .and_then(|l| l.split_whitespace().nth(4))
        .and_then(|s| s.parse().ok())
        .unwrap_or(f64::INFINITY);
    assert!(ate_rmse_m < 0.03, "{text}");
}

#[test]
fn star_track_notifies_systemd() {
    use std::os::unix::net::UnixDatagram;
    let dir = tempfile::tempdir().unwrap();
    let tag = "notify";
    let _cleanup = common::Cleanup(common::prefix(tag));
    let config = configs(dir.path(), tag, "enabled = false");
    let sock_path = dir.path().join("notify.sock");
    let socket = UnixDatagram::bind(&sock_path).unwrap();
    socket
        .set_read_timeout(Some(Duration::from_millis(50)))
        .unwrap();
    let mut track = Command::new(STAR)
        .args(["track", "--config", config.to_str().unwrap()])
        .env("NOTIFY_SOCKET", &sock_path)
        .env("WATCHDOG_USEC", "400000")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let src = format!("replay:{}", dataset().display());
    let mut camera: Option<Child> = None;
    let mut messages = Vec::new();
    let mut buf = [0u8; 4096];
    let end = Instant::now() + Duration::from_secs(60);
    while Instant::now() < end {
        if let Ok(n) = socket.recv(&mut buf) {
            messages.push(String::from_utf8_lossy(&buf[..n]).into_owned());
        }
        if camera.is_none() && messages.iter().any(|m| m.contains("READY=1")) {
            let c = Command::new(STAR)
                .args(["camera", "--config", config.to_str().unwrap()])
                .args(["--source", &src, "--loop"])
                .stderr(Stdio::null())
                .spawn()
                .unwrap();
            camera = Some(c);
        }
        if messages.iter().any(|m| m.contains("STATUS=tracking")) {
            break;
        }
    }
    // SAFETY: signalling our own child.
    unsafe { libc::kill(track.id() as i32, libc::SIGTERM) };
    let status = track.wait().unwrap();
    if let Some(mut c) = camera {
        let _ = c.kill();
        let _ = c.wait();
    }
    assert!(status.success());
    let all = messages.join("|");
    assert!(all.contains("READY=1"), "{all}");
    assert!(all.contains("STATUS=tracking"), "{all}");
    assert!(all.contains("fps, keyframe age"), "{all}");
    assert!(all.contains("WATCHDOG=1"), "{all}");
}
