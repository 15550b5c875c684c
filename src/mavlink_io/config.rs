//! The `[mavlink]` configuration section: where the link goes, what it sends,
//! how fast, and the two mounting transforms that take a tracker pose into the
//! autopilot's frames.
//!
//! Takes its TOML section (through the aggregate `Config`), gives out a validated
//! [`MavlinkConfig`] whose transforms convert to [`crate::geometry::Pose`]s with
//! [`TransformConfig::to_pose`].
//!
//! Rotation convention for `rpy_deg = [roll, pitch, yaw]`: the aerospace
//! Z-Y-X order, `R = Rz(yaw) * Ry(pitch) * Rx(roll)`, the same as MAVLink's
//! attitude angles. A rotation may instead be given as `quaternion_wxyz`.

use std::time::Duration;

use serde::{Deserialize, Serialize};

pub use crate::geometry::TransformConfig;
use crate::mavlink_io::link::LinkAddress;
use crate::mavlink_io::udpin::PeerPolicy;
use crate::settings::{first_failure, SettingError};

/// MAVLink component id of a visual-inertial odometry source
/// (MAV_COMP_ID_VISUAL_INERTIAL_ODOMETRY).
pub const COMPONENT_ID_VISUAL_INERTIAL_ODOMETRY: u8 = 197;

/// Longest `timesync_wait_ms` accepted (a minute without poses is a
/// misconfiguration, not a wait).
pub const MAX_TIMESYNC_WAIT_MS: u32 = 60_000;

/// Bounds of `peer_silence_s`: shorter than a few HEARTBEAT periods lets a
/// foreign sender take the link in a short dropout; longer than ten minutes
/// is no failover.
pub const PEER_SILENCE_RANGE_S: (f64, f64) = (0.5, 600.0);

/// Default `autopilot_min_interval_ms`: ArduPilot's
/// `NavEKF3::extNavIntervalMin_ms`.
pub const DEFAULT_AUTOPILOT_MIN_INTERVAL_MS: f64 = 20.0;

/// Default `position_sigma_floor_m` (see `docs/benchmarks.md`, covariance).
pub const DEFAULT_POSITION_SIGMA_FLOOR_M: f64 = 0.0005;
/// Default `angle_sigma_floor_deg`.
pub const DEFAULT_ANGLE_SIGMA_FLOOR_DEG: f64 = 0.01;

/// Which message carries the pose.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum PoseMessage {
    /// VISION_POSITION_ESTIMATE (102): position and Euler angles, covariance.
    #[default]
    VisionPositionEstimate,
    /// ODOMETRY (331): position and quaternion in MAV_FRAME_LOCAL_FRD (the
    /// frame ArduPilot requires; PX4 accepts it too) with child frame
    /// MAV_FRAME_BODY_FRD, covariance, quality, `estimator_type` VISION.
    /// Velocities are sent as NaN (unknown).
    Odometry,
}

