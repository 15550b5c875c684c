//! The tracker process's loop (`star track`, and the tracker thread of
//! `star run`): frames from iceoryx2, read in place, into the STAR loop;
//! poses out to the iceoryx2 pose service and to MAVLink.
//!
//! Takes a started [`Tracker`] (map loaded, first keyframe rendered, ports
//! open); gives out a [`TrackSummary`]. One job, one loop:
//! [`Tracker::run`] is [`Tracker::step`] until it returns [`Step::Stop`],
//! then [`Tracker::finish`]; a step is one iteration (one frame tracked and
//! its pose sent, or one wait for a frame). The loop wakes on the frame event
//! listener with a short timeout so it sees the shutdown flag within 100 ms,
//! feeds the watchdog on every iteration (a loop stuck in a render or a
//! deadlock stops feeding it), and allocates nothing per frame but
//! iceoryx2's one per pose sample (`tests/tracker_alloc.rs`): the pose
//! message and the MAVLink sample are plain values, and the trajectory is
//! formatted into a fixed buffer that reaches its file at least once a
//! second ([`TrajectoryWriter`]), so a killed process loses at most a second
//! of it and a long flight holds no growing list.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use nalgebra::Matrix6;
use tracing::{info, warn};

use crate::clock::monotonic_now_ns;
use crate::dataset::TrajectoryWriter;
use crate::geometry::Pose;
use crate::ipc::{
    FrameSubscriber, FrameView, PoseMsg, PosePublisher, TrackingState, NO_DATASET_STAMP,
};
use crate::localizer::{FrameOutput, Localizer, LocalizerError, NextFrameHold, TrackState};
use crate::mavlink_io::frames::{twist_covariance_world_from_camera, upper_triangle};
use crate::mavlink_io::{LinkStats, MavlinkHandle, PoseSample};
use crate::output::{FramePixels, FrameSinks, RecordSink, RecordSummary};
use crate::service::{Service, ServiceState, StatusBoard, Watchdog};

/// Longest wait on the frame event before the loop checks its flags again.
const POLL: Duration = Duration::from_millis(100);
/// How often a silent tracker checks that it is still attached to the
/// frame service (its shared memory may have been deleted).
const SERVICE_CHECK_PERIOD: Duration = Duration::from_secs(1);

/// Everything the loop runs with, built by [`super::start`].
pub struct Tracker {
    /// Frame subscriber (zero-copy).
    pub subscriber: FrameSubscriber,
    /// Pose publisher.
    pub poses: PosePublisher,
    /// The STAR loop.
    pub localizer: Localizer,
    /// The MAVLink link, when enabled.
    pub mavlink: Option<MavlinkHandle>,
    /// systemd readiness, watchdog and status.
    pub service: Service,
    /// Set by SIGTERM/SIGINT.
    pub shutdown: Arc<AtomicBool>,
    /// The camera counts as silent after this long without a frame.
    pub silence: Duration,
    /// The initial pose (used for the pose message until the first fix).
    pub world_from_camera_start: Pose,
    /// The loop's state from one iteration to the next.
    pub(super) looping: LoopState,
    /// The iceoryx2 node of the ports (dropped after them); also used to
    /// re-attach to a frame service recreated after its shared memory was
    /// deleted.
    pub(crate) node: iceoryx2::node::Node<iceoryx2::service::ipc::Service>,
}

/// When the loop ends besides SIGTERM/SIGINT, and where the poses go.
#[derive(Default)]
pub struct StopWhen {
    /// After this many processed frames.
    pub frames: Option<u64>,
    /// After this long without a frame, once at least one frame arrived.
    pub idle: Option<Duration>,
    /// Once this flag is set and no frame arrived for `POLL` (the camera
    /// thread of `star run` finished).
    pub source_done: Option<Arc<AtomicBool>>,
    /// Stream the tracked poses to this file (created before the loop
    /// starts, so a bad path fails at start, not at the end).
    pub trajectory: Option<TrajectoryWriter>,
    /// The flight log (`--record DIR`), started before the loop.
    pub record: Option<RecordSink>,
    /// The live view (`--rerun`), started before the loop.
    #[cfg(feature = "rerun")]
    pub rerun: Option<crate::output::rerun_log::RerunSink>,
}

impl StopWhen {
    /// Whether the live view is on.
    #[cfg(feature = "rerun")]
    fn has_rerun(&self) -> bool {
        self.rerun.is_some()
    }

    /// Whether the live view is on: never without the `rerun` feature.
    #[cfg(not(feature = "rerun"))]
    fn has_rerun(&self) -> bool {
        false
    }
}

