//! The pose clock: what goes into `usec` (VISION_POSITION_ESTIMATE) or
//! `time_usec` (ODOMETRY), and what our TIMESYNC answers say.
//!
//! Takes each pose's capture time (CLOCK_MONOTONIC), the time now and the
//! TIMESYNC estimate ([`OffsetEstimate`]); gives out a [`Stamp`]: hold the
//! pose (clock not settled), skip it (it would land under the autopilot's
//! minimum spacing), or send it with this `usec`.
//!
//! One stream, one clock. A stream starts when the link opens
//! ([`PoseClock::start_stream`]). Its first pose decides the clock of the
//! whole stream:
//! - TIMESYNC has answered [`SETTLE_SAMPLES`] times (the sender asks every
//!   [`SETTLE_PERIOD_MS`] ms until then, so this takes about 100 ms), or has
//!   answered at all by `timesync_wait_ms`: the autopilot's clock,
//!   `capture + offset`. Several answers because the first one may be slow:
//!   against SITL, a first round trip of 40 ms put the first offset 20 ms
//!   off, and correcting that slowly cost EKF3 a dozen samples;
//! - not settled yet, and less than `timesync_wait_ms` since the stream
//!   started: the pose is held (the caller drops and counts it; nothing is
//!   queued);
//! - no answer within `timesync_wait_ms` (or `timesync = false`): star's own
//!   CLOCK_MONOTONIC, logged at warn, for the rest of the stream, even if
//!   answers come later. Both autopilots cope with a foreign clock that is
//!   consistent (ArduPilot's jitter correction, PX4's own TIMESYNC against
//!   our answers); what they cannot cope with is a clock that jumps, which a
//!   switch would be (issue 20: a first pose in CLOCK_MONOTONIC and the next
//!   in the autopilot's clock made ArduPilot date 200 samples 500 ms old).
//!
//! **The minimum spacing** (`autopilot_min_interval_ms`, default 20 ms, EKF3's
//! `extNavIntervalMin_ms`). EKF3 drops a sample whose time, `usec` through
//! ArduPilot's jitter correction and truncated to ms, is less than 20 ms
//! after the last sample it kept (`NavEKF3_core::writeExtNavData`). So
//! consecutive `usec` values of a stream are never closer than the minimum:
//! - a pose whose `usec` would be closer by at most [`TOLERANCE_NS`] (a
//!   camera at exactly 50 Hz whose capture times jitter by tens of µs) is
//!   stamped at the minimum: that moves its stamp later by under half of
//!   ArduPilot's 1 ms resolution;
//! - a pose closer than that is skipped ([`Stamp::Skip`], counted): a
//!   camera faster than the minimum allows loses frames here, on our side and
//!   counted, instead of in the EKF.
//!
//! **The offset.** In the autopilot's clock, the offset in `usec` is an
//! *applied* offset, not the raw estimate. It starts at the low edge of the
//! estimate's uncertainty interval (`offset +- rtt / 2`, where the true
//! offset lies; the low edge is the bound that holds when the autopilot
//! back-dates its TIMESYNC stamps, see `timesync.rs`). After that the applied
//! offset moves only when it leaves the current estimate's interval, toward
//! that interval:
//! - upward (later stamps, longer gaps) by at most [`SLEW_DIVISOR`] parts of
//!   the capture interval per pose (1 %: a 2 ms step of the estimate is
//!   absorbed over 200 ms of poses);
//! - downward (earlier stamps, shorter gaps) only out of the slack above the
//!   minimum spacing: a gap that is longer than the minimum (a frame that
//!   was skipped or came late) gives its excess. Before, a 1 % downward slew
//!   with the camera at exactly 50 Hz put consecutive stamps 19.8 ms apart,
//!   and EKF3 dropped about half of 40 samples a flight so. A camera at
//!   exactly the minimum leaves no slack: a downward correction that is
//!   still more than [`TOLERANCE_NS`] out after this skips one pose to make
//!   room (a drift of 50 ppm between the two clocks costs one pose in about
//!   500).
//!
//! So a new TIMESYNC sample, or a hostile reply, can never move two
//! consecutive `usec` values apart by more than 101 % of their capture
//! interval, nor closer than the minimum spacing. A confirmed jump of the
//! estimate (an autopilot restart, see `timesync.rs`) is followed the same
//! way: `usec` stays continuous.
//!
//! Our TIMESYNC answers use the same clock as the poses
//! ([`PoseClock::public_ns`]), so an autopilot that runs TIMESYNC itself
//! converts `usec` with the offset it measures against the clock `usec` is in.

use super::timesync::OffsetEstimate;

