//! Worked examples for the NED/body conversion and the covariance rotation.
//!
//! World frame of the examples: a z-up map, x east, y north (the default
//! `ned_from_world`, rpy_deg = [180, 0, 90]).

use super::*;
use crate::geometry::exp_se3;
use crate::mavlink_io::config::TransformConfig;
use nalgebra::{Matrix3, Rotation3, Translation3, UnitQuaternion, Vector6};
use proptest::prelude::*;

const DEG: f64 = std::f64::consts::PI / 180.0;

fn pose_from_columns(x: [f64; 3], y: [f64; 3], z: [f64; 3], t: [f64; 3]) -> Pose {
    let m = Matrix3::from_columns(&[x.into(), y.into(), z.into()]);
    let r = Rotation3::from_matrix_unchecked(m);
    Pose::from_parts(
        Translation3::new(t[0], t[1], t[2]),
        UnitQuaternion::from_rotation_matrix(&r),
    )
}

fn ned_from_enu() -> Pose {
    TransformConfig::from_rpy_deg([0.0; 3], [180.0, 0.0, 90.0]).to_pose()
}

/// Forward camera: optical axis = body forward, 10 cm ahead and 5 cm below
/// the body origin.
fn forward_camera() -> FrameConverter {
    let body_from_camera =
        TransformConfig::from_rpy_deg([0.10, 0.0, 0.05], [90.0, 0.0, 90.0]).to_pose();
    FrameConverter::new(ned_from_enu(), body_from_camera)
}

/// Downward camera: optical axis = body down, image top toward the nose,
/// 10 cm below the body origin.
fn downward_camera() -> FrameConverter {
    let body_from_camera =
        TransformConfig::from_rpy_deg([0.0, 0.0, 0.10], [0.0, 0.0, 90.0]).to_pose();
    FrameConverter::new(ned_from_enu(), body_from_camera)
}

fn assert_pose(got: &NedPose, position_ned_m: [f64; 3], rpy_deg: [f64; 3]) {
    let p = got.position_ned_m();
    let want = Vector3::from(position_ned_m);
    assert!((p - want).norm() < 1e-9, "position {p:?} want {want:?}");
    let rpy = [got.roll_rad / DEG, got.pitch_rad / DEG, got.yaw_rad / DEG];
    for (g, w) in rpy.iter().zip(rpy_deg) {
        assert!((g - w).abs() < 1e-9, "rpy {rpy:?} want {rpy_deg:?}");
    }
}

#[test]
fn forward_camera_facing_north() {
    // Camera at east 2, north 3, up 1.5, level, looking north.
    let world_from_camera = pose_from_columns(
        [1.0, 0.0, 0.0],
        [0.0, 0.0, -1.0],
        [0.0, 1.0, 0.0],
        [2.0, 3.0, 1.5],
    );
    let got = forward_camera().ned_pose(&world_from_camera);
    // Camera in NED (3, 2, -1.5); the body origin is 0.10 m behind, 0.05 m above.
    assert_pose(&got, [2.9, 2.0, -1.55], [0.0, 0.0, 0.0]);
    let q = got.quaternion_wxyz();
    assert!((q[0].abs() - 1.0).abs() < 1e-12, "{q:?}");
}

#[test]
fn forward_camera_facing_east() {
    // Same place, looking east: image right is south.
    let world_from_camera = pose_from_columns(
        [0.0, -1.0, 0.0],
        [0.0, 0.0, -1.0],
        [1.0, 0.0, 0.0],
        [2.0, 3.0, 1.5],
    );
    let got = forward_camera().ned_pose(&world_from_camera);
    // Body origin is 0.10 m west of the camera: NED (3, 1.9, -1.55), yaw +90.
    assert_pose(&got, [3.0, 1.9, -1.55], [0.0, 0.0, 90.0]);
}

#[test]
fn forward_camera_pitched_up_10_deg() {
    let (s, c) = (10.0 * DEG).sin_cos();
    let world_from_camera =
        pose_from_columns([1.0, 0.0, 0.0], [0.0, s, -c], [0.0, c, s], [2.0, 3.0, 1.5]);
    let got = forward_camera().ned_pose(&world_from_camera);
    // ned_from_body rotation = Ry(10 deg); lever arm Ry * (0.10, 0, 0.05) =
    // (0.1071632, 0, 0.0318756).
    let lever = [0.1 * c + 0.05 * s, 0.0, -0.1 * s + 0.05 * c];
    assert!((lever[0] - 0.107_163_2).abs() < 1e-7 && (lever[2] - 0.031_875_6).abs() < 1e-7);
    assert_pose(
        &got,
        [3.0 - lever[0], 2.0, -1.5 - lever[2]],
        [0.0, 10.0, 0.0],
    );
}

