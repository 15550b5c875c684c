//! Synthetic data: procedural textured indoor scenes (this part) and, built
//! on them, sequences with ground truth.
//!
//! - [`scene`]: a seeded room with furniture as a `map` mesh (with holes,
//!   no occluders) and a `truth` mesh (no holes, with occluders), plus its
//!   free space.
//! - [`texture`]: the seeded PRNG and the procedural gray textures.

pub mod scene;
pub mod texture;

pub use scene::{build_scene, default_scene, Scene, SceneBox, SceneParams, SceneParamsError};
pub use texture::SplitMix64;
