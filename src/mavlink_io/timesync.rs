//! TIMESYNC (111): answering the autopilot's requests and estimating the
//! offset between our CLOCK_MONOTONIC and the autopilot's clock.
//!
//! Takes our requests as we send them and the replies as they arrive (with
//! their arrival time); gives out the offset `autopilot_ns - monotonic_ns`
//! that is added to capture times before they go into `usec`.
//!
//! Protocol (nanoseconds both ways): a request has `tc1 = 0` and
//! `ts1 = requester's time`; the reply has `tc1 = responder's time` and the
//! request's `ts1`. For one of our requests answered at our time `now`,
//! `rtt = now - ts1` and `offset = tc1 - (ts1 + now) / 2`.
//!
//! Robust filter: the estimate is the offset of the lowest-RTT sample among
//! the last [`WINDOW`] accepted ones (queueing delay only ever adds to the
//! RTT, so the fastest exchange is the most symmetric). Replies that do not
//! match one of our last requests, or with an RTT above [`MAX_RTT_NS`], are
//! rejected. If [`RESYNC_AFTER`] samples in a row disagree with the estimate
//! by more than their RTT plus 10 ms (the autopilot rebooted), the window is
//! cleared and refilled from the new samples.
//!
//! Our "public" clock is `monotonic + offset`: poses are stamped with it and
//! requests from the autopilot are answered with it, so an autopilot that
//! runs its own TIMESYNC (PX4) measures an offset of about zero and does not
//! correct twice.

/// Number of samples the lowest-RTT filter looks at.
pub const WINDOW: usize = 16;
/// Replies slower than this round trip are not used, ns.
pub const MAX_RTT_NS: i64 = 100_000_000;
/// Consecutive disagreeing samples that trigger a resync.
pub const RESYNC_AFTER: usize = 3;
/// Our outstanding requests that a reply may match.
const PENDING: usize = 8;
/// Slack added to the RTT when checking agreement, ns.
const AGREEMENT_SLACK_NS: i64 = 10_000_000;

/// One accepted exchange.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TimesyncSample {
    /// `autopilot - ours`, ns.
    pub offset_ns: i64,
    /// Round trip, ns.
    pub rtt_ns: i64,
}

/// What a received TIMESYNC means.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TimesyncEvent {
    /// A reply to one of our requests, used as a sample.
    Sample(TimesyncSample),
    /// A reply that was not used (not ours, or too slow).
    Rejected,
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
        let rtt_ns = now_ns - ts1;
        if !(0..=MAX_RTT_NS).contains(&rtt_ns) {
            return TimesyncEvent::Rejected;
        }
        let sample = TimesyncSample {
            offset_ns: tc1.saturating_sub(ts1).saturating_sub(rtt_ns / 2),
            rtt_ns,
        };
        self.add(sample);
        TimesyncEvent::Sample(sample)
    }

    fn add(&mut self, sample: TimesyncSample) {
        if let Some(best) = self.best() {
            let tolerance = sample.rtt_ns + best.rtt_ns + AGREEMENT_SLACK_NS;
            if sample
                .offset_ns
                .saturating_sub(best.offset_ns)
                .saturating_abs()
                > tolerance
            {
                self.disagreeing[self.disagreeing_count] = Some(sample);
                self.disagreeing_count += 1;
                if self.disagreeing_count == RESYNC_AFTER {
                    tracing::warn!(
                        old_offset_ns = best.offset_ns,
                        new_offset_ns = sample.offset_ns,
                        "TIMESYNC offset jumped (autopilot restarted?): resyncing"
                    );
                    self.window = [None; WINDOW];
                    self.next_sample = 0;
                    let fresh = std::mem::replace(&mut self.disagreeing, [None; RESYNC_AFTER]);
                    self.disagreeing_count = 0;
                    for s in fresh.into_iter().flatten() {
                        self.push(s);
                    }
                }
                return;
            }
        }
        self.disagreeing = [None; RESYNC_AFTER];
        self.disagreeing_count = 0;
        self.push(sample);
    }

    fn push(&mut self, sample: TimesyncSample) {
        self.window[self.next_sample] = Some(sample);
        self.next_sample = (self.next_sample + 1) % WINDOW;
    }

    fn best(&self) -> Option<TimesyncSample> {
        self.window
            .iter()
            .flatten()
            .min_by_key(|s| s.rtt_ns)
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
}

/// Our public time for a monotonic time: `monotonic + offset` (no offset yet: unchanged).
pub fn to_public_ns(monotonic_ns: u64, offset_ns: Option<i64>) -> i64 {
    (monotonic_ns as i64).saturating_add(offset_ns.unwrap_or(0))
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
        // ...three in a row replace the estimate.
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
    fn absurd_replies_do_not_overflow() {
        let mut est = TimesyncEstimator::new();
        est.request_sent(1_000);
        assert!(matches!(
            est.reply_received(i64::MIN, 1_000, 2_000),
            TimesyncEvent::Sample(_)
        ));
        est.request_sent(3_000);
        assert!(matches!(
            est.reply_received(i64::MAX, 3_000, 4_000),
            TimesyncEvent::Sample(_)
        ));
        assert!(est.offset_ns().is_some());
    }

    #[test]
    fn public_time_applies_the_offset() {
        assert_eq!(to_public_ns(1_000, Some(-400)), 600);
        assert_eq!(to_public_ns(1_000, None), 1_000);
    }
}