#[test]
fn downward_camera_heading_east() {
    // Vehicle at NED (1, -2, -3) heading east; camera 0.10 m below it looks
    // down, image top toward the nose (east): image right = south, image down = west.
    let world_from_camera = pose_from_columns(
        [0.0, -1.0, 0.0],
        [-1.0, 0.0, 0.0],
        [0.0, 0.0, -1.0],
        [-2.0, 1.0, 2.9],
    );
    let got = downward_camera().ned_pose(&world_from_camera);
    assert_pose(&got, [1.0, -2.0, -3.0], [0.0, 0.0, 90.0]);
}

#[test]
fn downward_camera_heading_north() {
    // Image right = east, image down = south.
    let world_from_camera = pose_from_columns(
        [1.0, 0.0, 0.0],
        [0.0, -1.0, 0.0],
        [0.0, 0.0, -1.0],
        [-2.0, 1.0, 2.9],
    );
    let got = downward_camera().ned_pose(&world_from_camera);
    assert_pose(&got, [1.0, -2.0, -3.0], [0.0, 0.0, 0.0]);
}

#[test]
fn map_offset_shifts_position() {
    // The map origin sits at NED (10, 5, -1).
    let ned_from_world =
        TransformConfig::from_rpy_deg([10.0, 5.0, -1.0], [180.0, 0.0, 90.0]).to_pose();
    let body_from_camera =
        TransformConfig::from_rpy_deg([0.10, 0.0, 0.05], [90.0, 0.0, 90.0]).to_pose();
    let conv = FrameConverter::new(ned_from_world, body_from_camera);
    let world_from_camera = pose_from_columns(
        [1.0, 0.0, 0.0],
        [0.0, 0.0, -1.0],
        [0.0, 1.0, 0.0],
        [2.0, 3.0, 1.5],
    );
    assert_pose(
        &conv.ned_pose(&world_from_camera),
        [12.9, 7.0, -2.55],
        [0.0, 0.0, 0.0],
    );
}

#[test]
fn translation_covariance_is_rotated_into_ned() {
    let world_from_camera = pose_from_columns(
        [1.0, 0.0, 0.0],
        [0.0, 0.0, -1.0],
        [0.0, 1.0, 0.0],
        [2.0, 3.0, 1.5],
    );
    let conv = forward_camera();
    let pose = conv.ned_pose(&world_from_camera);
    // World: east 0.04, north 0.01, up 0.09 m^2.
    let sigma = Matrix6::from_diagonal(&Vector6::new(0.04, 0.01, 0.09, 0.0, 0.0, 0.0));
    let out = conv.pose_covariance(&pose, &sigma);
    let want = Matrix6::from_diagonal(&Vector6::new(0.01, 0.04, 0.09, 0.0, 0.0, 0.0));
    assert!((out - want).abs().max() < 1e-12, "{out}");
    let wire = upper_triangle(&out);
    let diag: Vec<f32> = UPPER_TRIANGLE_DIAGONAL.iter().map(|&i| wire[i]).collect();
    assert_eq!(diag, vec![0.01, 0.04, 0.09, 0.0, 0.0, 0.0]);
}

#[test]
fn yaw_uncertainty_about_the_camera_moves_the_body_through_the_lever_arm() {
    // Level forward camera facing north; yaw variance 4e-4 rad^2 about the
    // camera center (camera y = down, a right perturbation).
    let world_from_camera = pose_from_columns(
        [1.0, 0.0, 0.0],
        [0.0, 0.0, -1.0],
        [0.0, 1.0, 0.0],
        [2.0, 3.0, 1.5],
    );
    let conv = forward_camera();
    let pose = conv.ned_pose(&world_from_camera);
    let mut camera_cov = Matrix6::zeros();
    camera_cov[(4, 4)] = 4e-4;
    let world_cov = twist_covariance_world_from_camera(&world_from_camera, &camera_cov);
    let out = conv.pose_covariance(&pose, &world_cov);
    // The body origin is 0.10 m behind the camera: a yaw d turns it by
    // d * (0, -0.10, 0) in NED (east), so var(east) = 0.01 * 4e-4,
    // cov(east, yaw) = -0.10 * 4e-4, var(yaw) = 4e-4; nothing else.
    let mut want = Matrix6::zeros();
    want[(1, 1)] = 4e-6;
    want[(1, 5)] = -4e-5;
    want[(5, 1)] = -4e-5;
    want[(5, 5)] = 4e-4;
    assert!((out - want).abs().max() < 1e-15, "{out}");
    let wire = upper_triangle(&out);
    // Row 1 (y) starts at index 6; column 5 is 4 further on.
    assert!(
        (wire[6] - 4e-6).abs() < 1e-12
            && (wire[10] + 4e-5).abs() < 1e-12
            && (wire[20] - 4e-4).abs() < 1e-12
    );
}

