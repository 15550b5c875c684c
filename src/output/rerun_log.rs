//! The live view in Rerun (`--rerun save:FILE.rrd|connect:ADDR`, cargo
//! feature `rerun`): the tracker's end ([`RerunSink`]) and the logging
//! thread (`star-rerun`), which owns the Rerun recording stream.
//!
//! Takes what the flight log takes (a `Copy` [`FrameRow`] per frame; every
//! Nth frame the camera frame, the keyframe's gray, depth and level-0
//! points copied into a pooled buffer) plus each relocalization attempt's
//! candidates, through bounded queues that drop (and count) when full; the
//! tracker never waits and allocates nothing. Gives out, on the timelines
//! `frame` (sequence) and `time` (seconds since the first frame):
//!
//! | entity | what | when |
//! |---|---|---|
//! | `world/map` | the map mesh (gray vertex colors) | once, static |
//! | `world/ground_truth` | the true trajectory | once, static, when known |
//! | `world/trajectory` | the estimated trajectory so far | every picture frame and at the end |
//! | `world/camera` | `world_from_camera` (transform) and the pinhole | every tracked frame |
//! | `world/camera/image` | the camera frame, in 3D | every picture frame |
//! | `world/points` | the keyframe's selected points, colored by Huber weight (green 1, red 0, gray not visible) | every tracked picture frame |
//! | `frame/camera`, `frame/keyframe`, `frame/warped`, `frame/residual` | the view strip's four pictures | every picture frame |
//! | `scalars/inlier_ratio`, `scalars/correlation`, `scalars/iterations`, `scalars/track_ms`, `scalars/keyframe_age_ms`, `scalars/state` | per frame (state: 0 tracking, 1 searching, 2 lost) | every frame |
//! | `events` | state changes, relocalizations | when they happen |
//! | `reloc/candidates` | each attempt's candidate positions: green accepted by the gate, red refused | every attempt |
//!
//! The Huber weights are recomputed on the logging thread with the
//! aligner's rule (threshold `max(1.345 * 1.4826 * median |r|,
//! huber_min_gray)`, zero beyond `max(4 k, outlier_cut_gray)`) from the
//! level-0 points and the final pose, gain and bias; the tracker hands over
//! no per-point data of its own.

use std::path::Path;
use std::sync::atomic::{AtomicU64, Ordering::Relaxed};
use std::sync::mpsc::{sync_channel, Receiver, SyncSender, TrySendError};
use std::sync::Arc;
use std::thread::JoinHandle;

use crate::dataset::Trajectory;
use crate::geometry::{PinholeCamera, Pose};
use crate::imgproc::{ImageF32, ImageU8};
use crate::localizer::RelocAttempt;
use crate::map::Mesh;
use crate::track::{KeyPoint, Keyframe, TrackerConfig};

use super::record::FramePixels;
use super::rerun_logger::{Logger, Queues};
use super::rerun_target::RerunTarget;
use super::row::FrameRow;
use super::view::Alignment;

/// Errors starting the live view.
#[derive(Debug, thiserror::Error)]
pub enum RerunLogError {
    /// The recording stream could not be created (file, viewer address).
    #[error("cannot open the Rerun recording ({target}): {message}")]
    Open {
        /// The `--rerun` target.
        target: String,
        /// Rerun's message.
        message: String,
    },
    /// The logging thread could not be started.
    #[error("cannot start the Rerun logging thread: {0}")]
    Thread(#[source] std::io::Error),
}

/// What the live view shows once: the map and the truth.
#[derive(Default)]
pub struct RerunStatics {
    /// The map mesh.
    pub mesh: Option<Arc<Mesh>>,
    /// The ground truth, when the run has one (`star localize`).
    pub ground_truth: Option<Trajectory>,
}

/// What the live view sent, for the summary.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct RerunSummary {
    /// Rows logged (frames).
    pub rows: u64,
    /// Picture frames logged.
    pub pictures: u64,
    /// Relocalization attempts logged.
    pub attempts: u64,
    /// Rows dropped: the queue was full.
    pub rows_dropped: u64,
    /// Pictures skipped: no free buffer, or the queue was full.
    pub pictures_dropped: u64,
    /// Log calls Rerun refused (each logged at warn the first time).
    pub log_errors: u64,
}