/// What the loop did.
#[derive(Debug, Clone, Default)]
pub struct TrackSummary {
    /// Frames given to the localizer that it processed.
    pub frames: u64,
    /// Frames with a pose.
    pub tracked: u64,
    /// Frames lost.
    pub lost: u64,
    /// Frames rejected (inconsistent header, wrong size, timestamp order).
    pub rejected: u64,
    /// Of the rejected frames, those whose size is not the calibration's
    /// (`[camera.intrinsics]` width x height).
    pub wrong_size: WrongSize,
    /// Frames the camera published that the tracker never saw.
    pub dropped: u64,
    /// Times a new camera publisher appeared.
    pub publisher_changes: u64,
    /// Keyframes rendered.
    pub keyframes: u64,
    /// Wall time from the first to the last frame, seconds.
    pub active_s: f64,
    /// MAVLink counters, when enabled.
    pub link: Option<LinkStats>,
    /// Tracked poses written to the trajectory file, when one was given.
    pub trajectory_poses: Option<u64>,
    /// The renderer in use.
    pub renderer: String,
    /// Why the loop ended (`None` only for a summary not made by
    /// [`Tracker::run`]).
    pub stop_reason: Option<StopReason>,
    /// What the flight log recorded, when one was kept.
    pub record: Option<RecordSummary>,
    /// With `[keyframe] hold_for_next_frame`: tracked frames whose pose was
    /// not sent because the next frame was lost (or none came before the
    /// end; that last frame counts as lost).
    pub held_for_next_frame: Option<u64>,
    /// What the live view logged, when it was on.
    #[cfg(feature = "rerun")]
    pub rerun: Option<crate::output::rerun_log::RerunSummary>,
}

/// Frames refused because their size is not the calibration's: a camera
/// that delivers another size than `[camera.intrinsics]` asks for (a V4L2
/// driver that picked the nearest size it offers, a replayed dataset of
/// another resolution). The first is logged at warn, and again whenever the
/// size found changes; each is counted.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct WrongSize {
    /// Frames refused.
    pub frames: u64,
    /// The size of the last one refused, pixels (width, height).
    pub found: Option<(usize, usize)>,
    /// The calibrated size, pixels (width, height).
    pub calibrated: Option<(u32, u32)>,
}

/// What one iteration of the loop ([`Tracker::step`]) did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Step {
    /// A frame was tracked: its pose went to the pose service, to MAVLink
    /// and to the trajectory file.
    Tracked,
    /// A frame was processed without a pose (lost): the last pose went to
    /// the pose service and to MAVLink, marked lost. With `[keyframe]
    /// hold_for_next_frame` both name the frame sent, the one before the
    /// frame processed; the first frame, held, is `Lost` with nothing sent.
    Lost,
    /// A frame arrived but was rejected (inconsistent header, or refused by
    /// the localizer: wrong size, timestamps out of order); nothing went out.
    Rejected,
    /// No frame was pending; the loop waited for one (at most `POLL`).
    Waited,
    /// The loop is over; [`Tracker::finish`] ends the run.
    Stop(StopReason),
}

/// Why the loop ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StopReason {
    /// A stop signal (SIGTERM, SIGINT, SIGHUP, SIGQUIT, SIGUSR1) set the
    /// shutdown flag.
    Shutdown,
    /// [`StopWhen::frames`] frames were processed, the last one in this step.
    FrameLimit,
    /// No frame for [`StopWhen::idle`].
    Idle,
    /// [`StopWhen::source_done`] is set and no frame came for `POLL`.
    SourceDone,
}

/// The loop's state from one iteration to the next.
pub(super) struct LoopState {
    status: Arc<StatusBoard>,
    watchdog: Watchdog,
    frames: u64,
    tracked: u64,
    lost: u64,
    /// The last tracked pose (`None`: none yet, use [`Tracker::world_from_camera_start`]).
    world_from_camera_last: Option<Pose>,
    previous: Option<TrackState>,
    keyframe_id: u64,
    localizer_rejects: u64,
    wrong_size: WrongSize,
    publisher_changes: u64,
    trajectory_errors: u64,
    first_frame_at: Option<Instant>,
    /// The last frame's arrival; the first step sets it, so the silence
    /// clock starts with the loop, not with [`super::start`].
    last_frame_at: Option<Instant>,
    silent: bool,
    /// When the silent loop last checked the frame service.
    last_service_check: Option<Instant>,
    /// What is sent waits for the next frame (`[keyframe] hold_for_next_frame`).
    hold: NextFrameHold<SentFrame>,
}

