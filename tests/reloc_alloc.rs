//! The landmark pose allocates nothing per frame after construction, near
//! the last position (spatial cells) and over the whole map (vocabulary)
//! alike (issue 22).

#![allow(clippy::expect_used, clippy::unwrap_used)] // test code: a failed step should panic

mod common;

use std::sync::Arc;

use common::counting_alloc::{start_counting, stop_counting, CountingAlloc};
use nalgebra::{Translation3, Vector3};
use star::geometry::look::camera_rotation;
use star::geometry::{PinholeCamera, Pose};
use star::reloc::landmarks::LandmarkLocator;
use star::reloc::{build_database, RelocConfig, SearchRegion};
use star::render::cpu::CpuRenderer;
use star::render::{RenderedView, Renderer};

#[global_allocator]
static GLOBAL: CountingAlloc = CountingAlloc;

/// The textured room, its database (landmarks every metre), and a frame
/// rendered at a pose inside it, 8-bit.
struct Fixture {
    camera: PinholeCamera,
    config: RelocConfig,
    db: star::reloc::RelocDatabase,
    pose: Pose,
    frame: Vec<u8>,
}

fn fixture() -> Fixture {
    let mesh = common::room::textured_room();
    let camera = PinholeCamera::new(320, 256, 210.0, 210.0, 159.5, 127.5);
    let config = RelocConfig {
        grid_spacing_m: 1.5,
        heights_m: vec![1.2],
        yaw_steps: 4,
        pitches_deg: vec![-10.0],
        landmark_spacing_m: 1.0,
        landmark_heights_m: vec![1.2],
        landmark_yaw_steps: 8,
        floor_z_m: Some(0.0),
        ..RelocConfig::default()
    };
    let mut renderer = CpuRenderer::new(Arc::new(mesh.clone())).expect("renderer");
    let db = build_database(&mesh, &camera, &mut renderer, &config, &mut |_, _| {}).expect("db");
    let pose = Pose::from_parts(
        Translation3::new(2.7, 2.3, 1.3),
        camera_rotation(0.4, (-8f64).to_radians(), 0.0),
    );
    let mut view = RenderedView::for_camera(&camera);
    renderer.render(&pose, &camera, &mut view).expect("render");
    let frame: Vec<u8> = view
        .gray
        .data()
        .iter()
        .map(|&g| g.clamp(0.0, 255.0) as u8)
        .collect();
    Fixture {
        camera,
        config,
        db,
        pose,
        frame,
    }
}

#[test]
fn locating_from_landmarks_allocates_nothing() {
    let Fixture {
        camera,
        config,
        db,
        pose,
        frame,
    } = fixture();
    assert!(db.landmarks.len() > 50 && !db.vocabulary.is_empty());
    let mut locator = LandmarkLocator::new(&camera, &config, &db.landmarks, &db.vocabulary);

    let (w, h) = (camera.width as usize, camera.height as usize);
    let near = SearchRegion::Near {
        center_m: Vector3::new(2.5, 2.5, 1.2),
        radius_m: 1.0,
    };
    let regions = [near, SearchRegion::Everywhere];
    // The first call warms up (rayon's pool in the extractor, lazy tables).
    locator.locate_in(&frame, w, h, w, &regions);

    start_counting();
    let near_pose = locator.locate(&frame, w, h, w, near);
    let near_comparisons = locator.comparisons();
    let everywhere = locator.locate(&frame, w, h, w, SearchRegion::Everywhere);
    let everywhere_comparisons = locator.comparisons();
    let both = locator.locate_in(&frame, w, h, w, &regions);
    let allocations = stop_counting();
    assert_eq!(allocations, 0, "allocations while locating");
    // The poses at the other places the corners fit (rivals on a scan):
    // nothing allocated, and the search's own matches left as they were.
    let recall = locator.recall_of_last();
    let mut elsewhere = heapless::Vec::<star::reloc::landmarks::Located, 3>::new();
    start_counting();
    locator.poses_elsewhere(&pose, &mut elsewhere);
    let allocations = stop_counting();
    assert_eq!(allocations, 0, "allocations while solving other places");
    assert_eq!(locator.recall_of_last(), recall);
    // One room: whatever it gives stands at least a meter from the pose.
    assert!(elsewhere
        .iter()
        .all(|f| star::reloc::rivals::elsewhere(&pose, &f.world_from_camera)));

    // It searched, and over the whole map with fewer comparisons than
    // brute force.
    assert!(near_comparisons > 0 && everywhere_comparisons > 0);
    assert!(everywhere_comparisons < locator.brute_force_comparisons());
    for found in [near_pose, everywhere, both].into_iter().flatten() {
        let err = pose.inverse() * found.world_from_camera;
        assert!(
            err.translation.vector.norm() < 0.1,
            "a landmark pose {:?} off",
            err.translation.vector
        );
    }
}

