//! The flight log's recorder thread (`star-record`): takes rows and
//! pictures from the [`super::record::RecordSink`] queue and writes them;
//! the tracker never waits for it, nor wakes it: the thread polls the
//! queue every [`POLL`] when it finds it empty.
//!
//! Rows of a run with a MAVLink link are held back [`MAVLINK_HOLD_NS`]
//! after their capture, so the link has sent (or dropped) their pose before
//! the row looks it up in the link's [`SendLog`]. Every second, and every
//! 4 MB written, it checks the free space of the record folder; below the
//! floor, or on a write error, it stops writing with a warning and only
//! drains the queue (returning the buffers) from then on.

use std::collections::VecDeque;
use std::path::{Path, PathBuf};
use std::sync::atomic::Ordering::Relaxed;
use std::sync::mpsc::{Receiver, SyncSender, TryRecvError};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use crate::clock::monotonic_now_ns;
use crate::geometry::PinholeCamera;
use crate::mavlink_io::SendLog;

use super::files::{free_bytes, RotatingFile};
use super::record::{Message, Shared, Snapshot};
use super::row::{FrameRow, CSV_HEADER};
use super::view::{view_strip, warp_into_keyframe, ViewScratch};

/// How long after its capture a row waits for its pose's MAVLink send.
pub const MAVLINK_HOLD_NS: u64 = 500_000_000;
/// How long the thread sleeps when its queue is empty: at 50 Hz about one
/// frame's row, far below the queue's `record.queue_rows`.
const POLL: Duration = Duration::from_millis(20);
/// Longest time between two free-space checks.
const CHECK_PERIOD: Duration = Duration::from_secs(1);
/// Most bytes written between two free-space checks.
const CHECK_BYTES: u64 = 4_000_000;
/// The trajectory's header line.
const TRAJECTORY_HEADER: &str = "# timestamp tx ty tz qx qy qz qw (world_from_camera)";

/// The two text files of the log.
pub(super) struct Files {
    csv: RotatingFile,
    trajectory: RotatingFile,
}

impl Files {
    /// Creates `frames.csv` and `trajectory.txt` in `dir`.
    pub fn create(dir: &Path, max_bytes: u64) -> Result<Self, (PathBuf, std::io::Error)> {
        let open = |stem, ext, header| {
            RotatingFile::create(dir, stem, ext, header, max_bytes)
                .map_err(|e| (super::files::part_path(dir, stem, ext, 0), e))
        };
        Ok(Self {
            csv: open("frames", "csv", CSV_HEADER)?,
            trajectory: open("trajectory", "txt", TRAJECTORY_HEADER)?,
        })
    }
}

/// What the thread starts with.
pub(super) struct Setup {
    pub dir: PathBuf,
    pub camera: PinholeCamera,
    pub min_free_bytes: u64,
    /// `None`: below the floor at start; record nothing.
    pub files: Option<Files>,
    pub rx: Receiver<Message>,
    pub free: SyncSender<Box<Snapshot>>,
    pub shared: Arc<Shared>,
}

/// What the thread wrote.
#[derive(Debug, Default)]
pub(super) struct WriterReport {
    pub rows: u64,
    pub poses: u64,
    pub images: u64,
    pub views: u64,
    pub rows_after_stop: u64,
    pub csv_parts: u32,
    pub stopped: Option<String>,
}

/// Starts the recorder thread.
pub(super) fn spawn(setup: Setup) -> std::io::Result<JoinHandle<WriterReport>> {
    std::thread::Builder::new()
        .name("star-record".into())
        .spawn(move || Writer::new(setup).run())
}

struct Writer {
    setup: Setup,
    link: Option<Arc<SendLog>>,
    held: VecDeque<FrameRow>,
    line: Vec<u8>,
    scratch: Option<ViewScratch>,
    last_check: Instant,
    bytes_since_check: u64,
    report: WriterReport,
}

impl Writer {
    fn new(setup: Setup) -> Self {
        let stopped = setup.files.is_none();
        Self {
            setup,
            link: None,
            held: VecDeque::with_capacity(1024),
            line: Vec::with_capacity(512),
            scratch: None,
            last_check: Instant::now(),
            bytes_since_check: 0,
            report: WriterReport {
                stopped: stopped.then(|| "free space below record.min_free_mb at start".into()),
                csv_parts: u32::from(!stopped),
                ..WriterReport::default()
            },
        }
    }

    fn run(mut self) -> WriterReport {
        loop {
            // Polled, never blocked on: a receiver parked in `recv` would
            // make every `try_send` of the tracker a futex wake-up (and on
            // a busy machine a context switch, measured at ~20 us median).
            let message = match self.setup.rx.try_recv() {
                Ok(message) => message,
                Err(TryRecvError::Empty) => {
                    self.housekeeping();
                    std::thread::sleep(POLL);
                    continue;
                }
                Err(TryRecvError::Disconnected) => break,
            };
            match message {
                Message::Row(row) => {
                    if self.link.is_some() {
                        self.held.push_back(row);
                    } else {
                        self.write_row(&row);
                    }
                }
                Message::Image(snapshot) => {
                    self.write_image(&snapshot);
                    // The pool's channel holds every buffer: never full.
                    let _ = self.setup.free.try_send(snapshot);
                }
                Message::Link(log) => self.link = Some(log),
            }
            self.housekeeping();
        }
        self.release_held(true);
        if let Some(files) = &mut self.setup.files {
            let flushed = files.csv.flush().and_then(|()| files.trajectory.flush());
            if let Err(e) = flushed {
                tracing::warn!(error = %e, "flight log: cannot flush");
            }
            self.report.csv_parts = files.csv.parts();
        }
        self.report
    }

