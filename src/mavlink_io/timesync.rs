//! TIMESYNC (111): answering the autopilot's requests and estimating the
//! offset between our CLOCK_MONOTONIC and the autopilot's clock.
//!
//! Takes our requests as we send them and the replies as they arrive (with
//! their arrival time); gives out the offset `autopilot_ns - monotonic_ns`
//! and its uncertainty ([`OffsetEstimate`]). What goes into `usec` is decided
//! by the pose clock (`stamp.rs`), which settles on one clock per stream and
//! slews this estimate into it.
//!
//! Protocol (nanoseconds both ways): a request has `tc1 = 0` and
//! `ts1 = requester's time`; the reply has `tc1 = responder's time` and the
//! request's `ts1`. For one of our requests answered at our time `now`,
//! `rtt = now - ts1` and `offset = tc1 - (ts1 + now) / 2`. Whatever the
//! split of the round trip between the two directions, the true offset lies
//! within `offset +- rtt / 2`: that half round trip is the sample's
//! uncertainty.
//!
//! Robust filter: the estimate is the sample, among the last [`WINDOW`]
//! accepted ones, with the highest lower bound `offset - rtt / 2`
//! (`tc1 - now`, the autopilot's time at the request minus our time at the
//! reply). That bound holds however the autopilot stamps `tc1`, as long as
//! it stamps it between the request's arrival and the reply's departure; the
//! upper bound `tc1 - ts1` does not hold when the autopilot back-dates
//! `tc1`, and ArduPilot does: it stamps a request with its UART's
//! `receive_time_constraint_us`, the last read minus the byte time (at the
//! port's baud rate) of the packet *and of every byte queued behind it*.
//! Against SITL (SERIAL1 over TCP, 57 600 baud assumed, 174 µs a byte) a
//! request that arrived in one read with a VISION_POSITION_ESTIMATE behind it
//! was dated 22 ms early; picked as the lowest-RTT sample it moved the
//! estimate by -22 ms twice a flight (issue 20). A back-dated sample has a
//! lower lower bound, so it never wins here; with honest stamps the highest
//! lower bound is the exchange with the fastest way back, as symmetric a
//! pick as the lowest RTT. Rejected outright:
//! replies that do not match one of our last requests, with an RTT above
//! [`MAX_RTT_NS`], or with an implausible autopilot time (`tc1 <= 0` or
//! `tc1 >= 2^62` ns, 146 years).
//!
//! Plausibility bound: once there is an estimate, a sample that disagrees
//! with it by more than both RTTs plus [`AGREEMENT_SLACK_NS`] does not move
//! it. Only [`RESYNC_AFTER`] such samples in a row that also agree with each
//! other (the autopilot rebooted, or its clock was set) replace the window,
//! and that jump is logged at warn. Lone outliers, and hostile or corrupt
//! replies that do not agree with each other, are counted and ignored.
//!
//! Our "public" clock (what requests from the autopilot are answered with)
//! is the pose clock's: poses and answers use the same clock, so an
//! autopilot that runs its own TIMESYNC (PX4) converts `usec` consistently.

/// Number of samples the filter picks its estimate from.
pub const WINDOW: usize = 16;
/// Replies slower than this round trip are not used, ns.
pub const MAX_RTT_NS: i64 = 100_000_000;
/// Consecutive, mutually agreeing samples that move the estimate past the
/// plausibility bound (a resync).
pub const RESYNC_AFTER: usize = 3;
/// Autopilot times at or above this are implausible (2^62 ns, 146 years).
pub const MAX_AUTOPILOT_NS: i64 = 1 << 62;
/// Slack added to the RTTs when checking agreement, ns.
pub const AGREEMENT_SLACK_NS: i64 = 10_000_000;
/// Our outstanding requests that a reply may match.
const PENDING: usize = 8;

/// One accepted exchange.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TimesyncSample {
    /// `autopilot - ours`, ns.
    pub offset_ns: i64,
    /// Round trip, ns.
    pub rtt_ns: i64,
}

impl TimesyncSample {
    /// The lowest offset this exchange allows, `offset - rtt / 2`, ns.
    pub fn lower_bound_ns(&self) -> i64 {
        self.offset_ns.saturating_sub(self.rtt_ns / 2)
    }

    /// Whether two samples can describe the same clock offset.
    fn agrees_with(&self, other: &TimesyncSample) -> bool {
        let tolerance = self
            .rtt_ns
            .saturating_add(other.rtt_ns)
            .saturating_add(AGREEMENT_SLACK_NS);
        self.offset_ns
            .saturating_sub(other.offset_ns)
            .saturating_abs()
            <= tolerance
    }
}

