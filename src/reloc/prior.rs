//! The motion prior while lost: where the vehicle can be now, and which way
//! it can face, from its last tracked pose and how long it has been lost;
//! and the order in which one relocalization attempt draws its candidates.
//!
//! Takes the last tracked `world_from_camera`, the time lost and the
//! `[reloc]` reach settings (`search_radius_m + max_speed_m_s x lost`
//! around the last position, `search_yaw_deg + max_yaw_rate_deg_s x lost`
//! around the last heading); gives the region the nearby candidates are
//! searched in ([`MotionPrior::region`]), whether a pose lies within reach
//! in both position and heading ([`MotionPrior::reaches`]), and the
//! candidate sources of an attempt ([`sources`], [`landmark_regions`]).
//! The service ([`crate::localizer`]) and `star bench reloc` both take
//! their order and their prior from here. Nothing here allocates.

use nalgebra::Vector3;

use crate::geometry::Pose;

use super::config::RelocConfig;
use super::region::SearchRegion;

/// Where the last tracked pose says the vehicle can be.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MotionPrior {
    /// Last tracked position, world, meters.
    pub center_m: Vector3<f64>,
    /// Reach around it, meters.
    pub radius_m: f64,
    /// Last tracked heading ([`yaw_rad`]); `None` when the optical axis was
    /// too near the vertical to have one.
    pub yaw_rad: Option<f64>,
    /// Largest heading change within reach, radians (at most pi).
    pub max_turn_rad: f64,
}

impl MotionPrior {
    /// The prior after `lost_s` seconds lost from `world_from_camera`:
    /// reach `search_radius_m + max_speed_m_s x lost_s`, heading within
    /// `search_yaw_deg + max_yaw_rate_deg_s x lost_s` of the last one (a
    /// negative or non-finite time counts as 0).
    pub fn new(world_from_camera: &Pose, lost_s: f64, config: &RelocConfig) -> Self {
        let lost_s = if lost_s.is_finite() {
            lost_s.max(0.0)
        } else {
            0.0
        };
        let turn_deg = config.search_yaw_deg + config.max_yaw_rate_deg_s * lost_s;
        Self {
            center_m: world_from_camera.translation.vector,
            radius_m: config.search_radius_m + config.max_speed_m_s * lost_s,
            yaw_rad: yaw_rad(world_from_camera),
            max_turn_rad: turn_deg.to_radians().min(std::f64::consts::PI),
        }
    }

    /// The time lost that gives `radius_m` of reach under `config`
    /// (0 when the reach does not grow, or when `radius_m` is within
    /// `search_radius_m`), seconds.
    pub fn lost_s_for_radius(radius_m: f64, config: &RelocConfig) -> f64 {
        if config.max_speed_m_s > 0.0 && radius_m > config.search_radius_m {
            (radius_m - config.search_radius_m) / config.max_speed_m_s
        } else {
            0.0
        }
    }

    /// The region of the nearby candidates (position only).
    pub fn region(&self) -> SearchRegion {
        SearchRegion::Near {
            center_m: self.center_m,
            radius_m: self.radius_m,
        }
    }

    /// The heading change from the last pose to `world_from_camera`,
    /// radians in 0..=pi; `None` when either has no heading.
    pub fn turn_rad(&self, world_from_camera: &Pose) -> Option<f64> {
        let from = self.yaw_rad?;
        let to = yaw_rad(world_from_camera)?;
        let d = (to - from).rem_euclid(std::f64::consts::TAU);
        Some(d.min(std::f64::consts::TAU - d))
    }

    /// Whether `world_from_camera` is within reach: inside the radius and
    /// turned at most `max_turn_rad` from the last heading. A pose without
    /// a heading (or a prior without one) is not: the prior cannot vouch
    /// for it.
    pub fn reaches(&self, world_from_camera: &Pose) -> bool {
        self.region()
            .contains(&world_from_camera.translation.vector)
            && self
                .turn_rad(world_from_camera)
                .is_some_and(|t| t <= self.max_turn_rad)
    }
}

/// The optical axis's (camera +z) heading about the world vertical, radians
/// (0 along world +x, positive toward +y, as [`crate::geometry::look`]);
/// `None` when the axis is within about 6 degrees of the vertical.
pub fn yaw_rad(world_from_camera: &Pose) -> Option<f64> {
    let forward = world_from_camera.rotation * Vector3::z();
    let level = forward.x.hypot(forward.y);
    (level.is_finite() && level >= 0.1).then(|| forward.y.atan2(forward.x))
}

/// Where one step of an attempt draws its candidates from.
#[derive(Debug, Clone, Copy)]
pub enum Source {
    /// The landmark pose (features matched to the map's landmarks, PnP):
    /// one candidate, from [`landmark_regions`].
    Landmark,
    /// The landmark poses at the other places over the whole map where the
    /// frame's corners fit (`Relocalizer::landmark_rivals` of the landmark
    /// pose; only on a map checked for geometric twins, and only on a cold
    /// start, see [`sources`]): reached when the landmark pose was refused,
    /// which on a floor of look-alike rooms is most often because it took
    /// a look-alike of the true room.
    LandmarkElsewhere,
    /// The database views in a region, ranked by the whole-image descriptor
    /// and the coarse alignment.
    Views(SearchRegion),
}