    /// The held rows that are due, and the periodic free-space check.
    fn housekeeping(&mut self) {
        self.release_held(false);
        if self.last_check.elapsed() >= CHECK_PERIOD {
            self.check_space();
        }
    }

    /// Writes the held rows whose MAVLink send had time to happen (all of
    /// them when `all`).
    fn release_held(&mut self, all: bool) {
        let now_ns = monotonic_now_ns();
        while let Some(row) = self.held.front() {
            if !all && now_ns.saturating_sub(row.capture_ns) < MAVLINK_HOLD_NS {
                break;
            }
            if let Some(row) = self.held.pop_front() {
                self.write_row(&row);
            }
        }
    }

    fn write_row(&mut self, row: &FrameRow) {
        let Some(files) = &mut self.setup.files else {
            self.report.rows_after_stop += 1;
            return;
        };
        let mavlink = self
            .link
            .as_ref()
            .map(|log| match log.find(row.capture_ns) {
                Some(sent) => (Some(sent.send_ns), sent.timesync_offset_ns),
                None => (None, log.offset_ns()),
            });
        self.line.clear();
        let mut result = row
            .write_csv(&mut self.line, mavlink)
            .and_then(|()| files.csv.write_line(&self.line));
        if let (Ok(bytes), Some(pose)) = (&result, row.world_from_camera) {
            let t = pose.translation.vector;
            let q = pose.rotation.coords; // [x, y, z, w]
            self.line.clear();
            let written = std::io::Write::write_fmt(
                &mut self.line,
                format_args!(
                    "{} {} {} {} {} {} {} {}\n",
                    row.stamp_s, t.x, t.y, t.z, q[0], q[1], q[2], q[3]
                ),
            );
            let bytes = *bytes;
            result = written
                .and_then(|()| files.trajectory.write_line(&self.line))
                .map(|b| b + bytes);
            if result.is_ok() {
                self.report.poses += 1;
            }
        }
        match result {
            Ok(bytes) => {
                self.report.rows += 1;
                self.wrote(bytes);
            }
            Err(e) => {
                let why = format!("cannot write {}: {e}", files.csv.path().display());
                self.stop(why);
            }
        }
    }

    fn write_image(&mut self, snapshot: &Snapshot) {
        if self.setup.files.is_none() {
            return;
        }
        let dir = self.setup.dir.clone();
        let path = dir
            .join("frames")
            .join(format!("{:06}.png", snapshot.index));
        if let Err(e) = crate::dataset::write_gray8(&path, &snapshot.frame) {
            self.stop(format!("cannot write a frame picture: {e}"));
            return;
        }
        self.report.images += 1;
        self.wrote(file_len(&path));
        let Some(alignment) = snapshot.alignment else {
            return;
        };
        let (w, h) = (snapshot.frame.width(), snapshot.frame.height());
        let scratch = self.scratch.get_or_insert_with(|| ViewScratch::new(w, h));
        warp_into_keyframe(
            &snapshot.frame,
            &snapshot.keyframe_gray,
            &snapshot.keyframe_depth_m,
            &self.setup.camera,
            &alignment,
            scratch,
        );
        view_strip(&snapshot.frame, &snapshot.keyframe_gray, scratch);
        let path = dir.join("views").join(format!("{:06}.png", snapshot.index));
        if let Err(e) = crate::dataset::write_gray8(&path, &scratch.strip) {
            self.stop(format!("cannot write a view picture: {e}"));
            return;
        }
        tracing::debug!(
            frame = snapshot.index,
            residual_rms = scratch.residual_rms,
            pixels = scratch.residual_pixels,
            "flight log: view written"
        );
        self.report.views += 1;
        self.wrote(file_len(&path));
    }

    fn wrote(&mut self, bytes: u64) {
        self.bytes_since_check += bytes;
        if self.bytes_since_check >= CHECK_BYTES {
            self.check_space();
        }
    }

    /// Stops writing when the free space is below the floor.
    fn check_space(&mut self) {
        self.last_check = Instant::now();
        self.bytes_since_check = 0;
        if self.setup.files.is_none() {
            return;
        }
        match free_bytes(&self.setup.dir) {
            Ok(free) if free < self.setup.min_free_bytes => self.stop(format!(
                "free space {:.1} MB below record.min_free_mb ({:.1} MB)",
                free as f64 / 1e6,
                self.setup.min_free_bytes as f64 / 1e6
            )),
            Ok(_) => {}
            Err(e) => self.stop(format!(
                "cannot read the free space of {}: {e}",
                self.setup.dir.display()
            )),
        }
    }

    /// Stops recording: flushes and closes the files; tracking goes on.
    fn stop(&mut self, why: String) {
        let Some(mut files) = self.setup.files.take() else {
            return;
        };
        let _ = files.csv.flush();
        let _ = files.trajectory.flush();
        self.report.csv_parts = files.csv.parts();
        self.setup.shared.stopped.store(true, Relaxed);
        tracing::warn!(dir = %self.setup.dir.display(), reason = %why, "flight log: recording stopped (tracking goes on)");
        self.report.stopped = Some(why);
    }
}

fn file_len(path: &Path) -> u64 {
    std::fs::metadata(path).map_or(0, |m| m.len())
}