/// The geometric twin check of a held pose ([`star::reloc::twins`])
/// allocates nothing after construction; what it finds lies at least 1 m
/// away and scores at least the minimum (a plain box room lets a view of
/// one wall slide along it).
#[test]
fn checking_geometric_twins_allocates_nothing() {
    let mesh = common::room::textured_room();
    let camera = PinholeCamera::new(320, 256, 210.0, 210.0, 159.5, 127.5);
    let config = RelocConfig {
        geometric_twins: star::reloc::GeometricTwinMaps::Always,
        ..RelocConfig::default()
    };
    let mut twins = star::reloc::twins::GeometricTwins::new(&mesh, &config);
    assert!(twins.has_map());
    let mut renderer = CpuRenderer::new(Arc::new(mesh.clone())).expect("renderer");
    let tracker = star::track::TrackerConfig::default();
    let mut view = RenderedView::for_camera(&camera);
    let mut keyframes = Vec::new();
    for (x, yaw) in [(2.7, 0.4), (1.5, 2.0), (3.5, -1.2)] {
        let pose = Pose::from_parts(
            Translation3::new(x, 2.3, 1.3),
            camera_rotation(yaw, (-8f64).to_radians(), 0.0),
        );
        renderer.render(&pose, &camera, &mut view).expect("render");
        let mut kf = star::track::Keyframe::new(&camera, &tracker);
        kf.prepare(&view, pose, 1, &tracker);
        keyframes.push(kf);
    }
    twins.check(&keyframes[0]);
    let mut found = Vec::with_capacity(16);
    let mut allocations = 0;
    for kf in &keyframes {
        start_counting();
        twins.check(kf);
        allocations += stop_counting();
        found.extend_from_slice(twins.found());
    }
    assert_eq!(allocations, 0, "allocations while checking twins");
    for t in &found {
        assert!(
            t.offset_m[0].hypot(t.offset_m[1]) >= star::map::repeats::MIN_OFFSET_M,
            "{t:?}"
        );
        assert!(t.score >= star::map::repeats::MIN_SCORE, "{t:?}");
    }
}

/// A map whose every landmark has an exact twin 20 m away (a look-alike
/// room, as the `building` preset repeats its designs): every match's
/// runner-up is at the other place, so the ratio test refuses them all.
/// The second pass hands every match to RANSAC and finds the pose, at the
/// place or at its twin (which the gate and the rival rule then judge),
/// without allocating.
#[test]
fn the_landmark_pose_is_found_where_every_corner_has_a_twin() {
    let Fixture {
        camera,
        config,
        db,
        pose,
        frame,
    } = fixture();
    const TWIN_X_M: f32 = 20.0;
    let mut twinned = db.landmarks.clone();
    twinned.extend(
        db.landmarks
            .iter()
            .map(|l| star::reloc::landmarks::Landmark {
                world_m: [l.world_m[0] + TWIN_X_M, l.world_m[1], l.world_m[2]],
                descriptor: l.descriptor,
            }),
    );
    let mut single = LandmarkLocator::new(&camera, &config, &db.landmarks, &db.vocabulary);
    let mut locator = LandmarkLocator::new(&camera, &config, &twinned, &db.vocabulary);

    let (w, h) = (camera.width as usize, camera.height as usize);
    // The map without twins: found in the first pass.
    let alone = single
        .locate(&frame, w, h, w, SearchRegion::Everywhere)
        .expect("a landmark pose in the map without twins");
    assert!(
        (pose.inverse() * alone.world_from_camera)
            .translation
            .vector
            .norm()
            < 0.1
    );

    locator.locate(&frame, w, h, w, SearchRegion::Everywhere); // warm-up
    start_counting();
    let found = locator.locate(&frame, w, h, w, SearchRegion::Everywhere);
    let allocations = stop_counting();
    assert_eq!(allocations, 0, "allocations while locating");
    let found = found.expect("a landmark pose although every corner has a twin");
    let t = found.world_from_camera.translation.vector;
    let at_twin = t.x > (TWIN_X_M / 2.0) as f64;
    let truth = if at_twin {
        pose.translation.vector + Vector3::new(TWIN_X_M as f64, 0.0, 0.0)
    } else {
        pose.translation.vector
    };
    assert!(
        (t - truth).norm() < 0.1,
        "the pose {t:?} is neither the place nor its twin"
    );
    let rotation_deg = (pose.rotation.inverse() * found.world_from_camera.rotation)
        .angle()
        .to_degrees();
    assert!(rotation_deg < 3.0, "{rotation_deg} deg off");
}
