//! The live view's logging thread (`star-rerun`): owns the Rerun
//! recording stream and logs what [`super::rerun_log::RerunSink`] queues
//! (entities listed there). Polls its queues every [`POLL`] when they are
//! empty, so the tracker's `try_send` never wakes it; allocates freely
//! (it is not the hot path).

use std::sync::mpsc::{Receiver, SyncSender, TryRecvError};
use std::time::Duration;

use crate::geometry::{PinholeCamera, Pose};
use crate::imgproc::{ImageF32, ImageU8};
use crate::localizer::RelocAttempt;
use crate::track::TrackerConfig;

use super::rerun_log::{Message, RerunStatics, RerunSummary, Snapshot};
use super::row::{FrameRow, RowState};
use super::view::{warp_into_keyframe, Alignment, ViewScratch};

/// How long the logging thread sleeps on an empty queue.
const POLL: Duration = Duration::from_millis(20);

/// The queues between the sink and the thread.
pub(super) struct Queues {
    pub rx: Receiver<Message>,
    pub attempts_rx: Receiver<RelocAttempt>,
    pub free: SyncSender<Box<Snapshot>>,
}

/// The logging thread's state.
pub(super) struct Logger {
    stream: rerun::RecordingStream,
    camera: PinholeCamera,
    huber_min_gray: f32,
    outlier_cut_gray: f32,
    rx: Receiver<Message>,
    attempts_rx: Receiver<RelocAttempt>,
    free: SyncSender<Box<Snapshot>>,
    statics: RerunStatics,
    trajectory: Vec<[f32; 3]>,
    first_stamp_s: Option<f64>,
    last_state: Option<RowState>,
    last_reset: Option<u8>,
    scratch: ViewScratch,
    residuals: Vec<f32>,
    summary: RerunSummary,
}

fn position(pose: &Pose) -> [f32; 3] {
    let t = pose.translation.vector;
    [t.x as f32, t.y as f32, t.z as f32]
}

fn transform(pose: &Pose) -> rerun::Transform3D {
    let q = pose.rotation.coords; // [x, y, z, w]
    rerun::Transform3D::from_translation_rotation(
        position(pose),
        rerun::Quaternion::from_xyzw([q[0] as f32, q[1] as f32, q[2] as f32, q[3] as f32]),
    )
}

fn to_u8(image: &ImageF32) -> Vec<u8> {
    image
        .data()
        .iter()
        .map(|v| v.round().clamp(0.0, 255.0) as u8)
        .collect()
}

impl Logger {
    /// The thread's state for frames of `camera`'s size.
    pub fn new(
        stream: rerun::RecordingStream,
        camera: &PinholeCamera,
        tracker: &TrackerConfig,
        queues: Queues,
        statics: RerunStatics,
    ) -> Self {
        let (w, h) = (camera.width as usize, camera.height as usize);
        Self {
            stream,
            camera: *camera,
            huber_min_gray: tracker.huber_min_gray,
            outlier_cut_gray: tracker.outlier_cut_gray,
            rx: queues.rx,
            attempts_rx: queues.attempts_rx,
            free: queues.free,
            statics,
            trajectory: Vec::new(),
            first_stamp_s: None,
            last_state: None,
            last_reset: None,
            scratch: ViewScratch::new(w, h),
            residuals: Vec::with_capacity(tracker.max_points_per_level(0)),
            summary: RerunSummary::default(),
        }
    }

    /// Logs until the sink closes the queues, then flushes.
    pub fn run(mut self) -> RerunSummary {
        self.log_statics();
        loop {
            while let Ok(attempt) = self.attempts_rx.try_recv() {
                self.log_attempt(&attempt);
            }
            match self.rx.try_recv() {
                Ok(Message::Row(index, row)) => self.log_row(index, &row),
                Ok(Message::Picture(snapshot)) => {
                    self.log_picture(&snapshot);
                    let _ = self.free.try_send(snapshot);
                }
                Err(TryRecvError::Empty) => std::thread::sleep(POLL),
                Err(TryRecvError::Disconnected) => break,
            }
        }
        while let Ok(attempt) = self.attempts_rx.try_recv() {
            self.log_attempt(&attempt);
        }
        self.log_trajectory();
        if let Err(e) = self.stream.flush_blocking() {
            tracing::warn!(error = %e, "Rerun: cannot flush the recording");
        }
        self.summary
    }

    /// Counts (and reports once) a refused log call.
    fn check(&mut self, what: &str, result: rerun::RecordingStreamResult<()>) {
        if let Err(e) = result {
            self.summary.log_errors += 1;
            if self.summary.log_errors == 1 {
                tracing::warn!(entity = what, error = %e, "Rerun refused a log call");
            }
        }
    }

