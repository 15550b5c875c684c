//! Camera orientation from a viewing direction: the look-at construction
//! for the camera optical frame (x right, y down, z forward) in a z-up world.
//!
//! Takes yaw (about world +z, 0 = looking along +x, positive turns toward
//! +y), pitch (elevation of the optical axis, positive looks up) and roll
//! (about the optical axis, positive turns the image clockwise as seen by the
//! camera); gives the rotation part of `world_from_camera`.

use nalgebra::{Matrix3, Rotation3, UnitQuaternion, Vector3};

/// The world's up direction (the synthetic scene is z-up).
pub fn world_up() -> Vector3<f64> {
    Vector3::z()
}

/// The optical-axis direction (camera +z) in the world for `yaw` and `pitch`.
pub fn forward_from_yaw_pitch(yaw_rad: f64, pitch_rad: f64) -> Vector3<f64> {
    Vector3::new(
        pitch_rad.cos() * yaw_rad.cos(),
        pitch_rad.cos() * yaw_rad.sin(),
        pitch_rad.sin(),
    )
}

/// `world_from_camera` rotation of a camera looking along `forward_w` with
/// image "up" toward `up_w`: camera z = forward, camera x (right) =
/// forward x up, camera y (down) = forward x right. `None` when `forward_w`
/// is zero, not finite, or parallel to `up_w`.
pub fn look_rotation(forward_w: &Vector3<f64>, up_w: &Vector3<f64>) -> Option<UnitQuaternion<f64>> {
    let z = forward_w.try_normalize(1e-12)?;
    let x = z.cross(up_w).try_normalize(1e-9)?;
    let y = z.cross(&x);
    let m = Matrix3::from_columns(&[x, y, z]);
    m.iter()
        .all(|v| v.is_finite())
        .then(|| UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(m)))
}

/// `world_from_camera` rotation for yaw, pitch (|pitch| < 90 degrees) and
/// roll, all in radians.
pub fn camera_rotation(yaw_rad: f64, pitch_rad: f64, roll_rad: f64) -> UnitQuaternion<f64> {
    let forward = forward_from_yaw_pitch(yaw_rad, pitch_rad);
    // For |pitch| < 90 degrees the forward vector is never parallel to up.
    let level = look_rotation(&forward, &world_up()).unwrap_or_else(UnitQuaternion::identity);
    level * UnitQuaternion::from_axis_angle(&Vector3::z_axis(), roll_rad)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{PinholeCamera, Pose};
    use nalgebra::{Point3, Translation3, Vector2};

    fn project(pose: &Pose, p_world: Vector3<f64>) -> Vector2<f64> {
        let cam = PinholeCamera::new(640, 512, 420.0, 420.0, 319.5, 255.5);
        let p_camera = pose.inverse_transform_point(&Point3::from(p_world));
        cam.project(&p_camera.coords)
            .expect("in front of the camera")
    }

    #[test]
    fn look_at_puts_target_at_principal_point_and_up_at_top() {
        let eye = Vector3::new(1.0, 2.0, 1.5);
        for (yaw_deg, pitch_deg) in [(0.0, 0.0), (90.0, 10.0), (-135.0, -25.0), (200.0, 29.0)] {
            let (yaw, pitch) = (f64::to_radians(yaw_deg), f64::to_radians(pitch_deg));
            let pose = Pose::from_parts(Translation3::from(eye), camera_rotation(yaw, pitch, 0.0));
            let f = forward_from_yaw_pitch(yaw, pitch);
            let center = project(&pose, eye + 3.0 * f);
            assert!((center - Vector2::new(319.5, 255.5)).norm() < 1e-9);
            // A point above the target (world +z) is above the image center (smaller v).
            let above = project(&pose, eye + 3.0 * f + Vector3::new(0.0, 0.0, 0.5));
            assert!(
                above.y < 255.5 - 10.0 && (above.x - 319.5).abs() < 1e-6,
                "{above:?}"
            );
            // A point to the camera's left (world up x forward) is left in the image.
            let left_w = world_up().cross(&f).normalize();
            let left = project(&pose, eye + 3.0 * f + 0.5 * left_w);
            assert!(
                left.x < 319.5 - 10.0 && (left.y - 255.5).abs() < 1e-6,
                "{left:?}"
            );
        }
    }

    #[test]
    fn yaw_zero_looks_along_x_and_rotation_is_proper() {
        let r = camera_rotation(0.0, 0.0, 0.0);
        assert!(
            (r * Vector3::z() - Vector3::x()).norm() < 1e-12,
            "optical axis along +x"
        );
        assert!(
            (r * Vector3::x() - (-Vector3::y())).norm() < 1e-12,
            "image right is -y"
        );
        assert!(
            (r * Vector3::y() - (-Vector3::z())).norm() < 1e-12,
            "image down is -z"
        );
        let m = r.to_rotation_matrix();
        assert!((m.matrix().determinant() - 1.0).abs() < 1e-12);
    }

    #[test]
    fn roll_rotates_about_the_optical_axis() {
        let r0 = camera_rotation(0.3, 0.1, 0.0);
        let r = camera_rotation(0.3, 0.1, 0.2);
        assert!((r * Vector3::z() - r0 * Vector3::z()).norm() < 1e-12);
        assert!(((r0.inverse() * r).angle() - 0.2).abs() < 1e-12);
        assert!(look_rotation(&Vector3::z(), &world_up()).is_none());
        assert!(look_rotation(&Vector3::zeros(), &world_up()).is_none());
    }
}
