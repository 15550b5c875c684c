//! Geometric twins of a relocalized pose: the places where the map's
//! surfaces stand as they do in the held pose's view, moved by a horizontal
//! translation (found by [`crate::map::repeats`]), and the looser gate the
//! frame is checked through there.
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
//!   [`TWIN_CHECKS`] twins.
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

/// A view that fits at this many places or more is degenerate: refused
/// without a prior.
pub const DEGENERATE_TWINS: usize = 8;
/// Twins the frame is checked at, at most.
pub const TWIN_CHECKS: usize = 3;
/// The looser gate's correlation thresholds are this much lower.
pub const LOOSE_MARGIN: f32 = 0.1;
/// Pyramid level whose keyframe points describe the view (160x128 for the
/// presets' camera).
const POINTS_LEVEL: usize = 2;
/// Keyframe points handed to the search, at most.
const MAX_VIEW_POINTS: usize = 1024;

/// The map's occupancy, the looser gate and the buffers of one check.
#[derive(Debug, Clone)]
pub struct GeometricTwins {
    occupancy: MapOccupancy,
    scratch: TwinScratch,
    points: Vec<Vector3<f64>>,
    found: heapless::Vec<Twin, DEGENERATE_TWINS>,
    loose: RelocConfig,
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
        let checked = match config.geometric_twins {
            GeometricTwinMaps::Never => false,
            GeometricTwinMaps::Untextured => !textured,
            GeometricTwinMaps::Always => true,
        };
        let occupancy = if checked {
            MapOccupancy::build(mesh)
        } else {
            MapOccupancy::none()
        };
        Self::with_occupancy(occupancy, &relocalization_gate(config, checked))
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
            loose: loose_gate(config),
        }
    }

    /// Whether a map's occupancy is held.
    pub fn has_map(&self) -> bool {
        !self.occupancy.is_empty()
    }

    /// The gate a twin is checked through.
    pub fn loose(&self) -> &RelocConfig {
        &self.loose
    }

    /// Searches the twins of the view of `keyframe` (rendered at the held
    /// pose); at most [`TWIN_CHECKS`] are kept to check.
    pub fn check(&mut self, keyframe: &Keyframe) -> TwinCheck {
        self.found.clear();
        if !self.has_map() {
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
        self.occupancy.twins(
            &world_from_keyframe.translation.vector,
            &self.points,
            &mut self.scratch,
            &mut self.found,
        );
        match self.found.len() {
            0 => TwinCheck::Unique,
            n if n >= DEGENERATE_TWINS => TwinCheck::Degenerate,
            n => TwinCheck::Check(n.min(TWIN_CHECKS)),
        }
    }

    /// The twins of the last [`Self::check`], best first.
    pub fn found(&self) -> &[Twin] {
        &self.found
    }
}

/// `held` moved by the twin's offset (the same heading and height).
pub fn twin_pose(held: &Pose, twin: &Twin) -> Pose {
    Translation3::new(twin.offset_m[0], twin.offset_m[1], 0.0) * held
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
                score: 1.0,
            },
        );
        assert!((t.translation.vector - Vector3::new(41.0, 1.5, 1.4)).norm() < 1e-12);
        assert!(t.rotation.angle_to(&held.rotation) < 1e-12);
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
