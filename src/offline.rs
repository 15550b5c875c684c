//! Offline localization of a recorded dataset: the same STAR loop as on the
//! vehicle, fed from a TUM-layout folder instead of the camera, with timing
//! and quality summaries. Used by `star localize`, the accuracy tests and
//! the benchmarks.

use std::time::Instant;

use crate::config::Config;
use crate::dataset::{Dataset, Trajectory};
use crate::eval::{self, Evaluation};
use crate::geometry::Pose;
use crate::imgproc::ImageU8;
use crate::render::Renderer;

use crate::localizer::{FrameOutput, Localizer, LocalizerError, NextFrameHold, TrackState};
use crate::output::{FramePixels, FrameSinks, RecordSink};

/// Errors of an offline run.
#[derive(Debug, thiserror::Error)]
pub enum OfflineError {
    /// No `--init-pose` and no ground truth to start from.
    #[error("no initial pose: give one, or provide groundtruth.txt in {0}")]
    NoInitialPose(std::path::PathBuf),
    /// A cold start without a relocalization database.
    #[error("a cold start (no initial pose) needs a relocalization database")]
    ColdStartWithoutDatabase,
    /// The loop could not start.
    #[error(transparent)]
    Localizer(#[from] LocalizerError),
    /// The relocalization database does not fit this camera.
    #[error(transparent)]
    Reloc(#[from] crate::reloc::RelocDbError),
}

/// Options of an offline run.
#[derive(Debug, Clone, Default)]
pub struct OfflineOptions {
    /// Start pose; the ground truth nearest the first frame when `None`.
    pub world_from_camera_start: Option<Pose>,
    /// Process at most this many frames.
    pub max_frames: Option<usize>,
    /// Pace frames at the recorded rate (as a live camera would deliver them):
    /// a frame whose successor is already due when the loop gets to it is
    /// skipped, as a live camera's frame is replaced by the next one while
    /// the tracker is busy (`star run` takes the latest frame).
    pub realtime: bool,
    /// Relocalize from this database when lost.
    pub relocalizer: Option<crate::reloc::Relocalizer>,
    /// How the start pose is used.
    pub start: StartMode,
}

/// How an offline run starts.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum StartMode {
    /// The start pose (`init_pose`, else the ground truth) is trusted and
    /// tracked from at once: the tracker benchmarks' setting.
    #[default]
    Trusted,
    /// The start pose (`init_pose`, else the ground truth) is a hint that
    /// must pass the relocalization gate before a pose is output, as in
    /// flight.
    Hint,
    /// No start pose: the first frames are searched in the database (needs
    /// `relocalizer`), as in flight without a hint.
    Cold,
}

/// What an offline run produced.
#[derive(Debug, Clone)]
pub struct OfflineReport {
    /// Tracked poses (lost frames have none), stamped with dataset time.
    pub estimate: Trajectory,
    /// Per-frame tracking time, milliseconds, in frame order.
    pub track_ms: Vec<f64>,
    /// Frames that could not be decoded or were rejected, with the reason.
    pub bad_frames: Vec<(usize, String)>,
    /// Frames skipped in real time because the loop was still busy when
    /// the next one was due (a live camera would have replaced them).
    pub skipped_frames: usize,
    /// Frames processed.
    pub frames: usize,
    /// Frames in the lost state.
    pub lost_frames: usize,
    /// Per processed frame: the `reset_counter` it carried (in frame order,
    /// parallel to `track_ms`).
    pub reset_counters: Vec<u8>,
    /// Per processed frame: its dataset time and whether a pose was output.
    pub tracked: Vec<(f64, bool)>,
    /// Relocalizations accepted and confirmed.
    pub relocalizations: u64,
    /// Verifying frames that passed by tracking after their search failed
    /// ([`crate::localizer::LoopStats::verified_by_tracking`]).
    pub verified_by_tracking: u64,
    /// Frames that resumed tracking after a loss and were held, not output
    /// ([`crate::localizer::LoopStats::held_resumes`]).
    pub held_resumes: u64,
    /// With `[keyframe] hold_for_next_frame`: tracked frames not output
    /// because the next frame was lost (or none came).
    pub held_for_next_frame: Option<u64>,
    /// Keyframes asked for during short losses, following the camera
    /// ([`crate::localizer::LoopStats::lost_keyframes`]).
    pub lost_keyframes: u64,
    /// Relocalization attempts refused because two places passed the gate.
    pub reloc_ambiguous: u64,
    /// Passing rivals told apart by a decisive correlation.
    pub reloc_decided: u64,
    /// Losses of tracking by reason ([`crate::localizer::LoopStats::losses`]).
    pub losses: [u64; crate::localizer::LossReason::ALL.len()],
    /// Relocalization attempts (lost frames searched).
    pub reloc_attempts: u64,
    /// Keyframes rendered.
    pub keyframes: u64,
    /// Frames tracked while a newer keyframe was pending.
    pub stale_frames: u64,
    /// Largest keyframe age, seconds.
    pub max_keyframe_age_s: f64,
    /// Median points used per level, finest first.
    pub median_points: Vec<u32>,
    /// Lowest inlier ratio over the tracked frames.
    pub min_inlier_ratio: f32,
    /// Lowest normalized cross-correlation over the tracked frames.
    pub min_correlation: f32,
    /// Renderer name.
    pub renderer: String,
    /// Accuracy against the dataset's ground truth, when it has one.
    pub evaluation: Option<Evaluation>,
    /// Integrity against the ground truth (no alignment), when it has one.
    pub integrity: Option<Integrity>,
    /// With a flight log or the live view: per processed frame, the time
    /// the tracker spent handing it over (row, and every Nth frame the
    /// picture copy), ms.
    pub record_ms: Vec<f64>,
}

impl OfflineReport {
    /// Counts one frame as it goes out: its pose, or a lost frame.
    fn output(&mut self, out: &FrameOutput, stamp_s: f64) {
        self.tracked
            .push((stamp_s, out.world_from_camera.is_some()));
        match (out.state, out.world_from_camera) {
            (TrackState::Tracking, Some(pose)) => {
                self.estimate.push(stamp_s, pose);
                let q = &out.quality;
                self.min_inlier_ratio = self.min_inlier_ratio.min(q.inlier_ratio);
                self.min_correlation = self.min_correlation.min(q.correlation);
            }
            _ => self.lost_frames += 1,
        }
    }
}

/// Poses output that were wrong: the figure that matters most.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Integrity {
    /// Poses output more than [`WRONG_POSITION_M`] or [`WRONG_ROTATION_DEG`]
    /// from the ground truth, in the world frame, without alignment.
    pub wrong_poses: usize,
    /// Poses compared (those with a ground-truth pose within 5 ms).
    pub poses_checked: usize,
    /// Largest position error among the poses output, m.
    pub max_position_error_m: f64,
    /// Largest rotation error among the poses output, degrees.
    pub max_rotation_error_deg: f64,
    /// Dataset time from the first frame to the first pose output, s.
    pub first_pose_after_s: Option<f64>,
}

