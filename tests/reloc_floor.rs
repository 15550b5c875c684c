//! The relocalization grid's heights are measured from the floor found in
//! the map (issue 19): a map whose floor is not at world z = 0 gets its
//! views at the configured heights above that floor, and a map without a
//! floor is refused with a message that says how to give the heights.

mod common;

use std::process::Command;

use nalgebra::{Translation3, UnitQuaternion};
use star::geometry::{PinholeCamera, Pose};
use star::map::{write_obj, Mesh};
use star::reloc::{build_database, BuildError, RelocConfig};
use star::render::cpu::CpuRenderer;

const STAR: &str = env!("CARGO_BIN_EXE_star");

fn small_grid() -> RelocConfig {
    RelocConfig {
        grid_spacing_m: 1.0,
        heights_m: vec![1.2],
        yaw_steps: 4,
        pitches_deg: vec![-10.0],
        landmark_spacing_m: 0.0,
        ..RelocConfig::default()
    }
}

fn camera() -> PinholeCamera {
    PinholeCamera::new(320, 256, 210.0, 210.0, 159.5, 127.5)
}

#[test]
fn heights_are_measured_from_the_floor_found_in_the_map() {
    // The room of the GPU/CPU agreement test (floor at z = 0), raised 0.5 m
    // and turned about z, as a scanned map placed by `world_from_mesh` is.
    let mut mesh = common::room::textured_room();
    mesh.transform(
        1.0,
        &Pose::from_parts(
            Translation3::new(0.3, -0.2, 0.5),
            UnitQuaternion::from_euler_angles(0.0, 0.0, 0.4),
        ),
    );
    let floor = star::map::floor::find_floor(&mesh).expect("the room has a floor");
    assert!((floor.z_m - 0.5).abs() < 1e-4, "{floor:?}");
    let mut renderer = CpuRenderer::new(std::sync::Arc::new(mesh.clone())).expect("renderer");
    let db = build_database(
        &mesh,
        &camera(),
        &mut renderer,
        &small_grid(),
        &mut |_, _| {},
    )
    .expect("database");
    assert!(!db.entries.is_empty());
    for e in &db.entries {
        let z = e.world_from_camera.translation.z;
        assert!((z - 1.7).abs() < 1e-4, "view at z {z}, expected 0.5 + 1.2");
    }

    // An explicit floor height wins over the one found.
    let explicit = RelocConfig {
        floor_z_m: Some(0.8),
        ..small_grid()
    };
    let db = build_database(&mesh, &camera(), &mut renderer, &explicit, &mut |_, _| {})
        .expect("database");
    assert!(db
        .entries
        .iter()
        .all(|e| (e.world_from_camera.translation.z - 2.0).abs() < 1e-4));
}

/// Two facing vertical walls, 4 x 3 m, 3 m apart: no floor.
fn walls() -> Mesh {
    let mut mesh = Mesh::default();
    for x in [0.0f32, 3.0] {
        let base = mesh.positions.len() as u32;
        mesh.positions.extend_from_slice(&[
            [x, 0.0, 0.0],
            [x, 4.0, 0.0],
            [x, 4.0, 3.0],
            [x, 0.0, 3.0],
        ]);
        mesh.gray.extend_from_slice(&[60.0, 120.0, 200.0, 90.0]);
        mesh.indices
            .extend_from_slice(&[base, base + 1, base + 2, base, base + 2, base + 3]);
    }
    mesh.groups.push(star::map::MeshGroup {
        first_index: 0,
        index_count: mesh.indices.len() as u32,
        texture: None,
    });
    mesh
}

#[test]
fn a_map_without_a_floor_is_refused_with_the_key_to_set() {
    let mesh = walls();
    let mut renderer = CpuRenderer::new(std::sync::Arc::new(mesh.clone())).expect("renderer");
    let err = build_database(
        &mesh,
        &camera(),
        &mut renderer,
        &small_grid(),
        &mut |_, _| {},
    )
    .expect_err("no floor");
    assert!(matches!(err, BuildError::NoFloor { .. }), "{err}");

    // Through the CLI, as a user meets it.
    let dir = std::env::temp_dir().join(format!("star-reloc-floor-{}", std::process::id()));
    let obj = write_obj(&mesh, &dir, "walls").expect("write");
    let cam = dir.join("camera.toml");
    std::fs::write(
        &cam,
        "width = 320\nheight = 256\nfx = 210.0\nfy = 210.0\ncx = 159.5\ncy = 127.5\n",
    )
    .expect("camera");
    let out = Command::new(STAR)
        .args(["--log", "error", "reloc", "build", "--map"])
        .arg(&obj)
        .arg("--camera")
        .arg(&cam)
        .arg("-o")
        .arg(dir.join("walls.db"))
        .output()
        .expect("run star");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "built a database without a floor");
    assert!(stderr.contains("no floor found"), "{stderr}");
    assert!(stderr.contains("floor_z_m"), "{stderr}");
    assert!(!dir.join("walls.db").exists());
    let _ = std::fs::remove_dir_all(&dir);
}
