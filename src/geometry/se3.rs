//! SE(3) exponential and logarithm on top of nalgebra's `Isometry3<f64>`.
//!
//! A twist is `xi = [v; w]`: translation part first, rotation part second
//! (the Sophus/DSO ordering). `exp_se3(xi)` is the rigid transform
//! `exp(hat(xi))`; `log_se3` is its inverse on the principal branch
//! (rotation angle in `[0, pi]`).

use nalgebra::{Isometry3, Matrix3, Matrix6, Translation3, UnitQuaternion, Vector3, Vector6};

/// A rigid transform. Named after what it maps: `world_from_camera`.
pub type Pose = Isometry3<f64>;

/// The skew-symmetric matrix of `w`, so that `hat(w) * p == w.cross(p)`.
pub fn hat(w: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -w.z, w.y, w.z, 0.0, -w.x, -w.y, w.x, 0.0)
}

/// Left Jacobian of SO(3), `V` in `t = V v`.
fn so3_left_jacobian(w: &Vector3<f64>) -> Matrix3<f64> {
    let theta_sq = w.norm_squared();
    let wx = hat(w);
    let (a, b) = if theta_sq < 1e-10 {
        // Taylor expansion: (1 - cos)/t^2 ~ 1/2 - t^2/24, (t - sin)/t^3 ~ 1/6 - t^2/120
        (0.5 - theta_sq / 24.0, 1.0 / 6.0 - theta_sq / 120.0)
    } else {
        let theta = theta_sq.sqrt();
        (
            (1.0 - theta.cos()) / theta_sq,
            (theta - theta.sin()) / (theta_sq * theta),
        )
    };
    Matrix3::identity() + wx * a + wx * wx * b
}

/// Inverse of the left Jacobian of SO(3).
fn so3_left_jacobian_inv(w: &Vector3<f64>) -> Matrix3<f64> {
    let theta_sq = w.norm_squared();
    let wx = hat(w);
    let c = if theta_sq < 1e-10 {
        1.0 / 12.0 + theta_sq / 720.0
    } else {
        let theta = theta_sq.sqrt();
        let half = 0.5 * theta;
        (1.0 - half * half.cos() / half.sin()) / theta_sq
    };
    Matrix3::identity() - wx * 0.5 + wx * wx * c
}

/// The exponential map `se(3) -> SE(3)`, `xi = [v; w]`.
pub fn exp_se3(xi: &Vector6<f64>) -> Pose {
    let v = Vector3::new(xi[0], xi[1], xi[2]);
    let w = Vector3::new(xi[3], xi[4], xi[5]);
    let rotation = UnitQuaternion::from_scaled_axis(w);
    let t = so3_left_jacobian(&w) * v;
    Isometry3::from_parts(Translation3::from(t), rotation)
}

/// The logarithm `SE(3) -> se(3)`, `xi = [v; w]`, with `|w|` in `[0, pi]`.
pub fn log_se3(pose: &Pose) -> Vector6<f64> {
    let w = pose.rotation.scaled_axis();
    let v = so3_left_jacobian_inv(&w) * pose.translation.vector;
    Vector6::new(v.x, v.y, v.z, w.x, w.y, w.z)
}

/// Re-normalizes the rotation quaternion. Compose poses in a loop (tracking,
/// keyframes built on estimates) and the norm error compounds, because
/// inverses use the conjugate; call this on every pose that is fed back.
#[inline]
pub fn renormalized(mut pose: Pose) -> Pose {
    pose.rotation.renormalize();
    pose
}

/// Angle of the rotation part of `pose`, in radians, in `[0, pi]`.
pub fn rotation_angle_rad(pose: &Pose) -> f64 {
    pose.rotation.angle()
}

/// The adjoint of `pose` for twists ordered `[v; w]`:
/// `pose * exp(xi) * pose^-1 = exp(adjoint(pose) * xi)`.
pub fn adjoint(pose: &Pose) -> Matrix6<f64> {
    let r = pose.rotation.to_rotation_matrix().into_inner();
    let t = pose.translation.vector;
    let mut ad = Matrix6::zeros();
    ad.fixed_view_mut::<3, 3>(0, 0).copy_from(&r);
    ad.fixed_view_mut::<3, 3>(0, 3).copy_from(&(hat(&t) * r));
    ad.fixed_view_mut::<3, 3>(3, 3).copy_from(&r);
    ad
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn twist() -> impl Strategy<Value = Vector6<f64>> {
        // Rotation angle below pi so the principal branch is unique.
        (
            -5.0..5.0f64,
            -5.0..5.0f64,
            -5.0..5.0f64,
            -1.7..1.7f64,
            -1.7..1.7f64,
            -1.7..1.7f64,
        )
            .prop_map(|(a, b, c, d, e, f)| Vector6::new(a, b, c, d, e, f))
    }

    proptest! {
        #[test]
        fn exp_log_roundtrip(xi in twist()) {
            let pose = exp_se3(&xi);
            let back = exp_se3(&log_se3(&pose));
            let diff = pose.inverse() * back;
            prop_assert!(diff.translation.vector.norm() < 1e-9);
            prop_assert!(diff.rotation.angle() < 1e-9);
        }

        #[test]
        fn log_exp_roundtrip(xi in twist()) {
            let back = log_se3(&exp_se3(&xi));
            prop_assert!((back - xi).norm() < 1e-8, "{xi:?} -> {back:?}");
        }

        #[test]
        fn exp_is_homomorphic_on_one_parameter_subgroup(xi in twist(), s in 0.0..1.0f64) {
            let a = exp_se3(&(xi * s));
            let b = exp_se3(&(xi * (1.0 - s)));
            let ab = a * b;
            let full = exp_se3(&xi);
            let diff = ab.inverse() * full;
            prop_assert!(diff.translation.vector.norm() < 1e-9);
            prop_assert!(diff.rotation.angle() < 1e-9);
        }
    }

    #[test]
    fn small_angle_matches_first_order() {
        let xi = Vector6::new(0.1, -0.2, 0.3, 1e-7, -2e-7, 3e-7);
        let pose = exp_se3(&xi);
        assert!((pose.translation.vector - Vector3::new(0.1, -0.2, 0.3)).norm() < 1e-6);
        assert!((log_se3(&pose) - xi).norm() < 1e-12);
    }

    #[test]
    fn renormalized_restores_unit_norm() {
        let mut p = exp_se3(&Vector6::new(0.1, 0.2, 0.3, 0.4, 0.5, 0.6));
        *p.rotation.as_mut_unchecked() *= 1.01;
        let q = renormalized(p);
        assert!((q.rotation.coords.norm() - 1.0).abs() < 1e-15);
        assert!((q.translation.vector - p.translation.vector).norm() == 0.0);
    }

    #[test]
    fn hat_is_cross_product() {
        let w = Vector3::new(0.3, -1.0, 2.0);
        let p = Vector3::new(-4.0, 0.5, 1.5);
        assert!((hat(&w) * p - w.cross(&p)).norm() < 1e-12);
    }
}
