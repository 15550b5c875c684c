//! Seeing what the tracker sees: the flight log (`--record DIR`), the
//! pictures of the keyframe against the camera frame, and the plots of
//! `star eval --plot`.
//!
//! Owns the `[record]` section ([`RecordConfig`]); the tracker's end of the
//! flight log ([`RecordSink`], fed per frame with a `Copy` [`FrameRow`] and
//! every Nth frame a picture, without allocating or waiting) and its
//! recorder thread, which writes `trajectory.txt`, `frames.csv` and PNGs,
//! rotates files by size and stops at a free-space floor; reading the log
//! back ([`read_frames_log`], [`FrameLogSummary`]); the residual and view
//! strip ([`view`]); the trajectory plot ([`plot`]); with the cargo
//! feature `rerun`, the live view in Rerun (`rerun_log`, `--rerun`). Takes the localizer's
//! per-frame output and keyframe, the MAVLink link's send log and TUM
//! trajectories; gives out files.

pub mod config;
pub mod files;
pub mod frames_log;
pub mod plot;
pub mod record;
mod record_writer;
#[cfg(feature = "rerun")]
pub mod rerun_log;
#[cfg(feature = "rerun")]
mod rerun_logger;
pub mod rerun_target;
pub mod row;
pub mod view;

pub use config::RecordConfig;
pub use frames_log::{read_frames_log, FrameLogSummary, LogEvent};
pub use record::{FramePixels, KeyframeView, RecordError, RecordSink, RecordSummary};
pub use row::{FrameRow, LoggedFrame, RowState};