/// One picture frame, a buffer of the pool.
pub(super) struct Snapshot {
    pub index: u64,
    pub stamp_s: f64,
    pub frame: ImageU8,
    pub keyframe_gray: ImageF32,
    pub keyframe_depth_m: ImageF32,
    pub world_from_keyframe: Pose,
    /// Level-0 points of the keyframe; capacity fixed at start.
    pub points: Vec<KeyPoint>,
    pub alignment: Option<Alignment>,
}

/// Messages to the logging thread.
pub(super) enum Message {
    /// A frame's row and its index.
    Row(u64, FrameRow),
    /// A picture frame.
    Picture(Box<Snapshot>),
}

#[derive(Default)]
struct Counters {
    rows_dropped: AtomicU64,
    pictures_dropped: AtomicU64,
}

/// The tracker's end of the live view.
pub struct RerunSink {
    tx: Option<SyncSender<Message>>,
    attempts_tx: Option<SyncSender<RelocAttempt>>,
    free: Receiver<Box<Snapshot>>,
    spare: Option<Box<Snapshot>>,
    every_n: u64,
    frames: u64,
    attempts_seen: u64,
    counters: Arc<Counters>,
    thread: Option<JoinHandle<RerunSummary>>,
}

/// Rows the tracker may queue before rows are dropped.
const QUEUE_ROWS: usize = 512;
/// Picture buffers circulating.
const BUFFERS: usize = 3;

impl RerunSink {
    /// Opens the recording (a file, or a connection to a viewer), starts the
    /// logging thread and logs the statics. Pictures every `every_n` frames
    /// (0: none).
    pub fn start(
        target: &RerunTarget,
        camera: &PinholeCamera,
        tracker: &TrackerConfig,
        every_n: u32,
        statics: RerunStatics,
    ) -> Result<Self, RerunLogError> {
        let builder = rerun::RecordingStreamBuilder::new("star");
        let open_err = |e: rerun::RecordingStreamError| RerunLogError::Open {
            target: format!("{target:?}"),
            message: e.to_string(),
        };
        let stream = match target {
            RerunTarget::Save(path) => builder.save(path).map_err(open_err)?,
            RerunTarget::Connect(url) => {
                builder.connect_grpc_opts(url.clone()).map_err(open_err)?
            }
        };
        let (w, h) = (camera.width as usize, camera.height as usize);
        let points_capacity = tracker.max_points_per_level(0);
        let (free_tx, free_rx) = sync_channel(BUFFERS);
        if every_n > 0 {
            for _ in 0..BUFFERS {
                let mut snapshot = Box::new(Snapshot {
                    index: 0,
                    stamp_s: 0.0,
                    frame: ImageU8::new(w, h, 0),
                    keyframe_gray: ImageF32::new(w, h, 0.0),
                    keyframe_depth_m: ImageF32::new(w, h, 0.0),
                    world_from_keyframe: Pose::identity(),
                    points: Vec::with_capacity(points_capacity),
                    alignment: None,
                });
                snapshot.frame.fill(1);
                snapshot.keyframe_gray.fill(1.0);
                snapshot.keyframe_depth_m.fill(1.0);
                let _ = free_tx.try_send(snapshot);
            }
        }
        let (tx, rx) = sync_channel(QUEUE_ROWS);
        let (attempts_tx, attempts_rx) = sync_channel(4);
        let counters = Arc::new(Counters::default());
        let logger = Logger::new(
            stream,
            camera,
            tracker,
            Queues {
                rx,
                attempts_rx,
                free: free_tx,
            },
            statics,
        );
        let thread = std::thread::Builder::new()
            .name("star-rerun".into())
            .spawn(move || logger.run())
            .map_err(RerunLogError::Thread)?;
        tracing::info!(?target, every_n, "Rerun live view started");
        Ok(Self {
            tx: Some(tx),
            attempts_tx: Some(attempts_tx),
            free: free_rx,
            spare: None,
            every_n: u64::from(every_n),
            frames: 0,
            attempts_seen: 0,
            counters,
            thread: Some(thread),
        })
    }

