//! A candidate's verification, its coarse and finished starts shared
//! between two aligners on two threads of rayon's global pool
//! ([`star::reloc::verify_candidate`]), allocates nothing after a first
//! call, on any thread; and it finds the pose from a database view 0.2 m
//! and 10 degrees away. Alone in its test binary, since it counts every
//! thread's allocations.
//!
//! As in `render_cpu_alloc`, the one allocation that may remain is
//! rayon's: each `join` from outside the pool pushes a job onto the pool's
//! injector queue, a linked list of 63-slot blocks, so one block is
//! allocated every 63 jobs. Twenty verifications push 40 jobs: at most one
//! block boundary is crossed.

#![allow(clippy::expect_used, clippy::unwrap_used)] // test code: a failed step should panic

mod common;

use std::sync::Arc;

use common::counting_alloc::{
    start_counting_all_threads, stop_counting_all_threads, CountingAlloc,
};
use nalgebra::Translation3;
use star::geometry::look::camera_rotation;
use star::geometry::{PinholeCamera, Pose};
use star::reloc::{start_yaws_rad, verify_candidate, RelocConfig, Verdict};
use star::render::cpu::CpuRenderer;
use star::render::{RenderedView, Renderer};
use star::track::{build_config, Aligner, Keyframe, Pyramid, TrackerConfig};

#[global_allocator]
static GLOBAL: CountingAlloc = CountingAlloc;

#[test]
fn verifying_a_candidate_on_two_aligners_allocates_nothing() {
    let mesh = common::room::textured_room();
    let camera = PinholeCamera::new(320, 256, 210.0, 210.0, 159.5, 127.5);
    let config = RelocConfig {
        grid_spacing_m: 0.5,
        heights_m: vec![1.1, 1.5],
        ..RelocConfig::default()
    };
    let tracker = build_config(&TrackerConfig::default());
    let mut renderer = CpuRenderer::new(Arc::new(mesh)).expect("renderer");
    let mut view = RenderedView::for_camera(&camera);
    let truth = Pose::from_parts(
        Translation3::new(2.7, 2.3, 1.3),
        camera_rotation(0.4, (-8f64).to_radians(), 0.0),
    );
    renderer.render(&truth, &camera, &mut view).expect("frame");
    let frame = view.gray.to_u8();
    let mut pyramid = Pyramid::new(
        camera.width as usize,
        camera.height as usize,
        tracker.pyramid_levels as usize,
    );
    pyramid.fill_from_u8(frame.data(), frame.width());
    let candidate = Pose::from_parts(
        Translation3::new(2.5, 2.3, 1.3),
        camera_rotation(0.4 + 10f64.to_radians(), (-8f64).to_radians(), 0.0),
    );
    renderer
        .render(&candidate, &camera, &mut view)
        .expect("keyframe");
    let mut keyframe = Keyframe::new(&camera, &tracker);
    keyframe.prepare(&view, candidate, 1, &tracker);
    let mut aligners = [Aligner::new(&tracker), Aligner::new(&tracker)];
    let yaws = start_yaws_rad(&config, 0.0);
    // The pose it gives, to accept or to refine from.
    let mut verify =
        || match verify_candidate(&mut aligners, &keyframe, &pyramid, &camera, &config, &yaws) {
            Verdict::Accepted(v) => Some(v.world_from_camera),
            Verdict::Refine(p) => Some(p),
            Verdict::Rejected => None,
        };
    let first = verify();

    let mut same = 0;
    start_counting_all_threads();
    for _ in 0..20 {
        same += usize::from(verify() == first);
    }
    let allocations = stop_counting_all_threads();
    assert!(
        allocations <= 1,
        "{allocations} allocations in 20 verifications"
    );
    assert_eq!(same, 20, "the verdict changed between calls");
    let found = first.expect("a pose from the candidate 0.2 m away");
    let err = truth.inverse() * found;
    assert!(
        err.translation.vector.norm() < 0.05 && err.rotation.angle().to_degrees() < 2.0,
        "{:?} off, {:.2} deg",
        err.translation.vector,
        err.rotation.angle().to_degrees()
    );
}