/// `[mavlink]`: the link to the autopilot.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MavlinkConfig {
    /// Whether the tracker talks to an autopilot at all.
    pub enabled: bool,
    /// `udpout:HOST:PORT`, `udpin:ADDR:PORT`, `tcpout:HOST:PORT` or `serial:PORT:BAUD`.
    pub connection: String,
    /// Maximum pose message rate, Hz, on capture timestamps (ArduPilot drops
    /// samples less than 20 ms apart, hence 50).
    pub rate_hz: f64,
    /// Smallest spacing of consecutive `usec` values the autopilot keeps,
    /// ms: a pose that would be stamped closer to the last one is stamped at
    /// this spacing when that moves it by at most 0.5 ms, and skipped
    /// (counted) otherwise. Default 20: ArduPilot's EKF3 drops external
    /// navigation samples under 20 ms after the last one it kept
    /// (`extNavIntervalMin_ms`, on its jitter-corrected time in whole ms).
    /// PX4's EKF2 drops a vision sample closer than `_min_obs_interval_us` to
    /// the newest one in its buffer ("EV data too fast"), which is its
    /// fusion horizon over the observation buffer length, about 10.5 ms with
    /// the defaults (EKF2_PREDICT_US 10 000, EKF2_DELAY_MAX 200): 11 there,
    /// with `rate_hz` up to 90; 20 is safe for both.
    pub autopilot_min_interval_ms: f64,
    /// `vision_position_estimate` or `odometry`.
    pub message: PoseMessage,
    /// Our MAVLink system id (normally the autopilot's).
    pub system_id: u8,
    /// Our MAVLink component id (197 = MAV_COMP_ID_VISUAL_INERTIAL_ODOMETRY).
    pub component_id: u8,
    /// Poses older than this (now - capture time) when they reach the link
    /// are dropped, so a returning link gets no stale pose.
    pub max_pose_age_ms: u32,
    /// Send our own TIMESYNC requests and stamp `usec` in the autopilot's
    /// clock. Off: `usec` is star's CLOCK_MONOTONIC from the first pose on.
    pub timesync: bool,
    /// How long a new link waits for TIMESYNC answers before poses go out,
    /// ms (poses go out sooner, after four answers, about 100 ms). Poses in
    /// this time are dropped (counted), not queued. One answer or more by
    /// then: the autopilot's clock. None: the stream's `usec` is star's
    /// CLOCK_MONOTONIC from its first pose on (never switched later), logged
    /// at warn.
    pub timesync_wait_ms: u32,
    /// `udpin` only: system ids whose autopilot HEARTBEAT (`autopilot` not
    /// MAV_AUTOPILOT_INVALID, `type` not MAV_TYPE_GCS) may lock the link;
    /// empty = any system id.
    pub autopilot_system_ids: Vec<u8>,
    /// `udpin` only: how long the locked autopilot must send no valid frame
    /// before another may take the link, s.
    pub peer_silence_s: f64,
    /// Smallest position standard deviation sent, m (each of x, y, z): the
    /// tracker's covariance is calibrated on the benches
    /// (`tracker.covariance_scale`); this guards views they did not cover.
    pub position_sigma_floor_m: f64,
    /// Smallest angle standard deviation sent, degrees (roll, pitch, yaw).
    pub angle_sigma_floor_deg: f64,
    /// MAVLink 2 signing: a file holding the 32-byte secret key (raw bytes).
    /// Set: every frame we send is signed (link id 0), frames with a bad
    /// signature are dropped (counted). Unset: no signing.
    pub signing_key: Option<std::path::PathBuf>,
    /// With `signing_key`: drop unsigned incoming frames too (counted).
    pub signing_required: bool,
    /// The map (world) frame in local NED: `ned_from_world`.
    pub ned_from_world: TransformConfig,
    /// The camera mounting on the body (FRD): `body_from_camera`.
    pub body_from_camera: TransformConfig,
}

impl Default for MavlinkConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            connection: "udpout:127.0.0.1:14550".into(),
            rate_hz: 50.0,
            autopilot_min_interval_ms: DEFAULT_AUTOPILOT_MIN_INTERVAL_MS,
            message: PoseMessage::VisionPositionEstimate,
            system_id: 1,
            component_id: COMPONENT_ID_VISUAL_INERTIAL_ODOMETRY,
            max_pose_age_ms: 100,
            timesync: true,
            timesync_wait_ms: 1500,
            autopilot_system_ids: Vec::new(),
            peer_silence_s: 5.0,
            position_sigma_floor_m: DEFAULT_POSITION_SIGMA_FLOOR_M,
            angle_sigma_floor_deg: DEFAULT_ANGLE_SIGMA_FLOOR_DEG,
            signing_key: None,
            signing_required: false,
            // A z-up map with x east, y north: NED x = world y, NED y = world x,
            // NED z = -world z.
            ned_from_world: TransformConfig::from_rpy_deg([0.0; 3], [180.0, 0.0, 90.0]),
            // A forward-looking camera at the body origin: camera z (optical
            // axis) = body x, camera x (right) = body y, camera y (down) = body z.
            body_from_camera: TransformConfig::from_rpy_deg([0.0; 3], [90.0, 0.0, 90.0]),
        }
    }
}

