//! `[ipc]`: the iceoryx2 configuration file and the subscriber's timing, and
//! their validation.

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use crate::settings::{first_failure, SettingError};

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

impl IpcConfig {
    /// Checks every value against its valid range; keys are relative to `[ipc]`.
    pub fn validate(&self) -> Result<(), SettingError> {
        first_failure([
            (
                "spin_us",
                self.spin_us <= 5_000,
                format!("expected 0..=5000, found {}", self.spin_us),
            ),
            (
                "silence_timeout_ms",
                (10..=60_000).contains(&self.silence_timeout_ms),
                format!("expected 10..=60000, found {}", self.silence_timeout_ms),
            ),
        ])
    }
}
