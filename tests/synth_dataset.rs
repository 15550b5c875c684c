//! `star synth --preset realistic OUT` writes a dataset that third-party
//! tools accept: evo (`evo_traj tum OUT/groundtruth.txt`) loads the
//! trajectory and OpenCV decodes every image, 8-bit gray and 16-bit depth.
//! Bad arguments get a clear error.

#![allow(clippy::expect_used, clippy::unwrap_used)] // test code: a failed step should panic

mod common;

use std::process::Command;

const FRAMES: usize = 12;

fn star() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_star"));
    c.env("RUST_LOG", "warn");
    c
}

#[test]
fn realistic_dataset_loads_in_evo_and_opencv() {
    let Some(evo_traj) = common::venv_tool("evo_traj") else {
        return;
    };
    let python = evo_traj.with_file_name("python");
    let tmp = tempfile::tempdir().expect("tmp");
    let out = tmp.path().join("seq");
    let status = star()
        .args(["synth", "--preset", "realistic", "--seed", "5", "--frames"])
        .arg(FRAMES.to_string())
        .arg(&out)
        .status()
        .expect("run star synth");
    assert!(status.success());
    for f in [
        "camera.toml",
        "synth.toml",
        "rgb.txt",
        "depth.txt",
        "map/map.obj",
    ] {
        assert!(out.join(f).is_file(), "{f} missing");
    }

    let stdout = common::run_tool(
        &evo_traj,
        &["tum", out.join("groundtruth.txt").to_str().unwrap()],
        tmp.path(),
    );
    assert!(
        stdout.contains(&format!("{FRAMES} poses")),
        "evo_traj output: {stdout}"
    );

    let script = r##"
import sys, cv2
root = sys.argv[1]
for name, flag, dtype in (("rgb.txt", cv2.IMREAD_UNCHANGED, "uint8"), ("depth.txt", cv2.IMREAD_UNCHANGED, "uint16")):
    n = 0
    for line in open(f"{root}/{name}"):
        if line.startswith("#") or not line.strip():
            continue
        path = line.split()[1]
        img = cv2.imread(f"{root}/{path}", flag)
        assert img is not None, path
        assert img.shape == (512, 640), (path, img.shape)
        assert str(img.dtype) == dtype, (path, img.dtype)
        assert img.max() > img.min(), path
        n += 1
    print(name, n)
"##;
    let output = Command::new(&python)
        .arg("-c")
        .arg(script)
        .arg(&out)
        .output()
        .expect("run python");
    let text = String::from_utf8_lossy(&output.stdout);
    assert!(
        output.status.success(),
        "{text}\n{}",
        String::from_utf8_lossy(&output.stderr)
    );
    assert!(text.contains(&format!("rgb.txt {FRAMES}")), "{text}");
    assert!(text.contains(&format!("depth.txt {FRAMES}")), "{text}");
}

#[test]
fn bad_arguments_are_clear_errors() {
    let tmp = tempfile::tempdir().expect("tmp");
    let out = star()
        .args(["synth", "--preset", "nope"])
        .arg(tmp.path().join("x"))
        .output()
        .expect("run");
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("unknown preset `nope`") && err.contains("realistic"),
        "{err}"
    );

    let out = star()
        .args(["synth", "--frames", "0"])
        .arg(tmp.path().join("y"))
        .output()
        .expect("run");
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("frame count 0"), "{err}");

    // The output exists as a file: the error names it.
    let file = tmp.path().join("file");
    std::fs::write(&file, b"x").expect("write");
    let out = star().arg("synth").arg(&file).output().expect("run");
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains(file.to_str().unwrap()), "{err}");
}
