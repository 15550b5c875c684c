//! Typed configuration (`config/star.toml`, deployed as `/etc/star/star.toml`).
//!
//! Owns parsing and validation. Unknown keys are rejected by serde
//! (`deny_unknown_fields`) and out-of-range values by [`Config::validate`];
//! both errors name the file, the key and the reason. Every section has
//! defaults, so an empty file is a valid configuration.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::geometry::PinholeCamera;

/// Errors loading or validating a configuration.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    /// The file could not be read.
    #[error("cannot read config {path}: {source}")]
    Read {
        /// The file.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// The file is not valid TOML, has an unknown key, or a value of the wrong type.
    #[error("invalid config {path}: {message}")]
    Parse {
        /// The file.
        path: PathBuf,
        /// toml's message: line, column, key and what was expected.
        message: String,
    },
    /// A value is out of range.
    #[error("invalid config {path}: key `{key}`: {reason}")]
    Invalid {
        /// The file.
        path: PathBuf,
        /// Dotted key, e.g. `tracker.pyramid_levels`.
        key: String,
        /// What is wrong and what was expected.
        reason: String,
    },
}

/// Which renderer draws keyframes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum RendererKind {
    /// Hardware adapter, then software adapter, then the CPU rasterizer.
    #[default]
    Auto,
    /// A hardware wgpu adapter, which must exist at start; on a runtime
    /// failure, the software adapter, then the CPU rasterizer.
    Gpu,
    /// wgpu's software adapter (Mesa lavapipe/llvmpipe), which must exist at
    /// start; on a runtime failure, the CPU rasterizer.
    Software,
    /// The built-in CPU rasterizer.
    Cpu,
}

/// Photometric model between rendered keyframe and camera image.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum IlluminationModel {
    /// Affine gain and bias, estimated per frame.
    #[default]
    Affine,
    /// The paper's median offset (beta).
    Median,
}

/// The whole configuration.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Config {
    /// Camera source and calibration.
    pub camera: CameraConfig,
    /// The map.
    pub map: MapConfig,
    /// Keyframe rendering.
    pub render: RenderConfig,
    /// The tracker.
    pub tracker: TrackerConfig,
    /// When to render a new keyframe, and when tracking is lost.
    pub keyframe: KeyframeConfig,
    /// The MAVLink link to the autopilot.
    pub mavlink: crate::mavlink_io::MavlinkConfig,
    /// Inter-process transport (iceoryx2).
    pub ipc: IpcConfig,
    /// Relocalization: database grid, search and acceptance gate.
    pub reloc: crate::reloc::RelocConfig,
}

/// `[keyframe]`: the keyframe policy and the lost test.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct KeyframeConfig {
    /// Render a new keyframe when the visible fraction of keyframe points drops below this.
    pub min_visible: f32,
    /// ... when the translation from the keyframe exceeds this fraction of its median depth.
    pub max_baseline_ratio: f32,
    /// ... when the rotation from the keyframe exceeds this, degrees.
    pub max_rotation_deg: f32,
    /// ... when the inlier ratio drops below this.
    pub min_inlier_ratio: f32,
    /// ... when the keyframe is older than this, seconds.
    pub max_interval_s: f32,
    /// Tracking is lost when the inlier ratio drops below this.
    pub lost_inlier_ratio: f32,
    /// Tracking is lost when fewer than this fraction of keyframe points are visible.
    pub lost_visible_ratio: f32,
    /// Tracking is lost when the estimate jumps this far from the prediction in one frame, meters.
    pub lost_max_jump_m: f32,
    /// Tracking is lost when the normalized cross-correlation between the
    /// keyframe points and the aligned frame drops below this.
    pub lost_min_correlation: f32,
}

impl Default for KeyframeConfig {
    fn default() -> Self {
        Self {
            min_visible: 0.75,
            max_baseline_ratio: 0.08,
            max_rotation_deg: 6.0,
            min_inlier_ratio: 0.75,
            max_interval_s: 1.0,
            lost_inlier_ratio: 0.35,
            lost_visible_ratio: 0.15,
            lost_max_jump_m: 0.3,
            lost_min_correlation: 0.2,
        }
    }
}

