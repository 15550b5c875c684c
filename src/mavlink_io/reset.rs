//! The `reset_counter` that goes out with every pose.
//!
//! Takes each sample that is about to be sent (its tracker reset counter,
//! whether tracking was lost before it, its pose and capture time); gives out
//! the counter to send. The counter is incremented when:
//! - the tracker's own counter changes (relocalization, map reload);
//! - tracking resumes after it was lost;
//! - the pose jumps between two sent samples by more than the vehicle could
//!   move: over [`JUMP_BASE_M`] + [`JUMP_SPEED_M_PER_S`] * dt, or a rotation
//!   over [`JUMP_BASE_RAD`] + [`JUMP_RATE_RAD_PER_S`] * dt.

use crate::geometry::Pose;

/// Translation that always counts as a jump, plus the speed allowance below.
pub const JUMP_BASE_M: f64 = 0.5;
/// Fastest plausible speed of an indoor vehicle, m/s.
pub const JUMP_SPEED_M_PER_S: f64 = 20.0;
/// Rotation that always counts as a jump, rad (30 degrees).
pub const JUMP_BASE_RAD: f64 = std::f64::consts::FRAC_PI_6;
/// Fastest plausible rotation rate, rad/s (720 degrees/s).
pub const JUMP_RATE_RAD_PER_S: f64 = 4.0 * std::f64::consts::PI;

/// Tracks the counter across samples.
#[derive(Debug, Clone, Default)]
pub struct ResetCounter {
    counter: u8,
    tracker_counter: Option<u8>,
    lost_since_last_sent: bool,
    last_sent: Option<(u64, Pose)>,
}

impl ResetCounter {
    /// Starts at 0.
    pub fn new() -> Self {
        Self::default()
    }

    /// The counter as last sent.
    pub fn value(&self) -> u8 {
        self.counter
    }

    /// Notes a sample in which tracking was lost (nothing is sent for it).
    pub fn lost(&mut self) {
        if self.last_sent.is_some() {
            self.lost_since_last_sent = true;
        }
    }

    /// The counter for a tracked sample that is about to be sent;
    /// `ned_from_body` is the pose that goes out.
    pub fn next(&mut self, tracker_counter: u8, capture_ns: u64, ned_from_body: &Pose) -> u8 {
        let mut reset = false;
        if self.tracker_counter.is_some_and(|c| c != tracker_counter) {
            tracing::info!(tracker_counter, "tracker reset: incrementing reset_counter");
            reset = true;
        }
        if self.lost_since_last_sent {
            tracing::info!("tracking resumed: incrementing reset_counter");
            reset = true;
        }
        if let Some((last_ns, ned_from_body_last)) = &self.last_sent {
            let dt_s = capture_ns.saturating_sub(*last_ns) as f64 * 1e-9;
            let delta = ned_from_body_last.inverse() * ned_from_body;
            let moved_m = delta.translation.vector.norm();
            let turned_rad = delta.rotation.angle();
            if moved_m > JUMP_BASE_M + JUMP_SPEED_M_PER_S * dt_s
                || turned_rad > JUMP_BASE_RAD + JUMP_RATE_RAD_PER_S * dt_s
            {
                tracing::info!(
                    moved_m,
                    turned_rad,
                    dt_s,
                    "pose jump: incrementing reset_counter"
                );
                reset = true;
            }
        }
        if reset {
            self.counter = self.counter.wrapping_add(1);
        }
        self.tracker_counter = Some(tracker_counter);
        self.lost_since_last_sent = false;
        self.last_sent = Some((capture_ns, *ned_from_body));
        self.counter
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: u64 = 1_000_000;

    #[test]
    fn steady_tracking_keeps_the_counter() {
        let mut r = ResetCounter::new();
        for k in 0..10u64 {
            let p = Pose::translation(0.01 * k as f64, 0.0, 0.0);
            assert_eq!(r.next(0, k * 20 * MS, &p), 0);
        }
    }

    #[test]
    fn tracker_counter_change_increments() {
        let mut r = ResetCounter::new();
        assert_eq!(
            r.next(5, 0, &Pose::identity()),
            0,
            "first sample sets the baseline"
        );
        assert_eq!(r.next(5, 20 * MS, &Pose::identity()), 0);
        assert_eq!(r.next(6, 40 * MS, &Pose::identity()), 1);
        assert_eq!(r.next(6, 60 * MS, &Pose::identity()), 1);
    }

    #[test]
    fn resuming_after_lost_increments() {
        let mut r = ResetCounter::new();
        r.lost(); // lost before anything was sent: no reset needed
        assert_eq!(r.next(0, 0, &Pose::identity()), 0);
        r.lost();
        assert_eq!(r.next(0, 500 * MS, &Pose::identity()), 1);
        assert_eq!(r.value(), 1);
    }

    #[test]
    fn jumps_increment_but_fast_flight_does_not() {
        let mut r = ResetCounter::new();
        r.next(0, 0, &Pose::identity());
        // 0.2 m in 20 ms = 10 m/s: plausible.
        assert_eq!(r.next(0, 20 * MS, &Pose::translation(0.2, 0.0, 0.0)), 0);
        // 2 m in 20 ms: a jump.
        assert_eq!(r.next(0, 40 * MS, &Pose::translation(2.2, 0.0, 0.0)), 1);
        // 90 degrees in 20 ms: a jump.
        let turned = Pose::from_parts(
            nalgebra::Translation3::new(2.2, 0.0, 0.0),
            nalgebra::UnitQuaternion::from_euler_angles(0.0, 0.0, std::f64::consts::FRAC_PI_2),
        );
        assert_eq!(r.next(0, 60 * MS, &turned), 2);
    }

    #[test]
    fn counter_wraps() {
        let mut r = ResetCounter::new();
        r.next(0, 0, &Pose::identity());
        for k in 1..=256u64 {
            r.next((k % 256) as u8, k * 20 * MS, &Pose::identity());
        }
        assert_eq!(r.value(), 0, "256 increments wrap to 0");
    }
}
