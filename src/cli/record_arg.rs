//! `--record DIR` and its companions: the flight-log options shared by
//! `star track`, `star run` and `star localize`, and the summary line.

use std::path::PathBuf;

use anyhow::{Context, Result};

use crate::config::Config;
use crate::geometry::PinholeCamera;
use crate::output::{RecordSink, RecordSummary};

/// The flight-log options.
#[derive(Debug, Clone, Default, clap::Args)]
pub struct RecordArgs {
    /// Write a flight log into DIR (created if missing): trajectory.txt
    /// (TUM), frames.csv (one row per frame processed: state, inlier
    /// ratio, correlation, iterations, tracking time, keyframe age, pose
    /// sent, MAVLink send time and TIMESYNC offset) and every Nth camera
    /// frame as a PNG; `[record]` in the config sets sizes and the
    /// free-space floor.
    #[arg(long, value_name = "DIR")]
    pub record: Option<PathBuf>,
    /// With --record: write every Nth camera frame as a PNG (0: none);
    /// overrides `record.every_n_frames`.
    #[arg(long, value_name = "N", requires = "record")]
    pub record_every: Option<u32>,
    /// With --record: with each frame PNG also write the view strip (camera
    /// frame, keyframe render, frame warped into the keyframe, photometric
    /// residual) into DIR/views; sets `record.views`.
    #[arg(long, requires = "record")]
    pub record_views: bool,
}

impl RecordArgs {
    /// Starts the flight log for frames of `camera`'s size, when asked;
    /// a folder that cannot be created fails here, before the run.
    pub fn start(&self, config: &Config, camera: &PinholeCamera) -> Result<Option<RecordSink>> {
        let Some(dir) = &self.record else {
            return Ok(None);
        };
        let mut settings = config.record.clone();
        if let Some(n) = self.record_every {
            settings.every_n_frames = n;
        }
        settings.views |= self.record_views;
        RecordSink::start(dir, &settings, camera)
            .with_context(|| format!("--record {}", dir.display()))
            .map(Some)
    }
}

/// Prints what the flight log recorded.
pub fn print_record_summary(who: &str, s: &RecordSummary) {
    println!(
        "{who}: flight log {}: rows {}  poses {}  frame PNGs {}  view PNGs {}  dropped rows {}  skipped PNGs {}  csv parts {}",
        s.dir.display(),
        s.rows_written,
        s.poses_written,
        s.images_written,
        s.views_written,
        s.rows_dropped,
        s.images_dropped,
        s.csv_parts
    );
    if let Some(why) = &s.stopped {
        println!(
            "{who}: flight log stopped early ({why}); {} rows not recorded",
            s.rows_after_stop
        );
    }
}
