//! The `[reloc]` configuration section: how `star reloc build` places the
//! virtual cameras, and how the STAR loop searches, verifies and accepts a
//! relocalization while lost.
//!
//! Takes its TOML section (through the aggregate `Config`), gives out a validated
//! [`RelocConfig`]; [`RelocConfig::validate`] names the key and the reason.

use crate::settings::SettingError;
use serde::{Deserialize, Serialize};

use super::search::MAX_TOP_K;

/// Which maps [`RelocConfig::geometric_twins`] checks.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum GeometricTwinMaps {
    /// None.
    Never,
    /// Maps with no texture: their appearance is vertex color (a scan's).
    /// Held poses on the other maps are checked at their twins near the
    /// motion prior only ([`crate::reloc::twins::GeometricTwins::prior_only`]).
    Untextured,
    /// Every map. On the textured `building` floor (look-alike rooms by
    /// design) it refused 41 of 95 right cold starts: there the rivals'
    /// correlation tells the places apart (docs/building-scale.md).
    Always,
}

/// `[reloc]`: database grid, search and acceptance gate.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RelocConfig {
    /// Relocalization database (`star reloc build`) that `star track` and
    /// `star run` load; none disables relocalization there.
    pub database: Option<std::path::PathBuf>,
    /// Horizontal grid spacing of the virtual cameras, meters (0.35 m found
    /// 4 points fewer of the close-range views on the bench).
    pub grid_spacing_m: f64,
    /// Camera heights above the floor, meters.
    pub heights_m: Vec<f64>,
    /// Height of the floor (world z, meters) that `heights_m` and
    /// `landmark_heights_m` are measured from; absent: found in the map
    /// (the lowest large horizontal surface, [`crate::map::floor`]), and a
    /// map without one is refused with a message that says to set this.
    pub floor_z_m: Option<f64>,
    /// Number of yaw angles per position, evenly spaced over 360 degrees.
    pub yaw_steps: u32,
    /// Camera pitch angles, degrees (negative looks down).
    pub pitches_deg: Vec<f64>,
    /// Grid positions keep this distance from the mesh bounds, meters.
    pub bounds_margin_m: f64,
    /// A virtual camera is kept only if this fraction of its render sees the map.
    pub min_valid_fraction: f64,
    /// ... and its nearest rendered depth is at least this, meters (not
    /// inside or against geometry).
    pub min_depth_m: f64,
    /// Candidates rendered and aligned per relocalization attempt.
    pub top_k: u32,
    /// Candidates taken from the descriptor search and ranked by a coarse
    /// alignment against their stored coarse keyframes before the best
    /// `top_k` are rendered (at most 64; `top_k` or less: no ranking).
    pub rank_candidates: u32,
    /// Search radius around the last tracked position right after the
    /// failure, meters; it grows by `max_speed_m_s` per second lost.
    pub search_radius_m: f64,
    /// Fastest plausible motion while lost, m/s (search radius growth).
    pub max_speed_m_s: f64,
    /// Heading change allowed around the last tracked heading right after
    /// the failure, degrees; it grows by `max_yaw_rate_deg_s` per second
    /// lost. A relocalized pose within the search radius but turned more
    /// than this is not taken on the motion prior alone: it must beat its
    /// rivals as a cold start does ([`super::rivals`]).
    pub search_yaw_deg: f64,
    /// Fastest plausible turn while lost, degrees per second (a small
    /// indoor multirotor turns at up to about 120).
    pub max_yaw_rate_deg_s: f64,
    /// Frames whose thumbnail standard deviation is below this (gray levels)
    /// are not searched (black, saturated or covered frames).
    #[serde(alias = "min_contrast")]
    pub min_contrast_gray: f32,
    /// Acceptance gate: smallest inlier ratio of the candidate alignment.
    /// Correct poses on `scanned` (unmapped boxes in view, other light)
    /// aligned at 0.63-0.99; the local-contrast correlation does the
    /// rejecting (candidates more than 10 cm off reached 0.65).
    pub min_inlier_ratio: f32,
    /// Acceptance gate: smallest fraction of candidate points visible.
    pub min_visible_ratio: f32,
    /// Acceptance gate: largest inlier residual RMS, gray levels.
    #[serde(alias = "max_residual")]
    pub max_residual_gray: f32,
    /// Acceptance gate: smallest normalized cross-correlation between the
    /// candidate's points and the frame at the aligned pose, the lowest of
    /// pyramid levels 0, 1 and 2 (detail and layout). Correct poses
    /// on the `realistic` preset (vignetting, noise, occluders) measured
    /// 0.58-0.80 against a keyframe rendered at the truth (an object not in
    /// the map pulls it down); the local-contrast figure below does the rejecting
    /// this one used to do alone at 0.6.
    pub min_correlation: f32,
    /// Acceptance gate of relocalization on maps checked for geometric
    /// twins (`geometric_twins`; by default the untextured maps, a scan's
    /// vertex colors with its light baked in): the plain correlation's floor
    /// there, in place of `min_correlation` when lower. On such a map the
    /// plain figure tells nothing: on 4 scanned rooms, 2 447 alignments more
    /// than 30 cm off reached 0.78 while true poses under another light
    /// read 0.27-0.46; local contrast kept them apart (wrong at most 0.20,
    /// true 0.57-0.91). Look-alike places pass either figure (on the
    /// scanned floor, plain 0.59-0.82 and local up to 0.83); the rival rule
    /// and the twins refuse them (docs/building-scale.md). Tracking's own
    /// resuming keeps `min_correlation`.
    pub twin_checked_min_correlation: f32,
    /// Acceptance gate of relocalization on maps checked for geometric
    /// twins: the inlier ratio's floor there, in place of
    /// `min_inlier_ratio` when lower. Auto-exposure at a gain of 1.7-2.1
    /// scales the baked map's errors with it, and true poses on 4 scanned
    /// rooms then kept 0.51-0.58 of their points within the inlier
    /// threshold; alignments more than 30 cm off reached 0.94, so the ratio
    /// refuses true poses there and no wrong one (local contrast does).
    pub twin_checked_min_inlier_ratio: f32,
    /// Acceptance gate: smallest correlation of local contrast over the
    /// same levels, trimmed of the points that do not fit
    /// ([`crate::track::Correlations::local`]: each intensity divided by
    /// the mean around it, so a lamp's falloff or a map's baked light does
    /// not count against a correct pose, and an object not in the map is
    /// trimmed away). On `scanned` seed 1 (TSDF vertex colors, baked light,
    /// a moving lamp, auto-exposure, unmapped boxes), over 214 candidates of
    /// 60 integrity runs: correct poses (within 5 cm) 0.64-0.88, median
    /// 0.86; every candidate more than 10 cm off at most 0.42. It replaced
    /// the trimmed intensity correlation (`min_trimmed_correlation` 0.75),
    /// which refused 124 of those 189 correct poses (they measured
    /// 0.63-0.92) while the wrong ones reached 0.69.
    pub min_local_correlation: f32,
    /// Acceptance gate where it starts at the map's detail (a keyframe
    /// whose [`crate::track::Keyframe::gate_level`] is above 0, a map
    /// coarser than the camera's pixels, with `gate_at_map_detail`): the
    /// local-contrast floor of that first level alone, in place of
    /// `min_local_correlation` when lower; the two coarser levels keep
    /// `min_local_correlation`. At the first level the map's colors are
    /// still blurred over a pixel or two: on 4 scanned rooms (2 cm, gate
    /// level 1), 190 alignments within 5 cm of the truth read 0.54-0.91
    /// there and 0.71-0.94 at levels 2-3; of 1 032 more than 10 cm off,
    /// none read 0.5 at level 1 and 0.7 at both coarser levels (the nearest,
    /// a place 2.4 m away: 0.59, then 0.66 and 0.70; a slide of 13 cm: 0.24,
    /// 0.48, 0.63). docs/building-scale.md, "The gate's first level on a
    /// scanned map". A pose that passes only through this floor is never
    /// accepted on the motion prior alone: its rivals are verified as on a
    /// cold start ([`crate::reloc::rivals::RivalRule::for_held`]). Accepted
    /// alone, on the scanned floor of look-alike rooms, a turned look-alike
    /// 1.4 m and 90 degrees from the truth read 0.53-0.57 there (0.7 or
    /// more above) and was taken twice in 50 searches near the last
    /// position, where the true place read 0.88 (docs/building-scale.md,
    /// "A turned look-alike through the lowered first level"). Set it to
    /// `min_local_correlation` to turn the split off.
    pub min_local_correlation_at_map_detail: f32,
    /// On a map checked for geometric twins (`geometric_twins`: a scan's
    /// vertex colors, its light baked in), the least local contrast
    /// ([`crate::reloc::Verified::local_correlation`]) of a pose accepted
    /// on the motion prior alone; below it, the places near it that could
    /// rival it are verified first ([`crate::reloc::rivals`]). On the
    /// scanned floor's 3 000-frame flight (50 window searches) a turned
    /// look-alike 1.4 m and 90 degrees from the truth passed at 0.714 and
    /// was taken on the prior alone; right poses there read 0.74-0.93, 15
    /// of 40 under 0.8 (docs/building-scale.md, "The prior alone on a
    /// scanned map"). No figure keeps the two apart (wrong poses that
    /// passed anywhere on that flight reached 0.81): this is where the
    /// time of the rival check is spent, not a gate. Set it to
    /// `min_local_correlation` to accept on the prior alone as before, or
    /// above 1 to verify the rivals of every pose.
    pub prior_alone_min_local_correlation: f32,
    /// Whether a pose that passes the gate only through the first level's
    /// lowered floor (`min_local_correlation_at_map_detail`) may be held
    /// beyond the motion prior's reach: on a cold start, after a kidnap, or
    /// away from a start hint. Off by default: on the scanned floor of
    /// look-alike rooms every wrong cold accept that the rivals and the
    /// twins left came through that floor (rooms 8-40 m from the truth),
    /// and its figures are those of right poses on a scan without
    /// look-alikes. On such a map (4 scanned rooms, each its own design)
    /// it gives about a quarter of the cold starts, and the first pose
    /// after a cold start, a kidnap or a wrong hint comes sooner
    /// (docs/building-scale.md, "The lowered first level on a cold
    /// start"). Turn it on only for a map whose places do not repeat.
    pub lowered_floor_without_prior: bool,
    /// On a map checked for geometric twins (a scan), the least plain
    /// correlation of the place a decisive correlation
    /// ([`crate::reloc::rivals::DECISIVE_MARGIN`]) chooses between two
    /// places that both pass the gate; 0.7 elsewhere. On the scanned floor
    /// a paced kidnap held a place 12.7 m from the truth because it read
    /// 0.749 against another wrong place's 0.627, and sent it; over 6 seeds
    /// of `star bench reloc` 48 choices took the right place at 0.77-0.93
    /// and 3 a wrong one at 0.744-0.753 (docs/building-scale.md,
    /// [`crate::reloc::rivals::RivalRule::with_decisive_floor`]). 0.7
    /// chooses as on a textured map; above 1 never chooses.
    pub twin_checked_decisive_min_correlation: f32,
    /// On a map checked for geometric twins (a scan), whether a decisive
    /// correlation may choose between two places once the listed rivals
    /// are verified (up to 8), though more places were eligible; elsewhere
    /// only when every eligible place was listed. On the scanned floor the
    /// place chosen at the floor above was never a wrong one in 254 pairs,
    /// and 42 frames of 1 400 searches were refused only for the places
    /// left unlisted ([`crate::reloc::rivals::RivalRule::with_listed_rivals_deciding`]).
    pub twin_checked_decisive_with_listed_rivals: bool,
    /// Whether the gate's inlier floor (`min_inlier_ratio`, or
    /// `twin_checked_min_inlier_ratio` on a twin-checked map) is divided by
    /// the alignment's photometric gain where the camera sees the map
    /// brighter (gain above 1): the map's own errors (baked light, scan
    /// noise) reach the frame scaled by the gain, and fewer points stay
    /// within the aligner's fixed inlier threshold. On the scanned floor
    /// the true pose aligned at inlier ratios 0.38-0.48 under gains of
    /// 1.4-2.5 with good correlations (docs/building-scale.md, "Where the
    /// scanned floor's searches are lost"). Gains above 2.5 count as 2.5
    /// (`reloc::verify::INLIER_FLOOR_MAX_GAIN`).
    pub inlier_floor_follows_gain: bool,
    /// Acceptance gate: range of the photometric gain (camera / map) of the
    /// candidate alignment. A wrong pose on a look-alike surface fits by
    /// crushing the contrast (gains of 0.3-0.5 seen before the correlation
    /// gates existed); correct ones on the `realistic` preset (gain drift
    /// +-30 %, vignetting) ranged 0.58-1.55, on `scanned` (auto-exposure
    /// against baked light) down to 0.38: hence 0.25..4, with the
    /// correlations doing the rejecting.
    pub min_gain: f32,
    /// Upper end of that range.
    pub max_gain: f32,
    /// A candidate alignment short of the gate with at least this inlier
    /// ratio is refined: a keyframe is rendered at the aligned pose and the
    /// frame aligned again.
    pub refine_min_inlier_ratio: f32,
    /// Renders per candidate after the first, at most: refinements and the
    /// confirmation render (0: accept straight from the database keyframe).
    pub refine_renders: u32,
    /// A pose is accepted only from an alignment that moved at most this far
    /// from its keyframe (otherwise the keyframe is rendered again there),
    /// meters ...
    pub confirm_max_m: f64,
    /// ... and degrees.
    pub confirm_max_deg: f64,
    /// Ordinary tracking is also lost when the keyframe points correlate
    /// less than this with the frame (pyramid level 1). Correct poses
    /// measured 0.37-0.95 on the synthetic presets (the lowest on a dim,
    /// blurred `realistic` sequence, seed 12).
    pub track_min_correlation: f32,
    /// Ordinary tracking is also lost when the local-contrast correlation
    /// of the keyframe points with the frame (trimmed, the lowest of
    /// pyramid levels 0-2, as `min_local_correlation`) is below this. An alignment that slides
    /// along the planks of a wooden floor keeps the plain correlation near
    /// a correct pose's but loses the fine texture: on `aggressive
    /// --scanned` seed 2 such frames 8-15 cm off measured 0.06-0.20, the
    /// correct ones at least 0.5.
    pub track_min_local_correlation: f32,
    /// Where the local contrast of the frames tracked reads lower than
    /// this on average (its running mean, once settled), the map shows
    /// less fine detail than the camera (a scan at 2 cm: true poses
    /// 0.28-0.40, mean 0.36), and `track_min_local_correlation` is lowered
    /// in proportion, to no lower than `track_min_local_correlation_lowest`.
    /// 0 turns this off.
    pub track_local_reference: f32,
    /// The lowest the floor above is lowered to.
    pub track_min_local_correlation_lowest: f32,
    /// Frames after an accepted relocalization that must track through the
    /// same gate before a pose is output again. 2 since 2026-12-07: on the
    /// scanned floor a cold start accepted a place 4.3-5.6 m off and turned
    /// 180 degrees, the next frame confirmed it and one wrong pose went
    /// out; the frame after that was lost (docs/building-scale.md, "A
    /// second frame to confirm a relocalization").
    pub verify_frames: u32,
    /// Within this time of the failure, ordinary tracking may resume on its
    /// own; afterwards only an accepted relocalization restarts it, seconds.
    pub resume_window_s: f64,
    /// A frame resuming on its own needs local contrast of at least
    /// `min_local_correlation`, or this fraction of the reference the
    /// tracked frames before the loss set (the drop test's), where that is
    /// lower: blurred frames track at 0.55-0.70 and seldom resume
    /// against the fixed floor (docs/benchmarks.md, "A resume on blurred
    /// frames"). 0 keeps the fixed floor.
    pub resume_local_fraction: f32,
    /// A relocalization attempt tries no new candidate after this long,
    /// seconds (0: no limit): by then its frame is stale, and the next
    /// attempt starts from a fresh one. The landmark pose is always tried.
    /// Offline runs without `--realtime` do not limit it (the result would
    /// depend on the machine's speed).
    pub attempt_budget_s: f64,
    /// Landmarks (`star reloc build`): full-resolution views on a horizontal
    /// grid this far apart (meters; 0: no landmarks), ...
    pub landmark_spacing_m: f64,
    /// ... at these heights above the floor, meters, ...
    pub landmark_heights_m: Vec<f64>,
    /// ... with this many yaws, evenly spaced over 360 degrees, at the
    /// middle of `pitches_deg`.
    pub landmark_yaw_steps: u32,
    /// Features per view and per lost frame.
    pub landmark_features: u32,
    /// Largest Hamming distance (of 256 bits) of a feature-to-landmark match.
    #[serde(alias = "landmark_max_hamming")]
    pub landmark_max_hamming_bits: u32,
    /// Fewest PnP inliers for a landmark pose to become a candidate.
    pub landmark_min_inliers: u32,
    /// Whether relocalization's verification starts its correlations at the
    /// pyramid level the map's detail supports (`Keyframe::gate_level`:
    /// one level up on a map coarser than the camera's pixels) instead of
    /// level 0. On by default: on 4 rooms scanned at 2 cm it turned 0-21 %
    /// of cold starts into 39-40 %, and on the 22-room scanned floor 4 / 50
    /// into 10 / 50, with no wrong accept there once the geometric twins
    /// check ran. Tracking that resumes on its own after a short loss reads
    /// from level 0 whatever this says ([`super::passes_resume_gate`]).
    /// (docs/building-scale.md)
    pub gate_at_map_detail: bool,
    /// On which maps a pose the motion prior cannot vouch for is also
    /// checked at its geometric twins, the places where its view's surfaces
    /// stand again ([`super::twins`]): refused when its view fits at many
    /// places, or when the frame passes a looser gate at one of the best
    /// three. `untextured` (the default): maps whose appearance is vertex
    /// color, as a scan's is, with the scan's light baked in; there the
    /// frame can look more like a twin's scan than like its own place's.
    pub geometric_twins: GeometricTwinMaps,
}

