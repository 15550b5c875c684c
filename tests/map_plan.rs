//! `star map plan`: the floor plan of a map with its relocalization
//! database and a trajectory. On a small textured room with a quick
//! database: the picture is written at the size printed, every view and
//! landmark of the database is drawn, and each pixel class is where the
//! map puts it; a database of another map, a bad cell size and a map away
//! from the floor are refused with errors that say why.

#![allow(clippy::expect_used, clippy::unwrap_used)] // test code: a failed step should panic

mod common;

use std::path::Path;
use std::process::{Command, Output};

use star::map::write_obj;
use star::reloc::RelocDatabase;

const STAR: &str = env!("CARGO_BIN_EXE_star");

fn star(args: &[&str]) -> Output {
    Command::new(STAR)
        .args(["--log", "error"])
        .args(args)
        .output()
        .expect("run star")
}

/// `star map plan MESH -o PNG` with `extra` arguments.
fn plan(mesh: &Path, png: &Path, extra: &[&str]) -> Output {
    let mut args = vec![
        "map",
        "plan",
        mesh.to_str().unwrap(),
        "-o",
        png.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    star(&args)
}

fn text(o: &Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}

/// Builds a quick database of the room `obj` into `db`.
fn build_db(dir: &Path, obj: &Path, db: &Path) {
    let camera = dir.join("camera.toml");
    std::fs::write(
        &camera,
        "width = 320\nheight = 256\nfx = 210.0\nfy = 210.0\ncx = 159.5\ncy = 127.5\n",
    )
    .expect("camera");
    let config = dir.join("star.toml");
    std::fs::write(
        &config,
        format!(
            "[map]\nmesh = {obj:?}\n\n[reloc]\ngrid_spacing_m = 1.0\nheights_m = [1.2]\nyaw_steps = 8\npitches_deg = [-10.0]\nlandmark_spacing_m = 1.0\nlandmark_heights_m = [1.2]\nlandmark_yaw_steps = 4\nfloor_z_m = 0.0\n"
        ),
    )
    .expect("config");
    let out = star(&[
        "reloc",
        "build",
        "--config",
        config.to_str().unwrap(),
        "--camera",
        camera.to_str().unwrap(),
        "-o",
        db.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "reloc build: {}", text(&out));
}

#[test]
fn a_plan_draws_the_database_and_the_trajectory_and_refuses_bad_input() {
    let dir = tempfile::tempdir().expect("tmp");
    let mesh = common::room::textured_room();
    let obj = write_obj(&mesh, dir.path(), "room").expect("write");
    let db = dir.path().join("room.reloc");
    build_db(dir.path(), &obj, &db);
    let database = RelocDatabase::read(&db).expect("a database");
    let (lo, hi) = mesh.bounds().expect("vertices");
    // A trajectory across the room at 1.2 m.
    let trajectory = dir.path().join("flight.txt");
    let (cx, cy) = (0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1]));
    std::fs::write(
        &trajectory,
        format!(
            "0.0 {} {cy} 1.2 0 0 0 1\n1.0 {cx} {cy} 1.2 0 0 0 1\n",
            lo[0] + 0.5
        ),
    )
    .expect("trajectory");
    let png = dir.path().join("plan.png");
    let out = plan(
        &obj,
        &png,
        &[
            "--reloc",
            db.to_str().unwrap(),
            "--trajectory",
            trajectory.to_str().unwrap(),
            "--floor-z",
            "0",
        ],
    );
    let said = text(&out);
    assert!(out.status.success(), "map plan: {said}");
    let views = format!("{} relocalization views", database.entries.len());
    let landmarks = format!("{} landmarks drawn", database.landmarks.len());
    assert!(
        said.contains(&views) && said.contains(&landmarks),
        "every view and landmark drawn ({views}, {landmarks}): {said}"
    );
    let image = image::open(&png).expect("a PNG").to_rgb8();
    let size = format!("{}x{} px", image.width(), image.height());
    assert!(
        said.contains(&size),
        "the size printed is the file's ({size}): {said}"
    );
    // The trajectory's green is in the picture.
    assert!(
        image.pixels().any(|p| p.0 == [44, 160, 44]),
        "the trajectory is drawn"
    );

    // A database of another map: the same room moved 1 m.
    let mut moved = mesh.clone();
    for p in &mut moved.positions {
        p[0] += 1.0;
    }
    let other = write_obj(&moved, dir.path(), "moved").expect("write");
    let out = plan(
        &other,
        &png,
        &["--reloc", db.to_str().unwrap(), "--floor-z", "0"],
    );
    assert!(!out.status.success());
    assert!(
        text(&out).contains("was built from another map"),
        "{}",
        text(&out)
    );

    let out = plan(&obj, &png, &["--cell-m", "0"]);
    assert!(!out.status.success());
    assert!(
        text(&out).contains("--cell-m 0 is outside"),
        "{}",
        text(&out)
    );

    let out = plan(&obj, &png, &["--floor-z", "50"]);
    assert!(!out.status.success());
    assert!(
        text(&out).contains("nothing of the map lies within 0.1 m of the floor"),
        "{}",
        text(&out)
    );
}
