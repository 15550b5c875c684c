//! Running the `star` binary in tests: a synthetic dataset made once per
//! test process, copies of it with broken frames, an isolated star config
//! that tracks it, and spawning with stderr forwarded to a channel.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Output, Stdio};
use std::sync::mpsc;
use std::sync::OnceLock;
use std::time::{Duration, Instant};

/// The binary under test.
pub const STAR: &str = env!("CARGO_BIN_EXE_star");

/// Runs `star ARGS` to completion.
pub fn star(args: &[&str]) -> Output {
    Command::new(STAR).args(args).output().expect("run star")
}

/// A 60-frame synthetic sequence (50 Hz, stamps from 1000 s), made once per
/// test process in the target's temporary folder (one per test binary,
/// replaced by the next run, so runs do not pile up copies in /tmp).
pub fn dataset() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let dir = Path::new(env!("CARGO_TARGET_TMPDIR"))
            .join(format!("star_cli_ds_{}", env!("CARGO_CRATE_NAME")));
        let _ = std::fs::remove_dir_all(&dir);
        let o = star(&[
            "--log",
            "warn",
            "synth",
            "--preset",
            "realistic",
            dir.to_str().unwrap(),
            "--frames",
            "60",
            "--seed",
            "3",
            "--no-depth",
        ]);
        assert!(
            o.status.success(),
            "synth: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        dir
    })
}

/// `star synth --no-depth --preset PRESET --seed SEED --frames FRAMES OUT`,
/// which must succeed.
pub fn synth_no_depth(out: &Path, preset: &str, seed: u64, frames: usize) {
    let status = Command::new(STAR)
        .args(["synth", "--no-depth", "--preset", preset])
        .args(["--seed", &seed.to_string(), "--frames", &frames.to_string()])
        .arg(out)
        .env("RUST_LOG", "warn")
        .status()
        .expect("run star synth");
    assert!(status.success(), "star synth --preset {preset} failed");
}

/// The frame lines of `rgb.txt`: `(timestamp text, relative path)`.
pub fn frame_lines(ds: &Path) -> Vec<(String, String)> {
    std::fs::read_to_string(ds.join("rgb.txt"))
        .unwrap()
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .map(|l| {
            let mut t = l.split_whitespace();
            (t.next().unwrap().to_string(), t.next().unwrap().to_string())
        })
        .collect()
}

/// A copy of [`dataset`] in `dir`: camera, ground truth and map linked, the
/// frames linked one by one, and `rgb.txt` rewritten with `stamp(i, t)` as
/// the stamp of frame `i` (originally `t` seconds). Returns the copy and the
/// frames' paths in the copy, for the caller to break.
pub fn dataset_copy(dir: &Path, stamp: impl Fn(usize, f64) -> f64) -> (PathBuf, Vec<PathBuf>) {
    let src = dataset();
    let ds = dir.join("ds");
    std::fs::create_dir_all(ds.join("rgb")).unwrap();
    for name in ["camera.toml", "groundtruth.txt", "map"] {
        std::os::unix::fs::symlink(src.join(name), ds.join(name)).unwrap();
    }
    let mut list = String::from("# timestamp filename\n");
    let mut frames = Vec::new();
    for (i, (t, rel)) in frame_lines(src).into_iter().enumerate() {
        std::os::unix::fs::symlink(src.join(&rel), ds.join(&rel)).unwrap();
        let t: f64 = t.parse().unwrap();
        list.push_str(&format!("{:.6} {rel}\n", stamp(i, t)));
        frames.push(ds.join(&rel));
    }
    std::fs::write(ds.join("rgb.txt"), list).unwrap();
    (ds, frames)
}

/// A star config in `dir` that tracks [`dataset`] (first ground-truth pose
/// as the hint, MAVLink off) on the iceoryx2 prefix of `tag`, plus `extra`.
pub fn config(dir: &Path, tag: &str, extra: &str) -> PathBuf {
    config_with_mavlink(dir, tag, extra, "enabled = false")
}

