//! Typed configuration (`config/star.toml`, deployed as `/etc/star/star.toml`).
//!
//! Owns parsing and validation. Unknown keys are rejected by serde
//! (`deny_unknown_fields`) and out-of-range values by [`Config::validate`];
//! both errors name the file, the key and the reason. Every section has
//! defaults, so an empty file is a valid configuration.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

pub use crate::camera::CameraConfig;
pub use crate::ipc::IpcConfig;
pub use crate::localizer::KeyframeConfig;
pub use crate::map::MapConfig;
pub use crate::mavlink_io::MavlinkConfig;
pub use crate::output::RecordConfig;
pub use crate::reloc::RelocConfig;
pub use crate::render::{RenderConfig, RendererKind};
pub use crate::settings::SettingError;
pub use crate::track::{IlluminationModel, TrackerConfig};

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
    /// A value is out of range; the section's error names the dotted key
    /// (`tracker.pyramid_levels`) and the reason.
    #[error("invalid config {path}: {source}")]
    Invalid {
        /// The file.
        path: PathBuf,
        /// The section's error, its key prefixed with the section.
        source: SettingError,
    },
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
    pub mavlink: MavlinkConfig,
    /// Inter-process transport (iceoryx2).
    pub ipc: IpcConfig,
    /// Relocalization: database grid, search and acceptance gate.
    pub reloc: RelocConfig,
    /// The flight log (`--record DIR`).
    pub record: RecordConfig,
}

impl Config {
    /// Reads, parses and validates `path`.
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let read_err = |source| ConfigError::Read {
            path: path.to_owned(),
            source,
        };
        // A FIFO would block the read forever.
        if !std::fs::metadata(path).map_err(read_err)?.is_file() {
            return Err(read_err(std::io::Error::new(
                std::io::ErrorKind::InvalidInput,
                "not a regular file",
            )));
        }
        let text = std::fs::read_to_string(path).map_err(read_err)?;
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

    /// Checks every section; the error names the file and the dotted key.
    pub fn validate(&self, path: &Path) -> Result<(), ConfigError> {
        let sections: [(&str, Result<(), SettingError>); 9] = [
            ("camera", self.camera.validate()),
            ("map", self.map.validate()),
            ("render", self.render.validate()),
            ("ipc", self.ipc.validate()),
            ("tracker", self.tracker.validate()),
            ("keyframe", self.keyframe.validate()),
            ("mavlink", self.mavlink.validate()),
            ("reloc", self.reloc.validate()),
            ("record", self.record.validate()),
        ];
        for (section, result) in sections {
            if let Err(e) = result {
                return Err(ConfigError::Invalid {
                    path: path.to_owned(),
                    source: e.within(section),
                });
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
    fn keyframe_far_limit_is_off_by_default_and_validated() {
        let c = Config::parse("", Path::new("a.toml")).expect("defaults");
        assert_eq!(c.keyframe.far_m, 0.0);
        let c = Config::parse("[keyframe]\nfar_m = 4.0\n", Path::new("a.toml")).expect("valid");
        assert_eq!(c.keyframe.far_m, 4.0);
        for bad in ["-1.0", "0.5", "nan", "inf", "20000.0"] {
            let text = format!("[keyframe]\nfar_m = {bad}\n");
            let err = Config::parse(&text, Path::new("a.toml")).expect_err(bad);
            assert!(err.to_string().contains("keyframe.far_m"), "{bad}: {err}");
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
    fn shipped_record_section_is_the_default_and_validated() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/star.toml");
        let c = Config::load(&path).expect("config/star.toml must be valid");
        assert_eq!(c.record, RecordConfig::default());
        let err = Config::parse(
            "[record]
queue_rows = 1
",
            Path::new("s.toml"),
        )
        .expect_err("queue_rows");
        assert!(err.to_string().contains("record.queue_rows"), "{err}");
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
            c.tracker.world_from_camera_init,
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
    fn tracker_keys_carry_units_and_old_names_still_parse() {
        let new = Config::parse(
            "[tracker]\nhuber_min_gray = 5.0\noutlier_cut_gray = 30.0\n",
            Path::new("a.toml"),
        )
        .expect("new names");
        let old = Config::parse(
            "[tracker]\nhuber_min = 5.0\noutlier_cut = 30.0\n",
            Path::new("a.toml"),
        )
        .expect("old names");
        assert_eq!(new, old);
        assert_eq!(new.tracker.huber_min_gray, 5.0);
    }

    #[test]
    fn missing_file_names_path() {
        let err = Config::load(Path::new("/nonexistent/star.toml")).expect_err("missing");
        assert!(err.to_string().contains("/nonexistent/star.toml"));
    }
}