/// A pose further than this from the truth is wrong, m.
pub const WRONG_POSITION_M: f64 = 0.10;
/// A pose turned further than this from the truth is wrong, degrees.
pub const WRONG_ROTATION_DEG: f64 = 5.0;

/// The error of `pose`, stamped `stamp_s`, against the ground-truth pose
/// of `truth` nearest in time: position (m) and rotation (degrees), in the
/// world frame, without alignment; `None` without a truth pose within 5 ms.
pub fn pose_error(truth: &Trajectory, stamp_s: f64, pose: &Pose) -> Option<(f64, f64)> {
    let nearest = truth
        .stamps_s
        .partition_point(|t| *t < stamp_s)
        .min(truth.stamps_s.len().saturating_sub(1));
    let candidates = [nearest.saturating_sub(1), nearest];
    let &k = candidates
        .iter()
        .filter(|&&k| k < truth.stamps_s.len())
        .min_by(|&&a, &&b| {
            (truth.stamps_s[a] - stamp_s)
                .abs()
                .total_cmp(&(truth.stamps_s[b] - stamp_s).abs())
        })?;
    if (truth.stamps_s[k] - stamp_s).abs() > 0.005 {
        return None;
    }
    let error = truth.poses[k].inverse() * pose;
    Some((
        error.translation.vector.norm(),
        error.rotation.angle().to_degrees(),
    ))
}

