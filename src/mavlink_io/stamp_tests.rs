//! Tests of the pose clock (`stamp.rs`).

use super::*;
use crate::mavlink_io::timesync::{TimesyncEstimator, TimesyncEvent, WINDOW};

const MS: u64 = 1_000_000;
/// 50 Hz.
const INTERVAL: u64 = 20 * MS;
const WAIT: u64 = 1_500 * MS;

fn est(offset_ns: i64, uncertainty_ns: i64) -> Option<OffsetEstimate> {
    Some(OffsetEstimate {
        offset_ns,
        uncertainty_ns,
        samples: SETTLE_SAMPLES,
    })
}

fn usec(s: Stamp) -> u64 {
    match s {
        Stamp::Usec(u) => u,
        other => panic!("{other:?}"),
    }
}

/// Consecutive differences of `usecs`, µs.
fn gaps(usecs: &[u64]) -> Vec<i64> {
    usecs
        .windows(2)
        .map(|w| w[1] as i64 - w[0] as i64)
        .collect()
}

#[test]
fn first_pose_waits_for_the_offset() {
    let mut clock = PoseClock::new(true, WAIT, INTERVAL);
    let t0 = 10_000 * MS;
    clock.start_stream(t0);
    // Poses from 100 ms on, no answer yet: held.
    for k in 0..10 {
        let t = t0 + 100 * MS + k * INTERVAL;
        assert_eq!(clock.stamp(t, t + MS, None), Stamp::Hold);
        assert_eq!(clock.clock(), StreamClock::Waiting);
    }
    // The answer comes: the very first pose sent is in the autopilot's clock.
    let offset = -9_000_000_000i64;
    let t = t0 + 400 * MS;
    let first = usec(clock.stamp(t, t + MS, est(offset, 500_000)));
    // At the low edge of the estimate's interval.
    let applied = offset - 500_000;
    assert_eq!(first as i64, (t as i64 + applied) / 1_000);
    assert_eq!(clock.clock(), StreamClock::Autopilot);
    assert_eq!(clock.applied_offset_ns(), Some(applied));
    assert_eq!(clock.public_ns(t, None), t as i64 + applied);
    let second = usec(clock.stamp(t + INTERVAL, t + INTERVAL + MS, est(offset, 500_000)));
    assert_eq!(second - first, INTERVAL / 1_000);
}

#[test]
fn first_answers_settle_the_clock_before_the_first_pose() {
    let mut clock = PoseClock::new(true, WAIT, INTERVAL);
    let t0 = 10_000 * MS;
    clock.start_stream(t0);
    let few = |samples| {
        Some(OffsetEstimate {
            offset_ns: 1_000_000_000,
            uncertainty_ns: 2_000_000,
            samples,
        })
    };
    // One to three answers: still held (a first answer may be slow).
    for samples in 1..SETTLE_SAMPLES {
        let t = t0 + samples as u64 * 25 * MS;
        assert_eq!(clock.stamp(t, t, few(samples)), Stamp::Hold);
        assert!(clock.settling(t, few(samples)));
    }
    // Enough answers: no more fast requests, even before a pose comes.
    assert!(!clock.settling(t0 + 90 * MS, few(SETTLE_SAMPLES)));
    // Nor after the wait.
    assert!(!clock.settling(t0 + WAIT, None));
    let t = t0 + 100 * MS;
    assert!(matches!(
        clock.stamp(t, t, few(SETTLE_SAMPLES)),
        Stamp::Usec(_)
    ));
    assert!(!clock.settling(t, None), "a pose went out: settled");
    assert_eq!(clock.applied_offset_ns(), Some(998_000_000));
    // A slow autopilot that answered once by the end of the wait gets
    // its clock all the same.
    clock.start_stream(t0);
    let t = t0 + WAIT;
    assert_eq!(usec(clock.stamp(t, t, few(1))), (t + 998_000_000) / 1_000);
    assert_eq!(clock.clock(), StreamClock::Autopilot);
}

