//! What the service reports in `STATUS=`: state, frame rate and keyframe age.
//!
//! Takes updates from the tracker through atomics ([`StatusBoard`]: no locks,
//! no allocation on the tracking path); gives out a one-line text for
//! `systemctl status`, formatted on the service thread.

use std::sync::atomic::{AtomicU64, AtomicU8, Ordering::Relaxed};

/// The tracker's coarse state.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum ServiceState {
    /// Loading the map, starting the renderer.
    Starting = 0,
    /// Waiting for the first frame or the first pose.
    Waiting = 1,
    /// Tracking.
    Tracking = 2,
    /// Lost; relocalizing.
    Lost = 3,
    /// Shutting down.
    Stopping = 4,
}

impl ServiceState {
    fn from_u8(v: u8) -> Self {
        match v {
            1 => Self::Waiting,
            2 => Self::Tracking,
            3 => Self::Lost,
            4 => Self::Stopping,
            _ => Self::Starting,
        }
    }

    /// Lower-case name, as shown in the status line.
    pub fn name(self) -> &'static str {
        match self {
            Self::Starting => "starting",
            Self::Waiting => "waiting",
            Self::Tracking => "tracking",
            Self::Lost => "lost",
            Self::Stopping => "stopping",
        }
    }
}

/// Shared status, written by the tracker, read by the service thread.
#[derive(Debug, Default)]
pub struct StatusBoard {
    state: AtomicU8,
    frames: AtomicU64,
    keyframe_ns: AtomicU64,
}

impl StatusBoard {
    /// State `Starting`, no frames, no keyframe.
    pub fn new() -> Self {
        Self::default()
    }

    /// Sets the state.
    pub fn set_state(&self, state: ServiceState) {
        self.state.store(state as u8, Relaxed);
    }

    /// The current state.
    pub fn state(&self) -> ServiceState {
        ServiceState::from_u8(self.state.load(Relaxed))
    }

    /// Counts one processed frame (for the fps figure).
    pub fn frame_done(&self) {
        self.frames.fetch_add(1, Relaxed);
    }

    /// Frames processed so far.
    pub fn frames(&self) -> u64 {
        self.frames.load(Relaxed)
    }

    /// Records that the keyframe in use was rendered at `monotonic_ns`
    /// (CLOCK_MONOTONIC).
    pub fn keyframe_created(&self, monotonic_ns: u64) {
        self.keyframe_ns.store(monotonic_ns, Relaxed);
    }

    /// The status line: `tracking, 49.8 fps, keyframe age 0.42 s`.
    pub fn line(&self, fps: f64, now_ns: u64) -> String {
        let keyframe_ns = self.keyframe_ns.load(Relaxed);
        let age = if keyframe_ns == 0 {
            "no keyframe".to_string()
        } else {
            let age_s = now_ns.saturating_sub(keyframe_ns) as f64 * 1e-9;
            format!("keyframe age {age_s:.2} s")
        };
        format!("{}, {fps:.1} fps, {age}", self.state().name())
    }
}

/// Frame rate from two frame counts `elapsed_s` apart.
pub fn fps(frames_before: u64, frames_now: u64, elapsed_s: f64) -> f64 {
    if elapsed_s <= 0.0 {
        return 0.0;
    }
    frames_now.saturating_sub(frames_before) as f64 / elapsed_s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn line_reports_state_fps_and_keyframe_age() {
        let board = StatusBoard::new();
        assert_eq!(board.line(0.0, 5), "starting, 0.0 fps, no keyframe");
        board.set_state(ServiceState::Tracking);
        board.keyframe_created(1_000_000_000);
        for _ in 0..50 {
            board.frame_done();
        }
        let rate = fps(0, board.frames(), 1.0);
        assert_eq!(
            board.line(rate, 1_420_000_000),
            "tracking, 50.0 fps, keyframe age 0.42 s"
        );
        board.set_state(ServiceState::Lost);
        assert_eq!(board.state(), ServiceState::Lost);
        assert_eq!(fps(10, 5, 1.0), 0.0);
    }
}
