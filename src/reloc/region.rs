//! Where relocalization searches: near the last tracked position, or over
//! the whole map.
//!
//! Takes a center and a radius (or nothing); gives the membership test that
//! the descriptor search ([`super::search`]) and the landmark pose
//! ([`super::landmarks`]) filter by.

use nalgebra::Vector3;

/// Where to search.
#[derive(Debug, Clone, Copy)]
pub enum SearchRegion {
    /// Entries within `radius_m` of `center_m`.
    Near {
        /// Last tracked position, world, meters.
        center_m: Vector3<f64>,
        /// Search radius, meters.
        radius_m: f64,
    },
    /// The whole database.
    Everywhere,
}

impl SearchRegion {
    /// True when `position_m` (world, meters) lies in the region.
    pub fn contains(&self, position_m: &Vector3<f64>) -> bool {
        match self {
            Self::Near { center_m, radius_m } => (position_m - center_m).norm() <= *radius_m,
            Self::Everywhere => true,
        }
    }
}
