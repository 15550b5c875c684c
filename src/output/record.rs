//! The flight log (`--record DIR`), the tracker's side: [`RecordSink`].
//!
//! Takes, per frame, a [`FrameRow`] (a small `Copy` value) and, every Nth
//! frame, the camera frame (and with `views` the keyframe render) copied
//! into a preallocated buffer; hands them to the recorder thread
//! (`record_writer.rs`) through a bounded queue and never waits for it. A
//! full queue drops the row, no free buffer skips the picture; both are
//! counted. Buffers come back from the recorder thread through a return
//! channel, so [`RecordSink::frame`] allocates nothing.
//!
//! Gives out, in DIR: `trajectory.txt` (TUM), `frames.csv` (one row per
//! frame processed, [`super::row`]), `frames/NNNNNN.png` every Nth frame,
//! and with `views` `views/NNNNNN.png` (camera frame, keyframe render, frame
//! warped into the keyframe, residual). Files past `record.max_file_mb` go
//! on in a new part; below `record.min_free_mb` of free space the recorder
//! stops writing, with a warning, and tracking goes on.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering::Relaxed};
use std::sync::mpsc::{sync_channel, Receiver, SyncSender, TrySendError};
use std::sync::Arc;
use std::thread::JoinHandle;

use crate::geometry::PinholeCamera;
use crate::imgproc::{ImageF32, ImageU8};
use crate::mavlink_io::SendLog;
use crate::track::Keyframe;

use super::config::RecordConfig;
use super::files::free_bytes;
use super::record_writer::{self, WriterReport};
use super::row::FrameRow;
use super::view::Alignment;

/// Errors starting the flight log.
#[derive(Debug, thiserror::Error)]
pub enum RecordError {
    /// The record folder (or a folder inside it) could not be created.
    #[error("cannot create the record folder {path}: {source}")]
    CreateDir {
        /// The folder.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// A log file could not be created.
    #[error("cannot create {path}: {source}")]
    CreateFile {
        /// The file.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// The free space of the record folder could not be read.
    #[error("cannot read the free space of {path}: {source}")]
    FreeSpace {
        /// The folder.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// The recorder thread could not be started.
    #[error("cannot start the recorder thread: {0}")]
    Thread(#[source] std::io::Error),
}

/// Counters shared by the sink and the recorder thread.
#[derive(Debug, Default)]
pub(super) struct Shared {
    /// Set by the recorder thread when it stopped writing (free space,
    /// a write error): the sink then sends nothing more.
    pub stopped: AtomicBool,
    pub rows_dropped: AtomicU64,
    pub images_dropped: AtomicU64,
}

/// One picture handed to the recorder thread: a buffer of the pool.
#[derive(Debug)]
pub(super) struct Snapshot {
    /// Row number of the frame in `frames.csv` (0-based).
    pub index: u64,
    /// The trajectory's stamp of the frame, s.
    pub stamp_s: f64,
    /// The camera frame.
    pub frame: ImageU8,
    /// The keyframe render (gray), with `views` (else empty).
    pub keyframe_gray: ImageF32,
    /// The keyframe render's depth, m, with `views` (else empty).
    pub keyframe_depth_m: ImageF32,
    /// The alignment of the frame against that keyframe; `None` without
    /// `views` or when the frame gave no pose.
    pub alignment: Option<Alignment>,
}

/// Messages to the recorder thread.
pub(super) enum Message {
    Row(FrameRow),
    Image(Box<Snapshot>),
    Link(Arc<SendLog>),
}

/// The camera frame of one call to [`RecordSink::frame`], read in place.
#[derive(Debug, Clone, Copy)]
pub struct FramePixels<'a> {
    /// 8-bit gray pixels, rows `stride` bytes apart.
    pub pixels: &'a [u8],
    /// Width, pixels.
    pub width: usize,
    /// Height, pixels.
    pub height: usize,
    /// Row stride, bytes.
    pub stride: usize,
}

impl FramePixels<'_> {
    /// Copies the pixels into `into`; false (nothing copied) when the sizes
    /// differ or the slice is too short for its stride.
    pub(super) fn copy_into(&self, into: &mut ImageU8) -> bool {
        let (w, h) = (self.width, self.height);
        if into.width() != w
            || into.height() != h
            || self.stride < w
            || h == 0
            || self.pixels.len() < self.stride * (h - 1) + w
        {
            return false;
        }
        for y in 0..h {
            let src = &self.pixels[y * self.stride..y * self.stride + w];
            into.row_mut(y).copy_from_slice(src);
        }
        true
    }
}

/// The keyframe a frame was tracked against, for the view strip.
#[derive(Clone, Copy)]
pub struct KeyframeView<'a> {
    /// The keyframe.
    pub keyframe: &'a Keyframe,
    /// Where the aligner put the frame relative to it (`None`: no pose).
    pub alignment: Option<Alignment>,
}

/// What the flight log did, for the summary.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RecordSummary {
    /// The record folder.
    pub dir: PathBuf,
    /// Rows written to `frames.csv` (all parts).
    pub rows_written: u64,
    /// Poses written to `trajectory.txt` (all parts).
    pub poses_written: u64,
    /// Frame PNGs written.
    pub images_written: u64,
    /// View strips written.
    pub views_written: u64,
    /// Rows dropped because the queue was full.
    pub rows_dropped: u64,
    /// Pictures skipped: no free buffer, or the queue was full.
    pub images_dropped: u64,
    /// Rows not recorded because recording had stopped.
    pub rows_after_stop: u64,
    /// Parts of `frames.csv` written.
    pub csv_parts: u32,
    /// Why recording stopped early, if it did.
    pub stopped: Option<String>,
}

