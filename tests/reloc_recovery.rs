//! End-to-end relocalization on a short synthetic sequence: a 1 s blackout
//! and a teleport. The tracker must report lost, output no pose while lost,
//! recover within 50 frames (1 s) of the end of the fault at a pose within
//! 5 cm of the truth, and increment `reset_counter`.

#![allow(clippy::expect_used, clippy::unwrap_used)] // test code: a failed step should panic

mod common;

use common::reloc_fixture::{fixture, run, spliced, Fixture, FAULT_START, FRAMES};
use star::dataset::Dataset;
use star::offline::OfflineReport;
use star::reloc::landmarks::{Landmark, MatchPass};
use star::reloc::Relocalizer;

/// Checks the acceptance criteria on a run with a fault in
/// `FAULT_START..fault_end` (`fault_end` = first frame after the fault).
fn check(report: &OfflineReport, ds: &Dataset, what: &str, fault_end: usize) {
    assert_eq!(report.frames, FRAMES, "{what}: every frame processed");
    let gt = ds.ground_truth.as_ref().expect("gt");
    // Every output pose is within 5 cm of the truth: no wrong pose, ever.
    for (stamp_s, pose) in report.estimate.stamps_s.iter().zip(&report.estimate.poses) {
        let i = gt
            .stamps_s
            .iter()
            .position(|t| (t - stamp_s).abs() < 1e-6)
            .expect("stamp in gt");
        let err_m = (gt.poses[i].translation.vector - pose.translation.vector).norm();
        assert!(err_m < 0.05, "{what}: frame {i} pose off by {err_m:.3} m");
    }
    let tracked: Vec<bool> = report.tracked.iter().map(|t| t.1).collect();
    assert!(
        tracked[..FAULT_START].iter().all(|&t| t),
        "{what}: tracks before the fault"
    );
    let first_lost = (FAULT_START..FRAMES).find(|&i| !tracked[i]);
    let first_lost = first_lost.unwrap_or_else(|| panic!("{what}: never reported lost"));
    assert!(
        first_lost <= FAULT_START + 2,
        "{what}: lost only at frame {first_lost}"
    );
    let recovered = (first_lost.max(fault_end)..FRAMES).find(|&i| tracked[i]);
    let recovered = recovered.unwrap_or_else(|| panic!("{what}: never recovered"));
    assert!(
        recovered <= fault_end + 50,
        "{what}: recovered at frame {recovered}, more than 50 frames after the fault"
    );
    assert_eq!(report.reset_counters[FAULT_START - 1], 0, "{what}");
    assert!(
        report.reset_counters[recovered] >= 1,
        "{what}: reset_counter incremented on recovery"
    );
    assert!(report.relocalizations >= 1, "{what}");
    // The counter never increments while tracking without a fault.
    assert!(report.reset_counters[..FAULT_START].iter().all(|&c| c == 0));
    eprintln!(
        "{what}: lost {} frames, recovered at frame {recovered} ({} frames after the fault), {} attempts",
        report.lost_frames,
        recovered - fault_end,
        report.reloc_attempts
    );
}

/// The coarse ranking on real frames: every database entry carries coarse
/// points, and the best-ranked candidate of a whole-map search is rendered
/// where its coarse alignment moved it, nearer the truth than the grid.
fn check_ranking(fx: &Fixture) {
    assert!(fx.db.entries.iter().all(|e| e.coarse_len >= 30));
    let ds = Dataset::open(&fx.root).expect("dataset");
    let camera = ds.camera();
    let build = star::track::build_config(&fx.config.tracker);
    let mut aligner = star::track::Aligner::new(&build);
    let mut pyramid = star::track::Pyramid::new(
        camera.width as usize,
        camera.height as usize,
        build.pyramid_levels as usize,
    );
    let mut reloc = Relocalizer::new(fx.db.clone(), &fx.config.reloc, camera).expect("reloc");
    let (mut near, mut tried, mut moved_closer) = (0, 0, 0);
    for i in (10..FRAMES).step_by(19) {
        let frame = ds.load_frame(i).expect("frame");
        pyramid.fill_from_u8(frame.data(), frame.width());
        let Some(query) =
            reloc.describe(frame.data(), frame.width(), frame.height(), frame.width())
        else {
            continue;
        };
        tried += 1;
        let truth = fx.gt.poses[i];
        let found = reloc.search_ranked(
            &query,
            star::reloc::SearchRegion::Everywhere,
            &mut aligner,
            &pyramid,
        );
        assert!(found.len() <= fx.config.reloc.top_k as usize);
        let Some(best) = found.first() else {
            continue;
        };
        let aligned_m =
            (best.world_from_camera.translation.vector - truth.translation.vector).norm();
        let entry = fx.db.entries[best.ranked.index as usize].world_from_camera;
        let entry_m = (entry.translation.vector - truth.translation.vector).norm();
        near += usize::from(aligned_m < 0.2);
        moved_closer += usize::from(aligned_m < entry_m);
        eprintln!("ranking frame {i}: best candidate {aligned_m:.3} m from the truth (its entry {entry_m:.3} m), score {:.2}", best.score);
    }
    assert!(tried >= 8, "{tried} frames searched");
    // Most best candidates land within 20 cm, and nearer than their entry
    // (without the coarse alignment none would move; 8 and 7 of 10 when
    // this was written).
    assert!(near * 10 >= tried * 6, "{near} of {tried} within 20 cm");
    assert!(
        moved_closer * 10 >= tried * 6,
        "{moved_closer} of {tried} moved closer"
    );
}