/// What the send path needs of a frame besides its output.
#[derive(Debug, Clone, Copy)]
struct SentFrame {
    capture_ns: u64,
    sequence: u64,
    stamp_s: f64,
}

impl LoopState {
    /// The state before the first iteration of `service`'s loop.
    pub(super) fn new(service: &Service, hold_for_next_frame: bool) -> Self {
        Self {
            status: service.status(),
            watchdog: service.watchdog(),
            frames: 0,
            tracked: 0,
            lost: 0,
            world_from_camera_last: None,
            previous: None,
            keyframe_id: 0,
            localizer_rejects: 0,
            wrong_size: WrongSize::default(),
            publisher_changes: 0,
            trajectory_errors: 0,
            first_frame_at: None,
            last_frame_at: None,
            silent: false,
            last_service_check: None,
            hold: NextFrameHold::new(hold_for_next_frame),
        }
    }
}

impl Tracker {
    /// Runs until SIGTERM/SIGINT or a `stop` condition: [`Tracker::step`]
    /// until it returns [`Step::Stop`], then [`Tracker::finish`].
    pub fn run(mut self, stop: &mut StopWhen) -> Result<TrackSummary> {
        if let (Some(record), Some(link)) = (stop.record.as_mut(), &self.mavlink) {
            record.attach_mavlink(link.send_log());
        }
        let reason = loop {
            if let Step::Stop(reason) = self.step(stop)? {
                break reason;
            }
        };
        let mut summary = self.finish(stop)?;
        summary.stop_reason = Some(reason);
        Ok(summary)
    }

    /// One iteration of the loop. Feeds the watchdog, then tracks the newest
    /// frame and sends its pose out; or, when no frame is pending, waits for
    /// one (at most `POLL`) and checks the silence warning and the idle and
    /// camera-finished conditions. In steady state it allocates nothing but
    /// iceoryx2's one `Rc` per pose sample (`tests/tracker_alloc.rs`).
    ///
    /// Errors when iceoryx2 fails, except for a wait that SIGTERM/SIGINT
    /// interrupted: that is [`StopReason::Shutdown`].
    pub fn step(&mut self, stop: &mut StopWhen) -> Result<Step> {
        if self.shutdown.load(Ordering::Relaxed) {
            return Ok(Step::Stop(StopReason::Shutdown));
        }
        self.looping.watchdog.feed();
        let received = self.subscriber.take_latest().context("receiving frames")?;
        if let Some(frame) = received {
            let now = Instant::now();
            let state = &mut self.looping;
            state.first_frame_at.get_or_insert(now);
            state.last_frame_at = Some(now);
            let changes = self.subscriber.stats().publisher_changes;
            if state.silent || changes != state.publisher_changes {
                // A gap or a new camera: the velocity is stale, and a frame
                // held for the next one is not confirmed by a frame after
                // the gap (`hold_for_next_frame`): withheld, counted lost.
                self.localizer.forget_motion();
                state.publisher_changes = changes;
                if state.hold.finish().is_some() {
                    state.lost += 1;
                }
            }
            if state.silent {
                info!("camera frames resumed");
                state.silent = false;
            }
            let outcome = match frame.view() {
                Ok(view) => self.process(&view, stop),
                Err(e) => {
                    self.looping.localizer_rejects += 1;
                    warn!(error = %e, "rejected frame");
                    Step::Rejected
                }
            };
            drop(frame);
            self.looping.status.frame_done();
            let frames = self.looping.frames;
            if stop.frames.is_some_and(|n| frames >= n) {
                info!(frames, "frame limit reached");
                return Ok(Step::Stop(StopReason::FrameLimit));
            }
            return Ok(outcome);
        }
        let last_frame_at = *self.looping.last_frame_at.get_or_insert_with(Instant::now);
        let waited = self
            .subscriber
            .wait_for_frame(POLL)
            .context("waiting for frames");
        if let Err(e) = waited {
            if self.shutdown.load(Ordering::Relaxed) {
                return Ok(Step::Stop(StopReason::Shutdown));
            }
            return Err(e);
        }
        let state = &mut self.looping;
        let quiet = last_frame_at.elapsed();
        if quiet >= self.silence && !state.silent {
            state.silent = true;
            state.status.set_state(ServiceState::Waiting);
            warn!(silence_ms = quiet.as_millis() as u64, "no camera frames");
        }
        // A silent camera may be one that cannot open the frame service
        // because its shared memory was deleted: check once a second.
        if state.silent
            && state
                .last_service_check
                .is_none_or(|t| t.elapsed() >= SERVICE_CHECK_PERIOD)
        {
            state.last_service_check = Some(Instant::now());
            if let Err(e) = self.subscriber.reattach_if_orphaned(&self.node) {
                warn!(error = %e, "cannot check the frame service");
            }
        }
        if state.first_frame_at.is_some() && stop.idle.is_some_and(|d| quiet >= d) {
            info!("no frames for the idle limit; stopping");
            return Ok(Step::Stop(StopReason::Idle));
        }
        if quiet >= POLL
            && stop
                .source_done
                .as_ref()
                .is_some_and(|f| f.load(Ordering::Relaxed))
        {
            info!("camera finished; stopping");
            return Ok(Step::Stop(StopReason::SourceDone));
        }
        Ok(Step::Waited)
    }