/// The tracker's end of the flight log.
pub struct RecordSink {
    tx: Option<SyncSender<Message>>,
    free: Receiver<Box<Snapshot>>,
    /// A buffer taken from the pool that could not be queued.
    spare: Option<Box<Snapshot>>,
    every_n: u64,
    views: bool,
    frames: u64,
    rows_after_stop: u64,
    shared: Arc<Shared>,
    thread: Option<JoinHandle<WriterReport>>,
    dir: PathBuf,
    /// Wait for the recorder instead of dropping ([`Self::wait_for_writer`]).
    wait: bool,
}

impl RecordSink {
    /// Creates `dir` (and `frames/`, `views/` as needed), checks its free
    /// space, creates the files and starts the recorder thread, for frames
    /// of `camera`'s size. Below the free-space floor already, it warns
    /// and records nothing (the run goes on).
    pub fn start(
        dir: &Path,
        config: &RecordConfig,
        camera: &PinholeCamera,
    ) -> Result<Self, RecordError> {
        let create_dir = |path: PathBuf| {
            std::fs::create_dir_all(&path).map_err(|source| RecordError::CreateDir { path, source })
        };
        create_dir(dir.to_owned())?;
        let every_n = u64::from(config.every_n_frames);
        let views = config.views && every_n > 0;
        if every_n > 0 {
            create_dir(dir.join("frames"))?;
        }
        if views {
            create_dir(dir.join("views"))?;
        }
        let free = free_bytes(dir).map_err(|source| RecordError::FreeSpace {
            path: dir.to_owned(),
            source,
        })?;
        let shared = Arc::new(Shared::default());
        let floor = config.min_free_bytes();
        let files = if free < floor {
            tracing::warn!(
                dir = %dir.display(),
                free_mb = free as f64 / 1e6,
                min_free_mb = config.min_free_mb,
                "flight log: free space already below record.min_free_mb; nothing is recorded (tracking goes on)"
            );
            shared.stopped.store(true, Relaxed);
            None
        } else {
            Some(
                record_writer::Files::create(dir, config.max_file_bytes())
                    .map_err(|(path, source)| RecordError::CreateFile { path, source })?,
            )
        };
        let (w, h) = (camera.width as usize, camera.height as usize);
        let buffers = config.image_buffers as usize;
        let (free_tx, free_rx) = sync_channel(buffers);
        if every_n > 0 {
            for _ in 0..buffers {
                let (kw, kh) = if views { (w, h) } else { (0, 0) };
                let mut snapshot = Box::new(Snapshot {
                    index: 0,
                    stamp_s: 0.0,
                    frame: ImageU8::new(w, h, 0),
                    keyframe_gray: ImageF32::new(kw, kh, 0.0),
                    keyframe_depth_m: ImageF32::new(kw, kh, 0.0),
                    alignment: None,
                });
                // Zeroed allocations are mapped lazily: touch every page
                // now, not on the tracker's first copy into them.
                snapshot.frame.fill(1);
                snapshot.keyframe_gray.fill(1.0);
                snapshot.keyframe_depth_m.fill(1.0);
                // The channel holds every buffer: this never fails.
                let _ = free_tx.try_send(snapshot);
            }
        }
        let (tx, rx) = sync_channel(config.queue_rows as usize);
        let thread = record_writer::spawn(record_writer::Setup {
            dir: dir.to_owned(),
            camera: *camera,
            min_free_bytes: floor,
            files,
            rx,
            free: free_tx,
            shared: shared.clone(),
        })
        .map_err(RecordError::Thread)?;
        tracing::info!(dir = %dir.display(), every_n, views, "flight log recording");
        Ok(Self {
            tx: Some(tx),
            free: free_rx,
            spare: None,
            every_n,
            views,
            frames: 0,
            rows_after_stop: 0,
            shared,
            thread: Some(thread),
            dir: dir.to_owned(),
            wait: false,
        })
    }

    /// Makes [`Self::frame`] wait for the recorder (for a free picture
    /// buffer, for room in the queue) instead of dropping: for a replay
    /// that is not paced in real time (`star localize` without
    /// `--realtime`), where the tracker outruns the PNG encoder and nothing
    /// is gained by losing pictures. The tracker's loop never sets it.
    pub fn wait_for_writer(&mut self) {
        self.wait = true;
    }

