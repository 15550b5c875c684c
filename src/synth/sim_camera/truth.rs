//! The simulated vehicle's true state, from ArduPilot SITL's SIM_STATE
//! (MAVLink 108), in the local NED frame of a geodetic origin.
//!
//! Takes a SIM_STATE and the origin; gives out [`VehicleState`]: the body
//! (FRD) pose in local NED, the NED velocity and the body rates, and the
//! pose extrapolated a few milliseconds on (the camera's capture instants
//! fall between SIM_STATE samples).
//!
//! Resolution: SIM_STATE's float `lat`/`lon` are degrees times 1e7 in an
//! `f32` (3.5 cm steps at Canberra), so the extension fields `lat_int` /
//! `lon_int` (1e-7 degree, 1.1 cm north, 0.9 cm east there) are used; the
//! altitude is an `f32` of meters above sea level (0.06 mm steps at 600 m).
//! Geodetic offsets use ArduPilot's own flat-earth conversion
//! (`Location::get_distance_NE`), which is what the SITL integrates with.

use nalgebra::{Quaternion, Translation3, UnitQuaternion, Vector3};

use crate::camera::GeoPoint;
use crate::geometry::Pose;
use mavlink::dialects::common::SIM_STATE_DATA;

/// Meters per 1e-7 degree of latitude (ArduPilot's
/// `LOCATION_SCALING_FACTOR`).
pub const M_PER_DEG_E7: f64 = 0.011_131_884_502_145_034;

/// Why a SIM_STATE cannot be used.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum StateError {
    /// A field is NaN or infinite.
    #[error("SIM_STATE field `{field}` is not finite")]
    NotFinite {
        /// The field.
        field: &'static str,
    },
    /// The attitude quaternion is far from unit length.
    #[error("SIM_STATE quaternion has norm {norm}, expected 1")]
    Quaternion {
        /// Its norm.
        norm: f64,
    },
    /// The position is outside the earth's coordinates (also: `lat_int` and
    /// `lon_int` are zero when the sender has no MAVLink 2 extensions).
    #[error("SIM_STATE position lat {lat_deg} deg, lon {lon_deg} deg is not a position")]
    Position {
        /// Latitude, degrees.
        lat_deg: f64,
        /// Longitude, degrees.
        lon_deg: f64,
    },
}

/// The vehicle's true state at one instant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VehicleState {
    /// The body (FRD) pose in local NED, meters.
    pub ned_from_body: Pose,
    /// Velocity in NED, m/s.
    pub velocity_ned_mps: Vector3<f64>,
    /// Angular rate in the body frame, rad/s.
    pub rate_body_rps: Vector3<f64>,
}

/// The geodetic position in a SIM_STATE (`lat_int`, `lon_int`, `alt`).
pub fn position_of(m: &SIM_STATE_DATA) -> Result<GeoPoint, StateError> {
    let p = GeoPoint {
        lat_deg: f64::from(m.lat_int) * 1e-7,
        lon_deg: f64::from(m.lon_int) * 1e-7,
        alt_m: f64::from(m.alt),
    };
    if !p.alt_m.is_finite() {
        return Err(StateError::NotFinite { field: "alt" });
    }
    let on_earth = p.lat_deg.abs() <= 90.0 && p.lon_deg.abs() <= 180.0;
    if !on_earth || (m.lat_int == 0 && m.lon_int == 0) {
        return Err(StateError::Position {
            lat_deg: p.lat_deg,
            lon_deg: p.lon_deg,
        });
    }
    Ok(p)
}

/// `p` in the local NED frame at `origin`, meters (ArduPilot's flat earth:
/// the longitude scale at the mean latitude).
pub fn ned_offset_m(origin: &GeoPoint, p: &GeoPoint) -> Vector3<f64> {
    let north_m = (p.lat_deg - origin.lat_deg) * 1e7 * M_PER_DEG_E7;
    let mut dlon_deg = p.lon_deg - origin.lon_deg;
    if dlon_deg > 180.0 {
        dlon_deg -= 360.0;
    } else if dlon_deg < -180.0 {
        dlon_deg += 360.0;
    }
    let scale = (0.5 * (p.lat_deg + origin.lat_deg))
        .to_radians()
        .cos()
        .max(0.01);
    let east_m = dlon_deg * 1e7 * M_PER_DEG_E7 * scale;
    Vector3::new(north_m, east_m, origin.alt_m - p.alt_m)
}

