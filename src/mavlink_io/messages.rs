//! The messages this link sends, built from converted poses: pure functions,
//! no I/O.
//!
//! Takes a [`NedPose`], its `(x, y, z, roll, pitch, yaw)` covariance, a
//! timestamp and a reset counter; gives out `common::MavMessage` values for
//! VISION_POSITION_ESTIMATE (102), ODOMETRY (331), HEARTBEAT (0) and
//! TIMESYNC (111).

use mavlink::dialects::common::{
    MavAutopilot, MavEstimatorType, MavFrame, MavMessage, MavModeFlag, MavState, MavType,
    HEARTBEAT_DATA, ODOMETRY_DATA, TIMESYNC_DATA, VISION_POSITION_ESTIMATE_DATA,
};
use nalgebra::Matrix6;

use crate::mavlink_io::frames::{upper_triangle, NedPose};

/// What the HEARTBEAT reports.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LinkState {
    /// No tracked pose yet.
    Standby,
    /// Tracking: poses are going out.
    Active,
    /// Lost after having tracked: nothing is sent until tracking resumes.
    Lost,
}

/// VISION_POSITION_ESTIMATE: NED position, Euler angles, covariance.
pub fn vision_position_estimate(
    usec: u64,
    pose: &NedPose,
    covariance: &Matrix6<f64>,
    reset_counter: u8,
) -> MavMessage {
    let p = pose.position_ned_m();
    MavMessage::VISION_POSITION_ESTIMATE(VISION_POSITION_ESTIMATE_DATA {
        usec,
        x: p.x as f32,
        y: p.y as f32,
        z: p.z as f32,
        roll: pose.roll_rad as f32,
        pitch: pose.pitch_rad as f32,
        yaw: pose.yaw_rad as f32,
        covariance: upper_triangle(covariance),
        reset_counter,
    })
}

/// ODOMETRY: pose in MAV_FRAME_LOCAL_FRD (`frame_id` 20), velocities
/// unknown (NaN) in MAV_FRAME_BODY_FRD (`child_frame_id` 12),
/// `estimator_type` VISION, `quality` 0..=100 percent.
///
/// ArduPilot takes ODOMETRY only with exactly these two frames (it ignores
/// MAV_FRAME_LOCAL_NED); PX4 accepts LOCAL_NED and LOCAL_FRD alike (LOCAL_FRD
/// as a pose frame whose heading is not necessarily north). The values are
/// the same as in NED: our local FRD frame is the NED frame that
/// `ned_from_world` defines (x forward = north, y right = east, z down), so
/// the position and the quaternion are those of [`NedPose`] unchanged.
pub fn odometry(
    time_usec: u64,
    pose: &NedPose,
    covariance: &Matrix6<f64>,
    reset_counter: u8,
    quality_percent: u8,
) -> MavMessage {
    let p = pose.position_ned_m();
    let [w, x, y, z] = pose.quaternion_wxyz();
    let mut velocity_covariance = [0.0f32; 21];
    velocity_covariance[0] = f32::NAN;
    MavMessage::ODOMETRY(ODOMETRY_DATA {
        time_usec,
        x: p.x as f32,
        y: p.y as f32,
        z: p.z as f32,
        q: [w as f32, x as f32, y as f32, z as f32],
        vx: f32::NAN,
        vy: f32::NAN,
        vz: f32::NAN,
        rollspeed: f32::NAN,
        pitchspeed: f32::NAN,
        yawspeed: f32::NAN,
        pose_covariance: upper_triangle(covariance),
        velocity_covariance,
        frame_id: MavFrame::MAV_FRAME_LOCAL_FRD,
        child_frame_id: MavFrame::MAV_FRAME_BODY_FRD,
        reset_counter,
        estimator_type: MavEstimatorType::MAV_ESTIMATOR_TYPE_VISION,
        quality: quality_percent.min(100) as i8,
    })
}

