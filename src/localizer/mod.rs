//! The STAR loop: tracking at camera rate against keyframes rendered
//! asynchronously from the map (paper sections II-A to II-C).
//!
//! Takes camera frames (8-bit gray, raw and distorted, with a
//! CLOCK_MONOTONIC capture time), gives out one [`FrameOutput`] per frame: a
//! pose and covariance while tracking, nothing while lost. Owns the
//! constant-velocity prediction, the keyframe policy ([`policy`]), the lost
//! test, and the render thread ([`worker`]). Tracking never waits for a
//! render: when a new keyframe is due, it is requested and tracking goes on
//! against the old one until the new one is ready.
//!
//! A frame that resumes tracking on its own after a loss gives no pose:
//! the next frame must track too, and is the first output again (as after
//! a relocalization, whose `verify_frames` confirm it).
//!
//! While lost, with a relocalization database set
//! ([`Localizer::set_relocalizer`]), the loop searches the database and
//! renders and verifies candidates on the render thread, blocking in the
//! lost state only ([`relocalize`]).
//!
//! After [`Localizer::start`], [`Localizer::process_frame`] allocates nothing
//! while tracking.

pub mod config;
pub mod continuity;
pub mod hold;
pub mod policy;
mod relocalize;
pub mod worker;

pub use config::KeyframeConfig;
pub use hold::NextFrameHold;

use nalgebra::Matrix6;

use crate::geometry::{adjoint, exp_se3, log_se3, renormalized, PinholeCamera, Pose};
use crate::render::Renderer;
use crate::track::TrackerConfig;
use crate::track::{AlignQuality, Aligner, Keyframe, Pyramid};

use continuity::{Continuity, CORRELATION_MEAN_WEIGHT, SHORT_LOSS_S};
use worker::{RenderRequest, RenderWorker};

/// Errors from the STAR loop. Bad frames are rejected without changing state.
#[derive(Debug, thiserror::Error)]
pub enum LocalizerError {
    /// A frame does not match the calibrated size.
    #[error("frame is {found_w}x{found_h} (stride {stride}, {len} bytes) but the camera is {want_w}x{want_h}")]
    FrameSize {
        /// Frame width.
        found_w: usize,
        /// Frame height.
        found_h: usize,
        /// Row stride, bytes.
        stride: usize,
        /// Buffer length, bytes.
        len: usize,
        /// Calibrated width.
        want_w: u32,
        /// Calibrated height.
        want_h: u32,
    },
    /// A frame's capture time is not after the previous frame's.
    #[error(
        "frame capture time {capture_ns} ns is not after the previous frame's {previous_ns} ns"
    )]
    TimestampOrder {
        /// This frame's capture time.
        capture_ns: u64,
        /// The previous frame's capture time.
        previous_ns: u64,
    },
    /// The initial pose is not finite.
    #[error("initial pose is not finite")]
    BadInitialPose,
    /// The first keyframe could not be rendered.
    #[error("first keyframe could not be rendered: {0}")]
    FirstKeyframe(String),
    /// The render thread could not be started.
    #[error("cannot start the render thread: {0}")]
    Thread(#[from] std::io::Error),
}

/// Tracking state.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TrackState {
    /// The frame was aligned and passed the quality gate.
    Tracking,
    /// The frame failed the quality gate; no pose is output.
    Lost,
}

/// Why a tracked frame was lost: the first of the lost tests (in the order
/// they are made) that it failed. Logged with the loss and counted in
/// [`LoopStats::losses`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LossReason {
    /// The alignment did not converge, or gave a pose that is not finite.
    NotAligned,
    /// Inlier ratio below `[keyframe] lost_inlier_ratio`.
    InlierRatio,
    /// Visible fraction below `[keyframe] lost_visible_ratio`.
    VisibleRatio,
    /// Correlation below `[keyframe] lost_min_correlation`.
    Correlation,
    /// Correlation below `lost_correlation_drop` x its running mean.
    CorrelationDrop,
    /// The estimate landed beyond the jump limits from the prediction.
    Jump,
    /// With a gate: the keyframe points' plain correlation with the frame
    /// (pyramid level 1) below `[reloc] track_min_correlation`, or too few
    /// points to measure it.
    GateCorrelation,
    /// With a gate: local contrast correlation (lowest of levels 0-2)
    /// below `[reloc] track_min_local_correlation`.
    LocalContrast,
    /// With a gate: local contrast below `lost_local_correlation_drop` x its
    /// running mean.
    LocalContrastDrop,
}

