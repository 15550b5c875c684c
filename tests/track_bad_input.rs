//! Bad input to the tracker: every case gets a clear error or the lost
//! state, never a panic and never a non-finite pose. Data comes from
//! `star synth --preset ideal` with a fixed seed, damaged per case.

#![allow(clippy::expect_used, clippy::unwrap_used)] // test code: a failed step should panic

mod common;

use std::path::Path;
use std::sync::Arc;

use nalgebra::{Translation3, UnitQuaternion, Vector3};
use star::config::Config;
use star::dataset::Dataset;
use star::geometry::Pose;
use star::localizer::{Localizer, LocalizerError, TrackState};
use star::map::{Mesh, MeshGroup};
use star::offline::{localize_dataset, OfflineOptions};
use star::render::cpu::CpuRenderer;

const FRAMES: usize = 40;

fn synth(out: &Path) {
    common::star_cli::synth_no_depth(out, "ideal", 21, FRAMES);
}

fn cpu_renderer(dir: &Path) -> Box<CpuRenderer> {
    let mesh = star::map::load_obj(&dir.join("map/map.obj")).expect("map");
    Box::new(CpuRenderer::new(Arc::new(mesh)).expect("renderer"))
}

fn start(dir: &Path, dataset: &Dataset, init: Pose) -> Localizer {
    let config = Config::default();
    Localizer::start(
        cpu_renderer(dir),
        dataset.camera(),
        &config.tracker,
        &config.keyframe,
        init,
        1_000,
    )
    .expect("start")
}

fn first_pose(dataset: &Dataset) -> Pose {
    dataset.ground_truth.as_ref().expect("gt").poses[0]
}

fn assert_finite(pose: &Pose) {
    assert!(
        pose.translation.vector.iter().all(|v| v.is_finite())
            && pose.rotation.coords.iter().all(|v| v.is_finite()),
        "non-finite pose {pose:?}"
    );
}

#[test]
fn missing_and_corrupt_images_are_reported_and_skipped() {
    let tmp = tempfile::tempdir().expect("tmp");
    synth(tmp.path());
    let dataset = Dataset::open(tmp.path()).expect("open");
    // Frame 5 goes missing, frame 9 becomes garbage, frame 12 is truncated.
    std::fs::remove_file(tmp.path().join(&dataset.frames[5].path)).expect("rm");
    std::fs::write(tmp.path().join(&dataset.frames[9].path), b"not a png").expect("write");
    let p12 = tmp.path().join(&dataset.frames[12].path);
    let bytes = std::fs::read(&p12).expect("read");
    std::fs::write(&p12, &bytes[..bytes.len() / 3]).expect("truncate");

    let report = localize_dataset(
        &dataset,
        cpu_renderer(tmp.path()),
        &Config::default(),
        &OfflineOptions::default(),
        |_| {},
    )
    .expect("localize runs through bad frames");
    let bad: Vec<usize> = report.bad_frames.iter().map(|(i, _)| *i).collect();
    assert_eq!(bad, vec![5, 9, 12], "{:?}", report.bad_frames);
    for (i, reason) in &report.bad_frames {
        let name = dataset.frames[*i].path.to_string_lossy().to_string();
        assert!(reason.contains(&name), "error names the file: {reason}");
    }
    assert_eq!(report.frames, FRAMES - 3);
    assert_eq!(report.lost_frames, 0, "good frames keep tracking");
    let e = report.evaluation.expect("evaluation");
    assert!(e.ate.translation_m.rmse < 0.01);
}

