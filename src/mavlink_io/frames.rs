//! Frame conversion from the tracker's `world_from_camera` to what the
//! autopilot wants: the body (FRD) pose in local NED, as position, Euler angles
//! and quaternion, and the pose covariance in MAVLink's state order.
//!
//! Takes `ned_from_world` and `body_from_camera` (from the config) and, per
//! sample, `world_from_camera` with its covariance; gives out [`NedPose`] and
//! the 6x6 covariance of `(x, y, z, roll, pitch, yaw)`.
//!
//! The sent pose is `ned_from_body = ned_from_world * world_from_camera *
//! inverse(body_from_camera)` (DESIGN.md "Conventions").
//!
//! Covariance, exactly:
//! - Input: the covariance of the twist `xi = [v; w]` (meters, radians) that
//!   perturbs `world_from_camera` on the left, in the world frame:
//!   `world_from_camera_true = exp(xi) * world_from_camera`. A tracker with a
//!   right (camera-frame) perturbation converts with
//!   [`twist_covariance_world_from_camera`].
//! - Output: the covariance of MAVLink's pose states, in the order
//!   `x, y, z, roll, pitch, yaw`:
//!   - rows/columns 0..3 (position block, m^2): the body origin's position in
//!     local NED;
//!   - rows/columns 3..6 (attitude block, rad^2): the Z-Y-X Euler angles
//!     (roll, pitch, yaw) of `ned_from_body`, as the message fields are; near
//!     level flight they equal small rotations about NED north, east, down;
//!   - the off-diagonal 3x3 blocks (m rad) correlate the two.
//! - Propagation, first order: `Sigma_out = J * Sigma_in * J^T` with
//!   `J = [[I, -hat(p_ned_body)], [0, E^-1]] * Ad(ned_from_world)`, where `E`
//!   maps Euler-angle rates to angular velocity in NED.
//!   Near pitch +-90 deg (gimbal lock) `cos(pitch)` is clamped to 1e-3.
//! - Wire format: [`upper_triangle`], row-major, 21 floats; the diagonal is at
//!   indices 0, 6, 11, 15, 18, 20.

use nalgebra::{Matrix3, Matrix6, Vector3};

use crate::geometry::{adjoint, hat, Pose};

/// Indices of the diagonal in the 21-float upper triangle.
pub const UPPER_TRIANGLE_DIAGONAL: [usize; 6] = [0, 6, 11, 15, 18, 20];

/// Smallest `|cos(pitch)|` used in the Euler-rate inverse.
const MIN_COS_PITCH: f64 = 1e-3;

/// The body pose in local NED, in the forms the messages need.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NedPose {
    /// The body (FRD) pose in local NED.
    pub ned_from_body: Pose,
    /// Roll, rad (Z-Y-X Euler angles of `ned_from_body`).
    pub roll_rad: f64,
    /// Pitch, rad, in [-pi/2, pi/2].
    pub pitch_rad: f64,
    /// Yaw, rad, in (-pi, pi]; 0 = north, +pi/2 = east.
    pub yaw_rad: f64,
}

impl NedPose {
    /// Position of the body origin in NED, meters.
    pub fn position_ned_m(&self) -> Vector3<f64> {
        self.ned_from_body.translation.vector
    }

    /// Attitude quaternion `[w, x, y, z]`, NED from body (ODOMETRY `q`).
    pub fn quaternion_wxyz(&self) -> [f64; 4] {
        let q = self.ned_from_body.rotation;
        [q.w, q.i, q.j, q.k]
    }
}

/// Converts tracker poses into the autopilot's frames.
#[derive(Debug, Clone, Copy)]
pub struct FrameConverter {
    ned_from_world: Pose,
    camera_from_body: Pose,
    ned_from_world_adjoint: Matrix6<f64>,
}

impl FrameConverter {
    /// A converter for a map placed at `ned_from_world` and a camera mounted at
    /// `body_from_camera`.
    pub fn new(ned_from_world: Pose, body_from_camera: Pose) -> Self {
        Self {
            ned_from_world,
            camera_from_body: body_from_camera.inverse(),
            ned_from_world_adjoint: adjoint(&ned_from_world),
        }
    }

