//! Integrity: no wrong pose is ever sent (more than 10 cm or 5 degrees from
//! the truth, counted without alignment by `star::offline::integrity`), under
//! the faults that broke the closed world: a cold start without a pose, a
//! wrong initial hint 1-3 m off (with and without a database), a covered
//! lens, frames from a different place, a view that jumps, twin and
//! look-alike rooms, and a hint facing the wrong way. Where
//! recovery is possible it must happen; where it is not, nothing is sent.

#![allow(clippy::expect_used, clippy::unwrap_used)] // test code: a failed step should panic

mod common;

use common::reloc_fixture::{
    assembled, fixture, frame_path, run_with, write_image, Fixture, FAULT_START, FRAMES,
};
use common::room::twin_map;
use nalgebra::{Translation3, Vector3};
use star::dataset::Dataset;
use star::geometry::Pose;
use star::localizer::LossReason;
use star::offline::{OfflineOptions, OfflineReport, StartMode};
use star::synth::preset::Preset;
use star::synth::sequence::{write_sequence, SequenceOptions};

/// The frame rate of the fixture sequence.
const RATE_HZ: f64 = 50.0;

fn integrity(report: &OfflineReport, what: &str) -> star::offline::Integrity {
    let i = report.integrity.expect("the dataset has ground truth");
    eprintln!(
        "{what}: {} poses sent, {} wrong, largest error {:.3} m / {:.2} deg, first pose after {:?} s, {} reloc attempts",
        report.estimate.len(),
        i.wrong_poses,
        i.max_position_error_m,
        i.max_rotation_error_deg,
        i.first_pose_after_s,
        report.reloc_attempts
    );
    assert_eq!(report.frames, FRAMES, "{what}: every frame processed");
    assert_eq!(
        i.poses_checked,
        report.estimate.len(),
        "{what}: every pose checked"
    );
    assert_eq!(i.wrong_poses, 0, "{what}: wrong poses sent");
    i
}

fn plain(fx: &Fixture) -> Dataset {
    Dataset::open(&fx.root).expect("dataset")
}

#[test]
fn cold_start_and_wrong_hints_cost_time_never_a_wrong_pose() {
    let fx = fixture();
    let ds = plain(fx);

    // A cold start: no pose at all; the first frames are searched in the
    // database. The figure targets 2 s median; one start must be well within.
    let options = OfflineOptions {
        start: StartMode::Cold,
        ..OfflineOptions::default()
    };
    let report = run_with(fx, &ds, options, true);
    let i = integrity(&report, "cold start");
    let first_s = i.first_pose_after_s.expect("cold start: a pose was found");
    assert!(first_s <= 2.0, "cold start: first pose after {first_s} s");
    assert!(report.estimate.len() >= FRAMES - (first_s * RATE_HZ) as usize - 5);

    // A right hint is confirmed within two frames.
    let options = OfflineOptions {
        start: StartMode::Hint,
        world_from_camera_start: Some(fx.gt.poses[0]),
        ..OfflineOptions::default()
    };
    let report = run_with(fx, &ds, options, false);
    let i = integrity(&report, "right hint, no database");
    assert!(i.first_pose_after_s.expect("confirmed") <= 2.0 / RATE_HZ + 1e-9);

    // Wrong hints, 1 to 3 m off: with a database the tracker finds the
    // truth; without one it sends nothing.
    let truth = fx.gt.poses[0];
    for (offset_m, direction) in [
        (1.0, [1.0, 0.0, 0.0]),
        (2.0, [0.0, -1.0, 0.0]),
        (3.0, [-0.7, 0.7, 0.0]),
    ] {
        let shift = Vector3::from(direction).normalize() * offset_m;
        let hint = Pose::from_parts(
            Translation3::from(truth.translation.vector + shift),
            truth.rotation,
        );
        let with_db = OfflineOptions {
            start: StartMode::Hint,
            world_from_camera_start: Some(hint),
            ..OfflineOptions::default()
        };
        let what = format!("hint {offset_m} m off, database");
        let report = run_with(fx, &ds, with_db.clone(), true);
        let i = integrity(&report, &what);
        let first_s = i
            .first_pose_after_s
            .unwrap_or_else(|| panic!("{what}: never recovered"));
        assert!(first_s <= 2.0, "{what}: first pose after {first_s} s");

        let what = format!("hint {offset_m} m off, no database");
        let report = run_with(fx, &ds, with_db, false);
        integrity(&report, &what);
    }
}

