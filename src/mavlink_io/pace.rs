//! Transmission pacing: when a pose may leave, so that the autopilot reads
//! consecutive poses no closer than its minimum spacing *in its own clock*.
//!
//! Takes the send time of the last pose (CLOCK_MONOTONIC) and the time now;
//! gives out [`Pace`]: send now, hold the pose this long first, or skip it.
//!
//! Why the spacing of `usec` alone is not enough (issue 20). ArduPilot dates
//! a vision sample at `usec + L`, `L` the smallest `arrival - usec` it has
//! seen in the current 100-sample window (`JitterCorrection`), truncated to
//! whole ms, and EKF3 drops a sample dated under 20 ms after the last one it
//! kept. When the autopilot's clock runs slower than ours (SITL on a loaded
//! machine: 99-148 ppm; crystals: tens of ppm), a camera at 50 Hz on our
//! clock arrives at 50.006 Hz on the autopilot's: `arrival - usec` falls a
//! few µs every pose, `L` follows it down, the dated times are the arrival
//! times, 19.997 ms apart, and every time they cross a millisecond boundary
//! one lands at 19 ms and is dropped: one pose in about 400. No choice of
//! `usec` helps while the arrivals come faster than 50 Hz on the autopilot's
//! clock.
//!
//! So poses leave at least `min_spacing * (1 + PACE_MARGIN_PPM)` apart on our
//! clock, which is at least the minimum on any autopilot clock within that
//! drift. A pose that comes earlier is held until then (its `usec` stays its
//! capture time: only its arrival is later); one that would be held longer
//! than half the minimum spacing is skipped instead (counted with the
//! spacing skips), and the hold starts again from zero. With a 50 Hz camera
//! the hold grows by 6 µs a pose: a skip every 33 s, and on average 5 ms of
//! extra latency, which `usec` and ArduPilot's jitter correction account for.
//! `arrival - usec` then only rises between skips, `L` stays at the window's
//! first minimum, and the dated times are `usec` values spaced at least the
//! minimum apart (the pose clock, `stamp.rs`, keeps that).
//!
//! Fixed-size, allocation-free.

/// How much longer than the autopilot's minimum spacing two sends are kept
/// apart on our clock, parts per million: the clock drift between the two
/// that pacing absorbs.
pub const PACE_MARGIN_PPM: u64 = 300;

/// What to do with a pose that is ready to go.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Pace {
    /// Send it.
    Now,
    /// Send it after this many nanoseconds.
    HoldNs(u64),
    /// Drop it: it would have to wait longer than the hold limit.
    Skip,
}

/// The pacer of one link's pose stream.
#[derive(Debug, Clone, Copy)]
pub struct Pacer {
    interval_ns: u64,
    max_hold_ns: u64,
    last_send_ns: Option<u64>,
}

impl Pacer {
    /// Paces sends `min_spacing_ns` (the autopilot's minimum spacing) plus
    /// [`PACE_MARGIN_PPM`] apart, holding a pose up to half the minimum; `0`
    /// paces nothing.
    pub fn new(min_spacing_ns: u64) -> Self {
        Self {
            interval_ns: min_spacing_ns + min_spacing_ns * PACE_MARGIN_PPM / 1_000_000,
            max_hold_ns: min_spacing_ns / 2,
            last_send_ns: None,
        }
    }

    /// The smallest spacing of two sends, ns.
    pub fn interval_ns(&self) -> u64 {
        self.interval_ns
    }

    /// A new stream: nothing sent yet.
    pub fn reset(&mut self) {
        self.last_send_ns = None;
    }

    /// What to do with a pose ready at `now_ns`.
    pub fn decide(&self, now_ns: u64) -> Pace {
        let Some(last) = self.last_send_ns else {
            return Pace::Now;
        };
        let earliest = last.saturating_add(self.interval_ns);
        match earliest.checked_sub(now_ns) {
            None | Some(0) => Pace::Now,
            Some(hold) if hold <= self.max_hold_ns => Pace::HoldNs(hold),
            Some(_) => Pace::Skip,
        }
    }