impl LossReason {
    /// Every reason, in the order of [`LoopStats::losses`].
    pub const ALL: [Self; 9] = [
        Self::NotAligned,
        Self::InlierRatio,
        Self::VisibleRatio,
        Self::Correlation,
        Self::CorrelationDrop,
        Self::Jump,
        Self::GateCorrelation,
        Self::LocalContrast,
        Self::LocalContrastDrop,
    ];

    /// A short name for logs and summaries, naming the setting it tests.
    pub fn name(self) -> &'static str {
        match self {
            Self::NotAligned => "not aligned",
            Self::InlierRatio => "inlier ratio (lost_inlier_ratio)",
            Self::VisibleRatio => "visible fraction (lost_visible_ratio)",
            Self::Correlation => "correlation (lost_min_correlation)",
            Self::CorrelationDrop => "correlation drop (lost_correlation_drop)",
            Self::Jump => "jump from the prediction (lost_max_jump_m/_deg)",
            Self::GateCorrelation => "correlation (track_min_correlation)",
            Self::LocalContrast => "local contrast (track_min_local_correlation)",
            Self::LocalContrastDrop => "local contrast drop (lost_local_correlation_drop)",
        }
    }

    /// Its place in [`LossReason::ALL`] and [`LoopStats::losses`].
    pub fn index(self) -> usize {
        Self::ALL.iter().position(|&r| r == self).unwrap_or(0)
    }
}

/// What the loop gives out for one frame.
#[derive(Debug, Clone, Copy)]
pub struct FrameOutput {
    /// Capture time, CLOCK_MONOTONIC ns.
    pub capture_ns: u64,
    /// Tracking or lost.
    pub state: TrackState,
    /// The pose; `None` while lost.
    pub world_from_camera: Option<Pose>,
    /// Covariance of the right perturbation `xi = [v; w]` in the camera
    /// frame: `world_from_camera_true = world_from_camera * exp(xi)`.
    pub covariance: Matrix6<f64>,
    /// Alignment quality.
    pub quality: AlignQuality,
    /// Photometric gain and bias (camera = gain * keyframe + bias).
    pub gain: f32,
    /// See `gain`.
    pub bias: f32,
    /// Id of the keyframe tracked against.
    pub keyframe_id: u64,
    /// Age of that keyframe, seconds since the frame that requested it.
    pub keyframe_age_s: f64,
    /// True when a newer keyframe had been requested but was not ready yet.
    pub stale_keyframe: bool,
    /// Incremented on every discontinuity (relocalization, re-initialization).
    pub reset_counter: u8,
    /// No pose, and the loop is searching rather than just lost: this frame
    /// was searched in the relocalization database, or a start pose or
    /// relocalization candidate is being verified.
    pub searching: bool,
}

/// Candidates of a relocalization attempt kept for the logs
/// ([`Localizer::last_reloc_attempt`]); an attempt that tries more keeps
/// the first ones.
pub const ATTEMPT_CANDIDATES: usize = 16;

/// One candidate a relocalization attempt tried, and the gate's verdict.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RelocCandidate {
    /// The candidate's pose (the refined pose when the gate accepted it).
    pub world_from_camera: Pose,
    /// From the landmark matches (P3P), not from the database's views.
    pub from_landmarks: bool,
    /// The gate accepted it.
    pub accepted: bool,
}

/// What the last relocalization attempt tried. Fixed size, copied out
/// without allocating.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RelocAttempt {
    /// Capture time of the lost frame searched, CLOCK_MONOTONIC ns.
    pub capture_ns: u64,
    /// Candidates tried (all of them, also beyond [`ATTEMPT_CANDIDATES`]).
    pub tried: usize,
    /// The first candidates tried, in order; `min(tried,
    /// ATTEMPT_CANDIDATES)` of them are valid.
    pub candidates: [RelocCandidate; ATTEMPT_CANDIDATES],
}

