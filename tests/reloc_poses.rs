//! `star reloc build --poses`: views along a trajectory (the scanning
//! run's, an earlier flight's) join the grid's, where the vehicle will fly:
//! at its heights and attitudes, which the grid does not sample (issue 19).

#![allow(clippy::expect_used, clippy::unwrap_used)] // test code: a failed step should panic

mod common;

use std::process::Command;

use nalgebra::{Translation3, UnitQuaternion, Vector3};
use star::dataset::Trajectory;
use star::geometry::look::camera_rotation;
use star::geometry::{PinholeCamera, Pose};
use star::map::write_obj;
use star::reloc::{build_database, build_database_along, AlongTrajectory, RelocConfig};
use star::reloc::{RelocDatabase, RelocEntry};
use star::render::cpu::CpuRenderer;

const STAR: &str = env!("CARGO_BIN_EXE_star");

fn small_grid() -> RelocConfig {
    RelocConfig {
        grid_spacing_m: 1.0,
        heights_m: vec![1.2],
        yaw_steps: 8,
        pitches_deg: vec![-10.0],
        landmark_spacing_m: 0.0,
        floor_z_m: Some(0.0),
        ..RelocConfig::default()
    }
}

fn camera() -> PinholeCamera {
    PinholeCamera::new(320, 256, 210.0, 210.0, 159.5, 127.5)
}

/// A flight across the 6 x 5 m room at 0.8 m (below the grid's 1.2 m),
/// pitched down 20 degrees and rolled 5: poses every 2 cm over 2 m.
fn flight() -> Vec<Pose> {
    (0..=100)
        .map(|i| {
            let s = i as f64 / 100.0;
            Pose::from_parts(
                Translation3::new(2.0 + 2.0 * s, 2.5, 0.8),
                camera_rotation(0.3 + 0.5 * s, (-20f64).to_radians(), 5f64.to_radians()),
            )
        })
        .collect()
}

fn off_grid(db: &RelocDatabase) -> Vec<&RelocEntry> {
    db.entries
        .iter()
        .filter(|e| (e.world_from_camera.translation.z - 1.2).abs() > 1e-6)
        .collect()
}

#[test]
fn views_along_a_trajectory_join_the_grid() {
    let mesh = common::room::textured_room();
    let mut renderer = CpuRenderer::new(std::sync::Arc::new(mesh.clone())).expect("renderer");
    let config = small_grid();
    let grid_only =
        build_database(&mesh, &camera(), &mut renderer, &config, &mut |_, _| {}).expect("db");
    assert!(off_grid(&grid_only).is_empty());

    let poses = flight();
    let spacing_m = 0.25;
    let half_yaw_rad = std::f64::consts::PI / config.yaw_steps as f64;
    let samples = star::reloc::grid::sample_along(&poses, spacing_m, half_yaw_rad);
    // The first pose, then one each 0.25 m or 22.5 degrees over 2 m and
    // 29 degrees of turn.
    assert_eq!(samples[0], poses[0]);
    assert!(
        (8..=12).contains(&samples.len()),
        "{} samples",
        samples.len()
    );
    for pair in samples.windows(2) {
        let moved_m = (pair[1].translation.vector - pair[0].translation.vector).norm();
        assert!(
            moved_m >= spacing_m - 1e-9
                || pair[0].rotation.angle_to(&pair[1].rotation) >= half_yaw_rad
        );
    }

    let along = AlongTrajectory {
        poses: poses.clone(),
        spacing_m,
    };
    let mut calls = 0;
    let db = build_database_along(
        &mesh,
        &camera(),
        &mut renderer,
        &config,
        None,
        &along,
        &mut |done, total| {
            calls += 1;
            assert!(done <= total);
        },
    )
    .expect("db");
    assert_eq!(
        db.entries.len(),
        grid_only.entries.len() + off_grid(&db).len()
    );
    let added = off_grid(&db);
    // Five views per sample, all inside the room and facing its walls.
    assert_eq!(
        added.len(),
        5 * samples.len(),
        "every trajectory view was kept"
    );
    assert!(calls > samples.len());
    for e in &added {
        let p = e.world_from_camera.translation.vector;
        assert!(
            (p.z - 0.8).abs() < 1e-9,
            "a view left the flown height: {p:?}"
        );
        // Each view is a sample, turned about the vertical or moved half a
        // spacing sideways: near a sample, with its pitch and roll.
        let near = samples.iter().any(|s| {
            let d = p - s.translation.vector;
            let up = |q: &UnitQuaternion<f64>| q * Vector3::new(0.0, -1.0, 0.0);
            d.norm() <= 0.5 * spacing_m + 1e-9
                && (up(&e.world_from_camera.rotation).z - up(&s.rotation).z).abs() < 1e-9
        });
        assert!(near, "view at {p:?} is not near any sample");
    }
    // The coarse points of the added views are stored with them.
    assert!(added.iter().all(|e| e.coarse_len > 0));
}

