//! `star reloc build` on every core, interrupted and resumed (issue 22):
//! the database is the same, byte for byte, for any thread count, and a
//! build stopped part way (twice) then resumed from its checkpoint gives
//! the same database as an uninterrupted one.

#![allow(clippy::expect_used, clippy::unwrap_used)] // test code: a failed step should panic

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

use star::map::write_obj;
use star::reloc::RelocDatabase;

const STAR: &str = env!("CARGO_BIN_EXE_star");

struct Setup {
    dir: tempfile::TempDir,
    config: PathBuf,
    camera: PathBuf,
}

fn setup() -> Setup {
    let dir = tempfile::tempdir().expect("tmp");
    let mesh = common::room::textured_room();
    let obj = write_obj(&mesh, dir.path(), "room").expect("write");
    let camera = dir.path().join("camera.toml");
    std::fs::write(
        &camera,
        "width = 320\nheight = 256\nfx = 210.0\nfy = 210.0\ncx = 159.5\ncy = 127.5\n",
    )
    .expect("camera");
    // A coarse grid with landmark views: a quick build with every kind of
    // work unit, and landmarks to deduplicate and train a vocabulary on.
    let config = dir.path().join("star.toml");
    std::fs::write(
        &config,
        format!(
            "[map]\nmesh = {obj:?}\n\n[reloc]\ngrid_spacing_m = 1.0\nheights_m = [1.2]\nyaw_steps = 8\npitches_deg = [-10.0]\nlandmark_spacing_m = 1.0\nlandmark_heights_m = [1.2]\nlandmark_yaw_steps = 4\nfloor_z_m = 0.0\n"
        ),
    )
    .expect("config");
    Setup {
        dir,
        config,
        camera,
    }
}

impl Setup {
    fn build(&self, output: &Path, extra: &[&str]) -> String {
        let out = Command::new(STAR)
            .args(["--log", "error", "reloc", "build", "--config"])
            .arg(&self.config)
            .arg("--camera")
            .arg(&self.camera)
            .arg("-o")
            .arg(output)
            .args(extra)
            .output()
            .expect("run star");
        let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
        assert!(
            out.status.success(),
            "{stdout}\n{}",
            String::from_utf8_lossy(&out.stderr)
        );
        stdout
    }

    fn path(&self, name: &str) -> PathBuf {
        self.dir.path().join(name)
    }
}

#[test]
fn thread_count_and_interruptions_do_not_change_the_database() {
    let s = setup();
    let one = s.path("one.db");
    let said = s.build(&one, &["--threads", "1"]);
    assert!(said.contains("MB)"), "the size is reported: {said}");
    let reference = std::fs::read(&one).expect("read");
    let db = RelocDatabase::read(&one).expect("valid");
    assert!(!db.entries.is_empty() && db.landmarks.len() > 50);
    assert!(db.vocabulary.leaves.len() > 1, "a vocabulary was trained");

    let two = s.path("two.db");
    s.build(&two, &["--threads", "2"]);
    assert!(std::fs::read(&two).expect("read") == reference, "2 threads");

    // Interrupted after 5 units, then after 23 (on another thread count),
    // then resumed to the end.
    let cut = s.path("cut.db");
    let partial = s.path("cut.db.partial");
    let said = s.build(&cut, &["--threads", "2", "--stop-after-units", "5"]);
    assert!(said.contains("stopped after 5"), "{said}");
    assert!(!cut.exists() && partial.exists());
    s.build(&cut, &["--threads", "1", "--stop-after-units", "23"]);
    assert!(!cut.exists() && partial.exists());
    s.build(&cut, &["--resume"]);
    assert!(!partial.exists(), "the checkpoint is removed once written");
    assert!(std::fs::read(&cut).expect("read") == reference, "resumed");

    // `--resume` without a checkpoint is refused.
    let out = Command::new(STAR)
        .args(["--log", "error", "reloc", "build", "--resume", "--config"])
        .arg(&s.config)
        .arg("--camera")
        .arg(&s.camera)
        .arg("-o")
        .arg(s.path("none.db"))
        .output()
        .expect("run star");
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("none.db.partial"));
}