/// HEARTBEAT of an onboard controller that is not an autopilot.
pub fn heartbeat(state: LinkState) -> MavMessage {
    let system_status = match state {
        LinkState::Standby => MavState::MAV_STATE_STANDBY,
        LinkState::Active => MavState::MAV_STATE_ACTIVE,
        LinkState::Lost => MavState::MAV_STATE_CRITICAL,
    };
    MavMessage::HEARTBEAT(HEARTBEAT_DATA {
        custom_mode: 0,
        mavtype: MavType::MAV_TYPE_ONBOARD_CONTROLLER,
        autopilot: MavAutopilot::MAV_AUTOPILOT_INVALID,
        base_mode: MavModeFlag::empty(),
        system_status,
        mavlink_version: 3,
    })
}

/// A TIMESYNC message (both directions use the same layout).
pub fn timesync(tc1: i64, ts1: i64, target_system: u8, target_component: u8) -> MavMessage {
    MavMessage::TIMESYNC(TIMESYNC_DATA {
        tc1,
        ts1,
        target_system,
        target_component,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Pose;
    use crate::mavlink_io::frames::FrameConverter;
    use mavlink::{MAVLinkV2MessageRaw, MavHeader, Message};
    use nalgebra::Vector6;

    fn roundtrip(msg: &MavMessage) -> MavMessage {
        let mut raw = MAVLinkV2MessageRaw::new();
        let header = MavHeader {
            system_id: 1,
            component_id: 197,
            sequence: 3,
        };
        raw.serialize_message(header, msg);
        assert!(raw.has_valid_crc::<MavMessage>());
        MavMessage::parse(mavlink::MavlinkVersion::V2, raw.message_id(), raw.payload()).unwrap()
    }

    fn level_pose() -> NedPose {
        FrameConverter::new(Pose::identity(), Pose::identity())
            .ned_pose(&Pose::translation(1.0, 2.0, -3.0))
    }

    #[test]
    fn vision_position_estimate_survives_the_wire() {
        let cov = Matrix6::from_diagonal(&Vector6::new(0.1, 0.2, 0.3, 0.4, 0.5, 0.6));
        let msg = vision_position_estimate(123_456, &level_pose(), &cov, 7);
        let MavMessage::VISION_POSITION_ESTIMATE(d) = roundtrip(&msg) else {
            panic!("wrong message back");
        };
        assert_eq!(
            (d.usec, d.x, d.y, d.z, d.reset_counter),
            (123_456, 1.0, 2.0, -3.0, 7)
        );
        assert_eq!(d.covariance[15], 0.4);
        assert_eq!(d.covariance[20], 0.6);
    }

    #[test]
    fn odometry_has_vision_estimator_and_frames() {
        let msg = odometry(5, &level_pose(), &Matrix6::identity(), 2, 250);
        assert_eq!(msg.message_id(), 331);
        let MavMessage::ODOMETRY(d) = roundtrip(&msg) else {
            panic!("wrong message back");
        };
        assert_eq!(
            d.estimator_type,
            MavEstimatorType::MAV_ESTIMATOR_TYPE_VISION
        );
        assert_eq!(d.frame_id, MavFrame::MAV_FRAME_LOCAL_FRD);
        assert_eq!(d.frame_id as u8, 20, "what ArduPilot requires");
        assert_eq!(d.child_frame_id as u8, 12);
        assert_eq!(d.child_frame_id, MavFrame::MAV_FRAME_BODY_FRD);
        assert_eq!(d.quality, 100, "clamped");
        assert_eq!(d.q, [1.0, 0.0, 0.0, 0.0]);
        assert!(d.vx.is_nan() && d.velocity_covariance[0].is_nan());
        assert_eq!(d.reset_counter, 2);
    }

    #[test]
    fn heartbeat_is_onboard_controller() {
        let MavMessage::HEARTBEAT(d) = roundtrip(&heartbeat(LinkState::Lost)) else {
            panic!("wrong message back");
        };
        assert_eq!(d.mavtype, MavType::MAV_TYPE_ONBOARD_CONTROLLER);
        assert_eq!(d.autopilot, MavAutopilot::MAV_AUTOPILOT_INVALID);
        assert_eq!(d.system_status, MavState::MAV_STATE_CRITICAL);
    }
}
