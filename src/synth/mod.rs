//! Synthetic data: procedural textured indoor scenes and, built on them,
//! sequences with exact ground truth.
//!
//! - [`scene`]: a seeded room with furniture as a `map` mesh (with holes,
//!   no occluders) and a `truth` mesh (no holes, with occluders), plus its
//!   free space.
//! - [`texture`]: the seeded PRNG and the procedural gray textures.
//! - [`trajectory`] (with [`crate::geometry::look`]): seeded 50 Hz camera trajectories in
//!   the scene's free space (`slow_loop`, `aggressive`).
//! - [`corrupt`]: sensor corruptions (gain/bias drift, vignetting, noise,
//!   lens distortion, motion blur).
//! - [`preset`]: the named, fully specified sequence presets.
//! - [`scanned`]: the scanned variant: a map rebuilt by TSDF fusion of a
//!   noisy scanning run (through Open3D), a moving light and auto-exposure
//!   steps in flight.
//! - [`camera_model`]: renders turned into camera frames (blur, lens
//!   distortion, sensor model), for `sequence` and `sim_camera`.
//! - [`sequence`]: scene + trajectory + renderer + corruptions -> a TUM
//!   dataset folder (`star synth`).
//! - [`sim_camera`]: the `sim:` camera source: a simulated vehicle's camera,
//!   rendering a dataset's scene at the true pose ArduPilot SITL reports.

pub mod camera_model;
pub mod corrupt;
pub mod preset;
pub mod scanned;
pub mod scene;
pub mod sequence;
pub mod sim_camera;
pub mod texture;
pub mod trajectory;

pub use scene::{build_scene, default_scene, Scene, SceneBox, SceneParams, SceneParamsError};
pub use texture::SplitMix64;