    /// Records a pose sent at `send_ns`.
    pub fn sent(&mut self, send_ns: u64) {
        self.last_send_ns = Some(send_ns);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// ArduPilot's treatment of a vision sample, as in `../shared/sitl`'s
    /// source: `JitterCorrection::correct_offboard_timestamp_usec` (max lag
    /// 500 ms, 100-sample windows), truncation to ms, and
    /// `NavEKF3_core::writeExtNavData`'s 20 ms minimum after the last
    /// sample kept.
    struct ArduPilot {
        link_offset_us: Option<i64>,
        min_sample_us: i64,
        counter: u32,
        last_kept_ms: Option<i64>,
        kept: u32,
        dropped: u32,
    }

    impl ArduPilot {
        fn new() -> Self {
            Self {
                link_offset_us: None,
                min_sample_us: 0,
                counter: 0,
                last_kept_ms: None,
                kept: 0,
                dropped: 0,
            }
        }

        /// A sample stamped `usec`, read at `local_us` on the autopilot's
        /// clock.
        fn receive(&mut self, usec: i64, local_us: i64) {
            let diff = local_us - usec;
            if self.link_offset_us.is_none_or(|o| diff < o) {
                self.link_offset_us = Some(diff);
            }
            let mut estimate = usec + self.link_offset_us.unwrap_or(0);
            if estimate + 500_000 < local_us {
                estimate = local_us;
                self.link_offset_us = Some(estimate - usec);
            }
            if self.counter == 0 {
                self.min_sample_us = diff;
            }
            self.counter += 1;
            self.min_sample_us = self.min_sample_us.min(diff);
            if self.counter == 100 {
                self.link_offset_us = Some(self.min_sample_us);
                self.counter = 0;
            }
            let ms = estimate / 1_000;
            if self.last_kept_ms.is_some_and(|last| ms - last < 20) {
                self.dropped += 1;
            } else {
                self.last_kept_ms = Some(ms);
                self.kept += 1;
            }
        }
    }

    /// A deterministic jitter in `0..span_ns` for pose `k`.
    fn jitter(k: u64, salt: u64, span_ns: u64) -> u64 {
        let mut x = k.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ salt;
        x ^= x >> 31;
        x = x.wrapping_mul(0xBF58_476D_1CE4_E5B9);
        x ^= x >> 29;
        x % span_ns
    }

    /// Two minutes of a 50 Hz camera on our clock into an autopilot whose
    /// clock runs `drift_ppm` slow, with `usec` the capture time on its
    /// clock at exactly 20 ms steps (what the pose clock gives a camera at
    /// the cap), a send 3-3.2 ms after capture and 0.1-0.3 ms of transport.
    /// Returns (dropped by EKF3, skipped by the pacer, largest hold in ns).
    fn fly(drift_ppm: i64, pacing: bool) -> (u32, u32, u64) {
        let mut pacer = Pacer::new(if pacing { 20_000_000 } else { 0 });
        let mut autopilot = ArduPilot::new();
        let (mut skipped, mut largest_hold, mut last_usec) = (0, 0, None::<i64>);
        for k in 0..6_000u64 {
            let capture_ns = 1_000_000_000 + k * 20_000_000 + jitter(k, 1, 40_000);
            let ready_ns = capture_ns + 3_000_000 + jitter(k, 2, 200_000);
            let send_ns = match pacer.decide(ready_ns) {
                Pace::Now => ready_ns,
                Pace::HoldNs(h) => {
                    largest_hold = largest_hold.max(h);
                    ready_ns + h
                }
                Pace::Skip => {
                    skipped += 1;
                    continue;
                }
            };
            pacer.sent(send_ns);
            let to_autopilot =
                |t_ns: u64| t_ns as i64 / 1_000 - t_ns as i64 / 1_000 * drift_ppm / 1_000_000;
            // `usec` keeps at least 20 ms after the last one (the pose
            // clock), otherwise the capture time on the autopilot's clock.
            let natural = to_autopilot(capture_ns);
            let usec = last_usec.map_or(natural, |l| natural.max(l + 20_000));
            last_usec = Some(usec);
            let arrival_ns = send_ns + 100_000 + jitter(k, 3, 200_000);
            autopilot.receive(usec, to_autopilot(arrival_ns));
        }
        assert_eq!(autopilot.kept + autopilot.dropped + skipped, 6_000);
        (autopilot.dropped, skipped, largest_hold)
    }

    #[test]
    fn without_pacing_a_slow_autopilot_clock_drops_samples() {
        // What the SITL flights measured (13-16 a 2-minute flight at
        // 99-148 ppm): the replay above must see it, or the next test
        // proves nothing.
        let (dropped, _, _) = fly(124, false);
        assert!((5..=40).contains(&dropped), "{dropped} dropped");
    }

    #[test]
    fn pacing_leaves_ekf3_nothing_to_drop() {
        for drift_ppm in [-200, -50, 0, 50, 124, 250] {
            let (dropped, skipped, largest_hold) = fly(drift_ppm, true);
            assert_eq!(dropped, 0, "{drift_ppm} ppm: {dropped} dropped by EKF3");
            // 6 µs of hold a pose, up to 10 ms: a skip about every 1 700.
            assert!(skipped <= 5, "{drift_ppm} ppm: {skipped} skipped");
            assert!(largest_hold <= 10_000_000, "{largest_hold} ns");
        }
    }

    #[test]
    fn holds_then_skips_past_half_the_spacing() {
        let mut pacer = Pacer::new(20_000_000);
        assert_eq!(pacer.interval_ns(), 20_006_000);
        assert_eq!(pacer.decide(5), Pace::Now);
        pacer.sent(1_000_000_000);
        assert_eq!(pacer.decide(1_020_006_000), Pace::Now);
        assert_eq!(pacer.decide(1_020_000_000), Pace::HoldNs(6_000));
        assert_eq!(pacer.decide(1_010_006_000), Pace::HoldNs(10_000_000));
        assert_eq!(pacer.decide(1_010_005_999), Pace::Skip);
        pacer.reset();
        assert_eq!(pacer.decide(1_010_005_999), Pace::Now);
        // No minimum: nothing is held.
        let mut off = Pacer::new(0);
        off.sent(100);
        assert_eq!(off.decide(100), Pace::Now);
    }
}