/// The current estimate: the true offset lies within
/// `offset_ns +- uncertainty_ns` (up to clock drift since the sample).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct OffsetEstimate {
    /// `autopilot - monotonic`, ns.
    pub offset_ns: i64,
    /// Half the round trip of the sample the estimate comes from, ns.
    pub uncertainty_ns: i64,
    /// Samples in the window the estimate was picked from (1..=[`WINDOW`]).
    pub samples: usize,
}

/// What a received TIMESYNC means.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TimesyncEvent {
    /// A reply to one of our requests, used as a sample.
    Sample(TimesyncSample),
    /// A reply that was not used (not ours, too slow, implausible time).
    Rejected,
    /// A reply of ours that disagrees with the estimate beyond the
    /// plausibility bound; kept aside, not used (yet).
    Outlier(TimesyncSample),
    /// [`RESYNC_AFTER`] agreeing outliers in a row replaced the estimate.
    Resync {
        /// The estimate before, ns.
        old_offset_ns: i64,
        /// The estimate now, ns.
        new_offset_ns: i64,
    },
}

/// The offset estimator. Fixed-size, allocation-free.
#[derive(Debug, Clone, Default)]
pub struct TimesyncEstimator {
    pending: [Option<i64>; PENDING],
    next_pending: usize,
    window: [Option<TimesyncSample>; WINDOW],
    next_sample: usize,
    disagreeing: [Option<TimesyncSample>; RESYNC_AFTER],
    disagreeing_count: usize,
}

impl TimesyncEstimator {
    /// An estimator with no samples.
    pub fn new() -> Self {
        Self::default()
    }

    /// Forgets everything (a new link: the autopilot may have restarted).
    pub fn reset(&mut self) {
        *self = Self::default();
    }

    /// Records that we sent a request with `ts1 = now_ns` (our monotonic time).
    pub fn request_sent(&mut self, now_ns: i64) {
        self.pending[self.next_pending] = Some(now_ns);
        self.next_pending = (self.next_pending + 1) % PENDING;
    }

    /// Feeds a reply (`tc1 != 0`) that arrived at our monotonic `now_ns`.
    pub fn reply_received(&mut self, tc1: i64, ts1: i64, now_ns: i64) -> TimesyncEvent {
        let Some(slot) = self.pending.iter_mut().find(|p| **p == Some(ts1)) else {
            return TimesyncEvent::Rejected;
        };
        *slot = None;
        let rtt_ns = now_ns.saturating_sub(ts1);
        if !(0..=MAX_RTT_NS).contains(&rtt_ns) || !(1..MAX_AUTOPILOT_NS).contains(&tc1) {
            return TimesyncEvent::Rejected;
        }
        let sample = TimesyncSample {
            offset_ns: tc1.saturating_sub(ts1).saturating_sub(rtt_ns / 2),
            rtt_ns,
        };
        self.add(sample)
    }

    fn add(&mut self, sample: TimesyncSample) -> TimesyncEvent {
        let Some(best) = self.best() else {
            self.push(sample);
            return TimesyncEvent::Sample(sample);
        };
        if sample.agrees_with(&best) {
            self.disagreeing = [None; RESYNC_AFTER];
            self.disagreeing_count = 0;
            self.push(sample);
            return TimesyncEvent::Sample(sample);
        }
        // Outside the plausibility bound: it counts toward a resync only if
        // it agrees with the outliers before it.
        let consistent = self.disagreeing[..self.disagreeing_count]
            .iter()
            .flatten()
            .all(|s| s.agrees_with(&sample));
        if !consistent {
            self.disagreeing = [None; RESYNC_AFTER];
            self.disagreeing_count = 0;
        }
        self.disagreeing[self.disagreeing_count] = Some(sample);
        self.disagreeing_count += 1;
        if self.disagreeing_count < RESYNC_AFTER {
            return TimesyncEvent::Outlier(sample);
        }
        self.window = [None; WINDOW];
        self.next_sample = 0;
        let fresh = std::mem::replace(&mut self.disagreeing, [None; RESYNC_AFTER]);
        self.disagreeing_count = 0;
        for s in fresh.into_iter().flatten() {
            self.push(s);
        }
        let new_offset_ns = self.best().map_or(sample.offset_ns, |s| s.offset_ns);
        tracing::warn!(
            old_offset_ns = best.offset_ns,
            new_offset_ns,
            jump_ms = new_offset_ns.saturating_sub(best.offset_ns) as f64 * 1e-6,
            "TIMESYNC offset jumped ({RESYNC_AFTER} agreeing replies; autopilot restarted?): estimate replaced"
        );
        TimesyncEvent::Resync {
            old_offset_ns: best.offset_ns,
            new_offset_ns,
        }
    }

    fn push(&mut self, sample: TimesyncSample) {
        self.window[self.next_sample] = Some(sample);
        self.next_sample = (self.next_sample + 1) % WINDOW;
    }