    /// Hands the MAVLink link's send log to the recorder, which then fills
    /// the send-time and TIMESYNC columns (a short while after each frame,
    /// once the link had time to send its pose).
    pub fn attach_mavlink(&mut self, log: Arc<SendLog>) {
        if let Some(tx) = &self.tx {
            let _ = tx.try_send(Message::Link(log));
        }
    }

    /// Records one processed frame: its row, and every Nth frame its
    /// picture. Allocates nothing, and never waits unless
    /// [`Self::wait_for_writer`] was called.
    pub fn frame(
        &mut self,
        row: &FrameRow,
        pixels: FramePixels<'_>,
        keyframe: Option<KeyframeView<'_>>,
    ) {
        let index = self.frames;
        self.frames += 1;
        if self.shared.stopped.load(Relaxed) {
            self.rows_after_stop += 1;
            return;
        }
        let Some(tx) = &self.tx else {
            return;
        };
        let sent = if self.wait {
            tx.send(Message::Row(*row))
                .map_err(|e| TrySendError::Disconnected(e.0))
        } else {
            tx.try_send(Message::Row(*row))
        };
        if let Err(e) = sent {
            match e {
                TrySendError::Full(_) => {
                    self.shared.rows_dropped.fetch_add(1, Relaxed);
                }
                TrySendError::Disconnected(_) => self.shared.stopped.store(true, Relaxed),
            }
        }
        if self.every_n == 0 || index % self.every_n != 0 {
            return;
        }
        let free = if self.wait {
            self.spare.take().or_else(|| self.free.recv().ok())
        } else {
            self.spare.take().or_else(|| self.free.try_recv().ok())
        };
        let Some(mut snapshot) = free else {
            self.shared.images_dropped.fetch_add(1, Relaxed);
            return;
        };
        if !fill(
            &mut snapshot,
            index,
            row.stamp_s,
            pixels,
            keyframe.filter(|_| self.views),
        ) {
            self.shared.images_dropped.fetch_add(1, Relaxed);
            self.spare = Some(snapshot);
            return;
        }
        let sent = if self.wait {
            tx.send(Message::Image(snapshot))
                .map_err(|e| TrySendError::Disconnected(e.0))
        } else {
            tx.try_send(Message::Image(snapshot))
        };
        match sent {
            Ok(()) => {}
            Err(TrySendError::Full(Message::Image(snapshot)))
            | Err(TrySendError::Disconnected(Message::Image(snapshot))) => {
                self.shared.images_dropped.fetch_add(1, Relaxed);
                self.spare = Some(snapshot);
            }
            Err(_) => {}
        }
    }

    /// Whether recording stopped early (free space, a write error).
    pub fn stopped(&self) -> bool {
        self.shared.stopped.load(Relaxed)
    }

    /// The record folder.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Closes the queue, waits for the recorder thread to write what it
    /// holds, and says what was recorded.
    pub fn finish(mut self) -> RecordSummary {
        self.close()
    }

    fn close(&mut self) -> RecordSummary {
        self.tx = None;
        let report = match self.thread.take().map(JoinHandle::join) {
            Some(Ok(report)) => report,
            Some(Err(_)) => WriterReport {
                stopped: Some("the recorder thread panicked".into()),
                ..WriterReport::default()
            },
            None => WriterReport::default(),
        };
        RecordSummary {
            dir: self.dir.clone(),
            rows_written: report.rows,
            poses_written: report.poses,
            images_written: report.images,
            views_written: report.views,
            rows_dropped: self.shared.rows_dropped.load(Relaxed),
            images_dropped: self.shared.images_dropped.load(Relaxed),
            rows_after_stop: self.rows_after_stop + report.rows_after_stop,
            csv_parts: report.csv_parts,
            stopped: report.stopped,
        }
    }
}

impl Drop for RecordSink {
    fn drop(&mut self) {
        if self.thread.is_some() {
            self.close();
        }
    }
}

/// Copies the frame (and the keyframe) into the snapshot; false when the
/// sizes do not fit its buffers.
fn fill(
    snapshot: &mut Snapshot,
    index: u64,
    stamp_s: f64,
    pixels: FramePixels<'_>,
    keyframe: Option<KeyframeView<'_>>,
) -> bool {
    if !pixels.copy_into(&mut snapshot.frame) {
        return false;
    }
    snapshot.index = index;
    snapshot.stamp_s = stamp_s;
    snapshot.alignment = None;
    if let Some(view) = keyframe {
        let (gray, depth) = (view.keyframe.gray(), view.keyframe.depth_m());
        let fits = |image: &ImageF32, into: &ImageF32| {
            image.width() == into.width() && image.height() == into.height()
        };
        if fits(gray, &snapshot.keyframe_gray) && fits(depth, &snapshot.keyframe_depth_m) {
            snapshot
                .keyframe_gray
                .data_mut()
                .copy_from_slice(gray.data());
            snapshot
                .keyframe_depth_m
                .data_mut()
                .copy_from_slice(depth.data());
            snapshot.alignment = view.alignment;
        }
    }
    true
}
