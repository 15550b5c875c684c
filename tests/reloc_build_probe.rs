//! The clearance probes of `star reloc build` (issue 22): a grid position
//! or landmark view inside or against furniture or a wall is dropped from
//! renders cut at twice `min_depth_m`, before any full render, and the
//! database is the same, byte for byte, as the build that renders every
//! view in full and drops them afterwards.

#![allow(clippy::expect_used, clippy::unwrap_used)] // test code: a failed step should panic

mod common;

use std::sync::Arc;

use star::geometry::PinholeCamera;
use star::reloc::{build_database, build_parallel, BuildOptions, RelocConfig, StageTimes};
use star::render::cpu::CpuRenderer;

#[test]
fn probes_drop_blocked_views_and_change_nothing() {
    let mesh = Arc::new(common::room::textured_room());
    let camera = PinholeCamera::new(320, 256, 210.0, 210.0, 159.5, 127.5);
    // A grid at 1.2 m: positions inside the 1.6 m box, and against the
    // walls, are blocked.
    let config = RelocConfig {
        grid_spacing_m: 0.4,
        heights_m: vec![1.2],
        yaw_steps: 8,
        pitches_deg: vec![-10.0],
        landmark_spacing_m: 0.5,
        landmark_heights_m: vec![1.2],
        landmark_yaw_steps: 4,
        floor_z_m: Some(0.0),
        ..RelocConfig::default()
    };
    // One renderer that cannot be cut: every view rendered in full.
    let mut renderer = CpuRenderer::new(mesh.clone()).expect("renderer");
    let full =
        build_database(&mesh, &camera, &mut renderer, &config, &mut |_, _| {}).expect("full build");

    let mut times = StageTimes::default();
    let probed = build_parallel(
        &mesh,
        &camera,
        &config,
        None,
        &Default::default(),
        "cpu",
        &|| CpuRenderer::new(mesh.clone()),
        BuildOptions {
            threads: 2,
            checkpoint: None,
            stop_after: None,
            progress: &mut |_, _| {},
            sample_every: 1,
            stage_times: Some(&mut times),
            far_m: None,
        },
    )
    .expect("probed build");

    assert!(
        times.positions_skipped > 0 && times.landmarks_skipped > 0,
        "the probes dropped blocked views: {times}"
    );
    assert!(!full.entries.is_empty() && full.landmarks.len() > 50);
    assert!(
        probed.to_bytes() == full.to_bytes(),
        "same database: {} / {} entries, {} / {} landmarks",
        probed.entries.len(),
        full.entries.len(),
        probed.landmarks.len(),
        full.landmarks.len()
    );
}
