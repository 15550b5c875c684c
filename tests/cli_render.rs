//! `star render` end to end: an OBJ quad at 2 m rendered to an 8-bit gray
//! PNG and a 16-bit millimeter depth PNG; bad arguments give clear errors.

#![allow(clippy::expect_used, clippy::unwrap_used)]

use std::path::Path;
use std::process::Command;

fn star() -> Command {
    Command::new(env!("CARGO_BIN_EXE_star"))
}

/// A 2 x 2 m quad at z = 2 m with vertex color 0.5 gray.
fn write_quad(dir: &Path) -> std::path::PathBuf {
    let path = dir.join("quad.obj");
    std::fs::write(
        &path,
        "v -1 -1 2 0.5 0.5 0.5\nv 1 -1 2 0.5 0.5 0.5\nv 1 1 2 0.5 0.5 0.5\nv -1 1 2 0.5 0.5 0.5\n\
         f 1 2 3\nf 1 3 4\n",
    )
    .expect("write obj");
    path
}

#[test]
fn renders_gray_and_depth_pngs() {
    let dir = tempfile::tempdir().expect("tempdir");
    let obj = write_quad(dir.path());
    let (gray_png, depth_png) = (dir.path().join("gray.png"), dir.path().join("depth.png"));
    let out = star()
        .args(["render", "--map"])
        .arg(&obj)
        .args(["--pose", "0 0 0 0 0 0 1", "--width", "64", "--height", "48"])
        .args([
            "--fx", "20", "--fy", "20", "--cx", "31.5", "--cy", "23.5", "-o",
        ])
        .arg(&gray_png)
        .arg("--depth-out")
        .arg(&depth_png)
        .output()
        .expect("run star");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let gray = image::open(&gray_png).expect("gray png").into_luma8();
    assert_eq!(gray.dimensions(), (64, 48));
    // The quad spans 20 x 20 px around the principal point.
    let center = gray.get_pixel(31, 23)[0];
    assert!((126..=129).contains(&center), "center gray {center}");
    assert_eq!(gray.get_pixel(0, 0)[0], 0);
    let depth = image::open(&depth_png).expect("depth png").into_luma16();
    assert_eq!(depth.get_pixel(31, 23)[0], 2000, "2 m in millimeters");
    assert_eq!(depth.get_pixel(0, 0)[0], 0, "no surface");
}

#[test]
fn bad_arguments_are_clear_errors() {
    let dir = tempfile::tempdir().expect("tempdir");
    let obj = write_quad(dir.path());
    let run = |pose: &str, extra: &[&str]| {
        let out = star()
            .args(["render", "--map"])
            .arg(&obj)
            .args(["--pose", pose, "-o"])
            .arg(dir.path().join("x.png"))
            .args(extra)
            .output()
            .expect("run star");
        assert!(!out.status.success());
        String::from_utf8_lossy(&out.stderr).into_owned()
    };
    assert!(run("0 0 0 0 0 1", &[]).contains("expected 7"));
    assert!(run("0 0 0 0 0 zero 1", &[]).contains("not a number"));
    assert!(run("0 0 0 0 0 0 0", &[]).contains("zero quaternion"));
    assert!(run("0 0 0 0 0 0 1", &["--width", "0"]).contains("width"));
    let missing = star()
        .args([
            "render",
            "--map",
            "/nonexistent/map.obj",
            "--pose",
            "0 0 0 0 0 0 1",
            "-o",
        ])
        .arg(dir.path().join("x.png"))
        .output()
        .expect("run star");
    assert!(String::from_utf8_lossy(&missing.stderr).contains("/nonexistent/map.obj"));
}