    /// The sample with the highest lower bound (ties: the lower RTT).
    fn best(&self) -> Option<TimesyncSample> {
        self.window
            .iter()
            .flatten()
            .max_by_key(|s| (s.lower_bound_ns(), std::cmp::Reverse(s.rtt_ns)))
            .copied()
    }

    /// The estimated `autopilot - monotonic` offset, ns, once a reply came.
    pub fn offset_ns(&self) -> Option<i64> {
        self.best().map(|s| s.offset_ns)
    }

    /// Round trip of the sample the estimate comes from, ns.
    pub fn rtt_ns(&self) -> Option<i64> {
        self.best().map(|s| s.rtt_ns)
    }

    /// The estimate with its uncertainty, once a reply came.
    pub fn estimate(&self) -> Option<OffsetEstimate> {
        self.best().map(|s| OffsetEstimate {
            offset_ns: s.offset_ns,
            uncertainty_ns: s.rtt_ns / 2,
            samples: self.window.iter().flatten().count(),
        })
    }
}

/// `monotonic + offset`, saturating (no offset: unchanged).
pub fn to_public_ns(monotonic_ns: u64, offset_ns: Option<i64>) -> i64 {
    i64::try_from(monotonic_ns)
        .unwrap_or(i64::MAX)
        .saturating_add(offset_ns.unwrap_or(0))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An autopilot whose clock is ours + `offset`, reached with the given
    /// one-way delays.
    fn exchange(
        est: &mut TimesyncEstimator,
        t0: i64,
        offset: i64,
        up: i64,
        down: i64,
    ) -> TimesyncEvent {
        est.request_sent(t0);
        let tc1 = t0 + up + offset;
        est.reply_received(tc1, t0, t0 + up + down)
    }

    #[test]
    fn symmetric_exchange_gives_exact_offset() {
        let mut est = TimesyncEstimator::new();
        let ev = exchange(&mut est, 1_000_000_000, 5_000_000_000, 1_000_000, 1_000_000);
        assert_eq!(
            ev,
            TimesyncEvent::Sample(TimesyncSample {
                offset_ns: 5_000_000_000,
                rtt_ns: 2_000_000
            })
        );
        assert_eq!(est.offset_ns(), Some(5_000_000_000));
    }

    #[test]
    fn lowest_rtt_sample_wins_over_queueing_outliers() {
        let mut est = TimesyncEstimator::new();
        let offset = -3_000_000_000i64;
        // Asymmetric, slow exchanges bias the offset by (up - down) / 2.
        for k in 0..10 {
            exchange(&mut est, k * 1_000_000_000, offset, 30_000_000, 1_000_000);
        }
        // One fast, symmetric exchange.
        exchange(&mut est, 20_000_000_000, offset, 200_000, 200_000);
        for k in 21..25 {
            exchange(&mut est, k * 1_000_000_000, offset, 1_000_000, 25_000_000);
        }
        assert_eq!(est.offset_ns(), Some(offset));
        assert_eq!(est.rtt_ns(), Some(400_000));
    }

    #[test]
    fn back_dated_replies_do_not_move_the_estimate() {
        // ArduPilot dates a request by its UART's last read minus the byte
        // time of everything queued behind it: against SITL, a request read
        // together with a VISION_POSITION_ESTIMATE came back 22 ms early,
        // and with the fastest round trip of the window.
        let mut est = TimesyncEstimator::new();
        let offset = 4_000_000_000i64;
        for k in 0..6 {
            exchange(&mut est, k * 500_000_000, offset, 4_000_000, 4_000_000);
        }
        let before = est.estimate();
        // Within the plausibility bound of 8 ms round trips, and faster.
        est.request_sent(3_000_000_000);
        let tc1 = 3_000_000_000 + 3_000_000 + offset - 22_000_000;
        let ev = est.reply_received(tc1, 3_000_000_000, 3_000_000_000 + 6_000_000);
        assert!(matches!(ev, TimesyncEvent::Sample(_)), "{ev:?}");
        assert_eq!(
            est.estimate(),
            Some(OffsetEstimate {
                samples: 7,
                ..before.unwrap()
            })
        );
        // The fastest way back wins: the tightest lower bound.
        exchange(&mut est, 4_000_000_000, offset, 900_000, 100_000);
        assert_eq!(
            est.estimate().map(|e| e.offset_ns - e.uncertainty_ns),
            Some(offset - 100_000)
        );
    }

    #[test]
    fn foreign_and_slow_replies_are_rejected() {
        let mut est = TimesyncEstimator::new();
        est.request_sent(100);
        // ts1 we never sent.
        assert_eq!(est.reply_received(5, 99, 200), TimesyncEvent::Rejected);
        // Too slow.
        assert_eq!(
            est.reply_received(5, 100, 100 + MAX_RTT_NS + 1),
            TimesyncEvent::Rejected
        );
        // A request is matched once only.
        assert_eq!(est.reply_received(5, 100, 200), TimesyncEvent::Rejected);
        assert_eq!(est.offset_ns(), None);
    }

    #[test]
    fn autopilot_restart_resyncs_after_consecutive_disagreement() {
        let mut est = TimesyncEstimator::new();
        for k in 0..5 {
            exchange(&mut est, k * 1_000_000_000, 7_000_000_000, 500_000, 500_000);
        }
        // One outlier is ignored...
        exchange(
            &mut est,
            10_000_000_000,
            -1_000_000_000,
            2_000_000,
            2_000_000,
        );
        assert_eq!(est.offset_ns(), Some(7_000_000_000));
        exchange(
            &mut est,
            11_000_000_000,
            7_000_000_000,
            2_000_000,
            2_000_000,
        );
        // ...three agreeing ones in a row replace the estimate.
        for k in 12..15 {
            exchange(
                &mut est,
                k * 1_000_000_000,
                -1_000_000_000,
                2_000_000,
                2_000_000,
            );
        }
        assert_eq!(est.offset_ns(), Some(-1_000_000_000));
    }

    #[test]
    fn absurd_replies_are_rejected_without_overflow() {
        let mut est = TimesyncEstimator::new();
        for (k, tc1) in [i64::MIN, -(1 << 62), 0, 1 << 62, i64::MAX]
            .into_iter()
            .enumerate()
        {
            let ts1 = 1_000 + k as i64 * 10_000;
            est.request_sent(ts1);
            assert_eq!(
                est.reply_received(tc1, ts1, ts1 + 1_000),
                TimesyncEvent::Rejected,
                "tc1 = {tc1}"
            );
        }
        assert_eq!(est.offset_ns(), None);
        // A reply that arrives "before" its request (a corrupt ts1 that
        // happens to match) is not a sample either.
        est.request_sent(i64::MAX);
        assert_eq!(
            est.reply_received(5, i64::MAX, i64::MIN),
            TimesyncEvent::Rejected
        );
    }

    #[test]
    fn hostile_replies_do_not_move_the_estimate() {
        let mut est = TimesyncEstimator::new();
        let offset = 2_000_000_000i64;
        for k in 0..5 {
            exchange(&mut est, k * 500_000_000, offset, 1_000_000, 1_000_000);
        }
        let before = est.estimate();
        // Replies to our requests whose tc1 is absurd: 2^62 and -2^62 are
        // rejected outright; tc1 = 1 (an autopilot "just booted") disagrees
        // and, since each such reply implies a different offset, never
        // resyncs however often it comes.
        for k in 5..50i64 {
            let ts1 = k * 500_000_000;
            let tc1 = match k % 3 {
                0 => 1 << 62,
                1 => -(1 << 62),
                _ => 1,
            };
            est.request_sent(ts1);
            let ev = est.reply_received(tc1, ts1, ts1 + 2_000_000);
            assert!(
                matches!(ev, TimesyncEvent::Rejected | TimesyncEvent::Outlier(_)),
                "{ev:?}"
            );
            assert_eq!(est.estimate(), before);
        }
        // Outliers in a row that disagree with each other do not resync.
        for k in 50..60i64 {
            let jump = if k % 2 == 0 {
                3_000_000_000
            } else {
                -3_000_000_000
            };
            let ev = exchange(
                &mut est,
                k * 500_000_000,
                offset + jump,
                1_000_000,
                1_000_000,
            );
            assert!(matches!(ev, TimesyncEvent::Outlier(_)), "{ev:?}");
        }
        assert_eq!(est.estimate(), before);
        // Normal replies keep being used.
        assert!(matches!(
            exchange(&mut est, 70_000_000_000, offset, 1_000_000, 1_000_000),
            TimesyncEvent::Sample(_)
        ));
    }

    #[test]
    fn estimate_carries_half_the_round_trip() {
        let mut est = TimesyncEstimator::new();
        exchange(&mut est, 1_000, 7_000_000, 3_000_000, 1_000_000);
        assert_eq!(
            est.estimate(),
            Some(OffsetEstimate {
                offset_ns: 7_000_000 + 1_000_000,
                uncertainty_ns: 2_000_000,
                samples: 1,
            })
        );
        est.reset();
        assert_eq!(est.estimate(), None);
    }

    #[test]
    fn public_time_applies_the_offset() {
        assert_eq!(to_public_ns(1_000, Some(-400)), 600);
        assert_eq!(to_public_ns(1_000, None), 1_000);
    }
}
