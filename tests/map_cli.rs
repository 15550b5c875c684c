//! `star map info` and `star map align` end to end:
//! - `info --json` on a synthetic map finds its floor within 1 cm and
//!   0.5 deg, as the file has it and when `--config` tilts and lifts it by a
//!   known `[map.world_from_mesh]`;
//! - `align` on a `scanned` map (TSDF fusion in the scanner's y-down frame)
//!   recovers the floor of the true placement (declared times the seeded
//!   registration error) within 1 cm and 0.5 deg; its snippet loads as a
//!   config;
//! - `align` refuses a sphere and a lone vertical wall with a reason.
//!
//! The scanned map needs Python with open3d (see `common::open3d_python`).

#![allow(clippy::expect_used, clippy::unwrap_used)] // test code: a failed step should panic

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use nalgebra::Vector3;
use star::config::Config;
use star::geometry::{Pose, TransformConfig};
use star::map::{write_ply, Mesh, PlyEncoding};
use star::synth::scanned::{registration_error, ScannedSpec};

fn star(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_star"))
        .args(args)
        .env("RUST_LOG", "warn")
        .output()
        .expect("run star")
}

fn ok(output: &Output, what: &str) -> String {
    assert!(
        output.status.success(),
        "{what} failed: {}\n{}",
        String::from_utf8_lossy(&output.stdout),
        String::from_utf8_lossy(&output.stderr)
    );
    String::from_utf8_lossy(&output.stdout).into_owned()
}

/// A small synthetic dataset with its z-up map (floor at z = 0).
fn synthetic(dir: &Path) -> PathBuf {
    let out = dir.join("ds");
    ok(
        &star(&[
            "synth",
            "--preset",
            "realistic",
            "--frames",
            "2",
            "--no-depth",
            "--seed",
            "2",
            out.to_str().unwrap(),
        ]),
        "star synth",
    );
    out
}

fn vec3(v: &serde_json::Value) -> Vector3<f64> {
    let a: Vec<f64> = serde_json::from_value(v.clone()).expect("three numbers");
    Vector3::new(a[0], a[1], a[2])
}

/// Runs `star map info --json` and checks the floor it reports.
fn check_info_floor(args: &[&str], normal: Vector3<f64>, height_m: f64) -> serde_json::Value {
    let mut all = vec!["map", "info", "--json"];
    all.extend_from_slice(args);
    let text = ok(&star(&all), "star map info");
    let report: serde_json::Value = serde_json::from_str(&text).expect("JSON");
    let floor = &report["floor"];
    let found = vec3(&floor["normal"]);
    let angle_deg = found.angle(&normal).to_degrees();
    let height = floor["height_m"].as_f64().expect("height");
    eprintln!("floor normal {found:?} ({angle_deg:.4} deg off), height {height:.4} m (expected {height_m:.4})");
    assert!(
        angle_deg < 0.5,
        "floor normal {found:?} is {angle_deg} deg from {normal:?}"
    );
    assert!(
        (height - height_m).abs() < 0.01,
        "floor height {height} m, expected {height_m}"
    );
    report
}

#[test]
fn map_info_finds_the_floor_of_a_synthetic_map() {
    let dir = tempfile::tempdir().unwrap();
    let ds = synthetic(dir.path());
    let map = ds.join("map/map.obj");
    let camera = ds.join("camera.toml");
    let report = check_info_floor(
        &[map.to_str().unwrap(), "--camera", camera.to_str().unwrap()],
        Vector3::z(),
        0.0,
    );
    assert!(report["triangles"].as_u64().unwrap() > 1000, "{report}");
    assert!(
        report["colored_fraction"].as_f64().unwrap() > 0.99,
        "{report}"
    );
    assert!(
        report["holes"]["empty_fraction"].as_f64().unwrap() < 0.05,
        "{report}"
    );
    let cpu = &report["renderers"][0];
    assert_eq!(cpu["renderer"], "CPU rasterizer");
    assert!(cpu["median_ms"].as_f64().unwrap() > 0.0, "{report}");
    assert_eq!(report["memory"]["estimated_from"], "buffer sizes");

    // Placed by a config that tilts the map 4 deg and lifts it 0.3 m: the
    // floor moves with it.
    let config = dir.path().join("star.toml");
    std::fs::write(
        &config,
        "[map.world_from_mesh]\ntranslation_m = [0.5, -0.2, 0.3]\nrpy_deg = [3.0, -2.5, 40.0]\n",
    )
    .unwrap();
    let placed = TransformConfig::from_rpy_deg([0.5, -0.2, 0.3], [3.0, -2.5, 40.0]).to_pose();
    let normal = placed.rotation * Vector3::z();
    let height = normal.dot(&placed.translation.vector);
    let report = check_info_floor(
        &[
            map.to_str().unwrap(),
            "--camera",
            camera.to_str().unwrap(),
            "--config",
            config.to_str().unwrap(),
        ],
        normal,
        height,
    );
    // The transform it suggests levels the placed map again: it undoes the
    // tilt (the composition is a pure yaw and a shift along x and y).
    let suggested: star::map::MeshTransformConfig =
        serde_json::from_value(report["floor"]["world_from_mesh"].clone()).unwrap();
    let level = suggested.rigid().to_pose();
    let up = level.rotation * Vector3::z();
    assert!(up.angle(&Vector3::z()).to_degrees() < 0.5, "{suggested:?}");
    assert!(level.translation.z.abs() < 0.01, "{suggested:?}");
}