#[test]
fn silent_autopilot_gets_our_clock_from_the_first_pose_and_no_switch() {
    let mut clock = PoseClock::new(true, WAIT, INTERVAL);
    let t0 = 10_000 * MS;
    clock.start_stream(t0);
    let mut sent = Vec::new();
    for k in 0..200u64 {
        let t = t0 + k * INTERVAL;
        // The autopilot starts answering at 2.5 s, well after the wait.
        let e = (t >= t0 + 2_500 * MS).then_some(OffsetEstimate {
            offset_ns: 5_000_000_000,
            uncertainty_ns: 100_000,
            samples: WINDOW,
        });
        match clock.stamp(t, t + MS, e) {
            Stamp::Hold => {
                assert!(t + MS < t0 + WAIT, "held after the wait: {k}");
                assert!(sent.is_empty(), "held after a pose was sent: {k}");
            }
            Stamp::Usec(u) => sent.push((t, u)),
            Stamp::Skip => panic!("skipped: {k}"),
        }
    }
    assert_eq!(sent.first().map(|s| s.0), Some(t0 + 75 * INTERVAL));
    for (t, u) in &sent {
        assert_eq!(*u, t / 1_000, "usec is CLOCK_MONOTONIC throughout");
    }
    assert_eq!(clock.clock(), StreamClock::Monotonic);
    assert_eq!(clock.applied_offset_ns(), None);
    assert_eq!(
        clock.public_ns(123 * MS, est(5_000_000_000, 0)),
        123 * MS as i64,
        "TIMESYNC answers in the same clock as usec"
    );
    // A new stream (the link reopened) decides afresh.
    clock.start_stream(t0 + 10_000 * MS);
    assert_eq!(clock.clock(), StreamClock::Waiting);
    let t = t0 + 10_100 * MS;
    assert_eq!(
        usec(clock.stamp(t, t, est(5_000_000_000, 0))),
        (t + 5_000_000_000) / 1_000
    );
}

#[test]
fn timesync_off_sends_our_clock_at_once() {
    let mut clock = PoseClock::new(false, WAIT, INTERVAL);
    clock.start_stream(0);
    assert_eq!(clock.clock(), StreamClock::Monotonic);
    assert_eq!(clock.stamp(MS, MS, est(7, 0)), Stamp::Usec(1_000));
}

/// Sends the poses captured at `captures`, each with the estimate
/// `estimate_of(k)`; returns (capture, usec) of those sent and the
/// number skipped.
fn run(
    clock: &mut PoseClock,
    captures: impl IntoIterator<Item = u64>,
    estimate_of: impl Fn(usize) -> Option<OffsetEstimate>,
) -> (Vec<(u64, u64)>, usize) {
    let mut sent = Vec::new();
    let mut skipped = 0;
    for (k, t) in captures.into_iter().enumerate() {
        match clock.stamp(t, t + MS, estimate_of(k)) {
            Stamp::Usec(u) => sent.push((t, u)),
            Stamp::Skip => skipped += 1,
            Stamp::Hold => panic!("held"),
        }
    }
    (sent, skipped)
}

/// Every consecutive pair of `sent` is at least the minimum (20 ms)
/// apart, and at most 1 % more than its capture gap.
fn assert_spacing(sent: &[(u64, u64)]) {
    for (k, w) in sent.windows(2).enumerate() {
        let g = w[1].1 as i64 - w[0].1 as i64;
        let capture_gap = ((w[1].0 - w[0].0) / 1_000) as i64;
        assert!(g >= 20_000, "poses {k}, {}: {g} us apart", k + 1);
        assert!(
            g <= capture_gap + capture_gap / SLEW_DIVISOR + 1,
            "poses {k}, {}: {g} us for {capture_gap} us of capture",
            k + 1
        );
    }
}

#[test]
fn offset_steps_keep_the_spacing() {
    // The estimate steps by +-2 ms every 10 poses (new samples), with a
    // tight interval so each step is outside it.
    let mut clock = PoseClock::new(true, WAIT, INTERVAL);
    clock.start_stream(0);
    let base = 3_000_000_000i64;
    let (sent, skipped) = run(
        &mut clock,
        (0..2_000u64).map(|k| 1_000 * MS + k * INTERVAL),
        |k| {
            let step = if (k / 10) % 2 == 0 {
                2_000_000
            } else {
                -2_000_000
            };
            est(base + step, 50_000)
        },
    );
    assert_spacing(&sent);
    // Each step down is taken out of one skipped pose.
    assert!(skipped <= 100, "{skipped} skipped");
}

#[test]
fn offset_jump_down_never_shortens_a_gap_under_the_minimum() {
    // SITL's TIMESYNC answers jumped -22 ms (a request back-dated by
    // ArduPilot); slewed at 1 % into gaps of 19.8 ms, EKF3 dropped a
    // dozen samples. Now: two poses skipped, and the gaps they leave take
    // the correction.
    let mut clock = PoseClock::new(true, WAIT, INTERVAL);
    clock.start_stream(0);
    let offset = 5_000_000_000i64;
    let (sent, skipped) = run(
        &mut clock,
        (0..500u64).map(|k| 1_000 * MS + k * INTERVAL),
        |k| est(if k < 100 { offset } else { offset - 22_000_000 }, 500_000),
    );
    assert_spacing(&sent);
    assert_eq!(skipped, 2);
    assert_eq!(
        clock.applied_offset_ns(),
        Some(offset - 22_000_000 + 500_000),
        "at the top of the new interval"
    );
}

