//! `[tracker]`: the direct alignment's settings (pyramid, point selection,
//! robust weights, illumination model), and their validation.

use serde::{Deserialize, Serialize};

use crate::settings::{first_failure, SettingError};

/// Photometric model between rendered keyframe and camera image.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum IlluminationModel {
    /// Affine gain and bias, estimated per frame.
    #[default]
    Affine,
    /// The paper's median offset (beta).
    Median,
}

/// `[tracker]`
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TrackerConfig {
    /// Pyramid levels, coarsest first in alignment.
    pub pyramid_levels: u32,
    /// Illumination model.
    pub illumination: IlluminationModel,
    /// Most keyframe points at level 0; level `l` gets `max_points >> l`
    /// (at least 200).
    pub max_points: u32,
    /// Side of the blocks whose median gradient sets the local selection
    /// threshold, level-0 pixels.
    pub block_size_px: u32,
    /// Gradient magnitude above the block median needed for selection,
    /// gray levels per pixel.
    #[serde(alias = "gradient_threshold")]
    pub gradient_threshold_gray: f32,
    /// Fewest visible points for a level to be used.
    pub min_points: u32,
    /// Most Levenberg-Marquardt iterations per level.
    pub max_iterations: u32,
    /// Smallest Huber threshold, gray levels.
    #[serde(alias = "huber_min")]
    pub huber_min_gray: f32,
    /// Residuals above this (or above 4 Huber thresholds) get zero weight.
    #[serde(alias = "outlier_cut")]
    pub outlier_cut_gray: f32,
    /// A residual below this counts as an inlier in the quality figures.
    #[serde(alias = "inlier_threshold")]
    pub inlier_threshold_gray: f32,
    /// Factor on the variance of the alignment's covariance (dimensionless).
    /// The alignment's own estimate is the inverse Hessian scaled by the
    /// residual variance per degree of freedom, `sum(w r^2) / (n - 6)`, which
    /// holds for independent residuals; neighbouring points' residuals are
    /// not (blur, interpolation, the map's own shape and texture errors), so
    /// it is too confident. This factor is calibrated on the benches so that
    /// the normalized estimation error squared per degree of freedom of the
    /// position is near 1 (`hil_tests/nees.py`, docs/benchmarks.md).
    pub covariance_scale: f64,
    /// Initial pose of `star track` / `star run`, `world_from_camera` in TUM
    /// order `[tx, ty, tz, qx, qy, qz, qw]`; absent: `--init-pose` must give it.
    #[serde(rename = "init_pose")]
    pub world_from_camera_init: Option<[f64; 7]>,
}

/// Default `covariance_scale` (docs/benchmarks.md, "Covariance sent (NEES)").
pub const DEFAULT_COVARIANCE_SCALE: f64 = 9.0;

impl Default for TrackerConfig {
    fn default() -> Self {
        Self {
            pyramid_levels: 4,
            illumination: IlluminationModel::Affine,
            max_points: 6000,
            block_size_px: 32,
            gradient_threshold_gray: 4.0,
            min_points: 40,
            max_iterations: 12,
            huber_min_gray: 4.0,
            outlier_cut_gray: 40.0,
            inlier_threshold_gray: 20.0,
            covariance_scale: DEFAULT_COVARIANCE_SCALE,
            world_from_camera_init: None,
        }
    }
}

impl TrackerConfig {
    /// Point budget of pyramid level `level`.
    pub fn max_points_per_level(&self, level: usize) -> usize {
        ((self.max_points as usize) >> level).max(200)
    }
}

impl TrackerConfig {
    /// Checks every value against its valid range; keys are relative to `[tracker]`.
    pub fn validate(&self) -> Result<(), SettingError> {
        let t = self;
        if let Some(p) = &t.world_from_camera_init {
            let q_norm = (p[3] * p[3] + p[4] * p[4] + p[5] * p[5] + p[6] * p[6]).sqrt();
            if p.iter().any(|v| !v.is_finite()) || q_norm < 1e-6 {
                return Err(SettingError::new(
                    "init_pose",
                    format!("expected finite [tx, ty, tz, qx, qy, qz, qw] with a non-zero quaternion, found {p:?}"),
                ));
            }
        }
        first_failure([
            (
                "pyramid_levels",
                (1..=6).contains(&t.pyramid_levels),
                format!("expected 1..=6, found {}", t.pyramid_levels),
            ),
            (
                "max_points",
                (100..=100_000).contains(&t.max_points),
                format!("expected 100..=100000, found {}", t.max_points),
            ),
            (
                "block_size_px",
                (8..=256).contains(&t.block_size_px),
                format!("expected 8..=256, found {}", t.block_size_px),
            ),
            (
                "gradient_threshold_gray",
                t.gradient_threshold_gray.is_finite() && t.gradient_threshold_gray >= 0.0,
                format!(
                    "expected a finite value >= 0, found {}",
                    t.gradient_threshold_gray
                ),
            ),
            (
                "min_points",
                (6..=10_000).contains(&t.min_points),
                format!("expected 6..=10000, found {}", t.min_points),
            ),
            (
                "max_iterations",
                (1..=100).contains(&t.max_iterations),
                format!("expected 1..=100, found {}", t.max_iterations),
            ),
            (
                "huber_min_gray",
                t.huber_min_gray.is_finite() && t.huber_min_gray > 0.0,
                format!("expected a finite value > 0, found {}", t.huber_min_gray),
            ),
            (
                "covariance_scale",
                t.covariance_scale.is_finite() && t.covariance_scale > 0.0 && t.covariance_scale <= 1e6,
                format!("expected 0 < covariance_scale <= 1e6, found {}", t.covariance_scale),
            ),
            (
                "outlier_cut_gray",
                t.outlier_cut_gray.is_finite()
                    && t.outlier_cut_gray > t.huber_min_gray
                    && t.inlier_threshold_gray > 0.0,
                format!(
                    "expected outlier_cut_gray > huber_min_gray and inlier_threshold_gray > 0, found {} and {}",
                    t.outlier_cut_gray, t.inlier_threshold_gray
                ),
            ),
        ])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn covariance_scale_is_checked() {
        TrackerConfig::default().validate().expect("defaults valid");
        for bad in [0.0, -1.0, f64::NAN, f64::INFINITY, 2e6] {
            let c = TrackerConfig {
                covariance_scale: bad,
                ..Default::default()
            };
            let e = c.validate().unwrap_err();
            assert_eq!(e.key, "covariance_scale", "{bad}");
            assert!(e.reason.contains("0 < covariance_scale <= 1e6"), "{e}");
        }
    }
}