    fn log_statics(&mut self) {
        let c = self.camera;
        let projection =
            rerun::components::PinholeProjection::from_focal_length_and_principal_point(
                [c.fx as f32, c.fy as f32],
                [c.cx as f32, c.cy as f32],
            );
        let pinhole =
            rerun::Pinhole::new(projection).with_resolution([c.width as f32, c.height as f32]);
        let r = self.stream.log_static("world/camera/image", &pinhole);
        self.check("world/camera/image", r);
        if let Some(mesh) = self.statics.mesh.take() {
            let colors = mesh.gray.iter().map(|&g| {
                let g = g.round().clamp(0.0, 255.0) as u8;
                rerun::Color::from_rgb(g, g, g)
            });
            let triangles = mesh.indices.chunks_exact(3).map(|t| [t[0], t[1], t[2]]);
            let archetype = rerun::Mesh3D::new(mesh.positions.iter().copied())
                .with_triangle_indices(triangles)
                .with_vertex_colors(colors);
            let r = self.stream.log_static("world/map", &archetype);
            self.check("world/map", r);
        }
        if let Some(gt) = self.statics.ground_truth.take() {
            let strip: Vec<[f32; 3]> = gt.poses.iter().map(position).collect();
            let archetype = rerun::LineStrips3D::new([strip])
                .with_colors([rerun::Color::from_rgb(160, 160, 160)]);
            let r = self.stream.log_static("world/ground_truth", &archetype);
            self.check("world/ground_truth", r);
        }
    }

    fn set_time(&mut self, index: u64, stamp_s: f64) {
        let first = *self.first_stamp_s.get_or_insert(stamp_s);
        self.stream.set_time_sequence("frame", index as i64);
        self.stream.set_duration_secs("time", stamp_s - first);
    }

    fn log_row(&mut self, index: u64, row: &FrameRow) {
        self.summary.rows += 1;
        self.set_time(index, row.stamp_s);
        let state = match row.state {
            RowState::Tracking => 0.0,
            RowState::Searching => 1.0,
            RowState::Lost => 2.0,
        };
        let scalars = [
            ("scalars/inlier_ratio", f64::from(row.inlier_ratio)),
            ("scalars/correlation", f64::from(row.correlation)),
            ("scalars/iterations", f64::from(row.iterations)),
            ("scalars/track_ms", f64::from(row.track_ms)),
            ("scalars/keyframe_age_ms", f64::from(row.keyframe_age_ms)),
            ("scalars/state", state),
        ];
        for (entity, value) in scalars {
            let r = self.stream.log(entity, &rerun::Scalars::single(value));
            self.check(entity, r);
        }
        if let Some(pose) = row.world_from_camera {
            let r = self.stream.log("world/camera", &transform(&pose));
            self.check("world/camera", r);
            self.trajectory.push(position(&pose));
        }
        let relocalized = row.state == RowState::Tracking
            && self.last_reset.is_some_and(|r| r != row.reset_counter)
            && self.trajectory.len() > 1;
        if self.last_state != Some(row.state) || relocalized {
            let (text, level) = match (row.state, relocalized) {
                (RowState::Tracking, true) => ("relocalized: tracking restarted", "INFO"),
                (RowState::Tracking, false) => ("tracking", "INFO"),
                (RowState::Searching, _) => ("searching: no pose is sent", "WARN"),
                (RowState::Lost, _) => ("lost: no pose is sent", "WARN"),
            };
            let r = self
                .stream
                .log("events", &rerun::TextLog::new(text).with_level(level));
            self.check("events", r);
        }
        self.last_state = Some(row.state);
        if row.state == RowState::Tracking {
            self.last_reset = Some(row.reset_counter);
        }
    }

    fn log_trajectory(&mut self) {
        if self.trajectory.len() < 2 {
            return;
        }
        let archetype = rerun::LineStrips3D::new([self.trajectory.clone()])
            .with_colors([rerun::Color::from_rgb(214, 39, 40)]);
        let r = self.stream.log("world/trajectory", &archetype);
        self.check("world/trajectory", r);
    }

    fn log_picture(&mut self, s: &Snapshot) {
        self.summary.pictures += 1;
        self.set_time(s.index, s.stamp_s);
        let (w, h) = (s.frame.width() as u32, s.frame.height() as u32);
        let frame = rerun::Image::from_l8(s.frame.data().to_vec(), [w, h]);
        let r = self.stream.log("world/camera/image", &frame);
        self.check("world/camera/image", r);
        let r = self.stream.log("frame/camera", &frame);
        self.check("frame/camera", r);
        let keyframe = rerun::Image::from_l8(to_u8(&s.keyframe_gray), [w, h]);
        let r = self.stream.log("frame/keyframe", &keyframe);
        self.check("frame/keyframe", r);
        self.log_trajectory();
        let Some(alignment) = s.alignment else {
            return;
        };
        warp_into_keyframe(
            &s.frame,
            &s.keyframe_gray,
            &s.keyframe_depth_m,
            &self.camera,
            &alignment,
            &mut self.scratch,
        );
        let warped = rerun::Image::from_l8(self.scratch.warped.data().to_vec(), [w, h]);
        let r = self.stream.log("frame/warped", &warped);
        self.check("frame/warped", r);
        let residual = rerun::Image::from_l8(self.scratch.residual.data().to_vec(), [w, h]);
        let r = self.stream.log("frame/residual", &residual);
        self.check("frame/residual", r);
        self.log_points(s, &alignment);
    }