/// The floor of `world_from_mesh` in the mesh frame: its unit normal and
/// the mesh origin's height above it (the floor is world z = 0).
fn floor_in_mesh(world_from_mesh: &Pose) -> (Vector3<f64>, f64) {
    (
        world_from_mesh.rotation.inverse() * Vector3::z(),
        world_from_mesh.translation.z,
    )
}

#[test]
fn map_align_recovers_the_floor_of_a_scanned_map() {
    let Some(python) = common::open3d_python() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("scanned");
    let seed = 1u64;
    ok(
        &star(&[
            "synth",
            "--preset",
            "scanned",
            "--seed",
            &seed.to_string(),
            "--frames",
            "2",
            "--no-depth",
            "--scan-voxel-m",
            "0.03",
            "--python",
            python.to_str().unwrap(),
            out.to_str().unwrap(),
        ]),
        "star synth --preset scanned",
    );
    let declared = Config::load(&out.join("star.toml"))
        .unwrap()
        .map
        .world_from_mesh
        .rigid()
        .to_pose();
    let spec = ScannedSpec::default();
    let truth =
        declared * registration_error(spec.registration_error_m, spec.registration_error_deg, seed);
    let snippet = dir.path().join("align.toml");
    let stdout = ok(
        &star(&[
            "map",
            "align",
            out.join("map/map.obj").to_str().unwrap(),
            "-o",
            snippet.to_str().unwrap(),
        ]),
        "star map align",
    );
    assert!(
        stdout.contains("Yaw about the vertical is free"),
        "{stdout}"
    );
    let aligned = Config::load(&snippet).expect("the snippet is a valid config");
    let level = aligned.map.world_from_mesh.rigid().to_pose();
    let (n_true, h_true) = floor_in_mesh(&truth);
    let (n_found, h_found) = floor_in_mesh(&level);
    let angle_deg = n_found.angle(&n_true).to_degrees();
    eprintln!(
        "scanned floor: normal {angle_deg:.3} deg off, mesh origin {h_found:.4} m above it (truth {h_true:.4} m)"
    );
    assert!(angle_deg < 0.5, "floor normal off by {angle_deg} deg");
    assert!(
        (h_found - h_true).abs() < 0.01,
        "floor height off by {} m",
        h_found - h_true
    );
}

/// A wall of `w` x `h` meters in the x-z plane, as PLY.
fn wall_ply(path: &Path) {
    let mut mesh = Mesh::default();
    let n = 20;
    for j in 0..=n {
        for i in 0..=n {
            mesh.positions
                .push([4.0 * i as f32 / n as f32, 0.0, 3.0 * j as f32 / n as f32]);
            mesh.gray.push(((i * 7 + j * 13) % 200) as f32);
        }
    }
    for j in 0..n as u32 {
        for i in 0..n as u32 {
            let at = |i: u32, j: u32| j * (n as u32 + 1) + i;
            mesh.indices
                .extend([at(i, j), at(i + 1, j), at(i + 1, j + 1)]);
            mesh.indices
                .extend([at(i, j), at(i + 1, j + 1), at(i, j + 1)]);
        }
    }
    write_ply(&mesh, path, PlyEncoding::BinaryLittleEndian).unwrap();
}

/// A unit sphere, as PLY.
fn sphere_ply(path: &Path) {
    let mut mesh = Mesh::default();
    let (rings, segments) = (24u32, 48u32);
    for r in 0..=rings {
        let theta = std::f32::consts::PI * r as f32 / rings as f32;
        for s in 0..segments {
            let phi = std::f32::consts::TAU * s as f32 / segments as f32;
            mesh.positions.push([
                theta.sin() * phi.cos(),
                theta.sin() * phi.sin(),
                theta.cos(),
            ]);
            mesh.gray.push(100.0);
        }
    }
    let at = |r: u32, s: u32| r * segments + s % segments;
    for r in 0..rings {
        for s in 0..segments {
            mesh.indices
                .extend([at(r, s), at(r + 1, s), at(r + 1, s + 1)]);
            mesh.indices
                .extend([at(r, s), at(r + 1, s + 1), at(r, s + 1)]);
        }
    }
    write_ply(&mesh, path, PlyEncoding::Ascii).unwrap();
}

#[test]
fn map_align_refuses_a_mesh_without_a_floor() {
    let dir = tempfile::tempdir().unwrap();
    let wall = dir.path().join("wall.ply");
    wall_ply(&wall);
    let sphere = dir.path().join("sphere.ply");
    sphere_ply(&sphere);
    for (path, reason) in [(&wall, "flat"), (&sphere, "no plane of")] {
        let output = star(&["map", "align", path.to_str().unwrap()]);
        let stderr = String::from_utf8_lossy(&output.stderr);
        eprintln!("{stderr}");
        assert!(!output.status.success(), "{} was aligned", path.display());
        assert!(
            stderr.contains("no dominant horizontal plane") && stderr.contains(reason),
            "{stderr}"
        );
        assert!(
            stderr.contains(path.file_name().unwrap().to_str().unwrap()),
            "{stderr}"
        );
    }
}
