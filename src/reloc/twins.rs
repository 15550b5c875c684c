//! Geometric twins of a relocalized pose: the places where the map's
//! surfaces stand as they do in the held pose's view, moved by a horizontal
//! translation (found by [`crate::map::repeats`]), and the looser gate the
//! frame is checked through there; and its turned twins, where they stand
//! turned by a quarter, a half or three quarters about the camera's
//! vertical axis and then moved ([`TWIN_YAWS`]).
//!
//! Why. The rival rule ([`super::rivals`]) verifies the frame at the other
//! places the descriptor and the landmarks found. On a scanned map the
//! baked light differs from one stretch of corridor to the next, so the
//! frame can look more like the scan of a place 40 m away than like its own
//! place, and its own place is then never among the candidates (the
//! scanned floor's wrong accept, docs/building-scale.md). The repeat is in
//! the geometry, so the geometry finds it. A pose the prior cannot vouch
//! for is refused when:
//! - its view fits at [`DEGENERATE_TWINS`] places or more (a plain wall
//!   along a corridor: only appearance could tell them apart); or
//! - the frame passes [`GeometricTwins::loose`] at one of the best
//!   [`TWIN_CHECKS`] twins; or
//! - a twin, moved or turned, stands within the prior's reach while the
//!   held pose does not ([`prior_prefers_a_twin`]): the geometry stands
//!   the same where the vehicle is expected to be. On the scanned floor a
//!   window search accepted a pose 1.5 m from the truth and turned 179.8
//!   degrees from it (correlation 0.74); the truth was its turned twin, and
//!   the frame failed even the looser gate there (docs/building-scale.md).
//!
//! Turned twins refuse only that way: a box room's corners are each
//! other's turned twins, too common to make a view degenerate or to be
//! worth a render each. The turns make a check four searches instead of
//! one (a search took 2.5-17 ms on the scanned floor, `map::repeats`).
//!
//! Where: `[reloc] geometric_twins`, by default on maps without texture,
//! whose appearance is a scan's vertex color. On the textured `building`
//! floor, whose look-alike rooms are built to the last vertex, the rule
//! refused 41 of 95 right cold starts, and sent no fewer wrong poses (none
//! either way): there the rivals' correlation tells the places apart.
//!
//! The looser gate starts at the map's detail and lowers both correlation
//! thresholds by [`LOOSE_MARGIN`]: the true place of a scanned map, seen
//! through a different scan light, aligned with correlation 0.59-0.61 and
//! failed the strict gate only at level 0.
//!
//! Owns the map's occupancy and the search buffers; nothing allocates after
//! [`GeometricTwins::new`].

use nalgebra::{Translation3, Vector3};

use crate::geometry::Pose;
use crate::map::repeats::{MapOccupancy, Twin, TwinScratch};
use crate::map::Mesh;
use crate::track::Keyframe;

use super::config::{GeometricTwinMaps, RelocConfig};
use super::prior::MotionPrior;

/// A view that fits at this many places or more is degenerate: refused
/// without a prior.
pub const DEGENERATE_TWINS: usize = 8;
/// Twins the frame is checked at, at most: every twin short of a
/// degenerate view (3 until 2026-12-07: on the scanned floor the three
/// best were one room found three times, 0.35 m apart, and the true room
/// was not among them).
pub const TWIN_CHECKS: usize = DEGENERATE_TWINS - 1;
/// [`GeometricTwins::check_near`] searches this far beyond the prior's
/// reach, meters: a kidnap lands outside it (the `building` floor's
/// integrity trial that sent wrong poses jumped 1.33 m while the reach was
/// 0.94 m), and a twin there is checked, not refused.
pub const NEAR_PRIOR_SLACK_M: f64 = 2.0;
/// The looser gate's correlation thresholds are this much lower.
pub const LOOSE_MARGIN: f32 = 0.1;
/// Pyramid level whose keyframe points describe the view (160x128 for the
/// presets' camera).
const POINTS_LEVEL: usize = 2;
/// Keyframe points handed to the search, at most.
const MAX_VIEW_POINTS: usize = 1024;
/// The turns of the view searched, radians: none, then a quarter, a half
/// and three quarters about the camera's vertical axis.
pub const TWIN_YAWS: [f64; 4] = [
    0.0,
    std::f64::consts::FRAC_PI_2,
    std::f64::consts::PI,
    3.0 * std::f64::consts::FRAC_PI_2,
];