#[test]
fn wrong_size_and_out_of_order_frames_are_rejected() {
    let tmp = tempfile::tempdir().expect("tmp");
    synth(tmp.path());
    let dataset = Dataset::open(tmp.path()).expect("open");
    let mut localizer = start(tmp.path(), &dataset, first_pose(&dataset));
    let frame = dataset.load_frame(0).expect("frame");
    let (w, h) = (frame.width(), frame.height());

    let small = vec![0u8; 320 * 256];
    let err = localizer
        .process_frame(&small, 320, 256, 320, 2_000)
        .unwrap_err();
    assert!(matches!(err, LocalizerError::FrameSize { .. }), "{err}");
    assert!(err.to_string().contains("320x256"), "{err}");
    // A buffer too short for its declared size.
    let err = localizer
        .process_frame(&frame.data()[..w * h / 2], w, h, w, 2_000)
        .unwrap_err();
    assert!(matches!(err, LocalizerError::FrameSize { .. }), "{err}");

    let out = localizer
        .process_frame(frame.data(), w, h, w, 5_000)
        .expect("good frame");
    assert_eq!(out.state, TrackState::Tracking);
    for stamp_ns in [5_000, 4_000] {
        let err = localizer
            .process_frame(frame.data(), w, h, w, stamp_ns)
            .unwrap_err();
        assert!(
            matches!(err, LocalizerError::TimestampOrder { .. }),
            "{err}"
        );
    }
    // Still tracking after the rejected frames.
    let out = localizer
        .process_frame(frame.data(), w, h, w, 6_000)
        .expect("good frame");
    assert_eq!(out.state, TrackState::Tracking);
}

#[test]
fn non_monotonic_dataset_timestamps_are_an_error() {
    let tmp = tempfile::tempdir().expect("tmp");
    synth(tmp.path());
    let list = tmp.path().join("rgb.txt");
    let text = std::fs::read_to_string(&list).expect("read");
    let mut lines: Vec<&str> = text.lines().collect();
    let n = lines.len();
    lines.swap(n - 1, n - 2);
    std::fs::write(&list, lines.join("\n")).expect("write");
    let err = Dataset::open(tmp.path()).unwrap_err().to_string();
    assert!(err.contains("rgb.txt"), "{err}");
}

#[test]
fn all_black_frames_are_lost_without_a_pose() {
    let tmp = tempfile::tempdir().expect("tmp");
    synth(tmp.path());
    let dataset = Dataset::open(tmp.path()).expect("open");
    let mut localizer = start(tmp.path(), &dataset, first_pose(&dataset));
    let frame = dataset.load_frame(0).expect("frame");
    let (w, h) = (frame.width(), frame.height());
    localizer
        .process_frame(frame.data(), w, h, w, 2_000)
        .expect("good frame");
    let black = vec![0u8; w * h];
    for k in 0..10u64 {
        let out = localizer
            .process_frame(&black, w, h, w, 3_000 + k * 20_000_000)
            .expect("processed");
        assert_eq!(out.state, TrackState::Lost, "black frame {k}");
        assert!(out.world_from_camera.is_none());
    }
    // One loss (the first black frame), counted under the test it failed.
    let losses = localizer.stats().losses;
    eprintln!("losses by reason: {losses:?}");
    assert_eq!(losses.iter().sum::<u64>(), 1, "{losses:?}");
    assert_eq!(
        localizer
            .stats()
            .losses_for(star::localizer::LossReason::NotAligned),
        1,
        "a black frame does not align: {losses:?}"
    );
}

/// What each frame gave: its state, whether a pose was output, and whether
/// the loop was searching.
type Outputs = Vec<(TrackState, bool, bool)>;

/// Tracks the first `frames` frames of a fresh `ideal` sequence from its
/// true first pose, with the frames in `black` replaced by black ones (a
/// loss), each followed by a pause of `pause_ms` (0: none).
fn localize_with_black_frames(
    frames: usize,
    black: std::ops::Range<usize>,
    pause_ms: u64,
) -> (Localizer, Outputs) {
    let tmp = tempfile::tempdir().expect("tmp");
    synth(tmp.path());
    let dataset = Dataset::open(tmp.path()).expect("open");
    let mut localizer = start(tmp.path(), &dataset, first_pose(&dataset));
    let (w, h) = {
        let f = dataset.load_frame(0).expect("frame");
        (f.width(), f.height())
    };
    let black_pixels = vec![0u8; w * h];
    let mut outputs = Vec::new();
    for i in 0..frames {
        let stamp_ns = (dataset.frames[i].timestamp_s * 1e9).round() as u64;
        let frame = dataset.load_frame(i).expect("frame");
        let lost = black.contains(&i);
        let pixels = if lost {
            &black_pixels[..]
        } else {
            frame.data()
        };
        let out = localizer
            .process_frame(pixels, w, h, w, stamp_ns)
            .expect("processed");
        if lost && pause_ms > 0 {
            std::thread::sleep(std::time::Duration::from_millis(pause_ms));
        }
        outputs.push((out.state, out.world_from_camera.is_some(), out.searching));
    }
    (localizer, outputs)
}