impl Default for RelocAttempt {
    fn default() -> Self {
        Self {
            capture_ns: 0,
            tried: 0,
            candidates: [RelocCandidate {
                world_from_camera: Pose::identity(),
                from_landmarks: false,
                accepted: false,
            }; ATTEMPT_CANDIDATES],
        }
    }
}

impl RelocAttempt {
    /// The valid candidates.
    pub fn candidates(&self) -> &[RelocCandidate] {
        &self.candidates[..self.tried.min(ATTEMPT_CANDIDATES)]
    }
}

/// Running counters for the summary.
#[derive(Debug, Clone, Copy, Default)]
pub struct LoopStats {
    /// Frames processed.
    pub frames: u64,
    /// Frames lost (and frames tracked but not output: a resume waiting
    /// for the next frame, a relocalization being confirmed).
    pub lost_frames: u64,
    /// Frames that resumed tracking on their own after a loss, and were
    /// not output (the next tracked frame is).
    pub held_resumes: u64,
    /// Keyframes rendered (including the first).
    pub keyframes: u64,
    /// Keyframes asked for during a short loss, where the keyframe follows
    /// the camera for the frame that resumes.
    pub lost_keyframes: u64,
    /// Keyframe renders that failed.
    pub render_failures: u64,
    /// Frames tracked while a newer keyframe was pending.
    pub stale_frames: u64,
    /// Largest keyframe age seen, seconds.
    pub max_keyframe_age_s: f64,
    /// Relocalization attempts (lost frames searched in the database).
    pub reloc_attempts: u64,
    /// Candidate keyframes rendered and aligned for relocalization.
    pub reloc_candidates: u64,
    /// Relocalizations accepted and verified (tracking restarted).
    pub relocalizations: u64,
    /// Verifying frames (of a relocalization or a start pose) that passed
    /// by ordinary tracking from the verifying frame before them, after
    /// their own search against the keyframe failed
    /// (`Localizer::verifies_by_tracking`).
    pub verified_by_tracking: u64,
    /// Relocalization attempts refused because candidates at two places
    /// passed the gate (look-alike rooms).
    pub reloc_ambiguous: u64,
    /// Passing rivals at another place that a decisive correlation told
    /// apart from the held pose (`reloc::rivals::DECISIVE_MARGIN`).
    pub reloc_decided: u64,
    /// Losses of tracking (a tracked frame followed by a lost one), by
    /// [`LossReason`], in the order of [`LossReason::ALL`].
    pub losses: [u64; LossReason::ALL.len()],
}

impl LoopStats {
    /// The losses counted for `reason`.
    pub fn losses_for(&self, reason: LossReason) -> u64 {
        self.losses.get(reason.index()).copied().unwrap_or(0)
    }
}

