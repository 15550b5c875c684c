//! The pose message the tracker publishes on the pose service.
//!
//! Owns the `#[repr(C)]` wire layout [`PoseMsg`] and its conversion from and
//! to the crate's [`Pose`](crate::geometry::Pose) (`world_from_camera`). Takes
//! in a tracker result, gives out a fixed-size message any process can read in
//! place.

use iceoryx2::prelude::ZeroCopySend;
use nalgebra::{Quaternion, Translation3, UnitQuaternion};

use crate::geometry::Pose;

/// Tracker state carried in [`PoseMsg::state`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u32)]
pub enum TrackingState {
    /// Tracking normally; the pose is valid.
    Tracking = 1,
    /// Lost; the pose is the last valid one and must not be used for control.
    Lost = 2,
    /// Just relocalized; the pose jumped and `reset_counter` was incremented.
    Relocalized = 3,
}

impl TrackingState {
    /// The state for a wire code, `None` when unknown.
    pub fn from_code(code: u32) -> Option<Self> {
        match code {
            1 => Some(Self::Tracking),
            2 => Some(Self::Lost),
            3 => Some(Self::Relocalized),
            _ => None,
        }
    }
}

/// One pose estimate. Plain numbers only, so any bit pattern is readable.
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[repr(C)]
#[type_name("star::PoseMsg")]
pub struct PoseMsg {
    /// Capture time of the frame this pose belongs to, CLOCK_MONOTONIC ns.
    pub capture_ns: u64,
    /// Sequence number of that frame.
    pub frame_sequence: u64,
    /// `world_from_camera` translation, meters (x, y, z).
    pub translation_m: [f64; 3],
    /// `world_from_camera` rotation as a unit quaternion, TUM order (x, y, z, w).
    pub rotation_xyzw: [f64; 4],
    /// Upper triangle, row-major, of the 6x6 covariance of
    /// (x, y, z, roll, pitch, yaw); diagonal at indices 0, 6, 11, 15, 18, 20.
    pub covariance: [f32; 21],
    /// Fraction of keyframe points that were inliers, 0..=1.
    pub inlier_ratio: f32,
    /// Mean photometric residual of the inliers, gray levels.
    pub mean_residual: f32,
    /// Fraction of keyframe points visible in the frame, 0..=1.
    pub visible_fraction: f32,
    /// [`TrackingState`] code.
    pub state: u32,
    /// Incremented at every relocalization or other pose jump (MAVLink `reset_counter`).
    pub reset_counter: u32,
}

impl PoseMsg {
    /// Builds a message from a `world_from_camera` pose; quality fields zero,
    /// covariance zero.
    pub fn new(
        capture_ns: u64,
        frame_sequence: u64,
        world_from_camera: &Pose,
        state: TrackingState,
    ) -> Self {
        let t = world_from_camera.translation.vector;
        let q = world_from_camera.rotation.quaternion();
        Self {
            capture_ns,
            frame_sequence,
            translation_m: [t.x, t.y, t.z],
            rotation_xyzw: [q.i, q.j, q.k, q.w],
            covariance: [0.0; 21],
            inlier_ratio: 0.0,
            mean_residual: 0.0,
            visible_fraction: 0.0,
            state: state as u32,
            reset_counter: 0,
        }
    }

    /// The `world_from_camera` pose (the quaternion is renormalized).
    pub fn world_from_camera(&self) -> Pose {
        let [x, y, z, w] = self.rotation_xyzw;
        let rotation = UnitQuaternion::from_quaternion(Quaternion::new(w, x, y, z));
        let [tx, ty, tz] = self.translation_m;
        Pose::from_parts(Translation3::new(tx, ty, tz), rotation)
    }

    /// The decoded state, `None` for an unknown code.
    pub fn tracking_state(&self) -> Option<TrackingState> {
        TrackingState::from_code(self.state)
    }

    /// Index into [`PoseMsg::covariance`] of element (row, col), `row <= col < 6`.
    pub fn covariance_index(row: usize, col: usize) -> Option<usize> {
        (row <= col && col < 6).then(|| row * 6 - row * (row.saturating_sub(1)) / 2 + col - row)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    #[test]
    fn pose_round_trips() {
        let pose = Pose::from_parts(
            Translation3::new(1.0, -2.0, 0.5),
            UnitQuaternion::from_scaled_axis(Vector3::new(0.1, -0.3, 0.7)),
        );
        let msg = PoseMsg::new(42, 7, &pose, TrackingState::Tracking);
        let back = msg.world_from_camera();
        assert!((back.translation.vector - pose.translation.vector).norm() < 1e-12);
        assert!(back.rotation.angle_to(&pose.rotation) < 1e-12);
        assert_eq!(msg.tracking_state(), Some(TrackingState::Tracking));
    }

    #[test]
    fn unknown_state_is_none() {
        let mut msg = PoseMsg::new(0, 0, &Pose::identity(), TrackingState::Lost);
        msg.state = 99;
        assert_eq!(msg.tracking_state(), None);
    }

    #[test]
    fn covariance_diagonal_indices_match_mavlink() {
        let diag: Vec<usize> = (0..6)
            .map(|i| PoseMsg::covariance_index(i, i).expect("diagonal"))
            .collect();
        assert_eq!(diag, vec![0, 6, 11, 15, 18, 20]);
        assert_eq!(PoseMsg::covariance_index(0, 5), Some(5));
        assert_eq!(PoseMsg::covariance_index(1, 2), Some(7));
        assert_eq!(PoseMsg::covariance_index(2, 1), None);
        assert_eq!(PoseMsg::covariance_index(0, 6), None);
    }
}