/// The steps of an attempt, in order: the landmark pose (one candidate, a
/// few renders, wherever it is), then the views near the last position
/// (with a prior) or, on a cold start, the landmark poses at the other
/// places, then the views over the whole map.
///
/// The landmark poses elsewhere are a cold start's step only: there every
/// pose that passes is checked against its rivals, while a prior accepts
/// a pose within its reach alone, and one of these at a repeat of the
/// frame's corners within that reach would go out unchecked. With a
/// prior they added one success in 100 searches of the scanned floor's
/// 2 m window (docs/building-scale.md, "The landmarks' other places as
/// candidates").
pub fn sources(prior: Option<&MotionPrior>) -> [Option<Source>; 3] {
    [
        Some(Source::Landmark),
        Some(match prior {
            Some(p) => Source::Views(p.region()),
            None => Source::LandmarkElsewhere,
        }),
        Some(Source::Views(SearchRegion::Everywhere)),
    ]
}

/// The regions the landmark pose is searched in, in order (near the last
/// position, then, when that gives none, the whole map), and how many.
pub fn landmark_regions(prior: Option<&MotionPrior>) -> ([SearchRegion; 2], usize) {
    match prior {
        Some(p) => ([p.region(), SearchRegion::Everywhere], 2),
        None => ([SearchRegion::Everywhere; 2], 1),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::look::camera_rotation;
    use nalgebra::Translation3;

    fn looking(x: f64, yaw_deg: f64) -> Pose {
        Pose::from_parts(
            Translation3::new(x, 0.0, 1.4),
            camera_rotation(yaw_deg.to_radians(), -5f64.to_radians(), 0.0),
        )
    }

    #[test]
    fn yaw_is_the_optical_axis_heading() {
        for yaw_deg in [0.0, 45.0, 90.0, 179.0, -120.0] {
            let yaw = yaw_rad(&looking(0.0, yaw_deg)).unwrap_or(f64::NAN);
            assert!((yaw.to_degrees() - yaw_deg).abs() < 1e-9, "{yaw_deg}");
        }
        let down = Pose::from_parts(
            Translation3::new(0.0, 0.0, 1.4),
            camera_rotation(0.0, -89.0f64.to_radians(), 0.0),
        );
        assert_eq!(yaw_rad(&down), None);
    }

    #[test]
    fn reach_grows_with_the_time_lost_in_position_and_heading() {
        let config = RelocConfig::default(); // 0.5 m + 2 m/s, 30 deg + 120 deg/s
        let prior = MotionPrior::new(&looking(0.0, 170.0), 0.25, &config);
        assert!((prior.radius_m - 1.0).abs() < 1e-12);
        assert!((prior.max_turn_rad.to_degrees() - 60.0).abs() < 1e-9);
        assert!(prior.reaches(&looking(0.9, 170.0)));
        // The heading wraps: -140 deg is 50 deg from 170 deg.
        assert!(prior.reaches(&looking(0.5, -140.0)));
        assert!(!prior.reaches(&looking(0.5, -110.0)));
        assert!(!prior.reaches(&looking(1.1, 170.0)));
        let long = MotionPrior::new(&looking(0.0, 0.0), 60.0, &config);
        assert!((long.max_turn_rad - std::f64::consts::PI).abs() < 1e-12);
        assert!(long.reaches(&looking(3.0, 180.0)));
    }

    #[test]
    fn the_time_lost_for_a_radius_gives_that_radius_back() {
        let config = RelocConfig::default();
        let lost_s = MotionPrior::lost_s_for_radius(2.0, &config);
        assert!((lost_s - 0.75).abs() < 1e-12);
        let prior = MotionPrior::new(&looking(0.0, 0.0), lost_s, &config);
        assert!((prior.radius_m - 2.0).abs() < 1e-12);
        assert_eq!(MotionPrior::lost_s_for_radius(0.3, &config), 0.0);
    }

    #[test]
    fn the_landmark_poses_elsewhere_are_a_cold_starts_step_before_the_whole_map() {
        let kinds = |prior: Option<&MotionPrior>| {
            sources(prior)
                .into_iter()
                .flatten()
                .map(|s| match s {
                    Source::Landmark => "landmark",
                    Source::LandmarkElsewhere => "elsewhere",
                    Source::Views(SearchRegion::Near { .. }) => "near views",
                    Source::Views(SearchRegion::Everywhere) => "all views",
                })
                .collect::<Vec<_>>()
        };
        assert_eq!(kinds(None), ["landmark", "elsewhere", "all views"]);
        let prior = MotionPrior::new(&looking(0.0, 0.0), 0.5, &RelocConfig::default());
        assert_eq!(kinds(Some(&prior)), ["landmark", "near views", "all views"]);
    }
}
