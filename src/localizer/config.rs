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
    /// Tracking is lost when the estimate lands farther than this from the
    /// constant-velocity prediction, meters per 20 ms predicted (the limit
    /// grows in proportion over longer gaps between tracked frames). An
    /// unmapped object dragging the alignment away shows here first: a
    /// drone cannot leave its predicted path by centimeters in one frame.
    pub lost_max_jump_m: f32,
    /// ... or turns farther than this from the prediction, degrees per 20 ms.
    pub lost_max_jump_deg: f32,
    /// Tracking is lost when the normalized cross-correlation between the
    /// keyframe points and the aligned frame drops below this.
    pub lost_min_correlation: f32,
    /// Tracking is lost when the correlation falls below this fraction of
    /// its running mean over the last frames tracked (about ten): the same
    /// scene 20 ms later against the same keyframe does not lose a third of
    /// its correlation unless the alignment failed to follow (a view that
    /// jumped, an unmapped object dragging it).
    pub lost_correlation_drop: f32,
    /// Tracking is lost when the local contrast correlation (the lowest of
    /// pyramid levels 0-2, as `[reloc] track_min_local_correlation` reads
    /// it) falls below this fraction of its running mean over the last
    /// frames tracked (once the mean covers 10 of them); 0 turns the test
    /// off. Measured on `aggressive --scanned` seed 1 (docs/benchmarks.md):
    /// a drift against a keyframe not yet replaced fell to 0.46-0.71 of the
    /// mean at its first wrong frame, while 5 615 right frames stayed at
    /// 0.74 or more. Only with a relocalization gate (a database or a
    /// verified start).
    pub lost_local_correlation_drop: f32,
    /// Far limit of a tracking keyframe, meters along the optical axis
    /// (0: the renderer's own, `[render] far_m`; never beyond it). A
    /// keyframe rendered near a tracked pose needs only the surfaces its
    /// points lie on; on the synthetic floor of rooms, the views down the
    /// corridor and through doorways cost wgpu on lavapipe twice a room's
    /// render at 30 m and 1.4 times at 4 m, while on the same floor scanned
    /// 4 m cost accuracy (docs/building-scale.md). Relocalization
    /// candidates and the start pose are drawn to the renderer's whole
    /// limit: the gate tells look-alike rooms apart by what it sees through
    /// their doors.
    pub far_m: f32,
    /// Hold each pose until the next frame has tracked too; a frame whose
    /// next frame is lost is never sent ([`super::hold`]). One frame of
    /// latency on every pose (the capture time sent stays the frame's
    /// own) against the wrong poses at the end of a slide: on `aggressive
    /// --scanned` the next frame was lost after each wrong pose of the
    /// slides and steps measured (docs/benchmarks.md, "A pose held for the
    /// next frame"). Off by default.
    pub hold_for_next_frame: bool,
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
            lost_max_jump_m: 0.05,
            lost_max_jump_deg: 4.0,
            lost_min_correlation: 0.2,
            lost_correlation_drop: 0.6,
            lost_local_correlation_drop: 0.7,
            far_m: 0.0,
            hold_for_next_frame: false,
        }
    }
}

