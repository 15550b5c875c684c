//! `[keyframe]`: when a new keyframe is rendered and when tracking is lost,
//! and their validation.

use serde::{Deserialize, Serialize};

use crate::settings::SettingError;

/// `[keyframe]`: the keyframe policy and the lost test.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct KeyframeConfig {
    /// Render a new keyframe when the visible fraction of keyframe points drops below this.
    pub min_visible: f32,
    /// ... when the translation from the keyframe exceeds this fraction of its median depth.
    pub max_baseline_ratio: f32,
    /// ... when the rotation from the keyframe exceeds this, degrees.
    pub max_rotation_deg: f32,
    /// ... when the inlier ratio drops below this.
    pub min_inlier_ratio: f32,
    /// ... when the keyframe is older than this, seconds.
    pub max_interval_s: f32,
    /// Tracking is lost when the inlier ratio drops below this.
    pub lost_inlier_ratio: f32,
    /// Tracking is lost when fewer than this fraction of keyframe points are visible.
    pub lost_visible_ratio: f32,
    /// Tracking is lost when the estimate jumps this far from the prediction in one frame, meters.
    pub lost_max_jump_m: f32,
    /// Tracking is lost when the normalized cross-correlation between the
    /// keyframe points and the aligned frame drops below this.
    pub lost_min_correlation: f32,
}

impl Default for KeyframeConfig {
    fn default() -> Self {
        Self {
            min_visible: 0.75,
            max_baseline_ratio: 0.08,
            max_rotation_deg: 6.0,
            min_inlier_ratio: 0.75,
            max_interval_s: 1.0,
            lost_inlier_ratio: 0.35,
            lost_visible_ratio: 0.15,
            lost_max_jump_m: 0.3,
            lost_min_correlation: 0.2,
        }
    }
}

impl KeyframeConfig {
    /// Checks every value against its valid range; keys are relative to `[keyframe]`.
    pub fn validate(&self) -> Result<(), SettingError> {
        let k = self;
        let unit = |v: f32| v.is_finite() && (0.0..=1.0).contains(&v);
        let positive = |v: f32| v.is_finite() && v > 0.0;
        let checks: [(&str, bool, f32); 9] = [
            ("min_visible", unit(k.min_visible), k.min_visible),
            (
                "max_baseline_ratio",
                positive(k.max_baseline_ratio),
                k.max_baseline_ratio,
            ),
            (
                "max_rotation_deg",
                positive(k.max_rotation_deg) && k.max_rotation_deg < 90.0,
                k.max_rotation_deg,
            ),
            (
                "min_inlier_ratio",
                unit(k.min_inlier_ratio),
                k.min_inlier_ratio,
            ),
            (
                "max_interval_s",
                positive(k.max_interval_s),
                k.max_interval_s,
            ),
            (
                "lost_inlier_ratio",
                unit(k.lost_inlier_ratio),
                k.lost_inlier_ratio,
            ),
            (
                "lost_visible_ratio",
                unit(k.lost_visible_ratio),
                k.lost_visible_ratio,
            ),
            (
                "lost_max_jump_m",
                positive(k.lost_max_jump_m),
                k.lost_max_jump_m,
            ),
            (
                "lost_min_correlation",
                unit(k.lost_min_correlation),
                k.lost_min_correlation,
            ),
        ];
        match checks.into_iter().find(|(_, ok, _)| !ok) {
            Some((key, _, value)) => Err(SettingError::new(
                key,
                format!("out of range: {value} (ratios are 0..=1, others > 0)"),
            )),
            None => Ok(()),
        }
    }
}
