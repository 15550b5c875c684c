//! Motion blur: a frame is the average of sub-frame renders spread evenly
//! over the exposure, centered on the frame's timestamp.
//!
//! The number of sub-frames follows the image motion during the exposure,
//! estimated as `f * (rotation angle + translation / typical_depth_m)`
//! pixels: one sub-frame per `px_per_subframe` pixels of motion, at least
//! one, at most `max_subframes`. A slow frame therefore costs one render.

use serde::Serialize;

use crate::geometry::Pose;

/// Exact motion-blur parameters of a preset.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct BlurSpec {
    /// Exposure time, seconds.
    pub exposure_s: f64,
    /// Image motion covered by one sub-frame, pixels.
    pub px_per_subframe: f64,
    /// Most sub-frames per frame.
    pub max_subframes: u32,
    /// Scene depth used to turn translation into image motion, m.
    pub typical_depth_m: f64,
}

/// Image motion in pixels between two poses, as [`BlurSpec`] estimates it.
pub fn motion_px(spec: &BlurSpec, focal_px: f64, a: &Pose, b: &Pose) -> f64 {
    let rel = a.inverse() * b;
    focal_px * (rel.rotation.angle() + rel.translation.vector.norm() / spec.typical_depth_m)
}

/// Sub-frame times relative to the frame timestamp for the motion of
/// `pose_at` around `t_s`, written into `out` (cleared first).
pub fn subframe_offsets_s(
    spec: &BlurSpec,
    focal_px: f64,
    pose_at: impl Fn(f64) -> Pose,
    t_s: f64,
    out: &mut Vec<f64>,
) {
    out.clear();
    let half = 0.5 * spec.exposure_s;
    let px = motion_px(spec, focal_px, &pose_at(t_s - half), &pose_at(t_s + half));
    let wanted = (px / spec.px_per_subframe.max(1e-6)).ceil();
    let n = if wanted.is_finite() {
        (wanted as u32).clamp(1, spec.max_subframes.max(1))
    } else {
        1
    };
    if n == 1 {
        out.push(0.0);
        return;
    }
    out.extend((0..n).map(|k| spec.exposure_s * ((k as f64 + 0.5) / n as f64 - 0.5)));
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion, Vector3};

    const SPEC: BlurSpec = BlurSpec {
        exposure_s: 0.006,
        px_per_subframe: 1.5,
        max_subframes: 8,
        typical_depth_m: 2.0,
    };

    fn spinning(rate_dps: f64) -> impl Fn(f64) -> Pose {
        move |t| {
            Pose::from_parts(
                Translation3::identity(),
                UnitQuaternion::from_axis_angle(&Vector3::y_axis(), (rate_dps * t).to_radians()),
            )
        }
    }

    #[test]
    fn still_camera_gets_one_subframe() {
        let mut out = Vec::new();
        subframe_offsets_s(&SPEC, 420.0, spinning(0.0), 1.0, &mut out);
        assert_eq!(out, vec![0.0]);
    }

    #[test]
    fn fast_rotation_gets_subframes_spanning_the_exposure() {
        let mut out = Vec::new();
        // 100 deg/s over 6 ms = 0.6 deg = 4.4 px at f = 420: 3 sub-frames.
        subframe_offsets_s(&SPEC, 420.0, spinning(100.0), 1.0, &mut out);
        assert_eq!(out.len(), 3);
        assert!(
            (out[0] + 0.002).abs() < 1e-12
                && out[1].abs() < 1e-12
                && (out[2] - 0.002).abs() < 1e-12
        );
        subframe_offsets_s(&SPEC, 420.0, spinning(2000.0), 1.0, &mut out);
        assert_eq!(out.len(), 8, "capped");
        let mean: f64 = out.iter().sum::<f64>() / out.len() as f64;
        assert!(mean.abs() < 1e-12, "centered on the timestamp");
    }
}
