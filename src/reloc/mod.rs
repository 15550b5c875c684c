//! Relocalization (paper section II-D, issue 5): recovering the pose after
//! tracking is lost, from a database of rendered views of the map.
//!
//! - [`descriptor`]: 80x64 thumbnail and 256-bit binary descriptor.
//! - [`coarse`]: the 40x32 keyframe points stored per entry, aligned
//!   before anything is rendered to rank the candidates.
//! - [`database`]: keyframe poses, descriptors and coarse points, the
//!   landmarks, and the checks that a database fits the map and camera.
//! - [`file`]: the versioned, checksummed file, read through a memory map,
//!   and its checks (magic, version, length, checksum, fields).
//! - [`grid`]: `star reloc build`: virtual cameras on a grid in free space.
//! - [`build`]: rendering and describing them on every core;
//!   [`checkpoint`]: resuming an interrupted build; [`build_stats`]: where
//!   its time goes.
//! - [`landmarks`]: map points with feature descriptors, and the pose of a
//!   frame from them (features matched, then RANSAC PnP).
//! - [`features`]: FAST corners and 256-bit upright BRIEF descriptors on an
//!   image pyramid, and brute-force Hamming matching.
//! - [`vocabulary`]: the landmark descriptors' vocabulary, trained at
//!   build time; [`landmark_index`]: the landmarks each frame corner is
//!   compared with (spatial cells near the last position, vocabulary
//!   leaves for the whole map).
//! - [`pnp`]: P3P (Lambda Twist) in RANSAC, refined on the inliers.
//! - The online side; the STAR loop ([`crate::localizer`]) renders and
//!   aligns the candidates:
//!   - [`region`]: where to search (near the last position, or everywhere).
//!   - [`prior`]: the motion prior while lost (reach in position and
//!     heading) and the order an attempt draws its candidates in.
//!   - [`search`]: radius-bounded Hamming search and the ranking of the
//!     candidates by coarse alignment.
//!   - [`rivals`]: when a pose may be taken on the prior alone, and the
//!     candidates at another place that must otherwise fail the gate
//!     before it is accepted (look-alike rooms).
//!   - [`twins`]: the places where a held pose's view stands again in
//!     the map's geometry, checked before a pose the prior cannot vouch
//!     for is accepted.
//!   - [`local_contrast`]: the locally normalized images a candidate can
//!     be aligned on where the map's light is not the flight's (`star
//!     bench reloc` only, so far).
//!   - [`verify`]: the strict acceptance gate a rendered candidate passes
//!     (its correlation test is [`crate::track::correlation`]).
//! - [`config`]: the `[reloc]` section.

pub mod build;
pub mod build_stats;
pub mod checkpoint;
pub mod coarse;
pub mod config;
pub mod database;
pub mod descriptor;
pub mod features;
pub mod file;
pub mod grid;
pub mod landmark_index;
pub mod landmarks;
pub mod local_contrast;
pub mod places;
pub mod pnp;
pub mod prior;
pub mod region;
pub mod rivals;
pub mod search;
pub mod twins;
pub mod verify;
pub mod vocabulary;

#[cfg(test)]
mod database_tests;

pub use build::{
    build_database, build_database_along, build_database_in, build_parallel, BuildOptions,
};
pub use build_stats::StageTimes;
pub use checkpoint::checkpoint_path;
pub use config::{GeometricTwinMaps, RelocConfig};
pub use database::{
    map_fingerprint, CoarsePoints, CoarseSlice, RelocDatabase, RelocDbError, RelocEntry,
};
pub use descriptor::{Descriptor, Thumbnailer, THUMB_H, THUMB_W};
pub use grid::{above_floor, AlongTrajectory, BuildError};
pub use prior::MotionPrior;
pub use region::SearchRegion;
pub use search::{
    is_landmark_index, Candidate, Query, Ranked, Relocalizer, SearchIndex, LANDMARK_CANDIDATE,
    LANDMARK_ELSEWHERE, MAX_LANDMARK_ELSEWHERE, MAX_TOP_K,
};
pub use verify::{
    passes_gate, passes_resume_gate, passes_whole_gate, resume_local_floor, start_yaws_rad,
    through_lowered_first_level, try_candidate, verify_candidate, Verdict, Verified,
    PRECISE_START_SKIPPED_LEVELS,
};
