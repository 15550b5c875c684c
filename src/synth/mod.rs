//! Synthetic sequences: camera trajectories, sensor corruptions and presets
//! that `star synth` combines with the procedural scene and the CPU
//! rasterizer into TUM datasets with exact ground truth.

pub mod corrupt;
pub mod look;
pub mod preset;
pub mod trajectory;