#[test]
fn offset_jump_up_lengthens_gaps_by_one_percent_at_most() {
    let mut clock = PoseClock::new(true, WAIT, INTERVAL);
    clock.start_stream(0);
    let offset = 5_000_000_000i64;
    let (sent, skipped) = run(
        &mut clock,
        (0..500u64).map(|k| 1_000 * MS + k * INTERVAL),
        |k| est(if k < 100 { offset } else { offset + 22_000_000 }, 500_000),
    );
    assert_spacing(&sent);
    assert_eq!(skipped, 0);
    let slewed = sent.windows(2).filter(|w| w[1].1 - w[0].1 > 20_000).count();
    assert_eq!(slewed, 110, "22 ms at 0.2 ms a pose");
    assert_eq!(
        clock.applied_offset_ns(),
        Some(offset + 22_000_000 - 500_000)
    );
}

#[test]
fn steady_camera_at_the_cap_with_jitter_loses_nothing() {
    // A 50 Hz camera whose capture times jitter by up to +-40 us, at
    // exactly the autopilot's 20 ms: no pose skipped, none under the
    // minimum, each stamp at most 0.5 ms after its capture time.
    let mut clock = PoseClock::new(true, WAIT, INTERVAL);
    clock.start_stream(0);
    let offset = 1_000_000_000i64;
    let captures: Vec<u64> = (0..5_000u64)
        .map(|k| 1_000 * MS + k * INTERVAL + (k * 7_919 % 81) * 1_000 - 40_000)
        .collect();
    // The estimate wanders inside its interval (new samples).
    let (sent, skipped) = run(&mut clock, captures.iter().copied(), |k| {
        est(offset + [0, -200_000, -100_000][k / 300 % 3], 600_000)
    });
    assert_eq!(skipped, 0);
    assert_eq!(sent.len(), captures.len());
    assert_spacing(&sent);
    let applied = clock.applied_offset_ns().unwrap();
    for (t, u) in &sent {
        let lead_ns = *u as i64 * 1_000 - (*t as i64 + applied);
        assert!(
            (-1_000..=TOLERANCE_NS).contains(&lead_ns),
            "{t}: {lead_ns} ns"
        );
    }
}

#[test]
fn a_faster_camera_is_skipped_on_our_side() {
    // 60 Hz into a 20 ms minimum: every other pose goes (33 ms apart).
    let mut clock = PoseClock::new(false, WAIT, INTERVAL);
    clock.start_stream(0);
    let (sent, skipped) = run(
        &mut clock,
        (0..600u64).map(|k| 1_000 * MS + k * 16_666_667),
        |_| None,
    );
    assert_eq!((sent.len(), skipped), (300, 300));
    assert!(sent.windows(2).all(|w| w[1].1 - w[0].1 >= 20_000));
}

#[test]
fn clock_drift_costs_a_pose_now_and_then() {
    // The autopilot's clock 50 ppm slower than ours: the offset falls by
    // 1 us a pose, which a camera at exactly 20 ms leaves no room for.
    let mut clock = PoseClock::new(true, WAIT, INTERVAL);
    clock.start_stream(0);
    let (sent, skipped) = run(
        &mut clock,
        (0..15_000u64).map(|k| 1_000 * MS + k * INTERVAL),
        |k| est(2_000_000_000 - k as i64 * 1_000, 300_000),
    );
    assert_spacing(&sent);
    // One skip per ~0.5 ms of drift.
    assert!((20..=40).contains(&skipped), "{skipped} skipped");
    let high_ns = clock.applied_offset_ns().unwrap() - (2_000_000_000 - 15_000 * 1_000 + 300_000);
    assert!(high_ns <= TOLERANCE_NS, "{high_ns} ns above the interval");
}

#[test]
fn offset_inside_the_uncertainty_does_not_move_usec() {
    let mut clock = PoseClock::new(true, WAIT, INTERVAL);
    clock.start_stream(0);
    let mut usecs = Vec::new();
    for k in 0..500u64 {
        let t = 1_000 * MS + k * INTERVAL;
        // The estimate wanders by +-2 ms, each with a 2.5 ms half round
        // trip that contains where the first (tight) one put the clock.
        let wander = [0, 2_000_000, -2_000_000, 1_000_000][(k / 25) as usize % 4];
        let half_rtt = if k == 0 { 100_000 } else { 2_500_000 };
        usecs.push(usec(clock.stamp(t, t, est(wander, half_rtt))));
    }
    assert!(
        gaps(&usecs).iter().all(|&g| g == 20_000),
        "{:?}",
        gaps(&usecs)
    );
    assert_eq!(clock.applied_offset_ns(), Some(-100_000));
}