/// Whether a pose with this error ([`pose_error`]: m, degrees) is wrong:
/// beyond [`WRONG_POSITION_M`] or [`WRONG_ROTATION_DEG`] (or not finite).
pub fn is_wrong((position_m, rotation_deg): (f64, f64)) -> bool {
    !(position_m <= WRONG_POSITION_M && rotation_deg <= WRONG_ROTATION_DEG)
}

/// Counts the poses of `estimate` that are wrong against `truth`.
pub fn integrity(truth: &Trajectory, estimate: &Trajectory, first_stamp_s: f64) -> Integrity {
    let mut out = Integrity {
        first_pose_after_s: estimate.stamps_s.first().map(|t| t - first_stamp_s),
        ..Integrity::default()
    };
    for (stamp_s, pose) in estimate.stamps_s.iter().zip(&estimate.poses) {
        let Some((position_m, rotation_deg)) = pose_error(truth, *stamp_s, pose) else {
            continue;
        };
        out.poses_checked += 1;
        out.max_position_error_m = out.max_position_error_m.max(position_m);
        out.max_rotation_error_deg = out.max_rotation_error_deg.max(rotation_deg);
        if is_wrong((position_m, rotation_deg)) {
            out.wrong_poses += 1;
            tracing::debug!(
                after_s = stamp_s - first_stamp_s,
                position_m,
                rotation_deg,
                "wrong pose output"
            );
        }
    }
    out
}

/// Runs the STAR loop over `dataset` with `renderer` (built on the map).
/// `on_frame` is called after every frame (for progress bars).
pub fn localize_dataset(
    dataset: &Dataset,
    renderer: Box<dyn Renderer>,
    config: &Config,
    options: &OfflineOptions,
    on_frame: impl FnMut(usize),
) -> Result<OfflineReport, OfflineError> {
    localize_dataset_recorded(dataset, renderer, config, options, on_frame, None)
}

/// Where an offline run hands its frames besides its report: the flight
/// log (`--record`) and the live view (`--rerun`).
#[derive(Default)]
pub struct OfflineSinks {
    /// The flight log.
    pub record: Option<RecordSink>,
    /// The live view.
    #[cfg(feature = "rerun")]
    pub rerun: Option<crate::output::rerun_log::RerunSink>,
}

impl OfflineSinks {
    /// The flight log alone (the live view, with the `rerun` feature, is
    /// set after).
    pub fn with_record(record: Option<RecordSink>) -> Self {
        Self {
            record,
            #[cfg(feature = "rerun")]
            rerun: None,
        }
    }

    /// True when nothing is on.
    pub fn is_empty(&self) -> bool {
        #[cfg(feature = "rerun")]
        if self.rerun.is_some() {
            return false;
        }
        self.record.is_none()
    }
}

