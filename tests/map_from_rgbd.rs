//! `scripts/map_from_rgbd.py` end to end: an RGB-D sequence of a synthetic
//! room (the `aggressive` flight, with its distorted images and depth)
//! fused into a PLY map (written by Open3D), and another flight of the same
//! room (`realistic`, same seed, so the same scene) localized against that
//! map: every frame tracked, ATE under 2 cm. The fused PLY converted to GLB
//! by Open3D loads to the same mesh.
//!
//! Needs Python with open3d and OpenCV (see `common::open3d_python`).

#![allow(clippy::expect_used, clippy::unwrap_used)] // test code: a failed step should panic

mod common;

use std::path::Path;
use std::process::{Command, Output};

use star::map::load_mesh;

fn ok(output: Output, what: &str) -> String {
    assert!(
        output.status.success(),
        "{what} failed: {}\n{}",
        String::from_utf8_lossy(&output.stdout),
        String::from_utf8_lossy(&output.stderr)
    );
    String::from_utf8_lossy(&output.stdout).into_owned()
}

fn star(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_star"))
        .args(args)
        .env("RUST_LOG", "warn")
        .output()
        .expect("run star")
}

fn synth(preset: &str, out: &Path, depth: bool) {
    let mut args = vec![
        "synth",
        "--preset",
        preset,
        "--seed",
        "1",
        "--frames",
        "100",
        out.to_str().unwrap(),
    ];
    if !depth {
        args.push("--no-depth");
    }
    ok(star(&args), "star synth");
}

/// The number after `key` in `text`.
fn number_after(text: &str, key: &str) -> f64 {
    let rest = &text[text
        .find(key)
        .unwrap_or_else(|| panic!("no '{key}' in {text}"))
        + key.len()..];
    rest.split_whitespace()
        .next()
        .and_then(|w| w.parse().ok())
        .unwrap_or_else(|| panic!("no number after '{key}' in {text}"))
}

#[test]
fn a_map_fused_from_one_flight_tracks_another_within_2_cm() {
    let Some(python) = common::open3d_python() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let scan = dir.path().join("scan");
    let flight = dir.path().join("flight");
    synth("aggressive", &scan, true);
    synth("realistic", &flight, false);
    let fused = dir.path().join("fused.ply");
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/map_from_rgbd.py");
    let stats = ok(
        Command::new(&python)
            .arg(&script)
            .arg(&scan)
            .arg(&fused)
            .args(["--every", "2", "--voxel-m", "0.03"])
            .output()
            .expect("run map_from_rgbd.py"),
        "map_from_rgbd.py",
    );
    let stats: serde_json::Value = serde_json::from_str(stats.trim()).expect("stats JSON");
    assert_eq!(stats["frames"], 50, "{stats}");
    assert_eq!(stats["undistorted"], true, "{stats}");
    assert!(stats["triangles"].as_u64().unwrap() > 10_000, "{stats}");

    // The same mesh as GLB, written by Open3D (another writer than star's),
    // loads to the same vertices, gray and triangles.
    let glb = dir.path().join("fused.glb");
    ok(
        Command::new(&python)
            .args([
                "-c",
                "import sys, open3d as o3d; m = o3d.io.read_triangle_mesh(sys.argv[1]); \
                 sys.exit(0 if o3d.io.write_triangle_mesh(sys.argv[2], m) else 1)",
            ])
            .arg(&fused)
            .arg(&glb)
            .output()
            .expect("run open3d"),
        "open3d PLY to GLB",
    );
    let (from_ply, from_glb) = (load_mesh(&fused).unwrap(), load_mesh(&glb).unwrap());
    assert_eq!(from_ply.indices, from_glb.indices);
    assert_eq!(from_ply.positions.len(), from_glb.positions.len());
    for (a, b) in from_ply.positions.iter().zip(&from_glb.positions) {
        assert!(
            a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-5),
            "{a:?} {b:?}"
        );
    }
    for (a, b) in from_ply.gray.iter().zip(&from_glb.gray) {
        assert!((a - b).abs() < 1.0, "gray {a} from PLY, {b} from GLB");
    }

    let config = dir.path().join("star.toml");
    std::fs::write(&config, "[render]\nrenderer = \"cpu\"\n").unwrap();
    let est = dir.path().join("est.txt");
    let report = ok(
        star(&[
            "localize",
            flight.to_str().unwrap(),
            "--map",
            fused.to_str().unwrap(),
            "--config",
            config.to_str().unwrap(),
            "-o",
            est.to_str().unwrap(),
        ]),
        "star localize on the fused map",
    );
    eprintln!("{report}");
    assert_eq!(number_after(&report, "tracked"), 100.0, "{report}");
    let rmse_cm = number_after(&report, "translation rmse");
    assert!(rmse_cm < 2.0, "ATE {rmse_cm} cm on the fused map");
}
