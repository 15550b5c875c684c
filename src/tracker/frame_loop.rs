//! The tracker process's loop (`star track`, and the tracker thread of
//! `star run`): frames from iceoryx2, read in place, into the STAR loop;
//! poses out to the iceoryx2 pose service and to MAVLink.
//!
//! Takes a started [`Tracker`] (map loaded, first keyframe rendered, ports
//! open); gives out a [`TrackSummary`]. The loop wakes on the frame event
//! listener with a short timeout so it sees the shutdown flag within 100 ms,
//! feeds the watchdog on every iteration (a loop stuck in a render or a
//! deadlock stops feeding it), and allocates nothing per frame: the pose
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
use crate::localizer::{FrameOutput, Localizer, TrackState};
use crate::mavlink_io::frames::{covariance_camera_to_world, upper_triangle};
use crate::mavlink_io::{LinkStats, MavlinkHandle, PoseSample};
use crate::service::{Service, ServiceState};

/// Longest wait on the frame event before the loop checks its flags again.
const POLL: Duration = Duration::from_millis(100);

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
    pub init_pose: Pose,
    /// The iceoryx2 node of the ports (dropped after them).
    pub(crate) _node: iceoryx2::node::Node<iceoryx2::service::ipc::Service>,
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
}

impl Tracker {
    /// Runs until SIGTERM/SIGINT or a `stop` condition.
    pub fn run(mut self, stop: &mut StopWhen) -> Result<TrackSummary> {
        let mut summary = TrackSummary {
            renderer: self.localizer.renderer_name().to_string(),
            ..TrackSummary::default()
        };
        let status = self.service.status();
        let watchdog = self.service.watchdog();
        let mut state = LoopState {
            last_pose: self.init_pose,
            previous: None,
            keyframe_id: 0,
            localizer_rejects: 0,
            publisher_changes: 0,
            trajectory_errors: 0,
        };
        let mut first_frame_at: Option<Instant> = None;
        let mut last_frame_at = Instant::now();
        let mut silent = false;
        while !self.shutdown.load(Ordering::Relaxed) {
            watchdog.feed();
            let received = self.subscriber.take_latest().context("receiving frames")?;
            if let Some(frame) = received {
                let now = Instant::now();
                first_frame_at.get_or_insert(now);
                last_frame_at = now;
                let changes = self.subscriber.stats().publisher_changes;
                if silent || changes != state.publisher_changes {
                    // A gap or a new camera: the velocity is stale.
                    self.localizer.forget_motion();
                    state.publisher_changes = changes;
                }
                if silent {
                    info!("camera frames resumed");
                    silent = false;
                }
                match frame.view() {
                    Ok(view) => self.process(&view, &mut state, &mut summary, &mut *stop),
                    Err(e) => {
                        state.localizer_rejects += 1;
                        warn!(error = %e, "rejected frame");
                    }
                }
                drop(frame);
                status.frame_done();
                if stop.frames.is_some_and(|n| summary.frames >= n) {
                    info!(frames = summary.frames, "frame limit reached");
                    break;
                }
                continue;
            }
            let waited = self
                .subscriber
                .wait_for_frame(POLL)
                .context("waiting for frames");
            if let Err(e) = waited {
                if self.shutdown.load(Ordering::Relaxed) {
                    break;
                }
                return Err(e);
            }
            let quiet = last_frame_at.elapsed();
            if quiet >= self.silence && !silent {
                silent = true;
                status.set_state(ServiceState::Waiting);
                warn!(silence_ms = quiet.as_millis() as u64, "no camera frames");
            }
            if first_frame_at.is_some() && stop.idle.is_some_and(|d| quiet >= d) {
                info!("no frames for the idle limit; stopping");
                break;
            }
            if quiet >= POLL
                && stop
                    .source_done
                    .as_ref()
                    .is_some_and(|f| f.load(Ordering::Relaxed))
            {
                info!("camera finished; stopping");
                break;
            }
        }
        if let Some(start) = first_frame_at {
            summary.active_s = last_frame_at.duration_since(start).as_secs_f64();
        }
        let sub = self.subscriber.stats();
        summary.rejected = sub.rejected + state.localizer_rejects;
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
        Ok(summary)
    }

    fn process(
        &mut self,
        view: &FrameView<'_>,
        state: &mut LoopState,
        summary: &mut TrackSummary,
        stop: &mut StopWhen,
    ) {
        let header = view.header;
        let out = match self.localizer.process_frame(
            view.pixels,
            view.width(),
            view.height(),
            header.stride as usize,
            header.capture_ns,
        ) {
            Ok(out) => out,
            Err(e) => {
                state.localizer_rejects += 1;
                if state.localizer_rejects.is_power_of_two() {
                    warn!(error = %e, rejected = state.localizer_rejects, "frame rejected");
                }
                return;
            }
        };
        summary.frames += 1;
        let status = self.service.status();
        if out.keyframe_id != state.keyframe_id {
            state.keyframe_id = out.keyframe_id;
            status.keyframe_created(monotonic_now_ns());
        }
        log_state_change(state.previous, &out);
        state.previous = Some(out.state);
        let tracking = out.state == TrackState::Tracking && out.world_from_camera.is_some();
        let pose = out.world_from_camera.unwrap_or(state.last_pose);
        let covariance_world = covariance_camera_to_world(&pose, &out.covariance);
        if tracking {
            summary.tracked += 1;
            state.last_pose = pose;
            status.set_state(ServiceState::Tracking);
            if let Some(writer) = stop.trajectory.as_mut() {
                let stamp_s = if header.dataset_stamp_ns == NO_DATASET_STAMP {
                    header.capture_ns as f64 * 1e-9
                } else {
                    header.dataset_stamp_ns as f64 * 1e-9
                };
                if let Err(e) = writer.push(stamp_s, &pose) {
                    state.trajectory_errors += 1;
                    if state.trajectory_errors.is_power_of_two() {
                        warn!(error = %e, failures = state.trajectory_errors, "cannot write the trajectory");
                    }
                }
            }
        } else {
            summary.lost += 1;
            status.set_state(ServiceState::Lost);
        }
        let mut msg = PoseMsg::new(
            header.capture_ns,
            header.sequence,
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
        if let Err(e) = self.poses.publish(&msg) {
            warn!(error = %e, "cannot publish the pose on iceoryx2");
        }
        if let Some(link) = &self.mavlink {
            link.publish(PoseSample {
                capture_ns: header.capture_ns,
                world_from_camera: pose,
                covariance_6x6: rows(&covariance_world),
                reset_counter: out.reset_counter,
                quality_percent: (out.quality.inlier_ratio.clamp(0.0, 1.0) * 100.0) as u8,
                tracking,
            });
        }
    }
}

struct LoopState {
    last_pose: Pose,
    previous: Option<TrackState>,
    keyframe_id: u64,
    localizer_rejects: u64,
    publisher_changes: u64,
    trajectory_errors: u64,
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
