//! Benchmark runners behind `star bench`: each builds its own synthetic
//! data from a seed, runs the flight code on it and prints the figures it
//! measured (never pass/fail). `cli` only parses their arguments.
//!
//! - [`pairs`]: tracker pairs and their alignment time and error.
//! - [`reloc`]: relocalization success, wrong accepts and timings.
//! - [`integrity`]: wrong poses sent under faults, cold-start time, kidnap
//!   recovery, wrong hints.
//! - [`map_survey`]: a user's map's holes, render times and memory, for
//!   `star map info`.

pub mod integrity;
pub mod map_survey;
pub mod pairs;
pub mod reloc;
