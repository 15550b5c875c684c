//! Scenes shared by the benchmarks.

pub mod room_scene;
