//! Relocalization (paper section II-D, issue 5): recovering the pose after
//! tracking is lost, from a database of rendered views of the map.
//!
//! - [`descriptor`]: 80x64 thumbnail and 256-bit binary descriptor.
//! - [`coarse`]: the 40x32 keyframe points stored per entry, aligned
//!   before anything is rendered to rank the candidates.
//! - [`database`]: keyframe poses, descriptors and coarse points; the versioned, checksummed
//!   file and its checks (magic, version, length, checksum, map, camera).
//! - [`grid`]: `star reloc build`: virtual cameras on a grid in free space.
//! - [`landmarks`]: map points with feature descriptors, and the pose of a
//!   frame from them (features matched, then RANSAC PnP).
//! - [`features`]: FAST corners and 256-bit upright BRIEF descriptors on an
//!   image pyramid, and brute-force Hamming matching.
//! - [`pnp`]: P3P (Lambda Twist) in RANSAC, refined on the inliers.
//! - The online side; the STAR loop ([`crate::localizer`]) renders and
//!   aligns the candidates:
//!   - [`region`]: where to search (near the last position, or everywhere).
//!   - [`search`]: radius-bounded Hamming search and the ranking of the
//!     candidates by coarse alignment.
//!   - [`verify`]: the strict acceptance gate a rendered candidate passes
//!     (its correlation test is [`crate::track::correlation`]).
//! - [`config`]: the `[reloc]` section.

pub mod coarse;
pub mod config;
pub mod database;
pub mod descriptor;
pub mod features;
pub mod grid;
pub mod landmarks;
pub mod pnp;
pub mod region;
pub mod search;
pub mod verify;

#[cfg(test)]
mod database_tests;

pub use config::RelocConfig;
pub use database::{map_fingerprint, RelocDatabase, RelocDbError, RelocEntry};
pub use descriptor::{Descriptor, Thumbnailer, THUMB_H, THUMB_W};
pub use grid::{
    above_floor, build_database, build_database_along, build_database_in, AlongTrajectory,
    BuildError,
};
pub use region::SearchRegion;
pub use search::{
    Candidate, Query, Ranked, Relocalizer, SearchIndex, LANDMARK_CANDIDATE, MAX_TOP_K,
};
pub use verify::{
    passes_gate, passes_whole_gate, start_yaws_rad, try_candidate, verify_candidate, Verdict,
    Verified,
};