/// [`config`] with `mavlink` as the body of its `[mavlink]` section.
pub fn config_with_mavlink(dir: &Path, tag: &str, extra: &str, mavlink: &str) -> PathBuf {
    let ds = dataset();
    let cam = std::fs::read_to_string(ds.join("camera.toml")).unwrap();
    let cam: String = cam
        .lines()
        .filter(|l| !l.starts_with("depth_scale"))
        .map(|l| l.replace("[distortion]", "[camera.intrinsics.distortion]") + "\n")
        .collect();
    let gt = std::fs::read_to_string(ds.join("groundtruth.txt")).unwrap();
    let line = gt.lines().find(|l| !l.starts_with('#')).unwrap();
    let init: Vec<f64> = line
        .split_whitespace()
        .skip(1)
        .map(|v| v.parse().unwrap())
        .collect();
    let text = format!(
        "{extra}\n[map]\nmesh = \"{}\"\n[mavlink]\n{mavlink}\n[tracker]\ninit_pose = {init:?}\n[camera.intrinsics]\n{cam}",
        ds.join("map/map.obj").display()
    );
    super::write_isolated_configs(dir, tag, &text)
}

/// A spawned `star` with its stderr lines on a channel (and kept).
pub struct Running {
    /// The process.
    pub child: Child,
    /// Its stderr, line by line.
    pub log: mpsc::Receiver<String>,
    /// Every stderr line read so far by [`Running::wait_for`].
    pub seen: Vec<String>,
}

/// Spawns `star ARGS`, stdout piped, stderr forwarded to [`Running::log`].
pub fn spawn(args: &[&str]) -> Running {
    let (child, log) = spawn_logged(args);
    Running {
        child,
        log,
        seen: Vec::new(),
    }
}

/// Spawns `star ARGS`, stdout piped, its stderr lines sent to the receiver
/// (the caller owns the process).
pub fn spawn_logged(args: &[&str]) -> (Child, mpsc::Receiver<String>) {
    let mut child = Command::new(STAR)
        .args(args)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .env("NO_COLOR", "1")
        .spawn()
        .expect("spawn star");
    let (tx, rx) = mpsc::channel();
    let err = child.stderr.take().unwrap();
    std::thread::spawn(move || {
        for line in BufReader::new(err).lines().map_while(Result::ok) {
            if tx.send(line).is_err() {
                break;
            }
        }
    });
    (child, rx)
}

impl Running {
    /// Waits up to `timeout` for a stderr line containing `needle`.
    pub fn wait_for(&mut self, needle: &str, timeout: Duration) -> bool {
        let end = Instant::now() + timeout;
        while let Some(left) = end.checked_duration_since(Instant::now()) {
            match self.log.recv_timeout(left) {
                Ok(line) => {
                    let hit = line.contains(needle);
                    self.seen.push(line);
                    if hit {
                        return true;
                    }
                }
                Err(_) => return false,
            }
        }
        false
    }

    /// Sends `signal` and returns the exit status and how long the exit
    /// took; kills the process and panics after `guard`.
    pub fn signal_and_wait(&mut self, signal: i32, guard: Duration) -> (ExitStatus, Duration) {
        let sent = Instant::now();
        // SAFETY: signalling our own child.
        unsafe { libc::kill(self.child.id() as i32, signal) };
        self.wait_timeout(guard, sent)
    }

    /// Waits for the exit (polling every 2 ms), timing from `since`; kills
    /// the process and panics after `guard`.
    pub fn wait_timeout(&mut self, guard: Duration, since: Instant) -> (ExitStatus, Duration) {
        loop {
            if let Some(status) = self.child.try_wait().unwrap() {
                return (status, since.elapsed());
            }
            if since.elapsed() > guard {
                let _ = self.child.kill();
                let _ = self.child.wait();
                panic!(
                    "star did not exit within {guard:?}; stderr so far:\n{}",
                    self.drain_log()
                );
            }
            std::thread::sleep(Duration::from_millis(2));
        }
    }

    /// Every stderr line: those seen so far and the rest of the channel.
    pub fn drain_log(&mut self) -> String {
        while let Ok(line) = self.log.recv_timeout(Duration::from_millis(200)) {
            self.seen.push(line);
        }
        self.seen.join("\n")
    }

    /// The whole stdout (call after the exit).
    pub fn stdout(&mut self) -> String {
        let mut out = String::new();
        if let Some(mut pipe) = self.child.stdout.take() {
            std::io::Read::read_to_string(&mut pipe, &mut out).unwrap();
        }
        out
    }
}

impl Drop for Running {
    fn drop(&mut self) {
        if let Ok(None) = self.child.try_wait() {
            let _ = self.child.kill();
            let _ = self.child.wait();
        }
    }
}

/// Data lines of a TUM trajectory file.
pub fn trajectory_lines(path: &Path) -> usize {
    std::fs::read_to_string(path)
        .unwrap_or_default()
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .count()
}