/// The map's occupancy, the looser gate and the buffers of one check.
#[derive(Debug, Clone)]
pub struct GeometricTwins {
    occupancy: MapOccupancy,
    scratch: TwinScratch,
    points: Vec<Vector3<f64>>,
    found: heapless::Vec<Twin, DEGENERATE_TWINS>,
    /// The best twins turned by a quarter, a half or three quarters.
    turned: heapless::Vec<Twin, DEGENERATE_TWINS>,
    /// One turn's twins.
    found_turn: heapless::Vec<Twin, DEGENERATE_TWINS>,
    loose: RelocConfig,
    /// Only [`TwinRefusal::PriorPrefersATwin`] applies (a textured map
    /// under `geometric_twins = "untextured"`): see [`Self::prior_only`].
    prior_only: bool,
}

/// What the geometry says about a held pose.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TwinCheck {
    /// No other place holds its view's surfaces (or no map was given).
    Unique,
    /// Its view fits at [`DEGENERATE_TWINS`] places or more.
    Degenerate,
    /// This many twins to check the frame at.
    Check(usize),
}

impl GeometricTwins {
    /// For `mesh` under `config` (the occupancy takes about a second for a
    /// 15 M-triangle floor); none when `[reloc] geometric_twins` leaves the
    /// map out.
    pub fn new(mesh: &Mesh, config: &RelocConfig) -> Self {
        let textured = mesh.groups.iter().any(|g| g.texture.is_some());
        let (built, checked) = match config.geometric_twins {
            GeometricTwinMaps::Never => (false, false),
            GeometricTwinMaps::Untextured => (true, !textured),
            GeometricTwinMaps::Always => (true, true),
        };
        let occupancy = if built {
            MapOccupancy::build(mesh)
        } else {
            MapOccupancy::none()
        };
        let mut twins = Self::with_occupancy(occupancy, &relocalization_gate(config, checked));
        twins.prior_only = !checked;
        twins
    }

    /// No map: every pose is [`TwinCheck::Unique`].
    pub fn none(config: &RelocConfig) -> Self {
        Self::with_occupancy(MapOccupancy::none(), config)
    }

    fn with_occupancy(occupancy: MapOccupancy, config: &RelocConfig) -> Self {
        Self {
            scratch: occupancy.scratch(),
            occupancy,
            points: Vec::with_capacity(MAX_VIEW_POINTS),
            found: heapless::Vec::new(),
            turned: heapless::Vec::new(),
            found_turn: heapless::Vec::new(),
            loose: loose_gate(config),
            prior_only: false,
        }
    }

    /// Whether held poses are checked at their twins in full (a map
    /// `[reloc] geometric_twins` names: its gate's floors are lowered, a
    /// pose is refused when its view is degenerate or the frame passes at
    /// a twin, [`plan`]).
    pub fn has_map(&self) -> bool {
        self.has_occupancy() && !self.prior_only
    }

    /// Whether a map's occupancy is held: twins are searched, for the
    /// full check ([`Self::has_map`]) or for the prior's rule alone
    /// ([`Self::prior_only`]).
    pub fn has_occupancy(&self) -> bool {
        !self.occupancy.is_empty()
    }

    /// Whether only the prior's rule applies ([`TwinRefusal::PriorPrefersATwin`]):
    /// on a map `geometric_twins` does not name (a textured one, by
    /// default), whose gate stays whole and whose views are not refused as
    /// degenerate nor checked at their twins. Why: on the textured
    /// `building` floor a kidnap 1.33 m back along the flight was followed
    /// by a landmark pose in the look-alike room across the corridor, 20 m
    /// away and turned 180 degrees, which passed the gate alone (the true
    /// place was never aligned) and sent 77 wrong poses (`star bench
    /// integrity`, docs/building-scale.md); its turned twin stood where the
    /// prior expected the vehicle.
    pub fn prior_only(&self) -> bool {
        self.prior_only
    }

    /// The gate a twin is checked through.
    pub fn loose(&self) -> &RelocConfig {
        &self.loose
    }

    /// Searches the twins of the view of `keyframe` (rendered at the held
    /// pose); at most [`TWIN_CHECKS`] are kept to check.
    pub fn check(&mut self, keyframe: &Keyframe) -> TwinCheck {
        self.check_within(keyframe, None)
    }