impl Default for RelocConfig {
    fn default() -> Self {
        Self {
            database: None,
            grid_spacing_m: 0.25,
            heights_m: vec![1.0, 1.4, 1.8],
            floor_z_m: None,
            yaw_steps: 24,
            pitches_deg: vec![-5.0],
            bounds_margin_m: 0.3,
            min_valid_fraction: 0.8,
            min_depth_m: 0.4,
            top_k: 8,
            rank_candidates: 32,
            search_radius_m: 0.5,
            max_speed_m_s: 2.0,
            search_yaw_deg: 30.0,
            max_yaw_rate_deg_s: 120.0,
            min_contrast_gray: 4.0,
            min_inlier_ratio: 0.6,
            min_visible_ratio: 0.5,
            max_residual_gray: 12.0,
            min_correlation: 0.5,
            twin_checked_min_correlation: 0.2,
            twin_checked_min_inlier_ratio: 0.5,
            min_local_correlation: 0.7,
            min_local_correlation_at_map_detail: 0.5,
            prior_alone_min_local_correlation: 0.8,
            lowered_floor_without_prior: false,
            twin_checked_decisive_min_correlation: 0.8,
            twin_checked_decisive_with_listed_rivals: true,
            inlier_floor_follows_gain: true,
            min_gain: 0.25,
            max_gain: 4.0,
            refine_min_inlier_ratio: 0.4,
            refine_renders: 2,
            confirm_max_m: 0.03,
            confirm_max_deg: 1.5,
            track_min_correlation: 0.3,
            track_min_local_correlation: 0.3,
            track_local_reference: 0.5,
            track_min_local_correlation_lowest: 0.2,
            verify_frames: 2,
            resume_window_s: 0.2,
            resume_local_fraction: 0.9,
            attempt_budget_s: 0.5,
            landmark_spacing_m: 0.5,
            landmark_heights_m: vec![1.4],
            landmark_yaw_steps: 8,
            landmark_features: 300,
            landmark_max_hamming_bits: 50,
            landmark_min_inliers: 15,
            gate_at_map_detail: true,
            geometric_twins: GeometricTwinMaps::Untextured,
        }
    }
}