impl MavlinkConfig {
    /// Checks every value; keys are relative to `[mavlink]`.
    pub fn validate(&self) -> Result<(), SettingError> {
        LinkAddress::parse(&self.connection)
            .map_err(|e| SettingError::caused_by("connection", e))?;
        first_failure([
            (
                "rate_hz",
                self.rate_hz.is_finite() && self.rate_hz > 0.0 && self.rate_hz <= 1000.0,
                format!("expected 0 < rate_hz <= 1000, found {}", self.rate_hz),
            ),
            (
                "autopilot_min_interval_ms",
                self.autopilot_min_interval_ms.is_finite()
                    && (0.0..=1000.0).contains(&self.autopilot_min_interval_ms),
                format!(
                    "expected 0 <= autopilot_min_interval_ms <= 1000, found {}",
                    self.autopilot_min_interval_ms
                ),
            ),
            (
                "system_id",
                self.system_id != 0,
                "expected 1..=255, found 0".into(),
            ),
            (
                "component_id",
                self.component_id != 0,
                "expected 1..=255, found 0".into(),
            ),
            (
                "max_pose_age_ms",
                self.max_pose_age_ms != 0,
                "expected > 0, found 0".into(),
            ),
            (
                "timesync_wait_ms",
                self.timesync_wait_ms <= MAX_TIMESYNC_WAIT_MS,
                format!(
                    "expected 0..={MAX_TIMESYNC_WAIT_MS}, found {}",
                    self.timesync_wait_ms
                ),
            ),
            (
                "peer_silence_s",
                (PEER_SILENCE_RANGE_S.0..=PEER_SILENCE_RANGE_S.1).contains(&self.peer_silence_s),
                format!(
                    "expected {} <= peer_silence_s <= {}, found {}",
                    PEER_SILENCE_RANGE_S.0, PEER_SILENCE_RANGE_S.1, self.peer_silence_s
                ),
            ),
            (
                "position_sigma_floor_m",
                self.position_sigma_floor_m.is_finite()
                    && (0.0..=10.0).contains(&self.position_sigma_floor_m),
                format!(
                    "expected 0 <= position_sigma_floor_m <= 10, found {}",
                    self.position_sigma_floor_m
                ),
            ),
            (
                "angle_sigma_floor_deg",
                self.angle_sigma_floor_deg.is_finite()
                    && (0.0..=90.0).contains(&self.angle_sigma_floor_deg),
                format!(
                    "expected 0 <= angle_sigma_floor_deg <= 90, found {}",
                    self.angle_sigma_floor_deg
                ),
            ),
            (
                "signing_required",
                !self.signing_required || self.signing_key.is_some(),
                "signing_required = true needs signing_key (the key file)".into(),
            ),
            (
                "autopilot_system_ids",
                !self.autopilot_system_ids.contains(&0),
                format!(
                    "expected system ids 1..=255, found {:?}",
                    self.autopilot_system_ids
                ),
            ),
        ])?;
        self.ned_from_world
            .validate()
            .map_err(|e| SettingError::new("ned_from_world", e))?;
        self.body_from_camera
            .validate()
            .map_err(|e| SettingError::new("body_from_camera", e))?;
        Ok(())
    }

    /// Who may take a `udpin` link.
    pub fn peer_policy(&self) -> PeerPolicy {
        PeerPolicy {
            autopilot_system_ids: self.autopilot_system_ids.clone(),
            peer_silence: Duration::from_secs_f64(self.peer_silence_s),
            own_ids: (u32::from(self.system_id), self.component_id),
        }
    }

    /// Minimum spacing of pose messages on capture time, nanoseconds.
    pub fn min_interval_ns(&self) -> u64 {
        (1e9 / self.rate_hz).round() as u64
    }

    /// Minimum spacing of consecutive `usec` values, nanoseconds: the
    /// autopilot's (`autopilot_min_interval_ms`), and at least half the rate
    /// cap's interval.
    pub fn min_usec_spacing_ns(&self) -> u64 {
        let autopilot_ns = (self.autopilot_min_interval_ms * 1e6).round() as u64;
        autopilot_ns.max(self.min_interval_ns() / 2)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Matrix3, Vector3};

    #[test]
    fn default_transforms_match_their_comments() {
        let c = MavlinkConfig::default();
        c.validate().expect("defaults valid");
        let ned_from_world = c.ned_from_world.to_pose();
        let r = ned_from_world.rotation.to_rotation_matrix().into_inner();
        let expected = Matrix3::new(0.0, 1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, -1.0);
        assert!((r - expected).abs().max() < 1e-12, "{r}");
        let body_from_camera = c.body_from_camera.to_pose();
        // Optical axis (camera z) is body forward (x).
        let axis = body_from_camera.rotation * Vector3::z();
        assert!((axis - Vector3::x()).norm() < 1e-12);
        let right = body_from_camera.rotation * Vector3::x();
        assert!((right - Vector3::y()).norm() < 1e-12);
    }

