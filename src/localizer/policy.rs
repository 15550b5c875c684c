//! The keyframe policy: when the tracker asks for a new keyframe.
//!
//! A keyframe is due when the view has moved on (visible overlap drops,
//! translation large relative to scene depth, rotation large), when quality
//! degrades, or when the keyframe is old.

use super::config::KeyframeConfig;
use crate::track::{Alignment, Keyframe};

/// True when a new keyframe should be rendered at the current estimate.
pub fn needs_keyframe(
    policy: &KeyframeConfig,
    keyframe: &Keyframe,
    alignment: &Alignment,
    keyframe_age_s: f64,
) -> bool {
    let q = &alignment.quality;
    let baseline_m = alignment.camera_from_keyframe.translation.vector.norm() as f32;
    let depth_m = keyframe.median_depth_m.max(0.1);
    let rotation_deg = alignment.camera_from_keyframe.rotation.angle().to_degrees() as f32;
    q.visible_ratio < policy.min_visible
        || baseline_m > policy.max_baseline_ratio * depth_m
        || rotation_deg > policy.max_rotation_deg
        || q.inlier_ratio < policy.min_inlier_ratio
        || keyframe_age_s > policy.max_interval_s as f64
}