    /// [`Self::check`] with only the twins whose camera stands within
    /// `prior`'s region ([`MotionPrior::region`]): for the prior's rule
    /// ([`prior_prefers_a_twin`]) on a map checked for it alone
    /// ([`Self::prior_only`]). Searched over the whole map, a view of one
    /// of the `building` floor's rooms, which repeat along its corridor,
    /// fills the list with the rooms that score best, and the one across
    /// the corridor where the prior expects the vehicle was not among
    /// them.
    pub fn check_near(&mut self, keyframe: &Keyframe, prior: &MotionPrior) -> TwinCheck {
        let camera = keyframe.world_from_keyframe.translation.vector;
        let d = prior.center_m - camera;
        self.check_within(
            keyframe,
            Some(([d.x, d.y], prior.radius_m + NEAR_PRIOR_SLACK_M)),
        )
    }

    fn check_within(&mut self, keyframe: &Keyframe, within: Option<([f64; 2], f64)>) -> TwinCheck {
        self.found.clear();
        self.turned.clear();
        if !self.has_occupancy() {
            return TwinCheck::Unique;
        }
        let level = POINTS_LEVEL.min(keyframe.levels.len().saturating_sub(1));
        let Some(points) = keyframe.levels.get(level).map(|l| &l.points) else {
            return TwinCheck::Unique;
        };
        let stride = points.len().div_ceil(MAX_VIEW_POINTS).max(1);
        self.points.clear();
        let world_from_keyframe = &keyframe.world_from_keyframe;
        for p in points.iter().step_by(stride).take(MAX_VIEW_POINTS) {
            let p_keyframe = Vector3::new(
                f64::from(p.p_keyframe[0]),
                f64::from(p.p_keyframe[1]),
                f64::from(p.p_keyframe[2]),
            );
            self.points.push(
                world_from_keyframe.transform_vector(&p_keyframe)
                    + world_from_keyframe.translation.vector,
            );
        }
        self.search(&world_from_keyframe.translation.vector, within)
    }

    /// [`Self::check`] for the view's points already in `self.points`,
    /// seen from `camera_world`: the twins moved only ([`Self::found`],
    /// what the check says), then those turned by the other
    /// [`TWIN_YAWS`] ([`Self::turned`], for [`prior_prefers_a_twin`]
    /// only: a box room's corners are each other's turned twins, so they
    /// neither make a view degenerate nor are worth a render each); only
    /// those within `within` ([`MapOccupancy::twins_turned`]) when given.
    fn search(
        &mut self,
        camera_world: &Vector3<f64>,
        within: Option<([f64; 2], f64)>,
    ) -> TwinCheck {
        self.occupancy.twins_turned(
            camera_world,
            &self.points,
            (0.0, within),
            &mut self.scratch,
            &mut self.found,
        );
        self.turned.clear();
        for yaw_rad in TWIN_YAWS.into_iter().skip(1) {
            self.occupancy.twins_turned(
                camera_world,
                &self.points,
                (yaw_rad, within),
                &mut self.scratch,
                &mut self.found_turn,
            );
            for &twin in &self.found_turn {
                crate::map::repeats::insert(&mut self.turned, twin);
            }
        }
        match self.found.len() {
            0 => TwinCheck::Unique,
            n if n >= DEGENERATE_TWINS => TwinCheck::Degenerate,
            n => TwinCheck::Check(n.min(TWIN_CHECKS)),
        }
    }

    /// How well the view of the last [`Self::check`] fits at `twin`'s turn
    /// and offset ([`MapOccupancy::score_at`]): its score and free-space
    /// fraction, for diagnosis (why a place was not among the twins).
    pub fn score_of(&mut self, camera_world: &Vector3<f64>, twin: &Twin) -> Option<(f32, f32)> {
        self.occupancy.score_at(
            camera_world,
            &self.points,
            (twin.yaw_rad, twin.offset_m),
            &mut self.scratch,
        )
    }

    /// The turned twins of the last [`Self::check`], best first.
    pub fn turned(&self) -> &[Twin] {
        &self.turned
    }

    /// The twins of the last [`Self::check`], best first.
    pub fn found(&self) -> &[Twin] {
        &self.found
    }
}

/// The turn and offset that take `held` to `other` as [`twin_pose`] would
/// (the turn about the vertical from heading to heading; score 0): for
/// diagnosis, `other` a known true place.
pub fn twin_between(held: &Pose, other: &Pose) -> Twin {
    let heading = |p: &Pose| {
        let axis = p.rotation * Vector3::z();
        axis.y.atan2(axis.x)
    };
    let d = other.translation.vector - held.translation.vector;
    Twin {
        offset_m: [d.x, d.y],
        yaw_rad: (heading(other) - heading(held)).rem_euclid(std::f64::consts::TAU),
        score: 0.0,
    }
}