/// A frame that resumes tracking on its own after a loss is tracked but
/// not output: the next frame must track too, as after a relocalization.
#[test]
fn a_resume_after_a_short_loss_is_output_from_the_next_tracked_frame() {
    // Frames 10 and 11 are lost (black); 12 resumes.
    let (localizer, outputs) = localize_with_black_frames(20, 10..12, 0);
    let tracking = (TrackState::Tracking, true, false);
    assert!(outputs[..10].iter().all(|o| *o == tracking), "{outputs:?}");
    assert!(
        outputs[10..12]
            .iter()
            .all(|o| o.0 == TrackState::Lost && !o.1),
        "{outputs:?}"
    );
    assert_eq!(
        outputs[12],
        (TrackState::Lost, false, true),
        "the resuming frame is tracked, not output: {outputs:?}"
    );
    assert!(outputs[13..].iter().all(|o| *o == tracking), "{outputs:?}");
    let stats = localizer.stats();
    assert_eq!(stats.held_resumes, 1);
    assert_eq!(stats.lost_frames, 3, "two lost, one held");
}

/// During a short loss the keyframe follows the camera: the frame that
/// resumes is aligned against a keyframe near it, not the one from before
/// the loss (which `aggressive` leaves 30-40 degrees behind in 0.2 s).
#[test]
fn a_short_loss_asks_for_keyframes_near_the_camera() {
    // Frames 10 to 15 are lost (black, 0.12 s of capture time); each waits
    // a little so the render thread is free for the next request.
    let (localizer, outputs) = localize_with_black_frames(24, 10..16, 40);
    let stats = localizer.stats();
    assert!(
        stats.lost_keyframes >= 1,
        "no keyframe asked for in 6 lost frames: {stats:?}"
    );
    let sent: Vec<bool> = outputs.iter().map(|o| o.1).collect();
    assert!(sent[..10].iter().all(|&o| o), "{outputs:?}");
    assert!(
        !sent[10..17].iter().any(|&o| o),
        "lost, then held: {outputs:?}"
    );
    assert!(sent[17..].iter().all(|&o| o), "resumed: {outputs:?}");
}

#[test]
fn far_off_initial_pose_never_gives_a_wrong_pose() {
    let tmp = tempfile::tempdir().expect("tmp");
    synth(tmp.path());
    let dataset = Dataset::open(tmp.path()).expect("open");
    let gt = dataset.ground_truth.clone().expect("gt");
    // 1.5 m to the side and turned 60 degrees: the keyframe shows another view.
    let truth = first_pose(&dataset);
    let off = truth
        * Pose::from_parts(
            Translation3::new(1.5, 0.0, 0.5),
            UnitQuaternion::from_axis_angle(&Vector3::y_axis(), 60f64.to_radians()),
        );
    let mut localizer = start(tmp.path(), &dataset, off);
    let mut image = star::imgproc::ImageU8::new(0, 0, 0);
    let mut lost = 0;
    let mut max_correlation = f32::MIN;
    for i in 0..20 {
        dataset
            .load_frame_into(i, &mut image, &mut Vec::new())
            .expect("frame");
        let out = localizer
            .process_frame(
                image.data(),
                image.width(),
                image.height(),
                image.width(),
                2_000 + i as u64 * 20_000_000,
            )
            .expect("processed");
        max_correlation = max_correlation.max(out.quality.correlation);
        match out.world_from_camera {
            None => lost += 1,
            Some(pose) => {
                assert_finite(&pose);
                let err_m = (pose.translation.vector - gt.poses[i].translation.vector).norm();
                panic!(
                    "frame {i}: a pose {err_m:.2} m from the truth was output from a far-off start"
                );
            }
        }
    }
    eprintln!("far-off start: highest correlation {max_correlation:.3}");
    assert_eq!(lost, 20);
}