    /// `ned_from_body = ned_from_world * world_from_camera * camera_from_body`.
    pub fn ned_pose(&self, world_from_camera: &Pose) -> NedPose {
        let ned_from_body = self.ned_from_world * world_from_camera * self.camera_from_body;
        let (roll_rad, pitch_rad, yaw_rad) = ned_from_body.rotation.euler_angles();
        NedPose {
            ned_from_body,
            roll_rad,
            pitch_rad,
            yaw_rad,
        }
    }

    /// The covariance of `(x, y, z, roll, pitch, yaw)` (see the module docs)
    /// from the covariance of the left world-frame twist of `world_from_camera`.
    pub fn pose_covariance(
        &self,
        pose: &NedPose,
        twist_covariance_world: &Matrix6<f64>,
    ) -> Matrix6<f64> {
        let jacobian = self.state_jacobian(pose);
        jacobian * twist_covariance_world * jacobian.transpose()
    }

    /// `d(x, y, z, roll, pitch, yaw) / d(xi_world)` at `pose`.
    pub fn state_jacobian(&self, pose: &NedPose) -> Matrix6<f64> {
        let p = pose.position_ned_m();
        let mut local = Matrix6::<f64>::identity();
        local.fixed_view_mut::<3, 3>(0, 3).copy_from(&(-hat(&p)));
        local
            .fixed_view_mut::<3, 3>(3, 3)
            .copy_from(&euler_rates_from_angular_velocity(
                pose.pitch_rad,
                pose.yaw_rad,
            ));
        local * self.ned_from_world_adjoint
    }
}

/// `E^-1`: Z-Y-X Euler-angle rates `(roll, pitch, yaw)` from an angular
/// velocity expressed in the fixed (NED) frame.
fn euler_rates_from_angular_velocity(pitch_rad: f64, yaw_rad: f64) -> Matrix3<f64> {
    let (sp, cp) = pitch_rad.sin_cos();
    let (sy, cy) = yaw_rad.sin_cos();
    let cp = if cp.abs() < MIN_COS_PITCH {
        MIN_COS_PITCH.copysign(cp)
    } else {
        cp
    };
    Matrix3::new(
        cy / cp,
        sy / cp,
        0.0,
        -sy,
        cy,
        0.0,
        sp * cy / cp,
        sp * sy / cp,
        1.0,
    )
}

/// Converts the covariance of a right (camera-frame) twist,
/// `world_from_camera * exp(xi_camera)`, into the left world-frame twist
/// covariance that [`FrameConverter::pose_covariance`] takes.
pub fn twist_covariance_world_from_camera(
    world_from_camera: &Pose,
    covariance_camera: &Matrix6<f64>,
) -> Matrix6<f64> {
    let ad = adjoint(world_from_camera);
    ad * covariance_camera * ad.transpose()
}

/// Raises the variances of `(x, y, z)` to at least `position_sigma_m^2` and
/// those of `(roll, pitch, yaw)` to at least `angle_sigma_rad^2`: adds a
/// non-negative diagonal, so a positive semi-definite matrix stays one and
/// the correlations the tracker measured are kept. A matrix with a
/// non-finite entry ("unknown") is left alone.
pub fn floor_variances(covariance: &mut Matrix6<f64>, position_sigma_m: f64, angle_sigma_rad: f64) {
    if covariance.iter().any(|v| !v.is_finite()) {
        return;
    }
    for i in 0..6 {
        let sigma = if i < 3 {
            position_sigma_m
        } else {
            angle_sigma_rad
        };
        let floor = sigma * sigma;
        if covariance[(i, i)] < floor {
            covariance[(i, i)] = floor;
        }
    }
}

/// Row-major upper triangle of a symmetric 6x6 matrix, as MAVLink sends it
/// (21 floats, diagonal at [`UPPER_TRIANGLE_DIAGONAL`]). A matrix with a
/// non-finite entry becomes "unknown": NaN in the first element.
pub fn upper_triangle(covariance: &Matrix6<f64>) -> [f32; 21] {
    let mut out = [0.0f32; 21];
    if covariance.iter().any(|v| !v.is_finite()) {
        out[0] = f32::NAN;
        return out;
    }
    let mut k = 0;
    for row in 0..6 {
        for col in row..6 {
            out[k] = covariance[(row, col)] as f32;
            k += 1;
        }
    }
    out
}

#[cfg(test)]
#[path = "frames_tests.rs"]
mod tests;