/// The STAR loop.
pub struct Localizer {
    camera: PinholeCamera,
    policy: KeyframeConfig,
    aligner: Aligner,
    /// Align on every pyramid level, the extra coarse one included: two,
    /// for the two halves of a verification's starts
    /// ([`crate::reloc::verify_candidate`]).
    reloc_aligners: [Aligner; 2],
    pyramid: Pyramid,
    worker: RenderWorker,
    keyframe: Box<Keyframe>,
    next_keyframe_id: u64,
    pending: bool,
    /// Capture time of the previous frame (timestamp order check).
    previous_ns: Option<u64>,
    /// Capture time and pose of the last tracked frame (prediction).
    last: Option<(u64, Pose)>,
    /// From a relocalization until its confirming frames track: `last` as
    /// it was before it (the last verified pose, or none). While set, the
    /// rival rule's prior, which vouches for a pose's place, is taken from
    /// it rather than from `last`: a pose that was never confirmed must not
    /// vouch for the next attempt's (the search still starts near `last`).
    last_before_reloc: Option<Option<(u64, Pose)>>,
    /// Velocity as a twist per second, in the camera frame (right perturbation).
    velocity: nalgebra::Vector6<f64>,
    /// Running mean of how old a keyframe is when it is first tracked
    /// against (request to swap-in, camera time), seconds: how far ahead
    /// of the camera the next one is rendered.
    render_latency_s: f64,
    /// Consecutive tracked frames up to the previous one (the keyframe
    /// lead renders ahead from 2 on).
    tracked_run: u32,
    /// Whether the velocity is measured, and the local contrast's running
    /// mean (`lost_local_correlation_drop`): kept over a short loss.
    continuity: Continuity,
    /// Running mean of the correlation over the frames tracked since the
    /// last loss (`None` right after one): the reference of the lost
    /// test's correlation drop.
    correlation_mean: Option<f32>,
    /// The last frame's local contrast correlation (`NaN`: not measured).
    last_local: f32,
    state: TrackState,
    reset_counter: u8,
    stats: LoopStats,
    /// Relocalization database and search state, when set.
    reloc: Option<Box<crate::reloc::Relocalizer>>,
    /// Capture time of the last tracked frame before the current loss.
    lost_since_ns: Option<u64>,
    /// Frames still to verify after an accepted relocalization.
    verify_left: u32,
    /// A frame of the current verification has passed: a later one whose
    /// search from the keyframe fails may confirm it by ordinary tracking
    /// from that frame's pose, through the same gate. In a paced run the
    /// keyframe stands where the search's frame was, 0.5-1 s of flight
    /// before the first verifying frame, and the second is further from it
    /// (docs/building-scale.md, "A second frame to confirm a
    /// relocalization").
    verify_passed: bool,
    /// The pose being verified comes from a prior alone (a start hint, or
    /// the last keyframe without a database), with no rival checked: a
    /// frame that passes the gate only through its first level's lowered
    /// floor does not confirm it ([`crate::reloc::Verified::lowered_first_level`]).
    verify_prior_only: bool,
    /// How long one relocalization attempt may try new candidates, seconds
    /// (0: no limit).
    attempt_budget_s: f64,
    /// Gate settings for a verified start without a database
    /// ([`Localizer::verify_start`]).
    start_gate: Option<crate::reloc::RelocConfig>,
    /// The candidates of the last relocalization attempt, for the logs.
    last_attempt: RelocAttempt,
    /// The keyframe points where the frame sees them, for the per-frame
    /// correlation check; room for a full finest level.
    correlation_samples: Vec<crate::track::correlation::Sample>,
    /// Rigid motions under which the map looked the same to a
    /// relocalization (look-alike rooms): `second = symmetry * first`.
    map_symmetries: heapless::Vec<Pose, { relocalize::MAX_SYMMETRIES }>,
}

impl Localizer {
    /// Starts the render thread and renders the first keyframe at
    /// `world_from_camera` (this one blocks: there is nothing to track yet).
    pub fn start(
        renderer: Box<dyn Renderer>,
        camera: &PinholeCamera,
        tracker: &TrackerConfig,
        policy: &KeyframeConfig,
        world_from_camera: Pose,
        capture_ns: u64,
    ) -> Result<Self, LocalizerError> {
        if !pose_is_finite(&world_from_camera) {
            return Err(LocalizerError::BadInitialPose);
        }
        // Pyramids and keyframes carry one level more than tracking uses:
        // relocalization's coarse search aligns on it.
        let build = crate::track::build_config(tracker);
        let keyframe_far_m = (policy.far_m > 0.0).then_some(f64::from(policy.far_m));
        let worker = RenderWorker::spawn(renderer, camera, &build, keyframe_far_m)?;
        worker.try_request(RenderRequest {
            world_from_keyframe: world_from_camera,
            id: 1,
            requested_at_ns: capture_ns,
            // The start pose: verified by the caller or a hint not trusted
            // yet; drawn as a candidate would be.
            candidate: true,
        });
        let keyframe = worker
            .wait_result()
            .map_err(LocalizerError::FirstKeyframe)?;
        tracing::info!(
            renderer = worker.renderer_name(),
            points = keyframe.point_count(0),
            "first keyframe rendered"
        );
        Ok(Self {
            camera: *camera,
            policy: policy.clone(),
            aligner: Aligner::new(tracker),
            reloc_aligners: [Aligner::new(&build), Aligner::new(&build)],
            pyramid: Pyramid::new(
                camera.width as usize,
                camera.height as usize,
                build.pyramid_levels as usize,
            ),
            worker,
            keyframe,
            next_keyframe_id: 2,
            pending: false,
            // The first frame predicts from the keyframe pose with zero
            // velocity; velocity starts once two frames are tracked.
            previous_ns: None,
            last: None,
            last_before_reloc: None,
            velocity: nalgebra::Vector6::zeros(),
            render_latency_s: 0.0,
            tracked_run: 0,
            continuity: Continuity::new(),
            correlation_mean: None,
            last_local: f32::NAN,
            state: TrackState::Tracking,
            reset_counter: 0,
            stats: LoopStats {
                keyframes: 1,
                ..LoopStats::default()
            },
            reloc: None,
            lost_since_ns: None,
            verify_left: 0,
            verify_passed: false,
            verify_prior_only: false,
            start_gate: None,
            attempt_budget_s: 0.0,
            last_attempt: RelocAttempt::default(),
            correlation_samples: Vec::with_capacity(build.max_points_per_level(0)),
            map_symmetries: heapless::Vec::new(),
        })
    }