#[test]
fn texture_less_view_is_lost_or_refused() {
    // A uniform gray wall: no gradient, no keyframe points.
    let mesh = Mesh {
        positions: vec![
            [-3.0, -3.0, 3.0],
            [3.0, -3.0, 3.0],
            [3.0, 3.0, 3.0],
            [-3.0, 3.0, 3.0],
        ],
        gray: vec![128.0; 4],
        uvs: Vec::new(),
        indices: vec![0, 1, 2, 0, 2, 3],
        groups: vec![MeshGroup {
            first_index: 0,
            index_count: 6,
            texture: None,
        }],
        textures: Vec::new(),
    };
    let camera = star::geometry::PinholeCamera::new(640, 512, 420.0, 420.0, 319.5, 255.5);
    let config = Config::default();
    let renderer = Box::new(CpuRenderer::new(Arc::new(mesh)).expect("renderer"));
    match Localizer::start(
        renderer,
        &camera,
        &config.tracker,
        &config.keyframe,
        Pose::identity(),
        1_000,
    ) {
        // Refusing to start on a view with nothing to track is a clear error.
        Err(e) => assert!(!e.to_string().is_empty()),
        Ok(mut localizer) => {
            let flat = vec![128u8; 640 * 512];
            for k in 0..5u64 {
                let out = localizer
                    .process_frame(&flat, 640, 512, 640, 2_000 + k * 20_000_000)
                    .expect("processed");
                assert_eq!(out.state, TrackState::Lost);
                assert!(out.world_from_camera.is_none());
            }
        }
    }
}

/// `[keyframe] hold_for_next_frame`: a tracked frame is sent only once the
/// next frame tracks too, through `star localize`'s path. Frames 10 and 11
/// are black (lost): frame 9 is tracked but not sent, nor is the last frame
/// (no frame follows it); every other pose goes out as without the hold.
#[test]
fn a_pose_held_for_the_next_frame_is_not_sent_when_that_frame_is_lost() {
    let tmp = tempfile::tempdir().expect("tmp");
    synth(tmp.path());
    let dataset = Dataset::open(tmp.path()).expect("open");
    for i in [10, 11] {
        let path = tmp.path().join(&dataset.frames[i].path);
        let frame = image::open(&path).expect("frame");
        image::DynamicImage::new(frame.width(), frame.height(), frame.color())
            .save(&path)
            .expect("black frame");
    }
    let run = |hold: bool| {
        let mut config = Config::default();
        config.keyframe.hold_for_next_frame = hold;
        localize_dataset(
            &dataset,
            cpu_renderer(tmp.path()),
            &config,
            &OfflineOptions::default(),
            |_| {},
        )
        .expect("localize")
    };
    let stamp = |i: usize| dataset.frames[i].timestamp_s;
    let sent = |report: &star::offline::OfflineReport| -> Vec<usize> {
        (0..FRAMES)
            .filter(|&i| report.estimate.stamps_s.iter().any(|&s| s == stamp(i)))
            .collect()
    };
    let plain = run(false);
    let held = run(true);
    let plain_sent = sent(&plain);
    // Without the hold: every frame but the two black ones and the resume
    // (12), which is held as a resume is.
    let expected_plain: Vec<usize> = (0..FRAMES).filter(|i| ![10, 11, 12].contains(i)).collect();
    assert_eq!(plain_sent, expected_plain);
    assert_eq!(plain.held_for_next_frame, None);
    let expected_held: Vec<usize> = expected_plain
        .iter()
        .copied()
        .filter(|&i| i != 9 && i != FRAMES - 1)
        .collect();
    assert_eq!(
        sent(&held),
        expected_held,
        "frames 9 and {} withheld",
        FRAMES - 1
    );
    assert_eq!(held.held_for_next_frame, Some(2));
    assert_eq!(
        held.frames, plain.frames,
        "every frame processed either way"
    );
    assert_eq!(held.lost_frames, plain.lost_frames + 2);
    // The poses that go out are the frames' own, at their own stamps.
    for (i, s) in held.estimate.stamps_s.iter().enumerate() {
        let k = plain
            .estimate
            .stamps_s
            .iter()
            .position(|p| p == s)
            .expect("sent without the hold too");
        let d = (held.estimate.poses[i].translation.vector
            - plain.estimate.poses[k].translation.vector)
            .norm();
        assert!(d < 0.01, "frame at {s} s differs by {d} m");
    }
}
