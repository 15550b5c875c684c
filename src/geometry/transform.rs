//! Rigid transforms as the config writes them (`[mavlink.ned_from_world]`,
//! `[mavlink.body_from_camera]`, `[map.world_from_mesh]`): a translation and
//! a rotation as roll/pitch/yaw, a unit quaternion or a rotation matrix,
//! with validation that names the sub-key and the bound.

use nalgebra::{Matrix3, Quaternion, Rotation3, Translation3, UnitQuaternion};
use serde::{Deserialize, Serialize};

use super::Pose;

/// A rigid transform in the config: a translation and at most one rotation,
/// given as roll/pitch/yaw, a unit quaternion, or a rotation matrix.
///
/// With none of `rpy_deg`, `quaternion_wxyz` and `rotation_rows` the
/// rotation is the identity.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
pub struct TransformConfig {
    /// Translation `[x, y, z]` in meters, expressed in the target frame.
    pub translation_m: [f64; 3],
    /// Rotation as `[roll, pitch, yaw]` in degrees, `Rz(yaw) Ry(pitch) Rx(roll)`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub rpy_deg: Option<[f64; 3]>,
    /// Rotation as a unit quaternion `[w, x, y, z]`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub quaternion_wxyz: Option<[f64; 4]>,
    /// Rotation as a 3x3 matrix, row by row; must be orthonormal with
    /// determinant +1 (within 1e-4).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub rotation_rows: Option<[[f64; 3]; 3]>,
}

/// Largest roll, pitch or yaw accepted, degrees (a larger value is a typo).
pub const MAX_ANGLE_DEG: f64 = 360.0;
/// Largest translation accepted, meters (a building, not a planet).
pub const MAX_TRANSLATION_M: f64 = 100_000.0;
/// Tolerance of the orthonormality check of `rotation_rows`.
const ORTHONORMAL_TOLERANCE: f64 = 1e-4;

impl TransformConfig {
    /// A transform from a translation and roll/pitch/yaw in degrees.
    pub fn from_rpy_deg(translation_m: [f64; 3], rpy_deg: [f64; 3]) -> Self {
        Self {
            translation_m,
            rpy_deg: Some(rpy_deg),
            quaternion_wxyz: None,
            rotation_rows: None,
        }
    }

    /// Checks the values; `Err` holds the reason, naming the sub-key (the
    /// caller adds the section's key).
    pub fn validate(&self) -> Result<(), String> {
        if self
            .translation_m
            .iter()
            .any(|v| !(v.abs() <= MAX_TRANSLATION_M))
        {
            return Err(format!(
                "translation_m must be finite and within +-{MAX_TRANSLATION_M} m, found {:?}",
                self.translation_m
            ));
        }
        let given = [
            self.rpy_deg.is_some(),
            self.quaternion_wxyz.is_some(),
            self.rotation_rows.is_some(),
        ];
        if given.iter().filter(|g| **g).count() > 1 {
            return Err(
                "give one of rpy_deg, quaternion_wxyz and rotation_rows, not several".into(),
            );
        }
        if let Some(rpy) = self.rpy_deg {
            if rpy.iter().any(|v| !(v.abs() <= MAX_ANGLE_DEG)) {
                return Err(format!(
                    "rpy_deg must be finite and within +-{MAX_ANGLE_DEG} degrees, found {rpy:?}"
                ));
            }
        }
        if let Some(q) = self.quaternion_wxyz {
            let norm = q.iter().map(|v| v * v).sum::<f64>().sqrt();
            if !norm.is_finite() || (norm - 1.0).abs() > 1e-3 {
                return Err(format!(
                    "quaternion_wxyz must be a unit quaternion (norm 1 +- 1e-3), found {q:?} with norm {norm}"
                ));
            }
        }
        if let Some(rows) = self.rotation_rows {
            let m = Matrix3::from_fn(|r, c| rows[r][c]);
            let error = (m.transpose() * m - Matrix3::identity()).abs().max();
            let det = m.determinant();
            if !(error <= ORTHONORMAL_TOLERANCE) || !((det - 1.0).abs() <= ORTHONORMAL_TOLERANCE) {
                return Err(format!(
                    "rotation_rows must be orthonormal with determinant +1 (within {ORTHONORMAL_TOLERANCE}), found {rows:?}: |R^T R - I| = {error:.3e}, det = {det:.6}"
                ));
            }
        }
        Ok(())
    }

    /// The transform as a [`Pose`]. Call [`Self::validate`] first; an invalid
    /// quaternion is normalized here.
    pub fn to_pose(&self) -> Pose {
        let rotation = match (self.rpy_deg, self.quaternion_wxyz, self.rotation_rows) {
            (Some([r, p, y]), _, _) => UnitQuaternion::from_rotation_matrix(
                &Rotation3::from_euler_angles(r.to_radians(), p.to_radians(), y.to_radians()),
            ),
            (None, Some([w, x, y, z]), _) => {
                UnitQuaternion::from_quaternion(Quaternion::new(w, x, y, z))
            }
            (None, None, Some(rows)) => {
                UnitQuaternion::from_matrix(&Matrix3::from_fn(|r, c| rows[r][c]))
            }
            (None, None, None) => UnitQuaternion::identity(),
        };
        let [x, y, z] = self.translation_m;
        Pose::from_parts(Translation3::new(x, y, z), rotation)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rotation_rows_must_be_orthonormal() {
        // A scanner's first camera (y down, z forward) in a z-up world.
        let camera_axes = TransformConfig {
            rotation_rows: Some([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]]),
            ..Default::default()
        };
        camera_axes.validate().expect("a rotation");
        let p = camera_axes.to_pose();
        let down = p * nalgebra::Point3::new(0.0, 1.0, 0.0);
        assert!(
            (down.z + 1.0).abs() < 1e-12,
            "camera y (down) is world -z: {down}"
        );
        for rows in [
            [[2.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            [[1.0, 0.1, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            [[-1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            [[f64::NAN, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        ] {
            let t = TransformConfig {
                rotation_rows: Some(rows),
                ..Default::default()
            };
            let e = t.validate().expect_err("not a rotation");
            assert!(
                e.contains("rotation_rows") && e.contains("orthonormal"),
                "{e}"
            );
        }
    }

    #[test]
    fn huge_or_conflicting_values_are_refused() {
        let t = TransformConfig::from_rpy_deg([0.0; 3], [1e300, 0.0, 0.0]);
        assert!(t.validate().expect_err("huge angle").contains("rpy_deg"));
        let t = TransformConfig::from_rpy_deg([1e30, 0.0, 0.0], [0.0; 3]);
        assert!(t
            .validate()
            .expect_err("huge shift")
            .contains("translation_m"));
        let t = TransformConfig {
            quaternion_wxyz: Some([1.0, 0.0, 0.0, 0.0]),
            rotation_rows: Some([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]),
            ..Default::default()
        };
        assert!(t
            .validate()
            .expect_err("two rotations")
            .contains("not several"));
    }
}
