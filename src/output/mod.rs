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
//! strip ([`view`]); the trajectory plot ([`plot`]); the floor plan of a
//! map with its relocalization database ([`plan`]); with the cargo
//! feature `rerun`, the live view in Rerun (`rerun_log`, `--rerun`). Takes the localizer's
//! per-frame output and keyframe, the MAVLink link's send log and TUM
//! trajectories; gives out files.

pub mod config;
pub mod files;
pub mod frames_log;
pub mod plan;
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

use crate::localizer::{FrameOutput, Localizer};

/// The flight log and the live view of a running loop, borrowed for one
/// frame (either may be off).
pub struct FrameSinks<'a> {
    /// The flight log (`--record`).
    pub record: Option<&'a mut RecordSink>,
    /// The live view (`--rerun`).
    #[cfg(feature = "rerun")]
    pub rerun: Option<&'a mut rerun_log::RerunSink>,
}

impl FrameSinks<'_> {
    /// Hands one processed frame to each sink that is on: its row, its
    /// pixels and the keyframe it was aligned against (and to the live view,
    /// the last relocalization attempt). Copies into preallocated buffers
    /// and never waits.
    pub fn hand(
        self,
        localizer: &Localizer,
        out: &FrameOutput,
        stamp_s: f64,
        track_ms: f64,
        pixels: FramePixels<'_>,
    ) {
        let keyframe = localizer.keyframe();
        let alignment = view::Alignment::of(out, keyframe);
        let row = FrameRow::new(out, stamp_s, track_ms);
        if let Some(record) = self.record {
            record.frame(
                &row,
                pixels,
                Some(KeyframeView {
                    keyframe,
                    alignment,
                }),
            );
        }
        #[cfg(feature = "rerun")]
        if let Some(rerun) = self.rerun {
            rerun.frame(&row, pixels, keyframe, alignment);
            let attempts = localizer.stats().reloc_attempts;
            rerun.reloc_attempt(attempts, localizer.last_reloc_attempt());
        }
    }
}
pub use frames_log::{read_frames_log, FrameLogSummary, LogEvent};
pub use record::{FramePixels, KeyframeView, RecordError, RecordSink, RecordSummary};
pub use row::{FrameRow, LoggedFrame, RowState};