#[test]
fn a_real_offset_change_is_followed() {
    let mut clock = PoseClock::new(true, WAIT, INTERVAL);
    clock.start_stream(0);
    let t = 1_000 * MS;
    clock.stamp(t, t, est(0, 100_000));
    // The estimate moves 5 ms (a better sample): slewed in at 1 %.
    for k in 1..=300u64 {
        let t = t + k * INTERVAL;
        clock.stamp(t, t, est(5_000_000, 100_000));
    }
    let applied = clock.applied_offset_ns().unwrap();
    assert!((4_900_000..=5_000_000).contains(&applied), "{applied}");
}

#[test]
fn hostile_replies_never_move_usec_beyond_the_bound() {
    // Through the estimator: a synced stream at 50 Hz, TIMESYNC every
    // 500 ms, and replies with tc1 = 2^62, -2^62 and 1 in between.
    let mut ts = TimesyncEstimator::new();
    let mut clock = PoseClock::new(true, WAIT, INTERVAL);
    let offset = 4_000_000_000i64;
    let t0 = 20_000 * MS;
    clock.start_stream(t0);
    // The settling exchanges, honest, 25 ms apart.
    for k in 0..SETTLE_SAMPLES as i64 {
        let ts1 = t0 as i64 - 100_000_000 + k * 25_000_000;
        ts.request_sent(ts1);
        let ev = ts.reply_received(ts1 + 1_000_000 + offset, ts1, ts1 + 2_000_000);
        assert!(matches!(ev, TimesyncEvent::Sample(_)));
    }
    let mut usecs = Vec::new();
    let mut captures = Vec::new();
    for k in 0..1_000u64 {
        let t = t0 + k * INTERVAL;
        if k % 25 == 0 {
            let ts1 = t as i64;
            ts.request_sent(ts1);
            let tc1 = match (k / 25) % 4 {
                0 => ts1 + 1_000_000 + offset, // honest, 2 ms round trip
                1 => 1 << 62,
                2 => -(1 << 62),
                _ => 1,
            };
            ts.reply_received(tc1, ts1, ts1 + 2_000_000);
        }
        if let Stamp::Usec(u) = clock.stamp(t, t + MS, ts.estimate()) {
            usecs.push(u);
            captures.push(t);
        }
    }
    assert_eq!(usecs.len(), 1_000);
    for (k, g) in gaps(&usecs).into_iter().enumerate() {
        let capture_gap = ((captures[k + 1] - captures[k]) / 1_000) as i64;
        let bound = capture_gap / SLEW_DIVISOR + 1;
        assert!(
            (g - capture_gap).abs() <= bound,
            "poses {k}, {}: usec moved {g} us for {capture_gap} us",
            k + 1
        );
    }
    assert_eq!(
        usecs[999] as i64,
        (captures[999] as i64 + offset - 1_000_000) / 1_000,
        "still in the autopilot's clock (low edge of the 2 ms round trip)"
    );
}

#[test]
fn autopilot_restart_keeps_usec_continuous() {
    // A confirmed jump of the estimate (three agreeing replies) is not a
    // step in usec: up, it is slewed at 1 %; down, it is taken out of
    // skipped poses' gaps.
    for new_offset in [-1_000_000_000i64, 120_000_000_000] {
        let mut clock = PoseClock::new(true, WAIT, INTERVAL);
        clock.start_stream(0);
        let (sent, skipped) = run(
            &mut clock,
            (0..300u64).map(|k| 1_000 * MS + k * INTERVAL),
            |k| est(if k < 100 { 60_000_000_000 } else { new_offset }, 1_000_000),
        );
        assert_spacing(&sent);
        // Down: every other pose, each leaving 20 ms of room.
        assert_eq!(
            skipped,
            if new_offset < 0 { 100 } else { 0 },
            "{new_offset}"
        );
    }
}

#[test]
fn usec_is_never_closer_than_the_minimum() {
    // Capture times that jitter and even repeat or go back (a clock
    // glitch upstream), and an estimate that jumps around.
    let mut clock = PoseClock::new(true, WAIT, INTERVAL);
    clock.start_stream(0);
    let mut usecs = Vec::new();
    let mut t = 1_000 * MS;
    for k in 0..3_000u64 {
        t = match k % 7 {
            3 => t,                    // same capture time twice
            5 => t.saturating_sub(MS), // backwards
            _ => t + 10 * MS + (k * 7919 % 13) * MS,
        };
        let e = est(
            ((k * 104_729) % 40) as i64 * 1_000_000 - 20_000_000,
            200_000,
        );
        if let Stamp::Usec(u) = clock.stamp(t, t, e) {
            usecs.push(u);
        }
    }
    assert!(usecs.len() > 1_000, "{} sent", usecs.len());
    for (k, g) in gaps(&usecs).into_iter().enumerate() {
        assert!(g >= 20_000, "poses {k}, {}: {g} us", k + 1);
    }
}
