//! `[camera]`: the source, its calibration and the capture settings, and
//! their validation.

use serde::{Deserialize, Serialize};

use crate::geometry::PinholeCamera;
use crate::settings::{first_failure, SettingError};

/// `[camera]`
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CameraConfig {
    /// Source URI: `v4l2:/dev/videoN`, `aravis:ID`, `replay:DATASET`,
    /// `pattern:WxH`, `sim:LINK[?scene=DIR&origin=LAT,LON,ALT]`.
    pub source: String,
    /// Requested frame rate, Hz.
    pub fps: f64,
    /// Calibration of the camera (distortion included). Its width and height
    /// are also the capture size requested from the camera.
    pub intrinsics: PinholeCamera,
    /// Fixed exposure, microseconds; absent leaves auto exposure on.
    pub exposure_us: Option<f64>,
    /// Fixed analog gain, dB; absent leaves auto gain on.
    pub gain_db: Option<f64>,
    /// Driver buffers: V4L2 mmap buffers or the Aravis buffer pool (2..=32).
    pub buffers: u32,
    /// A camera that delivers no frame for this long is reconnected, ms.
    pub frame_timeout_ms: u64,
    /// Replay speed factor; 1 plays at the recorded rate.
    pub replay_speed: f64,
    /// Replay starts over at the end of the dataset.
    pub replay_loop: bool,
}

impl Default for CameraConfig {
    fn default() -> Self {
        Self {
            source: "v4l2:/dev/video0".into(),
            fps: 50.0,
            intrinsics: PinholeCamera::new(640, 512, 420.0, 420.0, 319.5, 255.5),
            exposure_us: None,
            gain_db: None,
            buffers: 4,
            frame_timeout_ms: 2000,
            replay_speed: 1.0,
            replay_loop: false,
        }
    }
}

impl CameraConfig {
    /// The settings camera sources take.
    pub fn source_settings(&self) -> super::SourceSettings {
        super::SourceSettings {
            width: self.intrinsics.width,
            height: self.intrinsics.height,
            fps: self.fps,
            buffers: self.buffers,
            exposure_us: self.exposure_us,
            gain_db: self.gain_db,
            replay_speed: self.replay_speed,
            replay_loop: self.replay_loop,
            frame_timeout_ms: self.frame_timeout_ms,
        }
    }
}

/// Slowest replay: one recorded second takes 100 s.
pub const MIN_REPLAY_SPEED: f64 = 0.01;
/// Fastest replay.
pub const MAX_REPLAY_SPEED: f64 = 100.0;

/// True for a replay speed factor within [`MIN_REPLAY_SPEED`]..=[`MAX_REPLAY_SPEED`]
/// (NaN is not).
pub fn replay_speed_is_sane(speed: f64) -> bool {
    (MIN_REPLAY_SPEED..=MAX_REPLAY_SPEED).contains(&speed)
}

impl CameraConfig {
    /// Checks every value against its valid range; keys are relative to `[camera]`.
    pub fn validate(&self) -> Result<(), SettingError> {
        self.intrinsics
            .validate()
            .map_err(|e| SettingError::caused_by("intrinsics", e))?;
        if !(self.fps.is_finite() && self.fps > 0.0 && self.fps <= 1000.0) {
            return Err(SettingError::new(
                "fps",
                format!("expected 0 < fps <= 1000, found {}", self.fps),
            ));
        }
        super::SourceUri::parse(&self.source).map_err(|e| SettingError::caused_by("source", e))?;
        let (w, h) = (self.intrinsics.width, self.intrinsics.height);
        let (max_w, max_h) = (crate::ipc::FRAME_MAX_WIDTH, crate::ipc::FRAME_MAX_HEIGHT);
        if w > max_w || h > max_h {
            return Err(SettingError::new(
                "intrinsics",
                format!("expected at most {max_w}x{max_h} (the frame capacity), found {w}x{h}"),
            ));
        }
        for (key, value) in [("exposure_us", self.exposure_us), ("gain_db", self.gain_db)] {
            if let Some(v) = value {
                if !v.is_finite() || (key == "exposure_us" && v <= 0.0) {
                    return Err(SettingError::new(
                        key,
                        format!("expected a positive finite value, found {v}"),
                    ));
                }
            }
        }
        first_failure([
            (
                "buffers",
                (2..=32).contains(&self.buffers),
                format!("expected 2..=32, found {}", self.buffers),
            ),
            (
                "frame_timeout_ms",
                (10..=60_000).contains(&self.frame_timeout_ms),
                format!("expected 10..=60000, found {}", self.frame_timeout_ms),
            ),
            (
                "replay_speed",
                replay_speed_is_sane(self.replay_speed),
                format!(
                    "expected {MIN_REPLAY_SPEED}..={MAX_REPLAY_SPEED}, found {}",
                    self.replay_speed
                ),
            ),
        ])
    }
}
