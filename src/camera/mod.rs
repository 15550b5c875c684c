//! Camera sources and the camera process's publish loop.
//!
//! Owns the [`FrameSource`] trait and its implementations: V4L2
//! (`v4l2:/dev/videoN`), Aravis/GenICam (`aravis:ID`), dataset replay
//! (`replay:DIR`) and a test pattern (`pattern:WxH`); it parses the
//! vehicle-simulator camera's URI (`sim:`, see [`SimUri`]), whose source
//! lives in `synth::sim_camera` (it renders a synthetic scene). Takes in a source URI
//! plus [`SourceSettings`] from the config; gives out 8-bit gray frames with a
//! CLOCK_MONOTONIC capture time, written straight into a frame slot (the
//! loaned shared-memory sample on the camera side, a heap frame for the
//! virtual-camera writer). [`runner`] drives a source into a
//! [`FramePublisher`](crate::ipc::FramePublisher), reconnecting with backoff.

pub mod config;
pub mod convert;
pub mod frame_size;
#[cfg(feature = "v4l2")]
pub mod loopback;
pub mod pattern;
pub mod replay;
pub mod runner;
mod uri;
#[cfg(feature = "v4l2")]
pub mod v4l2;

#[cfg(feature = "aravis")]
pub mod aravis;

pub use config::{replay_speed_is_sane, CameraConfig, MAX_REPLAY_SPEED, MIN_REPLAY_SPEED};
pub use frame_size::{known_frame_sizes, KnownSize};
pub use runner::{run_camera, RunError, RunSummary, RunnerSettings};
pub use uri::{GeoPoint, SimUri, SourceUri};

use std::path::PathBuf;

use crate::ipc::FrameSlot;

/// A camera that produces 8-bit gray frames.
pub trait FrameSource {
    /// One line for logs: device, size, pixel format, rate.
    fn describe(&self) -> String;

    /// Blocks until the next frame and writes it into `slot`: pixels tightly
    /// packed or at `slot.header.stride`, and every header field except
    /// `sequence` (the publisher numbers frames). Must not allocate in
    /// steady state.
    fn next_frame(&mut self, slot: &mut FrameSlot<'_>) -> Result<(), CameraError>;
}

/// Settings shared by all sources (from `[camera]` in the config).
#[derive(Debug, Clone, PartialEq)]
pub struct SourceSettings {
    /// Requested width, pixels.
    pub width: u32,
    /// Requested height, pixels.
    pub height: u32,
    /// Requested frame rate, Hz.
    pub fps: f64,
    /// Driver buffers (V4L2 mmap buffers, Aravis buffer pool).
    pub buffers: u32,
    /// Fixed exposure, microseconds; `None` leaves auto exposure on.
    pub exposure_us: Option<f64>,
    /// Fixed gain, dB; `None` leaves auto gain on.
    pub gain_db: Option<f64>,
    /// Replay speed factor (1 = recorded rate).
    pub replay_speed: f64,
    /// Replay starts over at the end of the dataset.
    pub replay_loop: bool,
    /// How long to wait for one frame before treating the camera as stalled, ms.
    pub frame_timeout_ms: u64,
}

impl Default for SourceSettings {
    fn default() -> Self {
        Self {
            width: 640,
            height: 512,
            fps: 30.0,
            buffers: 4,
            exposure_us: None,
            gain_db: None,
            replay_speed: 1.0,
            replay_loop: false,
            frame_timeout_ms: 2000,
        }
    }
}

/// What the publish loop does after a [`CameraError`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ErrorAction {
    /// Drop this frame and ask for the next one.
    Skip,
    /// Close the source and open it again after a backoff.
    Reconnect,
    /// The source has no more frames (replay without loop).
    End,
    /// Configuration error: stop with the error.
    Fatal,
}

