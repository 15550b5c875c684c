//! The camera process's loop: open a source, publish its frames, and on
//! errors skip the frame or reconnect with exponential backoff.
//!
//! Takes in a way to open the source, a [`FramePublisher`] and a stop
//! predicate; gives out a [`RunSummary`] of what was published. Every state
//! change (opened, disconnected, reconnecting, gave up) is logged at info or
//! warn; per-frame events at debug.

use std::time::{Duration, Instant};

use tracing::{debug, info, warn};

use super::{CameraError, ErrorAction, FrameSource};
use crate::ipc::{FramePublisher, IpcError, PublishError, PublisherStats};

/// Backoff and limits of the loop.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RunnerSettings {
    /// First wait before reopening a failed camera.
    pub initial_backoff: Duration,
    /// Longest wait between reopen attempts.
    pub max_backoff: Duration,
    /// Stop after this many published frames (tests, HIL runs).
    pub max_frames: Option<u64>,
    /// How often the counters are logged.
    pub stats_interval: Duration,
}

impl Default for RunnerSettings {
    fn default() -> Self {
        Self {
            initial_backoff: Duration::from_millis(100),
            max_backoff: Duration::from_secs(5),
            max_frames: None,
            stats_interval: Duration::from_secs(10),
        }
    }
}

/// Why the loop stopped with an error.
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    /// The source failed in a way a reconnect cannot fix.
    #[error(transparent)]
    Camera(#[from] CameraError),
    /// The transport failed.
    #[error(transparent)]
    Ipc(#[from] IpcError),
}

/// What the loop did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RunSummary {
    /// Publisher counters.
    pub stats: PublisherStats,
    /// Times the source was (re)opened successfully.
    pub opens: u64,
    /// Frames skipped because the source reported a bad frame.
    pub skipped: u64,
    /// The source ran out of frames (replay without loop).
    pub ended: bool,
}

/// Sleeps `total` in short steps, returning early when `stop()` says so.
fn sleep_unless_stopped(total: Duration, stop: &dyn Fn() -> bool) {
    let step = Duration::from_millis(20);
    let start = Instant::now();
    while start.elapsed() < total && !stop() {
        std::thread::sleep(step.min(total.saturating_sub(start.elapsed())));
    }
}

/// Runs until `stop()` is true, the source ends, `max_frames` is reached,
/// or a fatal error occurs. `open` is called again after every disconnect.
/// Once `stop()` has returned true the loop stops, even if later calls would
/// return false (signal checks consume the signal).
pub fn run_camera(
    mut open: impl FnMut() -> Result<Box<dyn FrameSource>, CameraError>,
    publisher: &mut FramePublisher,
    stop: &dyn Fn() -> bool,
    settings: &RunnerSettings,
) -> Result<RunSummary, RunError> {
    let stopped = std::cell::Cell::new(false);
    let stop = &|| {
        if !stopped.get() && stop() {
            stopped.set(true);
        }
        stopped.get()
    };
    let mut summary = RunSummary {
        stats: publisher.stats(),
        opens: 0,
        skipped: 0,
        ended: false,
    };
    let mut backoff = settings.initial_backoff;
    let mut last_log = Instant::now();
    'reopen: while !stop() {
        let mut source = match open() {
            Ok(source) => {
                summary.opens += 1;
                info!(camera = %source.describe(), opens = summary.opens, "camera opened");
                backoff = settings.initial_backoff;
                source
            }
            Err(e) if e.action() == ErrorAction::Fatal => return Err(e.into()),
            Err(e) => {
                warn!(error = %e, retry_in_ms = backoff.as_millis() as u64, "camera unavailable, retrying");
                sleep_unless_stopped(backoff, stop);
                backoff = (backoff * 2).min(settings.max_backoff);
                continue 'reopen;
            }
        };
        while !stop() {
            match publisher.publish_with(|slot| source.next_frame(slot)) {
                Ok(sequence) => {
                    debug!(sequence, "frame published");
                    if settings
                        .max_frames
                        .is_some_and(|n| publisher.stats().published >= n)
                    {
                        break 'reopen;
                    }
                }
                Err(PublishError::Source(e)) => match e.action() {
                    ErrorAction::Skip => {
                        summary.skipped += 1;
                        warn!(error = %e, skipped = summary.skipped, "camera frame skipped");
                    }
                    ErrorAction::Reconnect => {
                        warn!(error = %e, retry_in_ms = backoff.as_millis() as u64, "camera lost, reconnecting");
                        drop(source);
                        sleep_unless_stopped(backoff, stop);
                        backoff = (backoff * 2).min(settings.max_backoff);
                        continue 'reopen;
                    }
                    ErrorAction::End => {
                        info!("camera source ended");
                        summary.ended = true;
                        break 'reopen;
                    }
                    ErrorAction::Fatal => return Err(e.into()),
                },
                Err(PublishError::Rejected(e)) => {
                    warn!(error = %e, rejected = publisher.stats().rejected, "frame rejected before publishing");
                }
                Err(PublishError::Ipc(e)) => return Err(e.into()),
            }
            if last_log.elapsed() >= settings.stats_interval {
                let s = publisher.stats();
                info!(
                    published = s.published,
                    rejected = s.rejected,
                    source_errors = s.source_errors,
                    "camera stats"
                );
                last_log = Instant::now();
            }
        }
    }
    summary.stats = publisher.stats();
    Ok(summary)
}