/// The applied offset moves by at most `1 / SLEW_DIVISOR` of the capture
/// interval between two poses.
pub const SLEW_DIVISOR: i64 = 100;
/// TIMESYNC samples that settle the clock before the first pose.
pub const SETTLE_SAMPLES: usize = 4;
/// Period of our TIMESYNC requests while the clock is not settled, ms.
pub const SETTLE_PERIOD_MS: u64 = 25;
/// How far a stamp may be moved later to keep the minimum spacing, and how
/// far the applied offset may stay above the estimate's interval before a
/// pose is skipped to correct it, ns: half of ArduPilot's 1 ms resolution.
pub const TOLERANCE_NS: i64 = 500_000;

/// What a slew of the applied offset did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Slew {
    /// Moved as far as allowed (or needed no move).
    Done,
    /// More than [`TOLERANCE_NS`] above the estimate's interval with no room
    /// under the pose's stamp to come down.
    Stuck,
}

/// Which clock the current stream's `usec` is in.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum StreamClock {
    /// No pose sent yet in this stream: waiting for the first TIMESYNC
    /// answer.
    #[default]
    Waiting,
    /// The autopilot's clock (`capture + applied offset`).
    Autopilot,
    /// star's CLOCK_MONOTONIC (no answer in time, or TIMESYNC off).
    Monotonic,
}

/// What to do with a pose.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stamp {
    /// Drop it: the stream's clock is not settled yet.
    Hold,
    /// Drop it: its `usec` would be closer than the minimum spacing to the
    /// last one sent (by more than [`TOLERANCE_NS`]), or a downward offset
    /// correction needs the room.
    Skip,
    /// Send it with this `usec`.
    Usec(u64),
}

/// The pose clock of one link. Fixed-size, allocation-free.
#[derive(Debug, Clone)]
pub struct PoseClock {
    timesync: bool,
    wait_ns: u64,
    min_spacing_us: u64,
    clock: StreamClock,
    stream_start_ns: u64,
    applied_ns: i64,
    /// Capture time and `usec` of the last pose sent in this stream.
    last: Option<(u64, u64)>,
}

impl PoseClock {
    /// A clock that waits up to `wait_ns` for the first TIMESYNC answer
    /// (`timesync = false`: never waits, always CLOCK_MONOTONIC) and keeps
    /// consecutive `usec` values at least `min_spacing_ns` apart (rounded up
    /// to whole µs, 1 µs at least).
    pub fn new(timesync: bool, wait_ns: u64, min_spacing_ns: u64) -> Self {
        Self {
            timesync,
            wait_ns,
            min_spacing_us: min_spacing_ns.div_ceil(1_000).max(1),
            clock: Self::initial(timesync),
            stream_start_ns: 0,
            applied_ns: 0,
            last: None,
        }
    }

    fn initial(timesync: bool) -> StreamClock {
        if timesync {
            StreamClock::Waiting
        } else {
            StreamClock::Monotonic
        }
    }

    /// A new stream (the link opened or reopened) starts at `now_ns`: its
    /// clock is decided afresh by its first pose.
    pub fn start_stream(&mut self, now_ns: u64) {
        self.clock = Self::initial(self.timesync);
        self.stream_start_ns = now_ns;
        self.applied_ns = 0;
        self.last = None;
    }

    /// Whether the stream's clock still needs TIMESYNC answers before its
    /// first pose: no pose sent yet, fewer than [`SETTLE_SAMPLES`] answers,
    /// and the wait not over. The sender then asks every
    /// [`SETTLE_PERIOD_MS`] ms instead of every 500 ms.
    pub fn settling(&self, now_ns: u64, estimate: Option<OffsetEstimate>) -> bool {
        self.clock == StreamClock::Waiting
            && now_ns.saturating_sub(self.stream_start_ns) < self.wait_ns
            && estimate.is_none_or(|e| e.samples < SETTLE_SAMPLES)
    }

    /// The clock of the current stream.
    pub fn clock(&self) -> StreamClock {
        self.clock
    }

    /// The offset in `usec` (`usec * 1000 - capture`), while the stream is in
    /// the autopilot's clock.
    pub fn applied_offset_ns(&self) -> Option<i64> {
        (self.clock == StreamClock::Autopilot).then_some(self.applied_ns)
    }