    /// Ends the run: stops the MAVLink link and the service thread, flushes
    /// the trajectory file and says what the loop did.
    pub fn finish(mut self, stop: &mut StopWhen) -> Result<TrackSummary> {
        // The frame still held for the next one: none came, nothing is sent.
        let last_held = self.looping.hold.finish().is_some();
        let state = &self.looping;
        let mut summary = TrackSummary {
            frames: state.frames,
            tracked: state.tracked,
            lost: state.lost + u64::from(last_held),
            held_for_next_frame: state.hold.enabled().then(|| state.hold.withheld()),
            renderer: self.localizer.renderer_name().to_string(),
            ..TrackSummary::default()
        };
        if let (Some(start), Some(last)) = (state.first_frame_at, state.last_frame_at) {
            summary.active_s = last.duration_since(start).as_secs_f64();
        }
        let sub = self.subscriber.stats();
        summary.rejected = sub.rejected + state.localizer_rejects;
        summary.wrong_size = state.wrong_size;
        summary.dropped = sub.dropped;
        summary.publisher_changes = sub.publisher_changes;
        summary.keyframes = self.localizer.stats().keyframes;
        if let Some(link) = self.mavlink.take() {
            summary.link = Some(link.stats());
            link.shutdown();
        }
        self.service.stop();
        if let Some(writer) = stop.trajectory.as_mut() {
            writer.flush().context("trajectory file")?;
            summary.trajectory_poses = Some(writer.poses());
        }
        summary.record = stop.record.take().map(RecordSink::finish);
        #[cfg(feature = "rerun")]
        {
            summary.rerun = stop
                .rerun
                .take()
                .map(crate::output::rerun_log::RerunSink::finish);
        }
        Ok(summary)
    }

