//! Parsing of pose arguments given on the command line.

use anyhow::{bail, Result};
use nalgebra::{Quaternion, Translation3, UnitQuaternion};

use crate::geometry::Pose;

/// Parses "tx ty tz qx qy qz qw" (TUM order, world_from_camera).
pub fn parse_pose(text: &str) -> Result<Pose> {
    let values: Vec<f64> = text
        .split(|c: char| c.is_whitespace() || c == ',')
        .filter(|s| !s.is_empty())
        .map(|s| {
            s.parse::<f64>()
                .map_err(|_| anyhow::anyhow!("pose value `{s}` is not a number"))
        })
        .collect::<Result<_>>()?;
    let [tx, ty, tz, qx, qy, qz, qw] = values[..] else {
        bail!(
            "pose `{text}` has {} values; expected 7: tx ty tz qx qy qz qw",
            values.len()
        );
    };
    if values.iter().any(|v| !v.is_finite()) {
        bail!("pose `{text}` has a non-finite value");
    }
    let q = Quaternion::new(qw, qx, qy, qz);
    if q.norm() < 1e-6 {
        bail!("pose `{text}` has a zero quaternion");
    }
    Ok(Pose::from_parts(
        Translation3::new(tx, ty, tz),
        UnitQuaternion::from_quaternion(q),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_and_normalizes() {
        let p = parse_pose("1 2 3 0 0 0 2").expect("valid");
        assert_eq!(p.translation.vector.z, 3.0);
        assert!((p.rotation.angle()).abs() < 1e-12);
    }

    #[test]
    fn rejects_bad_input() {
        assert!(parse_pose("1 2 3").is_err());
        assert!(parse_pose("1 2 3 0 0 0 x").is_err());
        assert!(parse_pose("1 2 3 0 0 0 0").is_err());
        assert!(parse_pose("1 2 nan 0 0 0 1").is_err());
    }
}
