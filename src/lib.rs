//! STAR: Simultaneous Tracking and Rendering (Ok, Greene, Roy).
//!
//! Monocular localization of a micro air vehicle against a colored triangle
//! mesh of the building. Modules follow the data flow: a camera source
//! publishes frames, the tracker aligns each frame against a keyframe rendered
//! from the map, and the pose goes to the autopilot over MAVLink.

pub mod bench;
pub mod calib;
pub mod camera;
pub mod cli;
pub mod clock;
pub mod config;
pub mod dataset;
pub mod eval;
pub mod geometry;
pub mod imgproc;
pub mod ipc;
pub mod localizer;
pub mod map;
pub mod mavlink_io;
pub mod offline;
pub mod output;
pub mod reloc;
pub mod render;
pub mod rng;
pub mod service;
pub mod settings;
pub mod synth;
pub mod track;
pub mod tracker;