impl KeyframeConfig {
    /// Checks every value against its valid range; keys are relative to `[keyframe]`.
    pub fn validate(&self) -> Result<(), SettingError> {
        let k = self;
        let unit = |v: f32| v.is_finite() && (0.0..=1.0).contains(&v);
        let positive = |v: f32| v.is_finite() && v > 0.0;
        let far = |v: f32| v == 0.0 || crate::render::select::FAR_M_RANGE.contains(&f64::from(v));
        let checks: [(&str, bool, f32); 13] = [
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
                "lost_max_jump_deg",
                positive(k.lost_max_jump_deg) && k.lost_max_jump_deg < 180.0,
                k.lost_max_jump_deg,
            ),
            (
                "lost_min_correlation",
                unit(k.lost_min_correlation),
                k.lost_min_correlation,
            ),
            (
                "lost_correlation_drop",
                unit(k.lost_correlation_drop),
                k.lost_correlation_drop,
            ),
            (
                "lost_local_correlation_drop",
                unit(k.lost_local_correlation_drop),
                k.lost_local_correlation_drop,
            ),
            ("far_m", far(k.far_m), k.far_m),
        ];
        match checks.into_iter().find(|(_, ok, _)| !ok) {
            Some((key, _, value)) => Err(SettingError::new(
                key,
                format!(
                    "out of range: {value} (ratios are 0..=1, far_m 0 or 1..=10000, others > 0)"
                ),
            )),
            None => Ok(()),
        }
    }

    /// The lost test's limits on the distance and the angle between the
    /// estimate and the constant-velocity prediction over `dt_s` since the
    /// last tracked frame. `motion_known`: the velocity was measured over
    /// the last two tracked frames; without it (the frames after a start or
    /// a resume predict with zero or decayed velocity) the limits grow by
    /// what a vehicle at [`UNKNOWN_MOTION_SPEED_M_S`] and
    /// [`UNKNOWN_MOTION_YAW_RATE_DEG_S`] covers in `dt_s`: the motion the
    /// prediction left out.
    pub fn jump_limits(&self, dt_s: f64, motion_known: bool) -> (f64, f64) {
        let scale = (dt_s / JUMP_REFERENCE_S).max(1.0);
        let (mut max_m, mut max_deg) = (
            self.lost_max_jump_m as f64 * scale,
            self.lost_max_jump_deg as f64 * scale,
        );
        if !motion_known {
            let dt_s = dt_s.max(JUMP_REFERENCE_S);
            max_m += UNKNOWN_MOTION_SPEED_M_S * dt_s;
            max_deg += UNKNOWN_MOTION_YAW_RATE_DEG_S * dt_s;
        }
        (max_m, max_deg)
    }
}

/// The prediction interval that `lost_max_jump_m` and `lost_max_jump_deg`
/// are given for: one frame at 50 Hz.
pub const JUMP_REFERENCE_S: f64 = 0.02;

/// While the velocity is not measured, the jump limits grow by what a
/// vehicle at this speed covers ... (m/s; the fastest preset, `aggressive`,
/// flies at up to 2.43 m/s). With the defaults, 11 cm per 20 ms. It
/// replaced a factor of 6 on the limits (30 cm per 20 ms, 15 m/s), through
/// which, on `aggressive --scanned` seed 1, the second frame after a resume
/// sent poses 22 and 28 cm wrong, 21-27 cm from where the frame before
/// had put the vehicle (docs/design-decisions.md).
pub const UNKNOWN_MOTION_SPEED_M_S: f64 = 3.0;

/// ... and at this yaw rate, degrees per second (`aggressive` turns at up
/// to 193 deg/s). With the defaults, 9 degrees per 20 ms.
pub const UNKNOWN_MOTION_YAW_RATE_DEG_S: f64 = 250.0;

#[cfg(test)]
mod jump_tests {
    use super::*;

    #[test]
    fn unknown_motion_widens_the_limits_by_what_a_vehicle_covers() {
        let k = KeyframeConfig::default();
        let (m, deg) = k.jump_limits(0.02, true);
        assert!((m - 0.05).abs() < 1e-6 && (deg - 4.0).abs() < 1e-5);
        // Unknown motion over one frame: 5 cm + 3 m/s x 20 ms = 11 cm, not
        // the 30 cm that let a 22 cm-wrong pose out after a resume.
        let (m, deg) = k.jump_limits(0.02, false);
        assert!((m - 0.11).abs() < 1e-6, "{m}");
        assert!((deg - 9.0).abs() < 1e-5, "{deg}");
        // A longer gap (the first frame after a 0.1 s loss): both grow.
        let (m, deg) = k.jump_limits(0.1, false);
        assert!((m - (0.25 + 0.3)).abs() < 1e-6, "{m}");
        assert!((deg - (20.0 + 25.0)).abs() < 1e-5, "{deg}");
    }
}