/// Errors from camera sources.
#[derive(Debug, thiserror::Error)]
pub enum CameraError {
    /// The source URI is malformed.
    #[error("invalid camera source `{uri}`: {reason}")]
    InvalidUri {
        /// The URI given.
        uri: String,
        /// What was expected.
        reason: String,
    },
    /// The source kind exists but this binary was built without it.
    #[error("camera source `{uri}` needs cargo feature `{feature}`, not built in")]
    FeatureDisabled {
        /// The URI given.
        uri: String,
        /// The missing feature.
        feature: &'static str,
    },
    /// The device could not be opened or configured (it may come back).
    #[error("cannot open camera {device}: {reason}")]
    Open {
        /// Device path or camera id.
        device: String,
        /// The driver's error.
        reason: String,
    },
    /// The device does not offer what the config asks for.
    #[error("camera {device}: {reason}")]
    Unsupported {
        /// Device path or camera id.
        device: String,
        /// What was asked and what the device offers.
        reason: String,
    },
    /// The device went away or returned an I/O error while streaming.
    #[error("camera {device} disconnected: {reason}")]
    Disconnected {
        /// Device path or camera id.
        device: String,
        /// The driver's error.
        reason: String,
    },
    /// No frame within the timeout.
    #[error("camera {device}: no frame within {waited_ms} ms")]
    Timeout {
        /// Device path or camera id.
        device: String,
        /// How long we waited.
        waited_ms: u64,
    },
    /// One frame was corrupt or could not be decoded; the next may be fine.
    #[error("camera {device}: bad frame: {reason}")]
    BadFrame {
        /// Device path or camera id.
        device: String,
        /// What was wrong.
        reason: String,
    },
    /// A dataset file is missing or malformed.
    #[error("dataset {path}: {reason}")]
    Dataset {
        /// The file.
        path: PathBuf,
        /// What was wrong (with the line number where there is one).
        reason: String,
    },
    /// The replay reached the end of the dataset.
    #[error("end of dataset")]
    EndOfStream,
    /// A stop signal arrived while the source waited for a frame.
    #[error("stopped by a signal while waiting for a frame")]
    Stopped,
}

impl CameraError {
    /// How the publish loop reacts.
    pub fn action(&self) -> ErrorAction {
        match self {
            CameraError::BadFrame { .. } => ErrorAction::Skip,
            CameraError::Open { .. }
            | CameraError::Disconnected { .. }
            | CameraError::Timeout { .. } => ErrorAction::Reconnect,
            CameraError::EndOfStream | CameraError::Stopped => ErrorAction::End,
            CameraError::InvalidUri { .. }
            | CameraError::FeatureDisabled { .. }
            | CameraError::Unsupported { .. }
            | CameraError::Dataset { .. } => ErrorAction::Fatal,
        }
    }
}

/// Opens the source named by `uri` with `settings`.
pub fn open_source(
    uri: &SourceUri,
    settings: &SourceSettings,
) -> Result<Box<dyn FrameSource>, CameraError> {
    match uri {
        #[cfg(feature = "v4l2")]
        SourceUri::V4l2(path) => Ok(Box::new(v4l2::V4l2Source::open(path, settings)?)),
        #[cfg(not(feature = "v4l2"))]
        SourceUri::V4l2(path) => Err(CameraError::FeatureDisabled {
            uri: format!("v4l2:{}", path.display()),
            feature: "v4l2",
        }),
        #[cfg(feature = "aravis")]
        SourceUri::Aravis(id) => Ok(Box::new(aravis::AravisSource::open(id, settings)?)),
        #[cfg(not(feature = "aravis"))]
        SourceUri::Aravis(id) => Err(CameraError::FeatureDisabled {
            uri: format!("aravis:{id}"),
            feature: "aravis",
        }),
        SourceUri::Replay(dir) => Ok(Box::new(replay::ReplaySource::open(dir, settings)?)),
        SourceUri::Pattern { width, height } => Ok(Box::new(pattern::PatternSource::new(
            *width,
            *height,
            settings.fps,
        )?)),
        SourceUri::Sim(sim) => Err(CameraError::InvalidUri {
            uri: sim.to_string(),
            reason: "a sim: camera renders a synthetic scene with the config's transforms; \
                     `star camera` and `star run` open it (synth::sim_camera)"
                .into(),
        }),
    }
}
