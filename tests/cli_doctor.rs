//! `star doctor` end to end: it lists the adapters, names the one `auto`
//! would choose, and passes a test render with the configured renderer.

#![allow(clippy::expect_used, clippy::unwrap_used)]

use std::process::Command;

use star::render::gpu;

fn doctor(args: &[&str]) -> (bool, String) {
    doctor_in(Command::new(env!("CARGO_BIN_EXE_star")), args)
}

fn doctor_in(mut command: Command, args: &[&str]) -> (bool, String) {
    let out = command
        .arg("doctor")
        .args(args)
        .output()
        .expect("run star doctor");
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
    )
}

#[test]
fn doctor_reports_adapters_and_auto_choice() {
    let (ok, text) = doctor(&[]);
    assert!(ok, "{text}");
    assert!(text.contains("auto would choose:"), "{text}");
    assert!(text.contains("test render (Auto): ok"), "{text}");
    if gpu::lavapipe_installed() {
        assert!(text.contains("[software #0]"), "{text}");
    }
    let hardware = gpu::list_adapters()
        .iter()
        .any(|a| a.class == gpu::AdapterClass::Hardware);
    if hardware {
        assert!(text.contains("auto would choose: wgpu on"), "{text}");
    } else {
        assert!(
            text.contains("auto would choose: the CPU rasterizer"),
            "{text}"
        );
        assert!(text.contains("test render (Auto): ok on cpu"), "{text}");
    }
}

#[test]
fn doctor_tests_the_configured_renderer() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("star.toml");
    std::fs::write(&path, "[render]\nrenderer = \"cpu\"\n").expect("write config");
    let (ok, text) = doctor(&["--config", path.to_str().expect("utf-8 path")]);
    assert!(ok, "{text}");
    assert!(text.contains("test render (Cpu): ok on cpu"), "{text}");
}

/// Without `XDG_RUNTIME_DIR` (a system service, a container) Mesa prints an
/// "error" line on stderr; doctor says what it is and how to quiet it.
#[test]
fn doctor_explains_mesas_line_without_a_runtime_dir() {
    let dir = tempfile::tempdir().expect("tempdir");
    // The CPU rasterizer: the test render needs no adapter.
    let config = dir.path().join("star.toml");
    std::fs::write(&config, "[render]\nrenderer = \"cpu\"\n").expect("write config");
    let args = ["--config", config.to_str().expect("utf-8 path")];
    let mut unset = Command::new(env!("CARGO_BIN_EXE_star"));
    unset.env_remove("XDG_RUNTIME_DIR");
    let (ok, text) = doctor_in(unset, &args);
    assert!(ok, "{text}");
    assert!(text.contains("XDG_RUNTIME_DIR: not set"), "{text}");
    let mut set = Command::new(env!("CARGO_BIN_EXE_star"));
    set.env("XDG_RUNTIME_DIR", dir.path());
    let (ok, text) = doctor_in(set, &args);
    assert!(ok, "{text}");
    assert!(!text.contains("XDG_RUNTIME_DIR"), "{text}");
}
