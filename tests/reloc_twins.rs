//! Geometric twins (`star::reloc::twins`): a room built twice, the copy
//! 20 m away under a dimmer light, as two stretches of a scanned corridor
//! are. A frame taken in the copy but held in the original (the wrong
//! accept the scanned floor showed) must find the copy among its view's
//! geometric twins and pass the looser gate there, so that the rule refuses
//! it; the room built once has no twin.

#![allow(clippy::expect_used, clippy::unwrap_used)] // test code: a failed step should panic

mod common;

use std::sync::Arc;

use common::room::twin_map;
use nalgebra::Translation3;
use star::config::Config;
use star::dataset::Dataset;
use star::geometry::Pose;
use star::reloc::rivals::elsewhere;
use star::reloc::twins::{twin_pose, GeometricTwins, TwinCheck};
use star::reloc::{try_candidate, GeometricTwinMaps};
use star::render::cpu::CpuRenderer;
use star::render::{RenderedView, Renderer};
use star::synth::preset::Preset;
use star::synth::sequence::{write_sequence, SequenceOptions};
use star::track::{build_config, Aligner, Keyframe, Pyramid};

/// How far the copy stands from the room, meters along x.
const COPY_X_M: f64 = 20.0;
/// The copy's light, relative to the room's.
const COPY_GAIN: f32 = 0.6;

#[test]
fn a_frame_held_in_the_wrong_copy_of_a_room_passes_at_its_geometric_twin() {
    let tmp = tempfile::tempdir().expect("tmp");
    let root = tmp.path().join("seq");
    let options = SequenceOptions {
        preset: Preset::by_name("realistic").expect("preset"),
        seed: 3,
        frames: 60,
        write_depth: false,
    };
    write_sequence(&root, &options, &mut |_| {}).expect("sequence");
    let ds = Dataset::open(&root).expect("dataset");
    let mut config = Config::default();
    // The preset's map is textured: check it all the same.
    config.reloc.geometric_twins = GeometricTwinMaps::Always;
    let room = config
        .map
        .load_mesh_from(&root.join("map").join("map.obj"))
        .expect("map");
    let twice = Arc::new(twin_map(&room, COPY_X_M as f32, |_, g| g * COPY_GAIN));
    let camera = ds.camera().pinhole();
    let tracker = build_config(&config.tracker);
    let mut renderer = CpuRenderer::new(twice.clone()).expect("renderer");
    let mut view = RenderedView::for_camera(&camera);
    let mut aligners = [Aligner::new(&tracker), Aligner::new(&tracker)];
    let mut pyramid = Pyramid::new(
        camera.width as usize,
        camera.height as usize,
        tracker.pyramid_levels as usize,
    );
    let gt = ds.ground_truth.clone().expect("ground truth");
    let mut twins_room = GeometricTwins::new(&room, &config.reloc);
    let mut twins = GeometricTwins::new(&twice, &config.reloc);
    let mut checked = 0;
    for i in [10, 30, 50] {
        let held = gt.poses[i];
        let truth = Translation3::new(COPY_X_M, 0.0, 0.0) * held;
        // The frame, seen in the copy.
        renderer.render(&truth, &camera, &mut view).expect("frame");
        let frame = view.gray.to_u8();
        pyramid.fill_from_u8(frame.data(), frame.width());
        // The keyframe of the held pose, in the room.
        renderer
            .render(&held, &camera, &mut view)
            .expect("keyframe");
        let mut kf = Keyframe::new(&camera, &tracker);
        kf.prepare(&view, held, 1, &tracker);

        assert_eq!(
            twins_room.check(&kf),
            TwinCheck::Unique,
            "frame {i}: the room built once has no twin: {:?}",
            twins_room.found()
        );
        let check = twins.check(&kf);
        let TwinCheck::Check(n) = check else {
            panic!("frame {i}: {check:?} ({:?})", twins.found());
        };
        let twin = twins.found()[..n]
            .iter()
            .find(|t| (t.offset_m[0] - COPY_X_M).abs() <= 0.1 && t.offset_m[1].abs() <= 0.1)
            .copied()
            .unwrap_or_else(|| panic!("frame {i}: the copy is not a twin: {:?}", twins.found()));
        let at = twin_pose(&held, &twin);
        let mut render = |pose: &Pose| {
            let mut kf = Box::new(Keyframe::new(&camera, &tracker));
            renderer.render(pose, &camera, &mut view).ok()?;
            kf.prepare(&view, *pose, 2, &tracker);
            Some(kf)
        };
        let (passed, _) = try_candidate(
            &mut aligners,
            &pyramid,
            &camera,
            twins.loose(),
            &at,
            None,
            &mut render,
            &mut |_| {},
        )
        .unwrap_or_else(|| panic!("frame {i}: the frame fails the looser gate at its true place"));
        let off_m = (passed.world_from_camera.translation.vector - truth.translation.vector).norm();
        assert!(
            off_m < 0.05,
            "frame {i}: passed {off_m:.3} m from the truth"
        );
        assert!(elsewhere(&held, &passed.world_from_camera));
        checked += 1;
    }
    assert_eq!(checked, 3);
}