    /// Our public time (TIMESYNC answers) for a monotonic time: the stream's
    /// clock; before the first pose, the estimate the first pose would take.
    pub fn public_ns(&self, monotonic_ns: u64, estimate: Option<OffsetEstimate>) -> i64 {
        let offset_ns = match self.clock {
            StreamClock::Waiting => estimate.map_or(0, |e| e.offset_ns),
            StreamClock::Autopilot => self.applied_ns,
            StreamClock::Monotonic => 0,
        };
        i64::try_from(monotonic_ns)
            .unwrap_or(i64::MAX)
            .saturating_add(offset_ns)
    }

    /// The stamp of a pose captured at `capture_ns`, handed to the link at
    /// `now_ns`, with the current TIMESYNC estimate. A [`Stamp::Usec`] is
    /// taken as sent: the next pose is spaced from it.
    pub fn stamp(
        &mut self,
        capture_ns: u64,
        now_ns: u64,
        estimate: Option<OffsetEstimate>,
    ) -> Stamp {
        if self.clock == StreamClock::Waiting {
            let waited = now_ns.saturating_sub(self.stream_start_ns) >= self.wait_ns;
            if let Some(e) = estimate.filter(|e| waited || e.samples >= SETTLE_SAMPLES) {
                self.clock = StreamClock::Autopilot;
                self.applied_ns = e.offset_ns.saturating_sub(e.uncertainty_ns.max(0));
                tracing::info!(
                    offset_ns = e.offset_ns,
                    uncertainty_ns = e.uncertainty_ns,
                    samples = e.samples,
                    "first pose of the stream: usec in the autopilot's clock (TIMESYNC)"
                );
            } else if waited {
                self.clock = StreamClock::Monotonic;
                tracing::warn!(
                    waited_ms = self.wait_ns / 1_000_000,
                    "no TIMESYNC answer from the autopilot: this stream's usec is star's \
                     CLOCK_MONOTONIC, from its first pose on"
                );
            } else {
                return Stamp::Hold;
            }
        }
        let capture = i64::try_from(capture_ns).unwrap_or(i64::MAX);
        let Some((last_capture_ns, last_usec)) = self.last else {
            let usec = Self::usec_of(capture.saturating_add(self.applied_ns));
            self.last = Some((capture_ns, usec));
            return Stamp::Usec(usec);
        };
        // The earliest `usec` this pose may have.
        let floor_usec = last_usec.saturating_add(self.min_spacing_us);
        if self.clock == StreamClock::Autopilot {
            if let Some(e) = estimate {
                let gap_ns = capture_ns.saturating_sub(last_capture_ns);
                let floor_ns = i64::try_from(floor_usec)
                    .unwrap_or(i64::MAX)
                    .saturating_mul(1_000);
                if self.slew(e, gap_ns, capture, floor_ns) == Slew::Stuck {
                    // No room to correct downward: skip this pose, the next
                    // one gets two intervals of it.
                    return Stamp::Skip;
                }
            }
        }
        let natural_usec = Self::usec_of(capture.saturating_add(self.applied_ns));
        let usec = if natural_usec >= floor_usec {
            natural_usec
        } else if floor_usec - natural_usec <= TOLERANCE_NS.unsigned_abs() / 1_000 {
            floor_usec
        } else {
            return Stamp::Skip;
        };
        self.last = Some((capture_ns, usec));
        Stamp::Usec(usec)
    }

    fn usec_of(public_ns: i64) -> u64 {
        u64::try_from(public_ns.max(0) / 1_000).unwrap_or(0)
    }

    /// Moves the applied offset toward the estimate's interval: upward by at
    /// most `gap_ns / SLEW_DIVISOR`, downward by at most the room between
    /// this pose's natural stamp and `floor_ns`.
    fn slew(&mut self, estimate: OffsetEstimate, gap_ns: u64, capture: i64, floor_ns: i64) -> Slew {
        let half = estimate.uncertainty_ns.max(0);
        let lo = estimate.offset_ns.saturating_sub(half);
        let hi = estimate.offset_ns.saturating_add(half);
        let max_step = i64::try_from(gap_ns).unwrap_or(i64::MAX) / SLEW_DIVISOR;
        if self.applied_ns < lo {
            self.applied_ns = self
                .applied_ns
                .saturating_add(lo.saturating_sub(self.applied_ns).min(max_step));
        } else if self.applied_ns > hi {
            let room = capture
                .saturating_add(self.applied_ns)
                .saturating_sub(floor_ns)
                .max(0);
            let step = self.applied_ns.saturating_sub(hi).min(room);
            self.applied_ns = self.applied_ns.saturating_sub(step);
            if step == 0 && self.applied_ns.saturating_sub(hi) > TOLERANCE_NS {
                return Slew::Stuck;
            }
        }
        Slew::Done
    }
}

#[cfg(test)]
#[path = "stamp_tests.rs"]
mod tests;