    /// Logs one processed frame; every Nth frame its pictures. Never waits
    /// and allocates nothing.
    pub fn frame(
        &mut self,
        row: &FrameRow,
        pixels: FramePixels<'_>,
        keyframe: &Keyframe,
        alignment: Option<Alignment>,
    ) {
        let index = self.frames;
        self.frames += 1;
        let Some(tx) = &self.tx else {
            return;
        };
        if let Err(TrySendError::Full(_)) = tx.try_send(Message::Row(index, *row)) {
            self.counters.rows_dropped.fetch_add(1, Relaxed);
        }
        if self.every_n == 0 || index % self.every_n != 0 {
            return;
        }
        let Some(mut snapshot) = self.spare.take().or_else(|| self.free.try_recv().ok()) else {
            self.counters.pictures_dropped.fetch_add(1, Relaxed);
            return;
        };
        if !fill(
            &mut snapshot,
            index,
            row.stamp_s,
            pixels,
            keyframe,
            alignment,
        ) {
            self.counters.pictures_dropped.fetch_add(1, Relaxed);
            self.spare = Some(snapshot);
            return;
        }
        match tx.try_send(Message::Picture(snapshot)) {
            Ok(()) => {}
            Err(TrySendError::Full(Message::Picture(s)))
            | Err(TrySendError::Disconnected(Message::Picture(s))) => {
                self.counters.pictures_dropped.fetch_add(1, Relaxed);
                self.spare = Some(s);
            }
            Err(_) => {}
        }
    }

    /// Logs the localizer's last relocalization attempt if it is new
    /// (`attempts` is `LoopStats::reloc_attempts`).
    pub fn reloc_attempt(&mut self, attempts: u64, attempt: &RelocAttempt) {
        if attempts == self.attempts_seen {
            return;
        }
        self.attempts_seen = attempts;
        if let Some(tx) = &self.attempts_tx {
            let _ = tx.try_send(*attempt);
        }
    }

    /// Closes the queues, waits for the logging thread to log what it
    /// holds and flush, and says what was logged.
    pub fn finish(mut self) -> RerunSummary {
        self.close()
    }

    fn close(&mut self) -> RerunSummary {
        self.tx = None;
        self.attempts_tx = None;
        let mut summary = match self.thread.take().map(JoinHandle::join) {
            Some(Ok(summary)) => summary,
            _ => RerunSummary::default(),
        };
        summary.rows_dropped = self.counters.rows_dropped.load(Relaxed);
        summary.pictures_dropped = self.counters.pictures_dropped.load(Relaxed);
        summary
    }
}

impl Drop for RerunSink {
    fn drop(&mut self) {
        if self.thread.is_some() {
            self.close();
        }
    }
}

fn fill(
    s: &mut Snapshot,
    index: u64,
    stamp_s: f64,
    pixels: FramePixels<'_>,
    keyframe: &Keyframe,
    alignment: Option<Alignment>,
) -> bool {
    let (gray, depth) = (keyframe.gray(), keyframe.depth_m());
    let points = keyframe.levels.first().map_or(&[][..], |l| &l.points[..]);
    if gray.data().len() != s.keyframe_gray.data().len()
        || depth.data().len() != s.keyframe_depth_m.data().len()
        || points.len() > s.points.capacity()
        || !pixels.copy_into(&mut s.frame)
    {
        return false;
    }
    s.index = index;
    s.stamp_s = stamp_s;
    s.keyframe_gray.data_mut().copy_from_slice(gray.data());
    s.keyframe_depth_m.data_mut().copy_from_slice(depth.data());
    s.points.clear();
    s.points.extend_from_slice(points);
    s.world_from_keyframe = keyframe.world_from_keyframe;
    s.alignment = alignment;
    true
}

/// Entities and their row counts in a `.rrd` file (every chunk's rows,
/// summed per entity path): the check the tests run on a recording.
pub fn read_rrd_counts(path: &Path) -> Result<std::collections::BTreeMap<String, usize>, String> {
    use re_log_encoding::DecoderApp;
    let file = std::fs::File::open(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let mut counts = std::collections::BTreeMap::new();
    for msg in DecoderApp::decode_lazy(std::io::BufReader::new(file)) {
        let msg = msg.map_err(|e| format!("{}: {e}", path.display()))?;
        if let rerun::log::LogMsg::ArrowMsg(_, arrow) = msg {
            let chunk = rerun::log::Chunk::from_arrow_msg(&arrow)
                .map_err(|e| format!("{}: {e}", path.display()))?;
            *counts.entry(chunk.entity_path().to_string()).or_insert(0) += chunk.num_rows();
        }
    }
    Ok(counts)
}