impl RelocConfig {
    /// Checks every value; keys are relative to `[reloc]`.
    pub fn validate(&self) -> Result<(), SettingError> {
        self.check()
            .map_err(|(key, reason)| SettingError::new(key, reason))
    }

    fn check(&self) -> Result<(), (&'static str, String)> {
        let pos = |v: f64| v.is_finite() && v > 0.0;
        let unit = |v: f32| v.is_finite() && (0.0..=1.0).contains(&v);
        if !(pos(self.grid_spacing_m) && self.grid_spacing_m >= 0.05) {
            return Err((
                "grid_spacing_m",
                format!("expected >= 0.05, found {}", self.grid_spacing_m),
            ));
        }
        let heights_ok = |h: &[f64]| !h.is_empty() && h.iter().all(|v| v.is_finite());
        if !heights_ok(&self.heights_m) {
            return Err((
                "heights_m",
                format!(
                    "expected at least one finite height, found {:?}",
                    self.heights_m
                ),
            ));
        }
        if let Some(z) = self.floor_z_m {
            if !(z.is_finite() && z.abs() <= 1000.0) {
                return Err(("floor_z_m", format!("expected -1000..=1000 m, found {z}")));
            }
        }
        if self.pitches_deg.is_empty()
            || self
                .pitches_deg
                .iter()
                .any(|p| !(p.is_finite() && p.abs() < 90.0))
        {
            return Err((
                "pitches_deg",
                format!(
                    "expected at least one pitch in (-90, 90), found {:?}",
                    self.pitches_deg
                ),
            ));
        }
        let checks: [(&'static str, bool, String); 38] = [
            (
                "yaw_steps",
                (1..=360).contains(&self.yaw_steps),
                format!("expected 1..=360, found {}", self.yaw_steps),
            ),
            (
                "landmark_yaw_steps",
                (1..=360).contains(&self.landmark_yaw_steps),
                format!("expected 1..=360, found {}", self.landmark_yaw_steps),
            ),
            (
                "landmark_spacing_m",
                self.landmark_spacing_m == 0.0
                    || (self.landmark_spacing_m.is_finite() && self.landmark_spacing_m >= 0.1),
                format!(
                    "expected 0 (no landmarks) or >= 0.1, found {}",
                    self.landmark_spacing_m
                ),
            ),
            (
                "landmark_features",
                (16..=5000).contains(&self.landmark_features),
                format!("expected 16..=5000, found {}", self.landmark_features),
            ),
            (
                "landmark_max_hamming_bits",
                self.landmark_max_hamming_bits <= 256,
                format!("expected 0..=256, found {}", self.landmark_max_hamming_bits),
            ),
            (
                "landmark_min_inliers",
                self.landmark_min_inliers >= 6,
                format!("expected >= 6, found {}", self.landmark_min_inliers),
            ),
            (
                "confirm_max_m",
                self.confirm_max_m.is_finite() && self.confirm_max_m > 0.0,
                format!("expected > 0, found {}", self.confirm_max_m),
            ),
            (
                "confirm_max_deg",
                self.confirm_max_deg.is_finite() && self.confirm_max_deg > 0.0,
                format!("expected > 0, found {}", self.confirm_max_deg),
            ),
            (
                "max_gain",
                self.min_gain.is_finite()
                    && self.max_gain.is_finite()
                    && self.min_gain > 0.0
                    && self.max_gain > self.min_gain,
                format!(
                    "expected 0 < min_gain < max_gain, found {} and {}",
                    self.min_gain, self.max_gain
                ),
            ),
            (
                "refine_min_inlier_ratio",
                unit(self.refine_min_inlier_ratio),
                format!("expected 0..=1, found {}", self.refine_min_inlier_ratio),
            ),
            (
                "refine_renders",
                self.refine_renders <= 8,
                format!("expected 0..=8, found {}", self.refine_renders),
            ),
            (
                "track_min_correlation",
                self.track_min_correlation.is_finite()
                    && (-1.0..=1.0).contains(&self.track_min_correlation),
                format!("expected -1..=1, found {}", self.track_min_correlation),
            ),
            (
                "track_min_local_correlation",
                self.track_min_local_correlation.is_finite()
                    && (-1.0..=1.0).contains(&self.track_min_local_correlation),
                format!(
                    "expected -1..=1, found {}",
                    self.track_min_local_correlation
                ),
            ),
            (
                "track_local_reference",
                self.track_local_reference.is_finite()
                    && (0.0..=1.0).contains(&self.track_local_reference),
                format!("expected 0..=1, found {}", self.track_local_reference),
            ),
            (
                "track_min_local_correlation_lowest",
                self.track_min_local_correlation_lowest.is_finite()
                    && (-1.0..=1.0).contains(&self.track_min_local_correlation_lowest),
                format!(
                    "expected -1..=1, found {}",
                    self.track_min_local_correlation_lowest
                ),
            ),
            (
                "min_local_correlation_at_map_detail",
                self.min_local_correlation_at_map_detail.is_finite()
                    && (-1.0..=1.0).contains(&self.min_local_correlation_at_map_detail),
                format!(
                    "expected -1..=1, found {}",
                    self.min_local_correlation_at_map_detail
                ),
            ),
            (
                "prior_alone_min_local_correlation",
                self.prior_alone_min_local_correlation.is_finite(),
                format!(
                    "expected a number, found {}",
                    self.prior_alone_min_local_correlation
                ),
            ),
            (
                "twin_checked_decisive_min_correlation",
                self.twin_checked_decisive_min_correlation.is_finite(),
                format!(
                    "expected a number (0.7 chooses as on a textured map, above 1 never), found {}",
                    self.twin_checked_decisive_min_correlation
                ),
            ),
            (
                "min_local_correlation",
                self.min_local_correlation.is_finite()
                    && (-1.0..=1.0).contains(&self.min_local_correlation),
                format!("expected -1..=1, found {}", self.min_local_correlation),
            ),
            (
                "min_correlation",
                self.min_correlation.is_finite() && (-1.0..=1.0).contains(&self.min_correlation),
                format!("expected -1..=1, found {}", self.min_correlation),
            ),
            (
                "twin_checked_min_inlier_ratio",
                unit(self.twin_checked_min_inlier_ratio),
                format!(
                    "expected 0..=1, found {}",
                    self.twin_checked_min_inlier_ratio
                ),
            ),
            (
                "twin_checked_min_correlation",
                self.twin_checked_min_correlation.is_finite()
                    && (-1.0..=1.0).contains(&self.twin_checked_min_correlation),
                format!(
                    "expected -1..=1, found {}",
                    self.twin_checked_min_correlation
                ),
            ),
            (
                "bounds_margin_m",
                self.bounds_margin_m.is_finite() && self.bounds_margin_m >= 0.0,
                format!("expected >= 0, found {}", self.bounds_margin_m),
            ),
            (
                "min_valid_fraction",
                self.min_valid_fraction.is_finite()
                    && (0.0..=1.0).contains(&self.min_valid_fraction),
                format!("expected 0..=1, found {}", self.min_valid_fraction),
            ),
            (
                "min_depth_m",
                self.min_depth_m.is_finite() && self.min_depth_m >= 0.0,
                format!("expected >= 0, found {}", self.min_depth_m),
            ),
            (
                "top_k",
                (1..=MAX_TOP_K as u32).contains(&self.top_k),
                format!("expected 1..={MAX_TOP_K}, found {}", self.top_k),
            ),
            (
                "rank_candidates",
                self.rank_candidates <= MAX_TOP_K as u32,
                format!("expected 0..={MAX_TOP_K}, found {}", self.rank_candidates),
            ),
            (
                "search_radius_m",
                pos(self.search_radius_m),
                format!("expected > 0, found {}", self.search_radius_m),
            ),
            (
                "max_speed_m_s",
                self.max_speed_m_s.is_finite() && self.max_speed_m_s >= 0.0,
                format!("expected >= 0, found {}", self.max_speed_m_s),
            ),
            (
                "search_yaw_deg",
                (0.0..=180.0).contains(&self.search_yaw_deg),
                format!("expected 0..=180 degrees, found {}", self.search_yaw_deg),
            ),
            (
                "max_yaw_rate_deg_s",
                self.max_yaw_rate_deg_s.is_finite() && self.max_yaw_rate_deg_s >= 0.0,
                format!(
                    "expected >= 0 degrees per second, found {}",
                    self.max_yaw_rate_deg_s
                ),
            ),
            (
                "min_contrast_gray",
                self.min_contrast_gray.is_finite() && self.min_contrast_gray >= 0.0,
                format!("expected >= 0, found {}", self.min_contrast_gray),
            ),
            (
                "min_inlier_ratio",
                unit(self.min_inlier_ratio),
                format!("expected 0..=1, found {}", self.min_inlier_ratio),
            ),
            (
                "min_visible_ratio",
                unit(self.min_visible_ratio),
                format!("expected 0..=1, found {}", self.min_visible_ratio),
            ),
            (
                "max_residual_gray",
                self.max_residual_gray.is_finite() && self.max_residual_gray > 0.0,
                format!("expected > 0, found {}", self.max_residual_gray),
            ),
            (
                "attempt_budget_s",
                self.attempt_budget_s.is_finite() && self.attempt_budget_s >= 0.0,
                format!(
                    "expected >= 0 (0: no limit), found {}",
                    self.attempt_budget_s
                ),
            ),
            (
                "resume_local_fraction",
                self.resume_local_fraction.is_finite()
                    && (0.0..=1.0).contains(&self.resume_local_fraction),
                format!("expected 0..=1, found {}", self.resume_local_fraction),
            ),
            (
                "resume_window_s",
                self.resume_window_s.is_finite() && self.resume_window_s >= 0.0,
                format!("expected >= 0, found {}", self.resume_window_s),
            ),
        ];
        for (key, ok, reason) in checks {
            if !ok {
                return Err((key, reason));
            }
        }
        if self.landmark_spacing_m > 0.0 && !heights_ok(&self.landmark_heights_m) {
            return Err((
                "landmark_heights_m",
                format!(
                    "expected at least one finite height, found {:?}",
                    self.landmark_heights_m
                ),
            ));
        }
        if self.verify_frames > 50 {
            return Err((
                "verify_frames",
                format!("expected 0..=50, found {}", self.verify_frames),
            ));
        }
        Ok(())
    }

    /// The largest gap between adjacent `heights_m`, meters (0 with one
    /// height): the truth is at most half of it from a database height.
    /// Allocates nothing (relocalization calls it while lost).
    pub fn height_spacing_m(&self) -> f64 {
        let h = &self.heights_m;
        h.iter()
            .map(|&a| {
                // Gap to the next height above `a`.
                h.iter()
                    .filter(|&&b| b > a)
                    .fold(f64::INFINITY, |gap, &b| gap.min(b - a))
            })
            .filter(|gap| gap.is_finite())
            .fold(0.0, f64::max)
    }

    /// Yaws of the landmark views, radians.
    pub fn landmark_yaws_rad(&self) -> impl Iterator<Item = f64> {
        even_yaws_rad(self.landmark_yaw_steps)
    }

    /// Yaw angles of the grid, radians.
    pub fn yaws_rad(&self) -> impl Iterator<Item = f64> {
        even_yaws_rad(self.yaw_steps)
    }
}

/// `steps` yaws evenly spaced over a turn from 0, radians.
fn even_yaws_rad(steps: u32) -> impl Iterator<Item = f64> {
    let n = steps.max(1);
    (0..n).map(move |i| i as f64 * std::f64::consts::TAU / n as f64)
}

#[cfg(test)]
mod tests {
    use super::RelocConfig;

