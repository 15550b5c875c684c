//! The keyframe policy: when the tracker asks for a new keyframe.
//!
//! A keyframe is due when the view has moved on (visible overlap drops,
//! translation large relative to scene depth, rotation large), when quality
//! degrades, or when the keyframe is old.

use super::config::KeyframeConfig;
use crate::geometry::Pose;
use crate::track::{Alignment, Keyframe};

/// True when a new keyframe should be rendered: at the current estimate,
/// or where the camera will be (`camera_ahead_from_camera`) when it arrives.
pub fn needs_keyframe(
    policy: &KeyframeConfig,
    keyframe: &Keyframe,
    alignment: &Alignment,
    keyframe_age_s: f64,
    camera_ahead_from_camera: &Pose,
) -> bool {
    let q = &alignment.quality;
    let depth_m = keyframe.median_depth_m.max(0.1);
    let moved_on = |camera_from_keyframe: &Pose| {
        let baseline_m = camera_from_keyframe.translation.vector.norm() as f32;
        let rotation_deg = camera_from_keyframe.rotation.angle().to_degrees() as f32;
        baseline_m > policy.max_baseline_ratio * depth_m || rotation_deg > policy.max_rotation_deg
    };
    q.visible_ratio < policy.min_visible
        || moved_on(&alignment.camera_from_keyframe)
        || moved_on(&(camera_ahead_from_camera * alignment.camera_from_keyframe))
        || q.inlier_ratio < policy.min_inlier_ratio
        || keyframe_age_s > policy.max_interval_s as f64
}