impl VehicleState {
    /// The state in `m`, in the local NED frame at `origin`.
    pub fn from_sim_state(m: &SIM_STATE_DATA, origin: &GeoPoint) -> Result<Self, StateError> {
        let fields = [
            ("q1", m.q1),
            ("q2", m.q2),
            ("q3", m.q3),
            ("q4", m.q4),
            ("vn", m.vn),
            ("ve", m.ve),
            ("vd", m.vd),
            ("xgyro", m.xgyro),
            ("ygyro", m.ygyro),
            ("zgyro", m.zgyro),
        ];
        if let Some((field, _)) = fields.iter().find(|(_, v)| !v.is_finite()) {
            return Err(StateError::NotFinite { field });
        }
        // q1..q4 = w, x, y, z of the body-to-NED rotation.
        let q = Quaternion::new(
            f64::from(m.q1),
            f64::from(m.q2),
            f64::from(m.q3),
            f64::from(m.q4),
        );
        let norm = q.norm();
        if (norm - 1.0).abs() > 0.01 {
            return Err(StateError::Quaternion { norm });
        }
        let position_ned_m = ned_offset_m(origin, &position_of(m)?);
        Ok(Self {
            ned_from_body: Pose::from_parts(
                Translation3::from(position_ned_m),
                UnitQuaternion::from_quaternion(q),
            ),
            velocity_ned_mps: Vector3::new(f64::from(m.vn), f64::from(m.ve), f64::from(m.vd)),
            rate_body_rps: Vector3::new(f64::from(m.xgyro), f64::from(m.ygyro), f64::from(m.zgyro)),
        })
    }

    /// The body pose `dt_s` after this state (negative: before), at
    /// constant NED velocity and constant body rate.
    pub fn ned_from_body_after(&self, dt_s: f64) -> Pose {
        let translation = self.ned_from_body.translation.vector + self.velocity_ned_mps * dt_s;
        let rotation = self.ned_from_body.rotation
            * UnitQuaternion::from_scaled_axis(self.rate_body_rps * dt_s);
        Pose::from_parts(Translation3::from(translation), rotation)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const HOME: GeoPoint = GeoPoint {
        lat_deg: -35.363_261,
        lon_deg: 149.165_23,
        alt_m: 584.0,
    };

    fn sim_state(lat_int: i32, lon_int: i32, alt: f32) -> SIM_STATE_DATA {
        SIM_STATE_DATA {
            q1: 1.0,
            lat_int,
            lon_int,
            alt,
            ..SIM_STATE_DATA::default()
        }
    }

    #[test]
    fn offsets_follow_ardupilots_flat_earth() {
        let state = VehicleState::from_sim_state(
            &sim_state(-353_632_610 + 90, 1_491_652_300 + 100, 586.5),
            &HOME,
        )
        .expect("state");
        let p = state.ned_from_body.translation.vector;
        // 90 steps of 1e-7 deg north, 100 east (scaled by cos(lat)).
        assert!((p.x - 90.0 * M_PER_DEG_E7).abs() < 1e-6, "{p}");
        let east = 100.0 * M_PER_DEG_E7 * (-35.363_26f64).to_radians().cos();
        assert!((p.y - east).abs() < 1e-5, "{p}");
        assert!((p.z + 2.5).abs() < 1e-6, "up is negative down: {p}");
        // One step of lat_int is about 1.1 cm.
        assert!((M_PER_DEG_E7 - 0.0111).abs() < 1e-4);
    }

    #[test]
    fn the_quaternion_is_body_to_ned() {
        // Yaw 90 deg: the body's x (forward) points east.
        let half = std::f32::consts::FRAC_PI_4;
        let m = SIM_STATE_DATA {
            q1: half.cos(),
            q4: half.sin(),
            ..sim_state(-353_632_610, 1_491_652_300, 584.0)
        };
        let state = VehicleState::from_sim_state(&m, &HOME).expect("state");
        let forward_ned = state.ned_from_body.rotation * Vector3::x();
        assert!((forward_ned - Vector3::y()).norm() < 1e-6, "{forward_ned}");
    }

    #[test]
    fn extrapolates_at_constant_velocity_and_rate() {
        let m = SIM_STATE_DATA {
            vn: 0.5,
            vd: -0.2,
            zgyro: 0.1,
            ..sim_state(-353_632_610, 1_491_652_300, 584.0)
        };
        let state = VehicleState::from_sim_state(&m, &HOME).expect("state");
        let later = state.ned_from_body_after(0.02);
        let moved = later.translation.vector - state.ned_from_body.translation.vector;
        assert!(
            (moved - Vector3::new(0.01, 0.0, -0.004)).norm() < 1e-9,
            "{moved}"
        );
        let yawed = (state.ned_from_body.rotation.inverse() * later.rotation).angle();
        assert!((yawed - 0.002).abs() < 1e-9);
        assert_eq!(state.ned_from_body_after(0.0), state.ned_from_body);
    }

    #[test]
    fn rejects_unusable_states() {
        let good = sim_state(-353_632_610, 1_491_652_300, 584.0);
        let cases = [
            (
                SIM_STATE_DATA {
                    vn: f32::NAN,
                    ..good
                },
                "vn",
            ),
            (SIM_STATE_DATA { q1: 0.5, ..good }, "norm"),
            (sim_state(0, 0, 584.0), "not a position"),
            (sim_state(-953_632_610, 0, 584.0), "not a position"),
            (sim_state(1, 1, f32::INFINITY), "alt"),
        ];
        for (m, why) in cases {
            let err = VehicleState::from_sim_state(&m, &HOME).expect_err(why);
            assert!(err.to_string().contains(why), "{err}");
        }
    }
}