/// [`localize_dataset`], also handing every processed frame to `sinks`
/// (`star localize --record`, `--rerun`), stamped with dataset time.
pub fn localize_dataset_recorded(
    dataset: &Dataset,
    renderer: Box<dyn Renderer>,
    config: &Config,
    options: &OfflineOptions,
    mut on_frame: impl FnMut(usize),
    mut sinks: Option<&mut OfflineSinks>,
) -> Result<OfflineReport, OfflineError> {
    let camera = *dataset.camera();
    let n = options
        .max_frames
        .map_or(dataset.len(), |m| m.min(dataset.len()));
    let first_stamp_s = dataset.frames[0].timestamp_s;
    let init = match (
        options.start,
        options.world_from_camera_start,
        &options.relocalizer,
    ) {
        (StartMode::Cold, _, Some(r)) => r
            .database()
            .entries
            .first()
            .map(|e| e.world_from_camera)
            .ok_or(OfflineError::ColdStartWithoutDatabase)?,
        (StartMode::Cold, _, None) => return Err(OfflineError::ColdStartWithoutDatabase),
        (_, Some(p), _) => p,
        (_, None, _) => nearest_pose(dataset, first_stamp_s)
            .ok_or_else(|| OfflineError::NoInitialPose(dataset.root.clone()))?,
    };
    let to_ns = |t_s: f64| ((t_s - first_stamp_s) * 1e9).round().max(0.0) as u64 + 1_000_000_000;
    let mut localizer = Localizer::start(
        renderer,
        &camera,
        &config.tracker,
        &config.keyframe,
        init,
        to_ns(first_stamp_s).saturating_sub(1),
    )?;
    if let Some(r) = &options.relocalizer {
        localizer.set_relocalizer(r.clone())?;
        if !options.realtime {
            // Unpaced, search time costs no camera time; a budget would
            // only make the run depend on the machine's speed.
            localizer.set_attempt_budget_s(0.0);
        }
    }
    match options.start {
        StartMode::Trusted => localizer.use_gate(&config.reloc),
        start => localizer.verify_start(&config.reloc, start == StartMode::Hint),
    }
    let mut image = ImageU8::new(camera.width as usize, camera.height as usize, 0);
    let mut scratch = Vec::new();
    let mut report = OfflineReport {
        estimate: Trajectory::default(),
        track_ms: Vec::with_capacity(n),
        bad_frames: Vec::new(),
        skipped_frames: 0,
        frames: 0,
        lost_frames: 0,
        reset_counters: Vec::with_capacity(n),
        tracked: Vec::with_capacity(n),
        relocalizations: 0,
        held_resumes: 0,
        held_for_next_frame: None,
        verified_by_tracking: 0,
        lost_keyframes: 0,
        reloc_ambiguous: 0,
        reloc_decided: 0,
        losses: Default::default(),
        reloc_attempts: 0,
        keyframes: 0,
        stale_frames: 0,
        max_keyframe_age_s: 0.0,
        median_points: Vec::new(),
        min_inlier_ratio: 1.0,
        min_correlation: 1.0,
        renderer: localizer.renderer_name().to_string(),
        evaluation: None,
        integrity: None,
        record_ms: Vec::with_capacity(if sinks.is_some() { n } else { 0 }),
    };
    let levels = config.tracker.pyramid_levels as usize;
    let mut points: Vec<Vec<u32>> = vec![Vec::with_capacity(n); levels];
    // What is sent waits for the next frame when `hold_for_next_frame` is on.
    let mut hold = NextFrameHold::new(config.keyframe.hold_for_next_frame);
    let wall_start = Instant::now();
    for i in 0..n {
        let stamp_s = dataset.frames[i].timestamp_s;
        if options.realtime {
            let next_due_s = dataset
                .frames
                .get(i + 1)
                .map_or(f64::INFINITY, |f| f.timestamp_s - first_stamp_s);
            if wall_start.elapsed().as_secs_f64() >= next_due_s {
                report.skipped_frames += 1;
                on_frame(i);
                continue;
            }
            let due = std::time::Duration::from_secs_f64((stamp_s - first_stamp_s).max(0.0));
            if let Some(wait) = due.checked_sub(wall_start.elapsed()) {
                std::thread::sleep(wait);
            }
        }
        if let Err(e) = dataset.load_frame_into(i, &mut image, &mut scratch) {
            tracing::warn!(frame = i, error = %e, "skipping frame");
            report.bad_frames.push((i, e.to_string()));
            on_frame(i);
            continue;
        }
        let t0 = Instant::now();
        let out = localizer.process_frame(
            image.data(),
            image.width(),
            image.height(),
            image.width(),
            to_ns(stamp_s),
        );
        let ms = t0.elapsed().as_secs_f64() * 1e3;
        match out {
            Ok(out) => {
                if let Some(sinks) = sinks.as_deref_mut() {
                    let pixels = FramePixels {
                        pixels: image.data(),
                        width: image.width(),
                        height: image.height(),
                        stride: image.width(),
                    };
                    let handed_at = Instant::now();
                    FrameSinks {
                        record: sinks.record.as_mut(),
                        #[cfg(feature = "rerun")]
                        rerun: sinks.rerun.as_mut(),
                    }
                    .hand(&localizer, &out, stamp_s, ms, pixels);
                    report
                        .record_ms
                        .push(handed_at.elapsed().as_secs_f64() * 1e3);
                }
                report.frames += 1;
                report.track_ms.push(ms);
                report.reset_counters.push(out.reset_counter);
                for (l, p) in points.iter_mut().enumerate() {
                    p.push(out.quality.points_used[l]);
                }
                if let Some((out, stamp_s)) = hold.push(out, stamp_s) {
                    report.output(&out, stamp_s);
                }
            }
            Err(e) => {
                tracing::warn!(frame = i, error = %e, "frame rejected");
                report.bad_frames.push((i, e.to_string()));
            }
        }
        on_frame(i);
    }
    if let Some((out, stamp_s)) = hold.finish() {
        report.output(&out, stamp_s);
    }
    report.held_for_next_frame = hold.enabled().then(|| hold.withheld());
    let stats = localizer.stats();
    report.keyframes = stats.keyframes;
    report.relocalizations = stats.relocalizations;
    report.held_resumes = stats.held_resumes;
    report.verified_by_tracking = stats.verified_by_tracking;
    report.lost_keyframes = stats.lost_keyframes;
    report.reloc_ambiguous = stats.reloc_ambiguous;
    report.reloc_decided = stats.reloc_decided;
    report.losses = stats.losses;
    report.reloc_attempts = stats.reloc_attempts;
    report.stale_frames = stats.stale_frames;
    report.max_keyframe_age_s = stats.max_keyframe_age_s;
    report.median_points = points
        .iter_mut()
        .map(|p| {
            if p.is_empty() {
                0
            } else {
                let mid = p.len() / 2;
                *p.select_nth_unstable(mid).1
            }
        })
        .collect();
    if let Some(gt) = &dataset.ground_truth {
        report.integrity = Some(integrity(gt, &report.estimate, first_stamp_s));
        if !report.estimate.is_empty() {
            report.evaluation = eval::evaluate(gt, &report.estimate, 0.005, Some(1)).ok();
        }
    }
    Ok(report)
}

fn nearest_pose(dataset: &Dataset, stamp_s: f64) -> Option<Pose> {
    let gt = dataset.ground_truth.as_ref()?;
    let (i, _) = gt
        .stamps_s
        .iter()
        .enumerate()
        .min_by(|a, b| (a.1 - stamp_s).abs().total_cmp(&(b.1 - stamp_s).abs()))?;
    gt.poses.get(i).copied()
}

/// Median and 99th percentile of `samples` (0 when empty).
pub fn median_p99(samples: &[f64]) -> (f64, f64) {
    if samples.is_empty() {
        return (0.0, 0.0);
    }
    let mut s = samples.to_vec();
    s.sort_by(f64::total_cmp);
    let at = |q: f64| s[((s.len() - 1) as f64 * q).round() as usize];
    (at(0.5), at(0.99))
}