/// `[camera]`
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CameraConfig {
    /// Source URI: `v4l2:/dev/videoN`, `aravis:ID`, `replay:DATASET`.
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
    pub fn source_settings(&self) -> crate::camera::SourceSettings {
        crate::camera::SourceSettings {
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

/// `[ipc]`
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct IpcConfig {
    /// iceoryx2 configuration file (the repository ships `config/iceoryx2.toml`);
    /// when missing, iceoryx2's defaults are used and a warning is logged.
    pub iceoryx2_config: PathBuf,
    /// The tracker reports the camera silent after this long without a frame, ms.
    pub silence_timeout_ms: u64,
    /// Half-width of the window around a frame's predicted arrival in which
    /// the tracker polls for it instead of sleeping on the event, µs, at a
    /// cost of up to `2 * spin_us` of CPU per frame; 0 (the default) always
    /// sleeps. It helps where the camera's frames keep to their schedule
    /// within the window; on the 2-vCPU development VM it did not move the
    /// transport's p99 (README, "Camera and transport").
    pub spin_us: u64,
}

impl Default for IpcConfig {
    fn default() -> Self {
        Self {
            iceoryx2_config: PathBuf::from("/etc/star/iceoryx2.toml"),
            silence_timeout_ms: 500,
            spin_us: 0,
        }
    }
}

/// `[map]`
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MapConfig {
    /// OBJ mesh of the building, world frame, meters.
    pub mesh: PathBuf,
}

impl Default for MapConfig {
    fn default() -> Self {
        Self {
            mesh: PathBuf::from("/var/lib/star/map/map.obj"),
        }
    }
}

/// `[render]`
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RenderConfig {
    /// `auto`, `gpu`, `software` or `cpu`.
    pub renderer: RendererKind,
}

/// `[tracker]`
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TrackerConfig {
    /// Pyramid levels, coarsest first in alignment.
    pub pyramid_levels: u32,
    /// Illumination model.
    pub illumination: IlluminationModel,
    /// Most keyframe points at level 0; level `l` gets `max_points >> l`
    /// (at least 200).
    pub max_points: u32,
    /// Side of the blocks whose median gradient sets the local selection
    /// threshold, level-0 pixels.
    pub block_size_px: u32,
    /// Gradient magnitude above the block median needed for selection,
    /// gray levels per pixel.
    pub gradient_threshold: f32,
    /// Fewest visible points for a level to be used.
    pub min_points: u32,
    /// Most Levenberg-Marquardt iterations per level.
    pub max_iterations: u32,
    /// Smallest Huber threshold, gray levels.
    pub huber_min: f32,
    /// Residuals above this (or above 4 Huber thresholds) get zero weight.
    pub outlier_cut: f32,
    /// A residual below this counts as an inlier in the quality figures.
    pub inlier_threshold: f32,
    /// Initial pose of `star track` / `star run`, `world_from_camera` in TUM
    /// order `[tx, ty, tz, qx, qy, qz, qw]`; absent: `--init-pose` must give it.
    pub init_pose: Option<[f64; 7]>,
}

impl Default for TrackerConfig {
    fn default() -> Self {
        Self {
            pyramid_levels: 4,
            illumination: IlluminationModel::Affine,
            max_points: 6000,
            block_size_px: 32,
            gradient_threshold: 4.0,
            min_points: 40,
            max_iterations: 12,
            huber_min: 4.0,
            outlier_cut: 40.0,
            inlier_threshold: 20.0,
            init_pose: None,
        }
    }
}

impl TrackerConfig {
    /// Point budget of pyramid level `level`.
    pub fn max_points_per_level(&self, level: usize) -> usize {
        ((self.max_points as usize) >> level).max(200)
    }
}

impl Config {
    /// Reads, parses and validates `path`.
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Read {
            path: path.to_owned(),
            source,
        })?;
        Self::parse(&text, path)
    }

    /// Parses and validates TOML `text`; `path` is used in error messages.
    pub fn parse(text: &str, path: &Path) -> Result<Self, ConfigError> {
        let config: Config = toml::from_str(text).map_err(|e| ConfigError::Parse {
            path: path.to_owned(),
            message: e.to_string().trim_end().to_string(),
        })?;
        config.validate(path)?;
        Ok(config)
    }

    /// Checks every value against its valid range.
    pub fn validate(&self, path: &Path) -> Result<(), ConfigError> {
        let invalid = |key: &str, reason: String| ConfigError::Invalid {
            path: path.to_owned(),
            key: key.to_string(),
            reason,
        };
        if let Err(e) = self.camera.intrinsics.validate() {
            return Err(invalid("camera.intrinsics", e.to_string()));
        }
        if !(self.camera.fps.is_finite() && self.camera.fps > 0.0 && self.camera.fps <= 1000.0) {
            return Err(invalid(
                "camera.fps",
                format!("expected 0 < fps <= 1000, found {}", self.camera.fps),
            ));
        }
        if let Err(e) = crate::camera::SourceUri::parse(&self.camera.source) {
            return Err(invalid("camera.source", e.to_string()));
        }
        let (w, h) = (self.camera.intrinsics.width, self.camera.intrinsics.height);
        if w > crate::ipc::FRAME_MAX_WIDTH || h > crate::ipc::FRAME_MAX_HEIGHT {
            return Err(invalid(
                "camera.intrinsics",
                format!(
                    "expected at most {}x{} (the frame capacity), found {w}x{h}",
                    crate::ipc::FRAME_MAX_WIDTH,
                    crate::ipc::FRAME_MAX_HEIGHT
                ),
            ));
        }
        for (key, value) in [
            ("camera.exposure_us", self.camera.exposure_us),
            ("camera.gain_db", self.camera.gain_db),
        ] {
            if let Some(v) = value {
                if !v.is_finite() || (key == "camera.exposure_us" && v <= 0.0) {
                    return Err(invalid(
                        key,
                        format!("expected a positive finite value, found {v}"),
                    ));
                }
            }
        }
        if !(2..=32).contains(&self.camera.buffers) {
            return Err(invalid(
                "camera.buffers",
                format!("expected 2..=32, found {}", self.camera.buffers),
            ));
        }
        if !(10..=60_000).contains(&self.camera.frame_timeout_ms) {
            return Err(invalid(
                "camera.frame_timeout_ms",
                format!(
                    "expected 10..=60000, found {}",
                    self.camera.frame_timeout_ms
                ),
            ));
        }
        if !(self.camera.replay_speed.is_finite() && self.camera.replay_speed > 0.0) {
            return Err(invalid(
                "camera.replay_speed",
                format!(
                    "expected a positive factor, found {}",
                    self.camera.replay_speed
                ),
            ));
        }
        if self.ipc.spin_us > 5_000 {
            return Err(invalid(
                "ipc.spin_us",
                format!("expected 0..=5000, found {}", self.ipc.spin_us),
            ));
        }
        if !(10..=60_000).contains(&self.ipc.silence_timeout_ms) {
            return Err(invalid(
                "ipc.silence_timeout_ms",
                format!("expected 10..=60000, found {}", self.ipc.silence_timeout_ms),
            ));
        }
        if !(1..=6).contains(&self.tracker.pyramid_levels) {
            return Err(invalid(
                "tracker.pyramid_levels",
                format!("expected 1..=6, found {}", self.tracker.pyramid_levels),
            ));
        }
        if let Err((key, reason)) = self.mavlink.validate() {
            return Err(invalid(&format!("mavlink.{key}"), reason));
        }
        if let Err((key, reason)) = self.reloc.validate() {
            return Err(invalid(&format!("reloc.{key}"), reason));
        }
        let t = &self.tracker;
        let checks: [(&str, bool, String); 7] = [
            (
                "tracker.max_points",
                (100..=100_000).contains(&t.max_points),
                format!("expected 100..=100000, found {}", t.max_points),
            ),
            (
                "tracker.block_size_px",
                (8..=256).contains(&t.block_size_px),
                format!("expected 8..=256, found {}", t.block_size_px),
            ),
            (
                "tracker.gradient_threshold",
                t.gradient_threshold.is_finite() && t.gradient_threshold >= 0.0,
                format!(
                    "expected a finite value >= 0, found {}",
                    t.gradient_threshold
                ),
            ),
            (
                "tracker.min_points",
                (6..=10_000).contains(&t.min_points),
                format!("expected 6..=10000, found {}", t.min_points),
            ),
            (
                "tracker.max_iterations",
                (1..=100).contains(&t.max_iterations),
                format!("expected 1..=100, found {}", t.max_iterations),
            ),
            (
                "tracker.huber_min",
                t.huber_min.is_finite() && t.huber_min > 0.0,
                format!("expected a finite value > 0, found {}", t.huber_min),
            ),
            (
                "tracker.outlier_cut",
                t.outlier_cut.is_finite()
                    && t.outlier_cut > t.huber_min
                    && t.inlier_threshold > 0.0,
                format!(
                    "expected outlier_cut > huber_min and inlier_threshold > 0, found {} and {}",
                    t.outlier_cut, t.inlier_threshold
                ),
            ),
        ];
        if let Some(p) = &t.init_pose {
            let q_norm = (p[3] * p[3] + p[4] * p[4] + p[5] * p[5] + p[6] * p[6]).sqrt();
            if p.iter().any(|v| !v.is_finite()) || q_norm < 1e-6 {
                return Err(invalid(
                    "tracker.init_pose",
                    format!("expected finite [tx, ty, tz, qx, qy, qz, qw] with a non-zero quaternion, found {p:?}"),
                ));
            }
        }
        let k = &self.keyframe;
        let unit = |v: f32| v.is_finite() && (0.0..=1.0).contains(&v);
        let positive = |v: f32| v.is_finite() && v > 0.0;
        let kchecks: [(&str, bool, f32); 9] = [
            ("keyframe.min_visible", unit(k.min_visible), k.min_visible),
            (
                "keyframe.max_baseline_ratio",
                positive(k.max_baseline_ratio),
                k.max_baseline_ratio,
            ),
            (
                "keyframe.max_rotation_deg",
                positive(k.max_rotation_deg) && k.max_rotation_deg < 90.0,
                k.max_rotation_deg,
            ),
            (
                "keyframe.min_inlier_ratio",
                unit(k.min_inlier_ratio),
                k.min_inlier_ratio,
            ),
            (
                "keyframe.max_interval_s",
                positive(k.max_interval_s),
                k.max_interval_s,
            ),
            (
                "keyframe.lost_inlier_ratio",
                unit(k.lost_inlier_ratio),
                k.lost_inlier_ratio,
            ),
            (
                "keyframe.lost_visible_ratio",
                unit(k.lost_visible_ratio),
                k.lost_visible_ratio,
            ),
            (
                "keyframe.lost_max_jump_m",
                positive(k.lost_max_jump_m),
                k.lost_max_jump_m,
            ),
            (
                "keyframe.lost_min_correlation",
                unit(k.lost_min_correlation),
                k.lost_min_correlation,
            ),
        ];
        for (key, ok, value) in kchecks {
            if !ok {
                return Err(invalid(
                    key,
                    format!("out of range: {value} (ratios are 0..=1, others > 0)"),
                ));
            }
        }
        for (key, ok, reason) in checks {
            if !ok {
                return Err(invalid(key, reason));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn empty_file_is_default() {
        let c = Config::parse("", Path::new("x.toml")).expect("defaults are valid");
        assert_eq!(c, Config::default());
    }

    #[test]
    fn shipped_default_config_parses() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/star.toml");
        Config::load(&path).expect("config/star.toml must be valid");
    }

    #[test]
    fn unknown_key_names_file_and_key() {
        let err = Config::parse(
            "[tracker]\npyramid_levelz = 3\n",
            Path::new("/etc/star/star.toml"),
        )
        .expect_err("unknown key");
        let msg = err.to_string();
        assert!(msg.contains("/etc/star/star.toml"), "{msg}");
        assert!(msg.contains("pyramid_levelz"), "{msg}");
    }

    #[test]
    fn out_of_range_names_key_and_reason() {
        let err = Config::parse("[tracker]\npyramid_levels = 9\n", Path::new("a.toml"))
            .expect_err("out of range");
        let msg = err.to_string();
        assert!(
            msg.contains("a.toml")
                && msg.contains("tracker.pyramid_levels")
                && msg.contains("found 9"),
            "{msg}"
        );
        let err = Config::parse(
            "[camera.intrinsics]\nwidth=640\nheight=512\nfx=-3\nfy=400\ncx=320\ncy=256\n",
            Path::new("a.toml"),
        )
        .expect_err("negative focal length");
        assert!(err.to_string().contains("fx"), "{err}");
    }

    #[test]
    fn camera_and_ipc_keys_are_validated() {
        let c = Config::parse(
            "[camera]\nsource = \"aravis:fake\"\nexposure_us = 5000.0\nbuffers = 8\n[ipc]\nsilence_timeout_ms = 250\n",
            Path::new("a.toml"),
        )
        .expect("valid");
        assert_eq!(c.camera.exposure_us, Some(5000.0));
        assert_eq!(c.camera.source_settings().buffers, 8);
        assert_eq!(c.ipc.silence_timeout_ms, 250);
        for (text, key) in [
            ("[camera]\nsource = \"usb:0\"\n", "camera.source"),
            ("[camera]\nbuffers = 1\n", "camera.buffers"),
            ("[camera]\nexposure_us = -1.0\n", "camera.exposure_us"),
            ("[camera]\nreplay_speed = 0.0\n", "camera.replay_speed"),
            (
                "[camera]\nframe_timeout_ms = 1\n",
                "camera.frame_timeout_ms",
            ),
            ("[ipc]\nsilence_timeout_ms = 0\n", "ipc.silence_timeout_ms"),
            (
                "[camera.intrinsics]\nwidth=4096\nheight=512\nfx=400\nfy=400\ncx=320\ncy=256\n",
                "camera.intrinsics",
            ),
        ] {
            let err = Config::parse(text, Path::new("a.toml")).expect_err(key);
            assert!(err.to_string().contains(key), "{key}: {err}");
        }
    }

    #[test]
    fn wrong_type_is_rejected() {
        let err = Config::parse("[render]\nrenderer = \"vulkan\"\n", Path::new("a.toml"))
            .expect_err("unknown renderer");
        assert!(err.to_string().contains("renderer"), "{err}");
    }

    #[test]
    fn mavlink_section_is_validated() {
        let err = Config::parse(
            "[mavlink]\nconnection = \"serial:/dev/ttyACM0\"\n",
            Path::new("a.toml"),
        )
        .expect_err("serial without baud");
        let msg = err.to_string();
        assert!(
            msg.contains("mavlink.connection") && msg.contains("PORT:BAUD"),
            "{msg}"
        );
        let c = Config::parse(
            "[mavlink]\nmessage = \"odometry\"\n[mavlink.body_from_camera]\nquaternion_wxyz = [1.0, 0.0, 0.0, 0.0]\n",
            Path::new("a.toml"),
        )
        .expect("quaternion alone is valid");
        assert_eq!(c.mavlink.message, crate::mavlink_io::PoseMessage::Odometry);
        assert_eq!(c.mavlink.body_from_camera.rpy_deg, None);
        let err = Config::parse(
            "[mavlink.ned_from_world]\nrpy_deg = [0.0, 0.0]\n",
            Path::new("a.toml"),
        )
        .expect_err("two angles");
        assert!(err.to_string().contains("rpy_deg"), "{err}");
    }

    #[test]
    fn shipped_reloc_section_is_the_default() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/star.toml");
        let c = Config::load(&path).expect("config/star.toml must be valid");
        assert_eq!(c.reloc, crate::reloc::RelocConfig::default());
    }

    #[test]
    fn reloc_section_is_validated() {
        let err = Config::parse("[reloc]\ntop_k = 0\n", Path::new("s.toml")).expect_err("top_k");
        assert!(err.to_string().contains("reloc.top_k"), "{err}");
        let err =
            Config::parse("[reloc]\nheights_m = []\n", Path::new("s.toml")).expect_err("heights");
        assert!(err.to_string().contains("reloc.heights_m"), "{err}");
        let err = Config::parse("[reloc]\ngrid_spacing = 1.0\n", Path::new("s.toml"))
            .expect_err("unknown key");
        assert!(err.to_string().contains("grid_spacing"), "{err}");
    }

    #[test]
    fn init_pose_is_optional_and_validated() {
        let c = Config::parse(
            "[tracker]\ninit_pose = [1.0, 2.0, 1.5, 0.0, 0.0, 0.0, 1.0]\n",
            Path::new("a.toml"),
        )
        .expect("valid pose");
        assert_eq!(
            c.tracker.init_pose,
            Some([1.0, 2.0, 1.5, 0.0, 0.0, 0.0, 1.0])
        );
        for text in [
            "[tracker]\ninit_pose = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]\n",
            "[tracker]\ninit_pose = [0.0, 0.0, 0.0, 0.0, 0.0, 1.0]\n",
        ] {
            let err = Config::parse(text, Path::new("a.toml")).expect_err(text);
            assert!(err.to_string().contains("init_pose"), "{err}");
        }
    }

    #[test]
    fn missing_file_names_path() {
        let err = Config::load(Path::new("/nonexistent/star.toml")).expect_err("missing");
        assert!(err.to_string().contains("/nonexistent/star.toml"));
    }
}