/// `held` turned by the twin's yaw about its camera's vertical axis, then
/// moved by its offset (the same height, pitch and roll).
pub fn twin_pose(held: &Pose, twin: &Twin) -> Pose {
    let turn = nalgebra::UnitQuaternion::from_axis_angle(&Vector3::z_axis(), twin.yaw_rad);
    Pose::from_parts(
        Translation3::from(
            held.translation.vector + Vector3::new(twin.offset_m[0], twin.offset_m[1], 0.0),
        ),
        turn * held.rotation,
    )
}

/// Whether [`plan`] can refuse `held` under `rule` or list a twin for it:
/// not when the prior vouches for its place, nor, with `prior_only`, when
/// there is no prior (a cold start). The twin search (2.5-17 ms) is skipped
/// otherwise.
pub fn plan_needs_twins(rule: &super::rivals::RivalRule, held: &Pose, prior_only: bool) -> bool {
    !rule.vouches_for_place(held) && (!prior_only || rule.has_prior())
}

/// Whether a held pose the prior of `rule` cannot vouch for has a
/// geometric twin (of `found`, all of them) that it can: the map's geometry
/// stands the same where the vehicle is expected to be, so the held pose
/// is no more than a look-alike of it. Refused then even when the frame
/// fails the gate at the twin, as a scan's baked light can make it: on the
/// scanned floor a window search held a pose 1.5 m from the truth turned
/// 179.8 degrees, the truth its turned twin, where the frame aligned with
/// correlation 0.19 (docs/building-scale.md). Never with no prior (a cold
/// start).
pub fn prior_prefers_a_twin(
    rule: &super::rivals::RivalRule,
    held: &Pose,
    (found, turned): (&[Twin], &[Twin]),
) -> bool {
    !rule.prior_reaches(held)
        && found
            .iter()
            .chain(turned)
            .any(|t| rule.prior_reaches(&twin_pose(held, t)))
}

/// Turned twins the frame is checked at, at most, for a pose the prior
/// cannot vouch for (the best of [`GeometricTwins::turned`]).
pub const TURNED_CHECKS: usize = 2;
/// Most twins one [`TwinPlan`] checks.
pub const MAX_PLANNED: usize = TWIN_CHECKS + TURNED_CHECKS;

/// Why the geometry refuses a held pose without a render.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TwinRefusal {
    /// A twin stands within the prior's reach while the held pose does not
    /// ([`prior_prefers_a_twin`]).
    PriorPrefersATwin,
    /// Its view fits at [`DEGENERATE_TWINS`] places or more.
    Degenerate,
}

/// What the geometry asks of a held pose before it is accepted: one rule,
/// for the service and `star bench reloc` alike.
// The checks are held inline (about 300 bytes, on the stack of one
// attempt): a box would allocate in each relocalization attempt, which
// allocates nothing (`crate::localizer`'s relocalization, module docs).
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone, PartialEq)]
pub enum TwinPlan {
    /// Refused without a render.
    Refuse(TwinRefusal),
    /// Check the frame at these twins, in order, through
    /// [`GeometricTwins::loose`]: the pose is refused when the frame passes
    /// at one of them at another place ([`super::rivals::elsewhere`]).
    /// Empty: accepted.
    Check(heapless::Vec<Twin, MAX_PLANNED>),
}

/// The [`TwinPlan`] of `held` under `rule`, from its [`GeometricTwins::check`]
/// (`check`, `found`, `turned`); with `prior_only`
/// ([`GeometricTwins::prior_only`]: `found` and `turned` are the twins near
/// the prior, [`GeometricTwins::check_near`]) only the prior's rule refuses
/// outright, the view is never degenerate, and the best twins are checked.
///
/// - A pose whose place the prior vouches for
///   ([`RivalRule::vouches_for_place`]) is not checked.
/// - One it cannot vouch for is refused when a twin stands within the
///   prior's reach ([`prior_prefers_a_twin`]) or its view is degenerate,
///   else checked at its best [`TWIN_CHECKS`] moved twins, then at its best
///   [`TURNED_CHECKS`] turned ones: a room built again elsewhere turned
///   round is as much a twin as one moved (`tests/reloc_twins.rs`).
///
/// [`RivalRule::vouches_for_place`]: super::rivals::RivalRule::vouches_for_place
pub fn plan(
    rule: &super::rivals::RivalRule,
    held: &Pose,
    (check, prior_only): (TwinCheck, bool),
    (found, turned): (&[Twin], &[Twin]),
) -> TwinPlan {
    let mut out = heapless::Vec::new();
    if rule.vouches_for_place(held) {
        return TwinPlan::Check(out);
    }
    if prior_prefers_a_twin(rule, held, (found, turned)) {
        return TwinPlan::Refuse(TwinRefusal::PriorPrefersATwin);
    }
    // Prior only: the twins near the prior ([`GeometricTwins::check_near`]);
    // many of them there do not make the view degenerate.
    let moved = match check {
        _ if prior_only => TWIN_CHECKS,
        TwinCheck::Unique => 0,
        TwinCheck::Degenerate => return TwinPlan::Refuse(TwinRefusal::Degenerate),
        TwinCheck::Check(n) => n.min(TWIN_CHECKS),
    };
    for t in found
        .iter()
        .take(moved)
        .chain(turned.iter().take(TURNED_CHECKS))
    {
        if out.push(*t).is_err() {
            break;
        }
    }
    TwinPlan::Check(out)
}