    /// The renderer in use.
    pub fn renderer_name(&self) -> &str {
        self.worker.renderer_name()
    }

    /// Counters so far.
    pub fn stats(&self) -> LoopStats {
        self.stats
    }

    /// Current state.
    pub fn state(&self) -> TrackState {
        self.state
    }

    /// Forgets the motion model: the next frame is predicted at the last
    /// pose with zero velocity. For gaps in the frame stream (a camera
    /// restart, a silent period), where the constant-velocity prediction
    /// over the gap would be wrong.
    pub fn forget_motion(&mut self) {
        self.velocity = nalgebra::Vector6::zeros();
        self.tracked_run = 0;
        self.continuity.forget_motion();
    }

    /// What the last relocalization attempt tried (the attempt whose
    /// number is `stats().reloc_attempts`); empty before the first.
    pub fn last_reloc_attempt(&self) -> &RelocAttempt {
        &self.last_attempt
    }

    /// The keyframe currently tracked against.
    pub fn keyframe(&self) -> &Keyframe {
        &self.keyframe
    }

    /// Tracks one 8-bit gray frame with row stride `stride` bytes.
    pub fn process_frame(
        &mut self,
        pixels: &[u8],
        width: usize,
        height: usize,
        stride: usize,
        capture_ns: u64,
    ) -> Result<FrameOutput, LocalizerError> {
        let (want_w, want_h) = (self.camera.width, self.camera.height);
        if width != want_w as usize
            || height != want_h as usize
            || stride < width
            || pixels.len() < stride * (height - 1) + width
        {
            return Err(LocalizerError::FrameSize {
                found_w: width,
                found_h: height,
                stride,
                len: pixels.len(),
                want_w,
                want_h,
            });
        }
        if let Some(prev_ns) = self.previous_ns {
            if capture_ns <= prev_ns {
                return Err(LocalizerError::TimestampOrder {
                    capture_ns,
                    previous_ns: prev_ns,
                });
            }
        }
        self.previous_ns = Some(capture_ns);
        self.swap_in_ready_keyframe(capture_ns);
        self.pyramid.fill_from_u8(pixels, stride);

        // Constant-velocity prediction.
        let (prev_ns, world_from_camera_prev) = self
            .last
            .unwrap_or((capture_ns, self.keyframe.world_from_keyframe));
        let dt_s = (capture_ns.saturating_sub(prev_ns)) as f64 * 1e-9;
        let world_from_camera_predicted =
            renormalized(world_from_camera_prev * exp_se3(&(self.velocity * dt_s.min(0.2))));
        let camera_from_keyframe =
            world_from_camera_predicted.inverse() * self.keyframe.world_from_keyframe;

        // The frame that verifies a relocalization comes after the time the
        // search took (the vehicle moved on, 15 cm in 0.3 s at walking
        // speed) with no velocity to predict from: it gets the same coarse
        // multi-start search and gate as the candidate did.
        let verifying = self.verify_left > 0;
        let searched = self.verify_alignment().filter(|_| verifying);
        let by_search = searched.is_some();
        let result = match searched {
            Some(a) => a,
            None => {
                let mut a = self.aligner.align(
                    &self.keyframe,
                    &self.pyramid,
                    &self.camera,
                    camera_from_keyframe,
                );
                // A verification frame passes only through the search, or
                // tracked from a frame of it that passed (`verify_passed`).
                a.valid &= !verifying || (self.verify_passed && self.verifies_by_tracking(&a));
                a
            }
        };
        let (max_jump_m, max_jump_deg) = if by_search {
            (f64::INFINITY, f64::INFINITY) // bounded by the search (two grid spacings)
        } else {
            // Tracked, a verifying frame too: from the prediction.
            self.policy
                .jump_limits(dt_s, self.continuity.motion_known())
        };
        let world_from_camera =
            self.keyframe.world_from_keyframe * result.camera_from_keyframe.inverse();
        let predicted_from_camera = world_from_camera_predicted.inverse() * world_from_camera;
        let jump_m = predicted_from_camera.translation.vector.norm();
        let jump_deg = predicted_from_camera.rotation.angle().to_degrees();
        let q = result.quality;
        // The lost tests in order, the first failed named (NaN fails).
        // Resuming after a loss (`may_resume`) is not a loss of its own.
        let loss = if !(result.valid && pose_is_finite(&world_from_camera)) {
            Some(LossReason::NotAligned)
        } else if !(q.inlier_ratio >= self.policy.lost_inlier_ratio) {
            Some(LossReason::InlierRatio)
        } else if !(q.visible_ratio >= self.policy.lost_visible_ratio) {
            Some(LossReason::VisibleRatio)
        } else if !(q.correlation >= self.policy.lost_min_correlation) {
            Some(LossReason::Correlation)
        } else if self
            .correlation_mean
            .is_some_and(|mean| !(q.correlation >= self.policy.lost_correlation_drop * mean))
        {
            Some(LossReason::CorrelationDrop)
        } else if !(jump_m <= max_jump_m && jump_deg <= max_jump_deg) {
            Some(LossReason::Jump)
        } else if !self.may_resume(capture_ns, &result) {
            Some(LossReason::NotAligned)
        } else {
            self.correlation_check(&result.camera_from_keyframe).err()
        };
        let tracking = loss.is_none();

        let keyframe_age_s = capture_ns.saturating_sub(self.keyframe.requested_at_ns) as f64 * 1e-9;
        tracing::trace!(
            capture_ns,
            valid = result.valid,
            inliers = q.inlier_ratio,
            visible = q.visible_ratio,
            residual = q.residual_rms,
            correlation = q.correlation,
            iterations = q.iterations,
            jump_m,
            jump_deg,
            dt_s,
            keyframe_age_s,
            from_keyframe_m = result.camera_from_keyframe.translation.vector.norm(),
            from_keyframe_deg = result.camera_from_keyframe.rotation.angle().to_degrees(),
            stale = self.pending,
            "frame aligned"
        );
        self.stats.frames += 1;
        self.stats.max_keyframe_age_s = self.stats.max_keyframe_age_s.max(keyframe_age_s);
        if self.pending {
            self.stats.stale_frames += 1;
        }
        let mut out = FrameOutput {
            capture_ns,
            state: TrackState::Lost,
            world_from_camera: None,
            covariance: Matrix6::zeros(),
            quality: q,
            gain: result.gain,
            bias: result.bias,
            keyframe_id: self.keyframe.id,
            keyframe_age_s,
            stale_keyframe: self.pending,
            reset_counter: self.reset_counter,
            searching: false,
        };
        if !tracking {
            if self.state == TrackState::Tracking {
                let reason = loss.unwrap_or(LossReason::NotAligned);
                if let Some(n) = self.stats.losses.get_mut(reason.index()) {
                    *n += 1;
                }
                tracing::warn!(
                    reason = reason.name(),
                    inliers = q.inlier_ratio,
                    visible = q.visible_ratio,
                    correlation = q.correlation,
                    correlation_mean = self.correlation_mean,
                    local = self.last_local,
                    local_mean = self.continuity.local_mean().0,
                    jump_m,
                    jump_deg,
                    "tracking lost"
                );
                self.lost_since_ns = Some(self.last.map_or(capture_ns, |(t, _)| t));
            }
            if self.verify_left > 0 && self.reloc.is_none() {
                // Verifying the start pose or the last keyframe without a
                // database is retried every lost frame: not a warning.
                tracing::debug!(
                    inliers = q.inlier_ratio,
                    correlation = q.correlation,
                    "not verified; still searching"
                );
                self.verify_left = 0;
            }
            if self.verify_left > 0 {
                tracing::warn!(
                    inliers = q.inlier_ratio,
                    visible = q.visible_ratio,
                    residual = q.residual_rms,
                    correlation = q.correlation,
                    jump_m,
                    valid = result.valid,
                    "relocalization not confirmed by the next frame; still lost"
                );
                self.verify_left = 0;
            }
            self.state = TrackState::Lost;
            self.stats.lost_frames += 1;
            // Keep predicting from the last good pose. The vehicle moves on
            // as it did for a short loss (a frame refused by the jump test,
            // an occluder passing), and the local contrast's running mean
            // stays the reference for the frames after it ([`continuity`]);
            // over a longer one the velocity decays.
            if self.continuity.lost(self.lost_s(capture_ns)) {
                self.velocity *= 0.5;
            }
            self.tracked_run = 0;
            self.correlation_mean = None;
            let attempts = self.stats.reloc_attempts;
            if self.reloc.is_some() && self.reloc_due(capture_ns) {
                self.relocalize(pixels, stride, capture_ns);
                out.reset_counter = self.reset_counter;
            }
            self.reverify_without_database(capture_ns);
            out.searching = self.stats.reloc_attempts > attempts || self.verify_left > 0;
            if !out.searching && !self.pending && self.lost_s(capture_ns) <= SHORT_LOSS_S {
                // Within a short loss the keyframe follows the camera, at
                // this frame's alignment where it keeps to the motion, else
                // at the prediction: a frame resumes against a keyframe near
                // it. Frozen at the loss, the keyframe fell 30-40 degrees
                // behind `aggressive` in 0.2 s and no frame resumed
                // (docs/benchmarks.md, "A resume on blurred frames"). A
                // keyframe is the map seen from some pose; the gate, not
                // the pose it was rendered at, decides what is output.
                let near = result.valid
                    && pose_is_finite(&world_from_camera)
                    && jump_m <= max_jump_m
                    && jump_deg <= max_jump_deg;
                let world_from_keyframe = if near {
                    world_from_camera
                } else {
                    world_from_camera_predicted
                };
                if self.request_keyframe(world_from_keyframe, capture_ns) {
                    self.stats.lost_keyframes += 1;
                }
            }
            return Ok(out);
        }
        if dt_s > 0.0 {
            let step = log_se3(&(world_from_camera_prev.inverse() * world_from_camera));
            self.velocity = step / dt_s;
        }
        self.continuity.tracked(dt_s, self.last_local);
        self.tracked_run = self.tracked_run.saturating_add(1);
        self.correlation_mean = Some(self.correlation_mean.map_or(q.correlation, |mean| {
            mean + CORRELATION_MEAN_WEIGHT * (q.correlation - mean)
        }));
        self.last = Some((capture_ns, world_from_camera));
        // A frame that resumes tracking on its own after a loss is not
        // output: the next frame must track too, as the frames after a
        // relocalization must. On `aggressive --scanned` the wrong poses
        // left were such frames, 12-19 cm off after a loss of 4-5 frames,
        // against a keyframe 15-19 degrees away; the frame after each was
        // lost again (docs/benchmarks.md, "A resume confirmed by the next
        // frame").
        let mut held = self.state == TrackState::Lost;
        if self.verify_left > 0 {
            // Confirming a relocalization: no pose until it is confirmed.
            self.verify_left -= 1;
            if !by_search {
                self.stats.verified_by_tracking += 1;
            }
            if self.verify_left > 0 {
                self.verify_passed = true;
                self.stats.lost_frames += 1;
                out.searching = true;
                return Ok(out);
            }
            self.confirm_relocalization();
            out.reset_counter = self.reset_counter;
            // Confirmed by its own frames.
            held = false;
        }
        if held {
            self.stats.held_resumes += 1;
            tracing::info!(
                lost_s = self.lost_s(capture_ns),
                jump_m,
                "tracking resumed; poses are sent from the next tracked frame"
            );
        } else if self.state == TrackState::Lost {
            tracing::info!("tracking resumed");
        }
        self.last_before_reloc = None;
        self.state = TrackState::Tracking;
        self.lost_since_ns = None;
        let cov_delta = Matrix6::from_fn(|r, c| result.covariance_delta[r][c]);
        let adj = adjoint(&result.camera_from_keyframe);
        if held {
            // Tracked, and a keyframe may be asked for below, but nothing
            // is output for this frame.
            self.stats.lost_frames += 1;
            out.searching = true;
        } else {
            out.state = TrackState::Tracking;
            out.world_from_camera = Some(world_from_camera);
            out.covariance = adj * cov_delta * adj.transpose();
        }

        if !self.pending
            && policy::needs_keyframe(&self.policy, &self.keyframe, &result, keyframe_age_s)
        {
            let _ = self.request_keyframe(world_from_camera, capture_ns);
        }
        Ok(out)
    }