    /// The keyframe's level-0 points in the world, colored by the Huber
    /// weight of their residual in this frame.
    fn log_points(&mut self, s: &Snapshot, alignment: &Alignment) {
        let frame: &ImageU8 = &s.frame;
        let m = alignment.camera_from_keyframe;
        self.residuals.clear();
        let mut samples = Vec::with_capacity(s.points.len());
        for p in &s.points {
            let p_keyframe = nalgebra::Point3::new(
                f64::from(p.p_keyframe[0]),
                f64::from(p.p_keyframe[1]),
                f64::from(p.p_keyframe[2]),
            );
            let p_camera = m * p_keyframe;
            let r = self
                .camera
                .project(&p_camera.coords)
                .and_then(|uv| bilinear_u8(frame, uv.x as f32, uv.y as f32))
                .map(|sample| sample - (alignment.gain * p.gray + alignment.bias));
            if let Some(r) = r {
                self.residuals.push(r.abs());
            }
            samples.push(r);
        }
        let median = if self.residuals.is_empty() {
            0.0
        } else {
            let mid = self.residuals.len() / 2;
            *self.residuals.select_nth_unstable_by(mid, f32::total_cmp).1
        };
        let k = (1.345 * 1.4826 * median).max(self.huber_min_gray);
        let cut = (4.0 * k).max(self.outlier_cut_gray);
        let colors = samples.iter().map(|r| match r {
            None => rerun::Color::from_rgb(128, 128, 128),
            Some(r) => {
                let a = r.abs();
                let weight = if a > cut {
                    0.0
                } else if a <= k {
                    1.0
                } else {
                    k / a
                };
                rerun::Color::from_rgb((255.0 * (1.0 - weight)) as u8, (200.0 * weight) as u8, 40)
            }
        });
        let positions = s.points.iter().map(|p| {
            let p_world = s.world_from_keyframe
                * nalgebra::Point3::new(
                    f64::from(p.p_keyframe[0]),
                    f64::from(p.p_keyframe[1]),
                    f64::from(p.p_keyframe[2]),
                );
            [p_world.x as f32, p_world.y as f32, p_world.z as f32]
        });
        let archetype = rerun::Points3D::new(positions)
            .with_colors(colors)
            .with_radii([0.01f32]);
        let r = self.stream.log("world/points", &archetype);
        self.check("world/points", r);
    }

    fn log_attempt(&mut self, attempt: &RelocAttempt) {
        self.summary.attempts += 1;
        let candidates = attempt.candidates();
        let positions = candidates.iter().map(|c| position(&c.world_from_camera));
        let colors = candidates.iter().map(|c| {
            if c.accepted {
                rerun::Color::from_rgb(44, 160, 44)
            } else {
                rerun::Color::from_rgb(214, 39, 40)
            }
        });
        let labels = candidates.iter().map(|c| {
            let source = if c.from_landmarks {
                "landmarks"
            } else {
                "view"
            };
            let verdict = if c.accepted { "accepted" } else { "refused" };
            format!("{source}: {verdict}")
        });
        let archetype = rerun::Points3D::new(positions)
            .with_colors(colors)
            .with_labels(labels)
            .with_radii([0.05f32]);
        let r = self.stream.log("reloc/candidates", &archetype);
        self.check("reloc/candidates", r);
        let accepted = candidates.iter().filter(|c| c.accepted).count();
        let text = format!(
            "relocalization attempt: {} candidates tried, {accepted} accepted by the gate",
            attempt.tried
        );
        let r = self
            .stream
            .log("events", &rerun::TextLog::new(text).with_level("INFO"));
        self.check("events", r);
    }
}

fn bilinear_u8(image: &ImageU8, x: f32, y: f32) -> Option<f32> {
    let (w, h) = (image.width(), image.height());
    if !(x >= 0.0 && y >= 0.0 && x < (w - 1) as f32 && y < (h - 1) as f32) {
        return None;
    }
    let (x0, y0) = (x as usize, y as usize);
    let (fx, fy) = (x - x0 as f32, y - y0 as f32);
    let d = image.data();
    let at = |xx: usize, yy: usize| f32::from(d[yy * w + xx]);
    let top = at(x0, y0) + fx * (at(x0 + 1, y0) - at(x0, y0));
    let bottom = at(x0, y0 + 1) + fx * (at(x0 + 1, y0 + 1) - at(x0, y0 + 1));
    Some(top + fy * (bottom - top))
}