#[test]
fn the_cli_places_mesh_frame_poses_and_refuses_bad_ones() {
    let dir = tempfile::tempdir().expect("tmp");
    let mesh = common::room::textured_room();
    let obj = write_obj(&mesh, dir.path(), "room").expect("write");
    let cam = dir.path().join("camera.toml");
    std::fs::write(
        &cam,
        "width = 320\nheight = 256\nfx = 210.0\nfy = 210.0\ncx = 159.5\ncy = 127.5\n",
    )
    .expect("camera");
    // The mesh is in its own frame and units (placed by world_from_mesh:
    // scale 2, 0.5 m up), and so are the poses (`--poses-frame mesh`): the
    // views must come out at world = world_from_mesh * (scale * mesh), the
    // flight's 0.8 m at 2.1 m.
    let config = dir.path().join("star.toml");
    std::fs::write(
        &config,
        format!(
            "[map]\nmesh = {obj:?}\n\n[reloc]\ngrid_spacing_m = 1.5\nheights_m = [1.2]\nyaw_steps = 4\npitches_deg = [-10.0]\nlandmark_spacing_m = 0.0\nfloor_z_m = 0.0\n\n[map.world_from_mesh]\ntranslation_m = [0.0, 0.0, 0.5]\nscale = 2.0\n"
        ),
    )
    .expect("config");
    let mut trajectory = Trajectory::default();
    for (i, pose) in flight().iter().enumerate() {
        trajectory.push(i as f64 * 0.02, *pose);
    }
    let poses = dir.path().join("flight.txt");
    trajectory.write(&poses).expect("poses");

    let run = |extra: &[&str]| {
        Command::new(STAR)
            .args(["--log", "error", "reloc", "build", "--config"])
            .arg(&config)
            .arg("--camera")
            .arg(&cam)
            .arg("-o")
            .arg(dir.path().join("room.db"))
            .args(extra)
            .output()
            .expect("run star")
    };
    let out = run(&["--poses", poses.to_str().unwrap(), "--poses-frame", "mesh"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let db = RelocDatabase::read(&dir.path().join("room.db")).expect("db");
    let added = off_grid(&db);
    assert!(!added.is_empty());
    for e in &added {
        let p = e.world_from_camera.translation.vector;
        assert!((p.z - 2.1).abs() < 1e-9, "view at {p:?}, expected z 2.1");
        assert!(
            (3.5..8.5).contains(&p.x) && (p.y - 5.0).abs() < 0.5,
            "{p:?}"
        );
    }

    // A missing file, an empty trajectory and a zero spacing are refused,
    // naming what is wrong.
    let missing = dir.path().join("nowhere.txt");
    let out = run(&["--poses", missing.to_str().unwrap()]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(stderr.contains("nowhere.txt"), "{stderr}");
    let empty = dir.path().join("empty.txt");
    std::fs::write(&empty, "# nothing\n").expect("empty");
    let out = run(&["--poses", empty.to_str().unwrap()]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(stderr.contains("has no poses"), "{stderr}");
    let out = run(&["--poses", poses.to_str().unwrap(), "--poses-spacing-m", "0"]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(stderr.contains("--poses-spacing-m"), "{stderr}");
}
