//! `star doctor` end to end: it lists the adapters, names the one `auto`
//! would choose, and passes a test render with the configured renderer.

#![allow(clippy::expect_used, clippy::unwrap_used)]

use std::process::Command;

use star::render::gpu;

fn doctor(args: &[&str]) -> (bool, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_star"))
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