/// Relocalization's gate under `config` on a map whose held poses are
/// checked at their geometric twins (`twins_checked`, as
/// [`GeometricTwins::has_map`]): the plain correlation's and the inlier
/// ratio's floors are `twin_checked_min_correlation` and
/// `twin_checked_min_inlier_ratio` there when lower than `min_correlation`
/// and `min_inlier_ratio` (see those settings), else `config` unchanged.
/// Tracking's resuming gate is never this one.
pub fn relocalization_gate(config: &RelocConfig, twins_checked: bool) -> RelocConfig {
    RelocConfig {
        min_correlation: if twins_checked {
            config
                .min_correlation
                .min(config.twin_checked_min_correlation)
        } else {
            config.min_correlation
        },
        min_inlier_ratio: if twins_checked {
            config
                .min_inlier_ratio
                .min(config.twin_checked_min_inlier_ratio)
        } else {
            config.min_inlier_ratio
        },
        ..config.clone()
    }
}

/// The gate a twin is checked through: from the map's detail, with both
/// correlation thresholds [`LOOSE_MARGIN`] lower.
pub fn loose_gate(config: &RelocConfig) -> RelocConfig {
    RelocConfig {
        gate_at_map_detail: true,
        min_correlation: config.min_correlation - LOOSE_MARGIN,
        min_local_correlation: config.min_local_correlation - LOOSE_MARGIN,
        min_local_correlation_at_map_detail: config.min_local_correlation_at_map_detail
            - LOOSE_MARGIN,
        ..config.clone()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_loose_gate_is_looser_and_nothing_else_changes() {
        let strict = RelocConfig::default();
        let loose = loose_gate(&strict);
        assert!(loose.gate_at_map_detail);
        assert!((loose.min_correlation - (strict.min_correlation - LOOSE_MARGIN)).abs() < 1e-6);
        assert!(
            (loose.min_local_correlation - (strict.min_local_correlation - LOOSE_MARGIN)).abs()
                < 1e-6
        );
        assert!(
            (loose.min_local_correlation_at_map_detail
                - (strict.min_local_correlation_at_map_detail - LOOSE_MARGIN))
                .abs()
                < 1e-6
        );
        assert_eq!(loose.min_gain, strict.min_gain);
        assert_eq!(loose.min_inlier_ratio, strict.min_inlier_ratio);
        assert_eq!(loose.refine_renders, strict.refine_renders);
    }

    #[test]
    fn only_a_twin_checked_map_lowers_the_gates_floors() {
        let config = RelocConfig::default();
        let checked = relocalization_gate(&config, true);
        assert_eq!(checked.min_correlation, config.twin_checked_min_correlation);
        assert!(checked.min_correlation < config.min_correlation);
        assert_eq!(checked.min_local_correlation, config.min_local_correlation);
        assert_eq!(
            checked.min_inlier_ratio,
            config.twin_checked_min_inlier_ratio
        );
        assert!(checked.min_inlier_ratio < config.min_inlier_ratio);
        assert_eq!(checked.min_gain, config.min_gain);
        let unchecked = relocalization_gate(&config, false);
        assert_eq!(unchecked.min_correlation, config.min_correlation);
        assert_eq!(unchecked.min_inlier_ratio, config.min_inlier_ratio);
        // A floor set above the plain one does not raise it.
        let high = RelocConfig {
            twin_checked_min_correlation: 0.9,
            ..config.clone()
        };
        assert_eq!(
            relocalization_gate(&high, true).min_correlation,
            config.min_correlation
        );
        // The twins' looser gate is looser than the gate it loosens.
        let twins = GeometricTwins::none(&checked);
        assert!(twins.loose().min_correlation < checked.min_correlation);
    }

    #[test]
    fn a_twin_pose_keeps_heading_and_height() {
        let held = Pose::from_parts(
            Translation3::new(1.0, 2.0, 1.4),
            nalgebra::UnitQuaternion::from_euler_angles(0.1, -0.2, 2.0),
        );
        let t = twin_pose(
            &held,
            &Twin {
                offset_m: [40.0, -0.5],
                yaw_rad: 0.0,
                score: 1.0,
            },
        );
        assert!((t.translation.vector - Vector3::new(41.0, 1.5, 1.4)).norm() < 1e-12);
        assert!(t.rotation.angle_to(&held.rotation) < 1e-12);
    }

    #[test]
    fn a_turned_twin_turns_the_view_about_the_camera_and_keeps_its_tilt() {
        let held = Pose::from_parts(
            Translation3::new(1.0, 2.0, 1.4),
            crate::geometry::look::camera_rotation(0.3, -0.1, 0.0),
        );
        let t = twin_pose(
            &held,
            &Twin {
                offset_m: [0.0, 1.5],
                yaw_rad: std::f64::consts::PI,
                score: 1.0,
            },
        );
        assert!((t.translation.vector - Vector3::new(1.0, 3.5, 1.4)).norm() < 1e-12);
        // The optical axis turned half round, its pitch kept.
        let axis = |p: &Pose| p.rotation * Vector3::z();
        let (a, b) = (axis(&held), axis(&t));
        assert!((a.x + b.x).abs() < 1e-12 && (a.y + b.y).abs() < 1e-12);
        assert!((a.z - b.z).abs() < 1e-12);
    }

    #[test]
    fn a_twin_within_the_priors_reach_refuses_a_held_pose_beyond_it() {
        use super::super::prior::MotionPrior;
        use super::super::rivals::RivalRule;
        use crate::geometry::look::camera_rotation;
        let config = RelocConfig::default();
        // Tracked last at the truth, facing +x, lost for 0.1 s: a reach of
        // 0.7 m and 42 degrees.
        let truth = Pose::from_parts(
            Translation3::new(26.3, 13.1, 1.5),
            camera_rotation(0.0, 0.0, 0.0),
        );
        let rule = RivalRule::new(Some(MotionPrior::new(&truth, 0.1, &config)));
        // Held 1.5 m away, turned half round: its turned twin is the truth.
        let held = Pose::from_parts(
            Translation3::new(26.3, 11.6, 1.5),
            camera_rotation(std::f64::consts::PI, 0.0, 0.0),
        );
        assert!(!rule.accepts_alone(&held));
        let to_truth = Twin {
            offset_m: [0.0, 1.5],
            yaw_rad: std::f64::consts::PI,
            score: 0.95,
        };
        let far = Twin {
            offset_m: [30.0, 0.0],
            yaw_rad: 0.0,
            score: 0.97,
        };
        assert!(prior_prefers_a_twin(&rule, &held, (&[far], &[to_truth])));
        // Only far twins, no twin, or no prior (a cold start): no refusal
        // here (the twins are then checked through the looser gate).
        assert!(!prior_prefers_a_twin(&rule, &held, (&[far], &[])));
        assert!(!prior_prefers_a_twin(&rule, &held, (&[], &[])));
        assert!(!prior_prefers_a_twin(
            &RivalRule::new(None),
            &held,
            (&[far], &[to_truth])
        ));
        // A held pose the prior vouches for is not in question.
        assert!(!prior_prefers_a_twin(&rule, &truth, (&[], &[to_truth])));
    }

    #[test]
    fn the_plan_checks_the_twins_the_prior_cannot_tell_apart() {
        use super::super::prior::MotionPrior;
        use super::super::rivals::RivalRule;
        use crate::geometry::look::camera_rotation;
        let config = RelocConfig::default();
        let truth = Pose::from_parts(
            Translation3::new(22.1, 12.9, 1.4),
            camera_rotation(0.0, 0.0, 0.0),
        );
        let twin = |x: f64, y: f64, yaw_rad: f64| Twin {
            offset_m: [x, y],
            yaw_rad,
            score: 0.9,
        };
        // Lost for 0.5 s: a reach of 2 m and more than a quarter turn.
        let window = RivalRule::new(Some(MotionPrior::new(&truth, 0.5, &config)));
        // Held 1.4 m away and turned a quarter, within the reach: the prior
        // vouches for its place, nothing is checked, on a scanned map too
        // (there its rivals are verified instead).
        let held = Pose::from_parts(
            Translation3::new(22.1, 11.5, 1.4),
            camera_rotation(std::f64::consts::FRAC_PI_2, 0.0, 0.0),
        );
        assert!(window.vouches_for_place(&held));
        let to_truth = twin(0.0, 1.4, -std::f64::consts::FRAC_PI_2);
        let far = twin(40.0, 0.0, 0.0);
        let planned = |rule: &RivalRule, check, found: &[Twin], turned: &[Twin]| match plan(
            rule,
            &held,
            (check, false),
            (found, turned),
        ) {
            TwinPlan::Check(list) => Ok(list.to_vec()),
            TwinPlan::Refuse(why) => Err(why),
        };
        for rule in [window, window.with_alone_floor(0.8).for_held(false, 0.7)] {
            assert_eq!(
                planned(&rule, TwinCheck::Degenerate, &[far], &[to_truth]),
                Ok(vec![])
            );
        }
        // A cold start: the best moved twins, then the best turned ones.
        let cold = RivalRule::new(None);
        let moved: Vec<Twin> = (0..TWIN_CHECKS as u32 + 2)
            .map(|k| twin(10.0 * f64::from(k + 1), 0.0, 0.0))
            .collect();
        let turned: Vec<Twin> = (0..4)
            .map(|k| twin(0.0, 10.0 * f64::from(k + 1), std::f64::consts::PI))
            .collect();
        let list = planned(&cold, TwinCheck::Check(TWIN_CHECKS), &moved, &turned);
        let mut expected = moved[..TWIN_CHECKS].to_vec();
        expected.extend_from_slice(&turned[..TURNED_CHECKS]);
        assert_eq!(list, Ok(expected));
        // With no moved twin, the turned ones are still checked.
        assert_eq!(
            planned(&cold, TwinCheck::Unique, &[], &turned[..1]),
            Ok(turned[..1].to_vec())
        );
        assert_eq!(
            planned(&cold, TwinCheck::Degenerate, &moved, &turned),
            Err(TwinRefusal::Degenerate)
        );
        // Through the lowered first level the prior does not vouch for it:
        // checked as on a cold start.
        let lowered = window.for_held(true, 0.75);
        assert_eq!(
            planned(&lowered, TwinCheck::Check(1), &[far], &[to_truth]),
            Ok(vec![far, to_truth])
        );
        // Held beyond the reach, with a twin within it: refused outright.
        let beyond = Pose::from_parts(
            Translation3::new(62.1, 12.9, 1.4),
            camera_rotation(0.0, 0.0, 0.0),
        );
        assert!(matches!(
            plan(
                &window,
                &beyond,
                (TwinCheck::Check(1), false),
                (&[twin(-40.0, 0.0, 0.0)], &[])
            ),
            TwinPlan::Refuse(TwinRefusal::PriorPrefersATwin)
        ));
        // Prior only (a textured map; the twins are those near the prior):
        // the same refusal, by a moved or a turned twin; never degenerate,
        // the best twins checked.
        for (found, turned) in [
            (&[twin(-40.0, 0.0, 0.0)][..], &[][..]),
            (&[][..], &[twin(-40.0, 0.0, 0.0)][..]),
        ] {
            assert!(matches!(
                plan(
                    &window,
                    &beyond,
                    (TwinCheck::Check(1), true),
                    (found, turned)
                ),
                TwinPlan::Refuse(TwinRefusal::PriorPrefersATwin)
            ));
        }
        let across = twin(0.0, 10.0, std::f64::consts::PI);
        assert_eq!(
            planned(&window, TwinCheck::Degenerate, &[], &[]),
            Ok(vec![])
        );
        let held_beyond = |check| match plan(&window, &beyond, (check, true), (&[far], &[across])) {
            TwinPlan::Check(list) => Ok(list.to_vec()),
            TwinPlan::Refuse(why) => Err(why),
        };
        assert_eq!(held_beyond(TwinCheck::Degenerate), Ok(vec![far, across]));
        assert_eq!(held_beyond(TwinCheck::Unique), Ok(vec![far, across]));
        // The search runs only where the plan can use it.
        assert!(plan_needs_twins(&window, &beyond, true));
        assert!(!plan_needs_twins(&cold, &beyond, true));
        assert!(plan_needs_twins(&cold, &beyond, false));
        assert!(!plan_needs_twins(&window, &held, false));
    }

    /// A room (walls on four sides, one alcove near a corner) and, 30 m
    /// away along x, the same room turned half round about its center.
    fn room_and_turned_copy() -> Mesh {
        let mut mesh = Mesh::default();
        let mut wall = |a: [f32; 2], b: [f32; 2]| {
            let n = mesh.positions.len() as u32;
            for z in [0.0, 2.5] {
                mesh.positions.push([a[0], a[1], z]);
                mesh.positions.push([b[0], b[1], z]);
            }
            mesh.gray.extend([128.0; 4]);
            mesh.indices.extend([n, n + 1, n + 3, n, n + 3, n + 2]);
        };
        // Room 6 x 4 m with a 1 m alcove wall inside, near (5, 3).
        let walls: [([f32; 2], [f32; 2]); 5] = [
            ([0.0, 0.0], [6.0, 0.0]),
            ([6.0, 0.0], [6.0, 4.0]),
            ([6.0, 4.0], [0.0, 4.0]),
            ([0.0, 4.0], [0.0, 0.0]),
            ([4.5, 3.0], [5.5, 3.0]),
        ];
        for (a, b) in walls {
            wall(a, b);
            // Turned half round about (3, 2), then 30 m along x.
            let turn = |p: [f32; 2]| [6.0 - p[0] + 30.0, 4.0 - p[1]];
            wall(turn(a), turn(b));
        }
        // A floor under both, wider than their walls (flat: not in the
        // occupancy, but the grid spans it).
        let n = mesh.positions.len() as u32;
        mesh.positions.extend([
            [-1.0, -1.0, 0.0],
            [37.0, -1.0, 0.0],
            [37.0, 5.0, 0.0],
            [-1.0, 5.0, 0.0],
        ]);
        mesh.gray.extend([128.0; 4]);
        mesh.indices.extend([n, n + 1, n + 2, n, n + 2, n + 3]);
        mesh.groups = vec![crate::map::MeshGroup {
            first_index: 0,
            index_count: mesh.indices.len() as u32,
            texture: None,
        }];
        mesh
    }

    #[test]
    fn a_room_turned_half_round_elsewhere_is_a_turned_twin() {
        let mesh = room_and_turned_copy();
        let config = RelocConfig::default();
        let mut twins = GeometricTwins::new(&mesh, &config);
        assert!(twins.has_map());
        // A camera at (2, 1.5) looking toward the alcove: points on the
        // walls it sees, at two heights.
        let camera = Vector3::new(2.0, 1.5, 1.4);
        twins.points.clear();
        let seen: [fn(f64) -> [f64; 2]; 3] =
            [|t| [6.0, 4.0 * t], |t| [6.0 * t, 4.0], |t| [4.5 + t, 3.0]];
        for wall in seen {
            for k in 0..=40 {
                let [x, y] = wall(f64::from(k) / 40.0);
                for z in [0.6, 1.2, 1.8] {
                    twins.points.push(Vector3::new(x, y, z));
                }
            }
        }
        let check = twins.search(&camera, None);
        // Not turned, the view stands nowhere else.
        assert_eq!(check, TwinCheck::Unique, "{:?}", twins.found());
        // In the copy it stands turned half round, at (30 + 6 - 2,
        // 4 - 1.5): offset (32, 1), yaw pi.
        let turned = twins
            .turned()
            .iter()
            .find(|t| (t.yaw_rad - std::f64::consts::PI).abs() < 1e-9)
            .copied();
        let t = turned.unwrap_or_else(|| panic!("not a turned twin: {:?}", twins.turned()));
        assert!(
            (t.offset_m[0] - 32.0).abs() < 0.15 && (t.offset_m[1] - 1.0).abs() < 0.15,
            "{t:?}"
        );
        // Searched near a region only (`check_near`): found there, and
        // nothing where the map does not repeat the view.
        twins.search(&camera, Some(([31.0, 0.5], 1.5)));
        assert!(
            twins.turned().iter().any(|u| u.offset_m == t.offset_m),
            "{:?}",
            twins.turned()
        );
        twins.search(&camera, Some(([-20.0, 0.0], 3.0)));
        assert!(twins.found().is_empty() && twins.turned().is_empty());
    }

    #[test]
    fn without_a_map_every_pose_is_unique() {
        let config = RelocConfig::default();
        let mut twins = GeometricTwins::none(&config);
        assert!(!twins.has_map());
        let camera = crate::geometry::PinholeCamera::new(320, 256, 320.0, 320.0, 160.0, 128.0);
        let kf = Keyframe::new(&camera, &crate::track::TrackerConfig::default());
        assert_eq!(twins.check(&kf), TwinCheck::Unique);
        assert!(twins.found().is_empty());
    }
}