    #[test]
    fn quaternion_and_rpy_agree() {
        let rpy = TransformConfig::from_rpy_deg([1.0, 2.0, 3.0], [0.0, 0.0, 90.0]);
        let h = std::f64::consts::FRAC_1_SQRT_2;
        let q = TransformConfig {
            translation_m: [1.0, 2.0, 3.0],
            quaternion_wxyz: Some([h, 0.0, 0.0, h]),
            ..Default::default()
        };
        q.validate().expect("unit quaternion");
        let d = rpy.to_pose().inverse() * q.to_pose();
        assert!(d.rotation.angle() < 1e-12 && d.translation.vector.norm() < 1e-12);
    }

    #[test]
    fn bad_transforms_are_rejected() {
        let both = TransformConfig {
            rpy_deg: Some([0.0; 3]),
            quaternion_wxyz: Some([1.0, 0.0, 0.0, 0.0]),
            ..Default::default()
        };
        assert!(both.validate().unwrap_err().contains("not several"));
        let not_unit = TransformConfig {
            quaternion_wxyz: Some([2.0, 0.0, 0.0, 0.0]),
            ..Default::default()
        };
        assert!(not_unit.validate().unwrap_err().contains("norm 2"));
        let nan = TransformConfig {
            translation_m: [f64::NAN, 0.0, 0.0],
            ..Default::default()
        };
        assert!(nan.validate().unwrap_err().contains("translation_m"));
    }

    #[test]
    fn bad_values_name_their_key() {
        let c = MavlinkConfig {
            rate_hz: 0.0,
            ..Default::default()
        };
        assert_eq!(c.validate().unwrap_err().key, "rate_hz");
        let c = MavlinkConfig {
            timesync_wait_ms: MAX_TIMESYNC_WAIT_MS + 1,
            ..Default::default()
        };
        let e = c.validate().unwrap_err();
        assert_eq!(e.key, "timesync_wait_ms");
        assert!(e.reason.contains("60001"), "{e}");
        let c = MavlinkConfig {
            timesync_wait_ms: 0,
            ..Default::default()
        };
        c.validate().expect("0 = do not wait");
        for bad in [0.0, 0.1, 601.0, f64::NAN, f64::INFINITY] {
            let c = MavlinkConfig {
                peer_silence_s: bad,
                ..Default::default()
            };
            let e = c.validate().unwrap_err();
            assert_eq!(e.key, "peer_silence_s", "{bad}");
            assert!(e.reason.contains("0.5 <= peer_silence_s <= 600"), "{e}");
        }
        for (c, key) in [
            (
                MavlinkConfig {
                    position_sigma_floor_m: -0.001,
                    ..Default::default()
                },
                "position_sigma_floor_m",
            ),
            (
                MavlinkConfig {
                    angle_sigma_floor_deg: f64::NAN,
                    ..Default::default()
                },
                "angle_sigma_floor_deg",
            ),
        ] {
            assert_eq!(c.validate().unwrap_err().key, key);
        }
        let c = MavlinkConfig {
            signing_required: true,
            ..Default::default()
        };
        assert_eq!(c.validate().unwrap_err().key, "signing_required");
        let c = MavlinkConfig {
            autopilot_system_ids: vec![1, 0],
            ..Default::default()
        };
        let e = c.validate().unwrap_err();
        assert_eq!(e.key, "autopilot_system_ids");
        assert!(e.reason.contains("[1, 0]"), "{e}");
        let c = MavlinkConfig {
            connection: "udp:1.2.3.4".into(),
            ..Default::default()
        };
        let e = c.validate().unwrap_err();
        assert_eq!(e.key, "connection");
        assert!(e.reason.contains("udp:1.2.3.4"), "{e}");
        assert!(
            std::error::Error::source(&e).is_some(),
            "keeps the parser's error"
        );
    }

    #[test]
    fn interval_from_rate() {
        let c = MavlinkConfig::default();
        assert_eq!(c.min_interval_ns(), 20_000_000);
        assert_eq!(c.min_usec_spacing_ns(), 20_000_000);
        let px4 = MavlinkConfig {
            rate_hz: 90.0,
            autopilot_min_interval_ms: 11.0,
            ..Default::default()
        };
        assert_eq!(px4.min_usec_spacing_ns(), 11_000_000);
        let off = MavlinkConfig {
            autopilot_min_interval_ms: 0.0,
            ..Default::default()
        };
        off.validate()
            .expect("0 = no spacing beyond the rate cap's");
        assert_eq!(off.min_usec_spacing_ns(), 10_000_000);
        let bad = MavlinkConfig {
            autopilot_min_interval_ms: -1.0,
            ..Default::default()
        };
        assert_eq!(bad.validate().unwrap_err().key, "autopilot_min_interval_ms");
    }
}