    /// Asks the render thread for a keyframe near `world_from_camera`:
    /// where the camera will be when it arrives, at the measured velocity
    /// once two frames tracked in a row (a keyframe that trails a fast
    /// camera overlaps it less and lets the alignment drift). False when
    /// the render thread was busy.
    fn request_keyframe(&mut self, world_from_camera: Pose, capture_ns: u64) -> bool {
        let lead_s = if self.tracked_run >= 2 {
            self.render_latency_s.min(MAX_RENDER_LEAD_S)
        } else {
            0.0
        };
        let requested = self.worker.try_request(RenderRequest {
            world_from_keyframe: renormalized(
                world_from_camera * exp_se3(&(self.velocity * lead_s)),
            ),
            id: self.next_keyframe_id,
            requested_at_ns: capture_ns,
            // Near a tracked pose: in free space.
            candidate: false,
        });
        if requested {
            self.next_keyframe_id += 1;
            self.pending = true;
        }
        requested
    }

    /// Takes a finished keyframe from the render thread, if any, for the
    /// frame captured at `capture_ns`.
    fn swap_in_ready_keyframe(&mut self, capture_ns: u64) {
        while let Some(result) = self.worker.try_result() {
            self.pending = false;
            match result {
                Ok(kf) => {
                    let latency_s = capture_ns.saturating_sub(kf.requested_at_ns) as f64 * 1e-9;
                    self.render_latency_s = if self.render_latency_s > 0.0 {
                        self.render_latency_s
                            + RENDER_LATENCY_WEIGHT * (latency_s - self.render_latency_s)
                    } else {
                        latency_s
                    };
                    let old = std::mem::replace(&mut self.keyframe, kf);
                    self.worker.recycle(old);
                    self.stats.keyframes += 1;
                }
                Err(e) => {
                    self.stats.render_failures += 1;
                    tracing::warn!(error = %e, "keyframe render failed; tracking on the old keyframe");
                }
            }
        }
    }
}

/// Frames the local contrast's running mean must cover before
/// `lost_local_correlation_drop` reads it: right after a start or a resume
/// the first frame sits on its keyframe's pose, and its local contrast is
/// the highest the next frames will see (`realistic` seed 12: 0.78, then
/// 0.51 two frames later). A short loss keeps the mean
/// ([`continuity::Continuity::lost`]).
const LOCAL_MEAN_MIN_FRAMES: u32 = 10;

/// Weight of each keyframe in the running mean of the render latency.
const RENDER_LATENCY_WEIGHT: f64 = 0.3;

/// Most a keyframe is rendered ahead of the camera, seconds: at 2 m/s, 30
/// cm, about what the keyframe policy lets the camera move from one.
const MAX_RENDER_LEAD_S: f64 = 0.15;

fn pose_is_finite(p: &Pose) -> bool {
    p.translation.vector.iter().all(|v| v.is_finite())
        && p.rotation.coords.iter().all(|v| v.is_finite())
}