    /// Tracks one frame and sends its pose out.
    fn process(&mut self, view: &FrameView<'_>, stop: &mut StopWhen) -> Step {
        let header = view.header;
        let state = &mut self.looping;
        let started = Instant::now();
        let out = match self.localizer.process_frame(
            view.pixels,
            view.width(),
            view.height(),
            header.stride as usize,
            header.capture_ns,
        ) {
            Ok(out) => out,
            Err(LocalizerError::FrameSize {
                found_w,
                found_h,
                want_w,
                want_h,
                ..
            }) => {
                state.localizer_rejects += 1;
                let wrong = &mut state.wrong_size;
                wrong.frames += 1;
                let found = Some((found_w, found_h));
                if wrong.found != found {
                    warn!(
                        found = %format!("{found_w}x{found_h}"),
                        calibrated = %format!("{want_w}x{want_h}"),
                        refused_so_far = wrong.frames,
                        "camera frames are not the calibrated size ([camera.intrinsics]); they are refused and counted in the summary"
                    );
                }
                wrong.found = found;
                wrong.calibrated = Some((want_w, want_h));
                return Step::Rejected;
            }
            Err(e) => {
                state.localizer_rejects += 1;
                if state.localizer_rejects.is_power_of_two() {
                    warn!(error = %e, rejected = state.localizer_rejects, "frame rejected");
                }
                return Step::Rejected;
            }
        };
        let track_ms = started.elapsed().as_secs_f64() * 1e3;
        state.frames += 1;
        if out.keyframe_id != state.keyframe_id {
            state.keyframe_id = out.keyframe_id;
            state.status.keyframe_created(monotonic_now_ns());
        }
        log_state_change(state.previous, &out);
        state.previous = Some(out.state);
        let stamp_s = if header.dataset_stamp_ns == NO_DATASET_STAMP {
            header.capture_ns as f64 * 1e-9
        } else {
            header.dataset_stamp_ns as f64 * 1e-9
        };
        if stop.record.is_some() || stop.has_rerun() {
            // The flight log and the live view show what the tracker made
            // of this frame; with `hold_for_next_frame` its pose goes out
            // (or not) with the next frame.
            let pixels = FramePixels {
                pixels: view.pixels,
                width: view.width(),
                height: view.height(),
                stride: header.stride as usize,
            };
            FrameSinks {
                record: stop.record.as_mut(),
                #[cfg(feature = "rerun")]
                rerun: stop.rerun.as_mut(),
            }
            .hand(&self.localizer, &out, stamp_s, track_ms, pixels);
        }
        let sent = SentFrame {
            capture_ns: header.capture_ns,
            sequence: header.sequence,
            stamp_s,
        };
        let Some((out, sent)) = state.hold.push(out, sent) else {
            // The first frame, held for the next.
            return Step::Lost;
        };
        let stamp_s = sent.stamp_s;
        let tracking = out.state == TrackState::Tracking && out.world_from_camera.is_some();
        let pose = out
            .world_from_camera
            .or(state.world_from_camera_last)
            .unwrap_or(self.world_from_camera_start);
        let covariance_world = twist_covariance_world_from_camera(&pose, &out.covariance);
        if tracking {
            state.tracked += 1;
            state.world_from_camera_last = Some(pose);
            state.status.set_state(ServiceState::Tracking);
            if let Some(writer) = stop.trajectory.as_mut() {
                if let Err(e) = writer.push(stamp_s, &pose) {
                    state.trajectory_errors += 1;
                    if state.trajectory_errors.is_power_of_two() {
                        warn!(error = %e, failures = state.trajectory_errors, "cannot write the trajectory");
                    }
                }
            }
        } else {
            state.lost += 1;
            state.status.set_state(ServiceState::Lost);
        }
        let mut msg = PoseMsg::new(
            sent.capture_ns,
            sent.sequence,
            &pose,
            if tracking {
                TrackingState::Tracking
            } else {
                TrackingState::Lost
            },
        );
        msg.covariance = upper_triangle(&position_rotation_covariance(&pose, &out.covariance));
        msg.inlier_ratio = out.quality.inlier_ratio;
        msg.mean_residual = out.quality.residual_rms;
        msg.visible_fraction = out.quality.visible_ratio;
        msg.reset_counter = u32::from(out.reset_counter);
        // iceoryx2 0.10 allocates one small `Rc` per loaned sample
        // (`Publisher::loan_uninit` -> `ChunkMutSharedState::new`), freed
        // when the sample is sent: the one allocation of an iteration.
        if let Err(e) = self.poses.publish(&msg) {
            warn!(error = %e, "cannot publish the pose on iceoryx2");
        }
        if let Some(link) = &self.mavlink {
            link.publish(PoseSample {
                capture_ns: sent.capture_ns,
                world_from_camera: pose,
                covariance_6x6: rows(&covariance_world),
                reset_counter: out.reset_counter,
                quality_percent: (out.quality.inlier_ratio.clamp(0.0, 1.0) * 100.0) as u8,
                tracking,
            });
        }
        if tracking {
            Step::Tracked
        } else {
            Step::Lost
        }
    }
}

fn log_state_change(previous: Option<TrackState>, out: &FrameOutput) {
    if previous == Some(out.state) {
        return;
    }
    let q = &out.quality;
    match out.state {
        TrackState::Tracking => info!(
            inlier_ratio = q.inlier_ratio,
            visible_ratio = q.visible_ratio,
            reset_counter = out.reset_counter,
            "tracking"
        ),
        TrackState::Lost => warn!(
            inlier_ratio = q.inlier_ratio,
            visible_ratio = q.visible_ratio,
            "tracking lost; no pose is sent"
        ),
    }
}

/// Covariance of (world position, world-frame rotation vector) from the
/// covariance of the right camera-frame twist: to first order the position
/// moves by `R v` and the rotation by `R w`.
fn position_rotation_covariance(world_from_camera: &Pose, camera: &Matrix6<f64>) -> Matrix6<f64> {
    let r = world_from_camera.rotation.to_rotation_matrix().into_inner();
    let mut j = Matrix6::zeros();
    j.fixed_view_mut::<3, 3>(0, 0).copy_from(&r);
    j.fixed_view_mut::<3, 3>(3, 3).copy_from(&r);
    j * camera * j.transpose()
}

fn rows(m: &Matrix6<f64>) -> [[f64; 6]; 6] {
    let mut out = [[0.0; 6]; 6];
    for (r, row) in out.iter_mut().enumerate() {
        for (c, v) in row.iter_mut().enumerate() {
            *v = m[(r, c)];
        }
    }
    out
}