/// The landmarks on real frames (distorted, noisy, vignetted): the
/// features matched to the map's landmarks give, through RANSAC PnP, a pose
/// near the truth for most frames, with no database view involved.
fn check_landmarks(fx: &Fixture) {
    let ds = Dataset::open(&fx.root).expect("dataset");
    let camera = ds.camera();
    let mut reloc = Relocalizer::new(fx.db.clone(), &fx.config.reloc, camera).expect("reloc");
    let (mut tried, mut close) = (0, 0);
    for i in (10..FRAMES).step_by(19) {
        let frame = ds.load_frame(i).expect("frame");
        tried += 1;
        let truth = fx.gt.poses[i];
        let found = reloc.landmark_candidate(
            frame.data(),
            frame.width(),
            frame.height(),
            frame.width(),
            &[star::reloc::SearchRegion::Everywhere],
        );
        let Some((candidate, located)) = found else {
            eprintln!("landmarks frame {i}: no pose");
            continue;
        };
        let e = truth.inverse() * candidate.world_from_camera;
        let (err_m, err_deg) = (e.translation.vector.norm(), e.rotation.angle().to_degrees());
        close += usize::from(err_m < 0.05 && err_deg < 2.0);
        eprintln!(
            "landmarks frame {i}: pose {err_m:.3} m / {err_deg:.2} deg from the truth, {} inliers of {} matches",
            located.inliers, located.matches
        );
    }
    assert!(tried >= 8, "{tried} frames");
    assert!(
        close * 10 >= tried * 6,
        "{close} of {tried} within 5 cm / 2 deg"
    );
}

/// A room with a twin: every landmark of the fixture's map copied 30 m
/// along x, leaf by leaf of the vocabulary (as a database stores them).
/// Each corner's runner-up is now its twin, so the ratio test over the
/// whole map refuses every one; matched again place by place, the frame
/// must still give the pose of the room or of its twin, for most frames.
#[test]
fn the_landmark_pose_finds_a_room_whose_twin_is_in_the_map() {
    const TWIN_X_M: f32 = 30.0;
    let fx = fixture();
    let ds = Dataset::open(&fx.root).expect("dataset");
    let camera = ds.camera();
    let mut db = fx.db.clone();
    let mut landmarks: Vec<Landmark> = Vec::with_capacity(2 * db.landmarks.len());
    let mut start = 0usize;
    for size in db.vocabulary.leaf_sizes.iter_mut() {
        let leaf = &db.landmarks[start..start + *size as usize];
        landmarks.extend_from_slice(leaf);
        landmarks.extend(leaf.iter().map(|l| Landmark {
            world_m: [l.world_m[0] + TWIN_X_M, l.world_m[1], l.world_m[2]],
            descriptor: l.descriptor,
        }));
        start += *size as usize;
        *size *= 2;
    }
    assert_eq!(start, db.landmarks.len(), "leaves cover the landmarks");
    db.landmarks = landmarks;
    let mut reloc = Relocalizer::new(db, &fx.config.reloc, camera).expect("reloc");
    let (mut tried, mut close, mut from_places) = (0, 0, 0);
    for i in (10..FRAMES).step_by(19) {
        let frame = ds.load_frame(i).expect("frame");
        tried += 1;
        let truth = fx.gt.poses[i];
        let found = reloc.landmark_candidate(
            frame.data(),
            frame.width(),
            frame.height(),
            frame.width(),
            &[star::reloc::SearchRegion::Everywhere],
        );
        let Some((candidate, located)) = found else {
            eprintln!("twin landmarks frame {i}: no pose");
            continue;
        };
        let mut pose = candidate.world_from_camera;
        let in_twin =
            pose.translation.vector.x > truth.translation.vector.x + 0.5 * TWIN_X_M as f64;
        if in_twin {
            pose.translation.vector.x -= TWIN_X_M as f64;
        }
        let e = truth.inverse() * pose;
        let (err_m, err_deg) = (e.translation.vector.norm(), e.rotation.angle().to_degrees());
        close += usize::from(err_m < 0.05 && err_deg < 2.0);
        from_places += usize::from(located.pass == MatchPass::Place);
        eprintln!(
            "twin landmarks frame {i}: {:?}, in the twin: {in_twin}, {err_m:.3} m / {err_deg:.2} deg from the truth, {} inliers of {} matches",
            located.pass, located.inliers, located.matches
        );
    }
    assert!(tried >= 8, "{tried} frames");
    assert!(
        close * 10 >= tried * 6,
        "{close} of {tried} within 5 cm / 2 deg of the room or its twin"
    );
    assert!(
        from_places * 10 >= tried * 6,
        "{from_places} of {tried} from the places (the ratio test refuses every corner)"
    );
}

#[test]
fn recovers_after_blackout_and_teleport() {
    let fx = fixture();
    check_ranking(fx);
    check_landmarks(fx);
    let tmp = tempfile::tempdir().expect("tmp");

    // (a) 1 s blackout: 50 black frames from FAULT_START.
    let fault_end = FAULT_START + 50;
    let ds = spliced(fx, &tmp.path().join("blackout"), |i| {
        (!(FAULT_START..fault_end).contains(&i)).then_some(i)
    });
    let report = run(fx, &ds);
    check(&report, &ds, "blackout", fault_end);

    // (b) teleport: at FAULT_START the images jump 80 frames (1.6 s, about
    // 0.8 m) ahead along the trajectory; the fault is that one jump.
    let ds = spliced(fx, &tmp.path().join("teleport"), |i| {
        Some(if i < FAULT_START {
            i
        } else {
            (i + 80).min(FRAMES - 1)
        })
    });
    let report = run(fx, &ds);
    check(&report, &ds, "teleport", FAULT_START);
}
