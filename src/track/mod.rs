//! The tracker: semi-dense direct alignment of camera frames against
//! rendered keyframes (paper section II-A).
//!
//! - [`pyramid`]: Gaussian image pyramids, preallocated.
//! - [`keyframe`]: keyframe preparation from a rendered view: gradient-pixel
//!   selection with a block-adaptive threshold, back-projection, and the
//!   precomputed inverse-compositional Jacobians.
//! - [`align`]: coarse-to-fine inverse compositional LM with Huber weights
//!   and an affine or median-offset illumination model; quality and
//!   covariance.
//! - [`normal_eq`]: fixed-size normal equations.

pub mod align;
pub mod keyframe;
pub mod normal_eq;
pub mod pyramid;

#[cfg(test)]
mod tests;

pub use align::{AlignQuality, Aligner, Alignment, MAX_LEVELS};
pub use keyframe::{KeyPoint, Keyframe, KeyframeLevel};
pub use pyramid::Pyramid;