#[test]
fn a_covered_lens_sends_nothing_and_tracking_recovers() {
    let fx = fixture();
    let tmp = tempfile::tempdir().expect("tmp");

    // A covered lens for 1 s: dark, with sensor noise.
    let covered = write_image(&tmp.path().join("covered.png"), |x, y| {
        (6 + ((x * 7919 + y * 104_729) % 7)) as u8
    });
    let fault_end = FAULT_START + 50;
    let ds = assembled(fx, &tmp.path().join("covered"), |i| {
        let image = if (FAULT_START..fault_end).contains(&i) {
            covered.clone()
        } else {
            frame_path(fx, i)
        };
        (image, fx.gt.poses[i])
    });
    let report = run_with(fx, &ds, OfflineOptions::default(), true);
    integrity(&report, "covered lens");
    let tracked: Vec<bool> = report.tracked.iter().map(|t| t.1).collect();
    assert!(
        tracked[FAULT_START + 2..fault_end].iter().all(|t| !t),
        "covered lens: a pose was sent while the lens was covered"
    );
    let recovered = (fault_end..FRAMES).find(|&i| tracked[i]);
    let recovered = recovered.expect("covered lens: never recovered");
    assert!(
        recovered <= fault_end + 50,
        "covered lens: recovered at {recovered}"
    );
}

#[test]
fn frames_of_a_look_alike_room_send_nothing() {
    let fx = fixture();
    let tmp = tempfile::tempdir().expect("tmp");

    // Frames from a place that looks alike: another seed's room (another
    // layout and flight) papered with the very textures of the mapped room
    // (seed 3), LOOK_ALIKE_FRAMES of them from FAULT_START on, then the
    // mapped room's own frames again. Any pose sent for the look-alike
    // frames is wrong; their truth is set 1 km away so the count sees it.
    // (The look-alike ran to the end of the sequence until 2026-12-07,
    // 150 frames, each searched in the database: 96 s of CI's time.)
    const LOOK_ALIKE_FRAMES: usize = 75;
    let other = tmp.path().join("other");
    let mut preset = Preset::by_name("realistic").expect("preset");
    preset.scene.texture_seed = Some(3);
    let options = SequenceOptions {
        preset,
        seed: 11,
        frames: FAULT_START + LOOK_ALIKE_FRAMES,
        write_depth: false,
    };
    write_sequence(&other, &options, &mut |_| {}).expect("other sequence");
    let other_ds = Dataset::open(&other).expect("other dataset");
    let elsewhere = Pose::translation(1000.0, 0.0, 0.0);
    let ds = assembled(fx, &tmp.path().join("elsewhere"), |i| {
        if (FAULT_START..FAULT_START + LOOK_ALIKE_FRAMES).contains(&i) {
            (other.join(&other_ds.frames[i].path), elsewhere)
        } else {
            (frame_path(fx, i), fx.gt.poses[i])
        }
    });
    let report = run_with(fx, &ds, OfflineOptions::default(), true);
    integrity(&report, "look-alike room");
    let back = FAULT_START + LOOK_ALIKE_FRAMES;
    let sent_elsewhere = report.tracked[FAULT_START + 2..back]
        .iter()
        .filter(|t| t.1)
        .count();
    assert_eq!(
        sent_elsewhere, 0,
        "poses sent for frames of the look-alike room"
    );
    // Back in the mapped room, the search finds it again.
    let resumed = (back..FRAMES).find(|&i| report.tracked[i].1);
    assert!(
        resumed.is_some_and(|i| i <= back + 50),
        "back in the mapped room at frame {back}: resumed at {resumed:?}"
    );
}

