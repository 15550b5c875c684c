//! Local keypoint features of relocalization: FAST-9 corners on an image
//! pyramid, each with a 256-bit BRIEF-style descriptor, and the brute-force
//! Hamming matcher that pairs them with the map's landmarks
//! ([`super::landmarks`], ORB-SLAM style: features matched, then PnP).
//!
//! Takes an 8-bit gray image (`&[u8]`, width, height, row stride); gives out
//! [`Keypoint`]s in level-0 pixel coordinates (pixel centers at integers).
//! [`FeatureExtractor`] owns the pyramid, the score map, the candidate lists
//! and the comparison pattern: after [`FeatureExtractor::new`],
//! [`FeatureExtractor::extract`] allocates nothing.
//!
//! The descriptor is upright (no orientation is estimated): the vehicle's
//! roll stays small, and rotation invariance would cost distinctiveness.
//! Scale is covered by the pyramid.
//!
//! - [`extractor`]: [`FeatureExtractor`], [`FeatureParams`], [`Keypoint`]:
//!   the buffers, the split of the feature budget between levels, and the
//!   order of the steps below.
//! - [`pyramid`]: the pyramid levels and their bilinear downscaling.
//! - [`fast`]: FAST-9 scores, non-maximum suppression, grid selection.
//! - [`brief`]: the comparison pattern, the box blur, the descriptor.
//! - [`matching`]: nearest and second-nearest by Hamming distance.
//!
//! Timings: `cargo bench --bench reloc_features`.

pub mod brief;
pub mod extractor;
pub mod fast;
pub mod matching;
pub mod pyramid;

#[cfg(test)]
pub(crate) mod test_images;

pub use brief::{EDGE_PX, PATCH_SIZE, PATTERN_SEED};
pub use extractor::{FeatureExtractor, FeatureParams, Keypoint, MAX_LEVELS};
pub use matching::{best_two, best_two_batch, BATCH};
