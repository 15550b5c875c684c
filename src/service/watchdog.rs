//! The progress-gated systemd watchdog.
//!
//! Takes "progress" from the tracking loop ([`Watchdog::feed`], one atomic
//! add, no allocation); gives out the decision whether the service thread may
//! send `WATCHDOG=1` ([`WatchdogGate`]): only when the loop fed since the last
//! ping. A hung loop (deadlock, endless alignment) stops the pings and
//! systemd restarts the unit after `WatchdogSec`.
//!
//! Feed on every loop iteration, including idle wake-ups (a frame wait that
//! timed out), so that a camera outage is not mistaken for a hang.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;

/// The tracking loop's handle. Clone it into each loop that must stay alive.
#[derive(Debug, Clone, Default)]
pub struct Watchdog {
    progress: Arc<AtomicU64>,
}

impl Watchdog {
    /// A watchdog nobody has fed yet.
    pub fn new() -> Self {
        Self::default()
    }

    /// Records progress. Call once per loop iteration.
    pub fn feed(&self) {
        self.progress.fetch_add(1, Ordering::Relaxed);
    }

    /// How often the loop has fed so far.
    pub fn progress(&self) -> u64 {
        self.progress.load(Ordering::Relaxed)
    }
}

/// Decides whether a ping is deserved: progress since the last decision.
#[derive(Debug, Clone, Default)]
pub struct WatchdogGate {
    last_progress: u64,
    starved: bool,
}

impl WatchdogGate {
    /// A gate that pings once it sees the first feed.
    pub fn new() -> Self {
        Self::default()
    }

    /// True (ping) when `progress` moved since the previous call.
    pub fn should_ping(&mut self, progress: u64) -> bool {
        let moved = progress != self.last_progress;
        self.last_progress = progress;
        if !moved && !self.starved {
            tracing::warn!("tracking loop made no progress: withholding the watchdog ping");
        }
        if moved && self.starved {
            tracing::info!("tracking loop progressing again: watchdog pings resume");
        }
        self.starved = !moved;
        moved
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pings_only_after_progress() {
        let dog = Watchdog::new();
        let mut gate = WatchdogGate::new();
        assert!(!gate.should_ping(dog.progress()), "no feed yet");
        dog.feed();
        assert!(gate.should_ping(dog.progress()));
        assert!(
            !gate.should_ping(dog.progress()),
            "no feed since the last ping"
        );
        let clone = dog.clone();
        clone.feed();
        clone.feed();
        assert!(gate.should_ping(dog.progress()), "clones share progress");
    }
}