#[test]
fn a_view_that_jumps_is_not_sent() {
    // From FAULT_START on, the frames run 6 frames (0.12 s) ahead: between
    // two frames 20 ms apart the view jumps about 8 cm, more than a vehicle
    // moves, as when an unmapped object drags the alignment off. The
    // alignment does not follow such a jump; it settles near the
    // prediction, degrees wrong, with some inliers by chance. The lost test
    // must refuse that frame (its correlation falls far below its running
    // mean; with the old test, 0.2 absolute and a 0.3 m jump, the run
    // without a database sent 5 poses up to 0.9 m wrong). Tracking resumes
    // only through the relocalization gate.
    const AHEAD: usize = 6;
    let fx = fixture();
    let moved_m = (fx.gt.poses[FAULT_START + AHEAD].translation.vector
        - fx.gt.poses[FAULT_START - 1].translation.vector)
        .norm();
    assert!(
        (0.05..0.3).contains(&moved_m),
        "the fixture's jump is {moved_m} m: past the jump limit, within the old 0.3 m"
    );
    let tmp = tempfile::tempdir().expect("tmp");
    let ds = common::reloc_fixture::spliced(fx, &tmp.path().join("ahead"), |i| {
        if i < FAULT_START {
            Some(i)
        } else {
            Some(i + AHEAD).filter(|&j| j < FRAMES)
        }
    });
    for database in [true, false] {
        let what = format!("a view jumping {moved_m:.3} m, database: {database}");
        let report = run_with(fx, &ds, OfflineOptions::default(), database);
        integrity(&report, &what);
        let tracked: Vec<bool> = report.tracked.iter().map(|t| t.1).collect();
        assert!(
            tracked[FAULT_START - 1],
            "{what}: not tracking before the jump"
        );
        assert!(
            !tracked[FAULT_START],
            "{what}: the frame after the jump was sent"
        );
        eprintln!("{what}: losses by reason {:?}", report.losses);
        // Lost on the correlation: below its floor or its running mean
        // (which one varies from run to run with the render's timing).
        let on_correlation = [LossReason::Correlation, LossReason::CorrelationDrop]
            .map(|r| report.losses[r.index()])
            .iter()
            .sum::<u64>();
        assert!(
            on_correlation >= 1,
            "{what}: the jump was not lost on the correlation: {:?}",
            report.losses
        );
        if database {
            let resumed = (FAULT_START..FRAMES - AHEAD).find(|&i| tracked[i]);
            let resumed = resumed.unwrap_or_else(|| panic!("{what}: never resumed"));
            assert!(
                resumed <= FAULT_START + 50,
                "{what}: resumed only at frame {resumed}"
            );
        }
    }
}

/// A map of the fixture room and a copy of it beyond the far limit (`shade`
/// paints the copy, see [`twin_map`]), and a database with views along the
/// flight in both rooms.
struct TwinMap {
    mesh: std::sync::Arc<star::map::Mesh>,
    db: star::reloc::RelocDatabase,
}

impl TwinMap {
    fn new(shade: impl Fn([f32; 3], f32) -> f32) -> Self {
        use star::reloc::{build_database_along, AlongTrajectory};
        use star::render::cpu::CpuRenderer;
        use std::sync::Arc;

        let fx = fixture();
        let ds = plain(fx);
        let mesh = star::map::load_obj(&fx.root.join("map").join("map.obj")).expect("map");
        // Far enough along that neither room is seen from the other (through a
        // doorway) within the renderer's far limit, a whole number of grid
        // steps, so that the twins' database views are the same views.
        let (lo_m, hi_m) = mesh.bounds().expect("bounds");
        let step_m = fx.config.reloc.grid_spacing_m;
        let clear_m = f64::from(hi_m[0] - lo_m[0]) + fx.config.render.far_m + 1.0;
        let offset_x_m = (clear_m / step_m).ceil() * step_m;
        let twin = Arc::new(twin_map(&mesh, offset_x_m as f32, shade));
        let mut renderer = CpuRenderer::new(twin.clone()).expect("renderer");
        // The grid over the flown region, and views along the flight in both
        // rooms (as `star reloc build --poses` takes them).
        let shifted = Translation3::new(offset_x_m, 0.0, 0.0);
        let along = AlongTrajectory {
            poses: fx
                .gt
                .poses
                .iter()
                .copied()
                .chain(
                    fx.gt
                        .poses
                        .iter()
                        .map(|p| Pose::from_parts(shifted * p.translation, p.rotation)),
                )
                .collect(),
            spacing_m: 0.3,
        };
        let db = build_database_along(
            &twin,
            ds.camera(),
            &mut renderer,
            &fx.config.reloc,
            Some(fx.region),
            &along,
            &mut |_, _| {},
        )
        .expect("database over both rooms");
        Self { mesh: twin, db }
    }

