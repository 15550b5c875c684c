//! Where a database build's time goes: per worker, the seconds spent
//! rendering thumbnails and landmark views, describing, selecting coarse
//! points and lifting features, and how many views of each kind; summed
//! over the workers at the end of a build (`star reloc build` prints it).
//!
//! Perf counters only: nothing here changes what is built.

use std::time::Instant;

/// Time per stage of a database build, summed over the workers (so on `n`
/// busy workers the seconds add up to about `n` times the wall time).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct StageTimes {
    /// Thumbnail views rendered (grid positions and trajectory samples).
    pub thumb_views: u64,
    /// Seconds rendering them (and counting their hits).
    pub render_thumb_s: f64,
    /// Full-resolution landmark views rendered.
    pub landmark_views: u64,
    /// Seconds rendering them.
    pub render_landmark_s: f64,
    /// Seconds computing whole-image descriptors.
    pub describe_s: f64,
    /// Seconds selecting coarse points.
    pub coarse_s: f64,
    /// Seconds extracting and lifting landmark features.
    pub lift_s: f64,
    /// Clearance probes rendered (views cut short at twice `min_depth_m`).
    pub probe_views: u64,
    /// Seconds rendering them.
    pub probe_s: f64,
    /// Grid positions the probes dropped before any full render (inside or
    /// against furniture or walls).
    pub positions_skipped: u64,
    /// Landmark views the probes dropped.
    pub landmarks_skipped: u64,
}

impl StageTimes {
    /// Runs `render` (one thumbnail render) and counts it.
    pub(super) fn render_thumb<T>(&mut self, render: impl FnOnce() -> T) -> T {
        let t = Instant::now();
        let out = render();
        self.thumb_views += 1;
        self.render_thumb_s += t.elapsed().as_secs_f64();
        out
    }

    /// Adds `other`'s counts and times.
    pub fn add(&mut self, other: &StageTimes) {
        self.thumb_views += other.thumb_views;
        self.render_thumb_s += other.render_thumb_s;
        self.landmark_views += other.landmark_views;
        self.render_landmark_s += other.render_landmark_s;
        self.describe_s += other.describe_s;
        self.coarse_s += other.coarse_s;
        self.lift_s += other.lift_s;
        self.probe_views += other.probe_views;
        self.probe_s += other.probe_s;
        self.positions_skipped += other.positions_skipped;
        self.landmarks_skipped += other.landmarks_skipped;
    }

    /// Seconds in all the stages.
    pub fn total_s(&self) -> f64 {
        self.render_thumb_s
            + self.render_landmark_s
            + self.describe_s
            + self.coarse_s
            + self.lift_s
            + self.probe_s
    }
}

impl std::fmt::Display for StageTimes {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let per_ms = |s: f64, n: u64| 1e3 * s / n.max(1) as f64;
        write!(
            f,
            "{} thumbnail views rendered in {:.1} s ({:.2} ms each), {} landmark views in {:.1} s ({:.1} ms each); describing {:.1} s, coarse points {:.1} s, landmark features {:.1} s ({:.1} ms a view); {} clearance probes in {:.1} s ({:.2} ms each) dropped {} grid positions and {} landmark views",
            self.thumb_views,
            self.render_thumb_s,
            per_ms(self.render_thumb_s, self.thumb_views),
            self.landmark_views,
            self.render_landmark_s,
            per_ms(self.render_landmark_s, self.landmark_views),
            self.describe_s,
            self.coarse_s,
            self.lift_s,
            per_ms(self.lift_s, self.landmark_views),
            self.probe_views,
            self.probe_s,
            per_ms(self.probe_s, self.probe_views),
            self.positions_skipped,
            self.landmarks_skipped,
        )
    }
}
