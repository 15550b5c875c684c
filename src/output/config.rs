//! The `[record]` section: how `--record DIR` writes the flight log.

use serde::{Deserialize, Serialize};

use crate::settings::{first_failure, SettingError};

/// Flight-log settings (`[record]`); the log itself is switched on by
/// `--record DIR` on `star track`, `star run` and `star localize`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RecordConfig {
    /// Write every Nth camera frame as a PNG (0: none); `--record-every`
    /// overrides it.
    pub every_n_frames: u32,
    /// With each frame PNG, also write the view strip: the camera frame, the
    /// keyframe render, the frame warped into the keyframe, and their
    /// photometric residual (`views/`); `--record-views` turns it on.
    pub views: bool,
    /// Start a new part of a file (`frames.1.csv`, `trajectory.1.txt`)
    /// once it is this large, MB.
    pub max_file_mb: f64,
    /// Stop recording (with a warning; tracking goes on) when the free
    /// space of the record folder's file system falls below this, MB.
    pub min_free_mb: f64,
    /// Rows the tracker may queue for the recorder thread before further
    /// rows are dropped (and counted).
    pub queue_rows: u32,
    /// Frame buffers circulating between the tracker and the recorder
    /// thread; a frame due for a PNG when none is free is skipped (and
    /// counted).
    pub image_buffers: u32,
}

impl Default for RecordConfig {
    fn default() -> Self {
        Self {
            every_n_frames: 30,
            views: false,
            max_file_mb: 64.0,
            min_free_mb: 512.0,
            queue_rows: 512,
            image_buffers: 4,
        }
    }
}

impl RecordConfig {
    /// Checks the ranges.
    pub fn validate(&self) -> Result<(), SettingError> {
        first_failure([
            (
                "max_file_mb",
                self.max_file_mb.is_finite() && self.max_file_mb >= 0.01,
                format!("expected at least 0.01 MB, found {}", self.max_file_mb),
            ),
            (
                "min_free_mb",
                self.min_free_mb.is_finite() && self.min_free_mb >= 0.0,
                format!(
                    "expected a finite value >= 0 MB, found {}",
                    self.min_free_mb
                ),
            ),
            (
                "queue_rows",
                (8..=65_536).contains(&self.queue_rows),
                format!("expected 8..=65536, found {}", self.queue_rows),
            ),
            (
                "image_buffers",
                (1..=64).contains(&self.image_buffers),
                format!("expected 1..=64, found {}", self.image_buffers),
            ),
        ])
    }

    /// [`RecordConfig::max_file_mb`] in bytes.
    pub fn max_file_bytes(&self) -> u64 {
        (self.max_file_mb * 1e6) as u64
    }

    /// [`RecordConfig::min_free_mb`] in bytes (saturating).
    pub fn min_free_bytes(&self) -> u64 {
        (self.min_free_mb * 1e6).min(u64::MAX as f64) as u64
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_valid_and_bad_values_named() {
        RecordConfig::default().validate().expect("defaults");
        let bad = RecordConfig {
            max_file_mb: f64::NAN,
            ..RecordConfig::default()
        };
        assert_eq!(bad.validate().expect_err("NaN").key, "max_file_mb");
        let bad = RecordConfig {
            min_free_mb: -1.0,
            ..RecordConfig::default()
        };
        assert_eq!(bad.validate().expect_err("negative").key, "min_free_mb");
        let huge = RecordConfig {
            min_free_mb: 1e12,
            ..RecordConfig::default()
        };
        huge.validate().expect("a huge floor is valid");
        assert_eq!(huge.min_free_bytes(), 1_000_000_000_000_000_000);
    }
}