#[test]
fn pitch_uncertainty_of_a_downward_camera_heading_east() {
    // Heading east, rotation variance about the camera's x axis (image right =
    // south = body right) is the body's pitch variance.
    let world_from_camera = pose_from_columns(
        [0.0, -1.0, 0.0],
        [-1.0, 0.0, 0.0],
        [0.0, 0.0, -1.0],
        [-2.0, 1.0, 2.9],
    );
    let conv = downward_camera();
    let pose = conv.ned_pose(&world_from_camera);
    let mut camera_cov = Matrix6::zeros();
    camera_cov[(3, 3)] = 1e-4;
    let out = conv.pose_covariance(
        &pose,
        &twist_covariance_world_from_camera(&world_from_camera, &camera_cov),
    );
    assert!((out[(4, 4)] - 1e-4).abs() < 1e-15, "{out}");
    assert!(
        out[(3, 3)].abs() < 1e-15 && out[(5, 5)].abs() < 1e-15,
        "{out}"
    );
    // Body origin 0.10 m above the camera: pitch d moves it by 0.10 d forward (east).
    assert!((out[(1, 1)] - 1e-6).abs() < 1e-15, "{out}");
}

#[test]
fn upper_triangle_layout_and_unknown() {
    let mut m = Matrix6::zeros();
    for r in 0..6 {
        for c in 0..6 {
            m[(r, c)] = (10 * r.min(c) + r.max(c)) as f64;
        }
    }
    let wire = upper_triangle(&m);
    assert_eq!(&wire[..6], &[0.0, 1.0, 2.0, 3.0, 4.0, 5.0]);
    assert_eq!(&wire[6..11], &[11.0, 12.0, 13.0, 14.0, 15.0]);
    assert_eq!(wire[20], 55.0);
    for (k, &i) in UPPER_TRIANGLE_DIAGONAL.iter().enumerate() {
        assert_eq!(wire[i], (11 * k) as f32);
    }
    m[(2, 3)] = f64::NAN;
    let wire = upper_triangle(&m);
    assert!(wire[0].is_nan());
}

fn state(conv: &FrameConverter, world_from_camera: &Pose) -> Vector6<f64> {
    let p = conv.ned_pose(world_from_camera);
    let t = p.position_ned_m();
    Vector6::new(t.x, t.y, t.z, p.roll_rad, p.pitch_rad, p.yaw_rad)
}

fn angle_diff(a: f64, b: f64) -> f64 {
    let d = a - b;
    d.sin().atan2(d.cos())
}

proptest! {
    /// The analytic Jacobian matches central differences of the full chain.
    #[test]
    fn jacobian_matches_finite_differences(
        w in prop::array::uniform6(-1.0..1.0f64),
        n in prop::array::uniform6(-1.0..1.0f64),
        b in prop::array::uniform6(-1.0..1.0f64),
    ) {
        let world_from_camera = exp_se3(&(Vector6::from(w) * 2.0));
        let conv = FrameConverter::new(exp_se3(&(Vector6::from(n) * 3.0)), exp_se3(&Vector6::from(b)));
        let pose = conv.ned_pose(&world_from_camera);
        prop_assume!(pose.pitch_rad.cos() > 0.2);
        let jac = conv.state_jacobian(&pose);
        let h = 1e-6;
        for k in 0..6 {
            let mut d = Vector6::zeros();
            d[k] = h;
            let plus = state(&conv, &(exp_se3(&d) * world_from_camera));
            let minus = state(&conv, &(exp_se3(&(-d)) * world_from_camera));
            for i in 0..6 {
                let diff = if i < 3 { plus[i] - minus[i] } else { angle_diff(plus[i], minus[i]) };
                let numeric = diff / (2.0 * h);
                prop_assert!((numeric - jac[(i, k)]).abs() < 1e-5,
                    "d state[{}] / d xi[{}]: numeric {} analytic {}", i, k, numeric, jac[(i, k)]);
            }
        }
    }
}

#[test]
fn variance_floor_raises_only_what_is_below_it() {
    let mut c = Matrix6::<f64>::identity() * 1e-8;
    c[(0, 0)] = 0.04; // 20 cm: above a 1 cm floor, kept
    c[(0, 1)] = 1e-9;
    c[(1, 0)] = 1e-9;
    floor_variances(&mut c, 0.01, 0.002);
    assert_eq!(c[(0, 0)], 0.04);
    assert!((c[(1, 1)] - 1e-4).abs() < 1e-15 && (c[(2, 2)] - 1e-4).abs() < 1e-15);
    for i in 3..6 {
        assert!((c[(i, i)] - 4e-6).abs() < 1e-15, "{}", c[(i, i)]);
    }
    assert_eq!(c[(0, 1)], 1e-9, "correlations kept");
    assert!(c.symmetric_eigenvalues().iter().all(|&l| l > 0.0));
    let mut unknown = Matrix6::<f64>::identity();
    unknown[(2, 4)] = f64::NAN;
    floor_variances(&mut unknown, 0.01, 0.002);
    assert_eq!(unknown[(0, 0)], 1.0);
}