    /// The room and its exact copy, built once per test binary: two tests
    /// fly it (one database build less: docs/ci.md).
    fn identical() -> &'static Self {
        static SHARED: std::sync::OnceLock<TwinMap> = std::sync::OnceLock::new();
        SHARED.get_or_init(|| Self::new(|_, g| g))
    }

    /// Localizes the fixture's flight (cold or from a right hint) in this map.
    fn run(&self, starts: &[StartMode]) -> Vec<OfflineReport> {
        let hint = fixture().gt.poses[0];
        let starts: Vec<(StartMode, Option<Pose>)> = starts
            .iter()
            .map(|&s| (s, (s == StartMode::Hint).then_some(hint)))
            .collect();
        self.run_from(&starts)
    }

    /// As [`Self::run`], each run with its own start hint.
    fn run_from(&self, starts: &[(StartMode, Option<Pose>)]) -> Vec<OfflineReport> {
        use star::reloc::Relocalizer;
        use star::render::cpu::CpuRenderer;

        let fx = fixture();
        let ds = plain(fx);
        starts
            .iter()
            .map(|&(start, hint)| {
                let options = OfflineOptions {
                    start,
                    world_from_camera_start: hint,
                    relocalizer: Some(
                        Relocalizer::new(self.db.clone(), &fx.config.reloc, ds.camera())
                            .expect("reloc"),
                    ),
                    ..OfflineOptions::default()
                };
                let renderer = Box::new(CpuRenderer::new(self.mesh.clone()).expect("renderer"));
                star::offline::localize_dataset(&ds, renderer, &fx.config, &options, |_| {})
                    .expect("localize")
            })
            .collect()
    }
}

#[test]
fn a_twin_room_refuses_a_cold_start_and_a_hint_still_starts() {
    let reports = TwinMap::identical().run(&[StartMode::Cold, StartMode::Hint]);
    let [cold, hinted] = &reports[..] else {
        panic!("two runs");
    };

    // A cold start sees a room that is in the map twice: candidates pass the
    // gate in both, and nothing may be sent.
    let i = integrity(cold, "cold start, twin rooms");
    assert!(
        cold.reloc_ambiguous > 0,
        "the twin was never found: {} attempts",
        cold.reloc_attempts
    );
    assert_eq!(cold.relocalizations, 0, "a twin room was chosen");
    assert_eq!(i.poses_checked, 0);

    // A right hint is the prior that chooses: tracking starts.
    let i = integrity(hinted, "right hint, twin rooms");
    assert!(i.poses_checked > FRAMES / 2, "{} poses", i.poses_checked);
}

#[test]
fn a_look_alike_room_is_told_apart_by_its_correlation() {
    // The copy has a dark band painted across floor, walls and ceiling
    // (a fifth of the room's length): views of it still pass the gate in
    // the copy, which tolerates what the map lacks, but correlate worse.
    let mesh_x = std::sync::OnceLock::new();
    let reports = TwinMap::new(|p, g| {
        let &(lo, hi) = mesh_x.get_or_init(|| {
            let fx = fixture();
            let mesh = star::map::load_obj(&fx.root.join("map").join("map.obj")).expect("map");
            let (lo, hi) = mesh.bounds().expect("bounds");
            (lo[0], hi[0])
        });
        let t = (p[0] - lo) / (hi - lo);
        if (0.4..0.6).contains(&t) {
            0.5 * g
        } else {
            g
        }
    })
    .run(&[StartMode::Cold]);
    let cold = &reports[0];
    let i = integrity(cold, "cold start, look-alike rooms");
    assert!(
        cold.reloc_decided > 0,
        "no passing rival was told apart: {} attempts, {} ambiguous",
        cold.reloc_attempts,
        cold.reloc_ambiguous
    );
    assert!(cold.relocalizations > 0, "never started");
    assert!(i.poses_checked > FRAMES / 2, "{} poses", i.poses_checked);
}

#[test]
fn a_hint_at_the_right_place_facing_the_wrong_way_is_not_trusted() {
    // An operator's `init_pose` with the right position and the yaw off by
    // half a turn, in a room that has a twin: the hint fails its
    // verification (the view it predicts is the other half of the room),
    // and a hint that was never verified is no motion prior, so the search
    // that follows is a cold one, which the twin refuses. Nothing may be
    // sent, and in particular not the hint.
    let fx = fixture();
    let hint = fx.gt.poses[0];
    let turn = nalgebra::UnitQuaternion::from_axis_angle(&Vector3::z_axis(), std::f64::consts::PI);
    let turned = Pose::from_parts(hint.translation, turn * hint.rotation);
    let reports = TwinMap::identical().run_from(&[(StartMode::Hint, Some(turned))]);
    let report = &reports[0];
    let i = integrity(report, "hint facing the wrong way, twin rooms");
    assert_eq!(i.poses_checked, 0, "a pose was sent");
    assert_eq!(report.relocalizations, 0, "a room was chosen");
    assert!(
        report.reloc_ambiguous > 0,
        "the search never met the twin: {} attempts",
        report.reloc_attempts
    );
}
