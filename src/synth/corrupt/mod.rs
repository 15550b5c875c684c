//! Sensor and map corruptions of synthetic sequences.
//!
//! Takes rendered ideal-pinhole views (gray 0..=255 and depth) and gives the
//! 8-bit frames a real camera would deliver, plus a damaged map:
//! - [`photometric`]: slow global gain/bias drift, vignetting, Gaussian
//!   sensor noise (seeded per frame) and quantization;
//! - [`distortion`]: resampling of a pinhole render through the lens
//!   distortion of `camera.toml`, from an enlarged render so no pixel is
//!   missing;
//! - [`blur`]: motion blur as the average of sub-frame renders across the
//!   exposure, with as many sub-frames as the motion needs;
//!
//! Map holes and occluders are built by the scene
//! (`synth::scene::SceneParams::hole_fraction` and `occluders`): the map
//! mesh written to `map/` has the holes, the truth mesh the camera renders
//! has the occluders; the preset chooses which mesh draws the images.

pub mod blur;
pub mod distortion;
pub mod photometric;

pub use blur::{subframe_offsets_s, BlurSpec};
pub use distortion::{DistortionError, DistortionWarp};
pub use photometric::{PhotometricDrift, PhotometricSpec, SensorModel};

/// Mixes a seed with a stream index (frame number, component) into an
/// independent seed (SplitMix64 finalizer).
pub fn derive_seed(seed: u64, stream: u64) -> u64 {
    let mut z = seed ^ stream.wrapping_mul(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}