    #[test]
    fn height_spacing_is_the_largest_gap_between_adjacent_heights() {
        let with = |heights_m: Vec<f64>| RelocConfig {
            heights_m,
            ..RelocConfig::default()
        };
        assert!((with(vec![1.8, 1.0, 1.4]).height_spacing_m() - 0.4).abs() < 1e-12);
        assert!((with(vec![1.0, 1.2, 1.8]).height_spacing_m() - 0.6).abs() < 1e-12);
        assert_eq!(with(vec![1.2]).height_spacing_m(), 0.0);
        assert_eq!(with(vec![1.2, 1.2]).height_spacing_m(), 0.0);
    }

    #[test]
    fn a_bad_heading_bound_or_decisive_floor_names_its_key() {
        for (config, key) in [
            (
                RelocConfig {
                    search_yaw_deg: -1.0,
                    ..RelocConfig::default()
                },
                "search_yaw_deg",
            ),
            (
                RelocConfig {
                    search_yaw_deg: f64::NAN,
                    ..RelocConfig::default()
                },
                "search_yaw_deg",
            ),
            (
                RelocConfig {
                    max_yaw_rate_deg_s: f64::INFINITY,
                    ..RelocConfig::default()
                },
                "max_yaw_rate_deg_s",
            ),
            (
                RelocConfig {
                    twin_checked_decisive_min_correlation: f32::NAN,
                    ..RelocConfig::default()
                },
                "twin_checked_decisive_min_correlation",
            ),
        ] {
            let Err(e) = config.validate() else {
                panic!("{key} accepted");
            };
            assert_eq!(e.key, key);
        }
        assert!(RelocConfig::default().validate().is_ok());
    }
}
