//! The `mavlink-tx` thread and the one-slot mailbox it reads.
//!
//! Takes the newest [`PoseSample`] from the mailbox; owns (re)connecting with
//! exponential backoff (each new connection starts a new stream: TIMESYNC
//! estimate and pose clock start afresh), the rate cap, the staleness check,
//! frame conversion, stamping through the pose clock (`stamp.rs`), HEARTBEAT
//! at 1 Hz and our TIMESYNC requests (both between poses, see
//! [`quiet_at`]); gives out messages on the link.

use std::sync::atomic::Ordering;
use std::sync::{Arc, Condvar, Mutex, PoisonError};
use std::time::{Duration, Instant};

use mavlink::dialects::common::MavMessage;
use nalgebra::Matrix6;

use super::frames::{self, FrameConverter};
use super::link::Link;
use super::messages::{self, LinkState};
use super::reset::ResetCounter;
use super::stamp::{Stamp, StreamClock, SETTLE_PERIOD_MS};
use super::stats::bump;
use super::{PoseMessage, PoseSample, SendRecord, Shared};
use crate::clock::monotonic_now_ns;

/// HEARTBEAT period.
const HEARTBEAT_PERIOD: Duration = Duration::from_secs(1);
/// Period of our TIMESYNC requests.
const TIMESYNC_PERIOD: Duration = Duration::from_millis(500);
/// Period of our TIMESYNC requests until the stream's clock is settled.
const SETTLE_PERIOD: Duration = Duration::from_millis(SETTLE_PERIOD_MS);
/// Longest wait between checks of the shutdown flag.
const POLL: Duration = Duration::from_millis(50);
/// First and longest reconnect delay.
const MIN_BACKOFF: Duration = Duration::from_millis(200);
const MAX_BACKOFF: Duration = Duration::from_secs(5);

/// A one-slot mailbox: `put` replaces what is there, `take` empties it.
pub(crate) struct Mailbox {
    slot: Mutex<Option<PoseSample>>,
    wake: Condvar,
}

impl Mailbox {
    pub fn new() -> Self {
        Self {
            slot: Mutex::new(None),
            wake: Condvar::new(),
        }
    }

    /// Stores `sample`, dropping an older one not yet taken.
    pub fn put(&self, sample: PoseSample) {
        *self.slot.lock().unwrap_or_else(PoisonError::into_inner) = Some(sample);
        self.wake.notify_one();
    }

    /// Wakes a waiting `take` (for shutdown).
    pub fn wake(&self) {
        self.wake.notify_all();
    }

    /// Takes the sample, waiting up to `timeout` for one.
    pub fn take(&self, timeout: Duration) -> Option<PoseSample> {
        let guard = self.slot.lock().unwrap_or_else(PoisonError::into_inner);
        let (mut guard, _) = self
            .wake
            .wait_timeout_while(guard, timeout, |slot| slot.is_none())
            .unwrap_or_else(PoisonError::into_inner);
        guard.take()
    }
}

/// The pose-rate cap on capture times: a generic cell-rate algorithm
/// (a token bucket of depth two) plus a minimum spacing of half the
/// interval. Over any window the average rate stays at or below the cap,
/// and a camera running at exactly the cap keeps every frame although its
/// capture times jitter (a plain `spacing >= 1 / rate` test dropped about a
/// third of a 50 Hz camera whose frames came 19.9 and 20.1 ms apart).
#[derive(Debug, Clone, Copy)]
pub(crate) struct RateCap {
    interval_ns: u64,
    /// Theoretical arrival time of the next conforming sample.
    tat_ns: Option<u64>,
    last_ns: Option<u64>,
}

impl RateCap {
    /// A cap of one sample per `interval_ns` on average.
    pub(crate) fn new(interval_ns: u64) -> Self {
        Self {
            interval_ns,
            tat_ns: None,
            last_ns: None,
        }
    }

    /// True when a sample captured at `t_ns` may be sent.
    pub(crate) fn allows(&self, t_ns: u64) -> bool {
        let spaced = self
            .last_ns
            .is_none_or(|last| t_ns >= last.saturating_add(self.interval_ns / 2));
        // Conforming when at most one interval early on the schedule.
        let on_schedule = self
            .tat_ns
            .is_none_or(|tat| t_ns.saturating_add(self.interval_ns) >= tat);
        spaced && on_schedule
    }

    /// Records that the sample captured at `t_ns` was sent.
    pub(crate) fn sent(&mut self, t_ns: u64) {
        let base = self.tat_ns.map_or(t_ns, |tat| tat.max(t_ns));
        self.tat_ns = Some(base.saturating_add(self.interval_ns));
        self.last_ns = Some(t_ns);
    }
}

/// When a HEARTBEAT or TIMESYNC request that is due at `now` may go out:
/// half a pose interval after the last pose sent, the middle of the gap to
/// the next one. ArduPilot dates each packet by its UART's last read minus
/// the byte time of the packet and of everything queued behind it (174 µs a
/// byte at the 57 600 baud SITL assumes on TCP, 11 µs at 921 600): a
/// HEARTBEAT read together with the pose before it dated that pose up to
/// 3.6 ms early, and ArduPilot's jitter correction then put it under 20 ms
/// after the pose before (EKF3 dropped it); a TIMESYNC request read together
/// with the pose after it was dated 22 ms early. With no pose for two
/// intervals (tracking lost, not started) they go out at once.
pub(crate) fn quiet_at(now: Instant, last_pose: Option<Instant>, interval: Duration) -> Instant {
    let Some(last) = last_pose else {
        return now;
    };
    let since = now.saturating_duration_since(last);
    if since >= 2 * interval {
        now
    } else if since < interval / 4 {
        last + interval / 2
    } else if since <= interval * 3 / 4 {
        now
    } else {
        // The next pose is due: after it (this is moved then), or once the
        // stream has paused.
        last + 2 * interval
    }
}

/// Per-thread state of the sender.
struct Sender {
    shared: Arc<Shared>,
    converter: FrameConverter,
    rate: RateCap,
    max_age_ns: u64,
    reset: ResetCounter,
    state: LinkState,
    link: Option<(u64, Arc<Link>)>,
    generation: u64,
    /// The link's peer epoch the current stream belongs to.
    peer_epoch: u64,
    /// The reset counter last sent, and until when nothing follows a pose
    /// that changed it (see `handle`).
    last_reset_sent: Option<u8>,
    reset_hold_until: Option<Instant>,
    /// When the last pose went out, and the pose interval (`rate_hz`).
    last_pose_sent: Option<Instant>,
    pose_interval: Duration,
    backoff: Duration,
    reconnect_at: Instant,
    next_heartbeat: Instant,
    next_timesync: Instant,
}

/// The thread body.
pub(crate) fn run(shared: Arc<Shared>) {
    let config = &shared.config;
    let now = Instant::now();
    let mut sender = Sender {
        converter: FrameConverter::new(
            config.ned_from_world.to_pose(),
            config.body_from_camera.to_pose(),
        ),
        rate: RateCap::new(config.min_interval_ns()),
        max_age_ns: u64::from(config.max_pose_age_ms) * 1_000_000,
        reset: ResetCounter::new(),
        state: LinkState::Standby,
        link: None,
        generation: 0,
        peer_epoch: 0,
        last_reset_sent: None,
        reset_hold_until: None,
        last_pose_sent: None,
        pose_interval: Duration::from_nanos(config.min_interval_ns()),
        backoff: MIN_BACKOFF,
        reconnect_at: now,
        next_heartbeat: now,
        next_timesync: now,
        shared,
    };
    while !sender.shared.stopping() {
        sender.step();
    }
    sender.disconnect();
}

impl Sender {
    fn step(&mut self) {
        self.check_link();
        self.check_peer();
        let now = Instant::now();
        let quiet = quiet_at(now, self.last_pose_sent, self.pose_interval);
        if self.link.is_some() && now >= quiet {
            if now >= self.next_heartbeat {
                self.next_heartbeat = now + HEARTBEAT_PERIOD;
                if self.send(&messages::heartbeat(self.state)) {
                    bump(&self.shared.counters.heartbeat_sent);
                }
            }
            if self.shared.config.timesync && now >= self.next_timesync {
                let estimate = self.shared.estimate();
                let settling = self
                    .shared
                    .clock
                    .lock()
                    .unwrap_or_else(PoisonError::into_inner)
                    .settling(monotonic_now_ns(), estimate);
                self.next_timesync = now
                    + if settling {
                        SETTLE_PERIOD
                    } else {
                        TIMESYNC_PERIOD
                    };
                self.send_timesync_request();
            }
        }
        let mut deadline = (now + POLL).min(self.next_heartbeat.max(quiet));
        if self.shared.config.timesync {
            deadline = deadline.min(self.next_timesync.max(quiet));
        }
        if self.link.is_none() {
            deadline = deadline.min(self.reconnect_at);
        }
        let wait = deadline.saturating_duration_since(Instant::now());
        if let Some(sample) = self.shared.mailbox.take(wait) {
            self.handle(&sample);
        }
    }

    /// Drops a broken link and opens a new one when the backoff allows.
    fn check_link(&mut self) {
        let broken = self.shared.broken_generation.load(Ordering::Acquire);
        if self.link.is_some() && broken == self.generation {
            self.disconnect();
            self.reconnect_at = Instant::now() + self.backoff;
        }
        if self.link.is_some() || Instant::now() < self.reconnect_at {
            return;
        }
        let counters = &self.shared.counters;
        let policy = self.shared.config.peer_policy();
        match Link::open_with(
            &self.shared.address,
            &policy,
            self.shared.counters.clone(),
            self.shared.signing.clone(),
        ) {
            Ok(link) => {
                self.generation += 1;
                self.peer_epoch = link.peer_epoch();
                let link = Arc::new(link);
                *self
                    .shared
                    .link
                    .lock()
                    .unwrap_or_else(PoisonError::into_inner) =
                    Some((self.generation, link.clone()));
                self.link = Some((self.generation, link));
                counters.link_up.store(true, Ordering::Relaxed);
                bump(&counters.connects);
                self.backoff = MIN_BACKOFF;
                self.start_stream();
                let now = Instant::now();
                self.next_heartbeat = now;
                self.next_timesync = now;
                tracing::info!(connection = %self.shared.address, "MAVLink link up");
            }
            Err(error) => {
                if counters.link_errors.load(Ordering::Relaxed) == 0 || self.backoff == MAX_BACKOFF
                {
                    tracing::warn!(%error, retry_in = ?self.backoff, "MAVLink link not available");
                }
                bump(&counters.link_errors);
                self.reconnect_at = Instant::now() + self.backoff;
                self.backoff = (self.backoff * 2).min(MAX_BACKOFF);
            }
        }
    }

    /// A `udpin` link that locked a new autopilot starts a new stream (its
    /// clock is another one), with HEARTBEAT and TIMESYNC at once.
    fn check_peer(&mut self) {
        let Some((_, link)) = &self.link else {
            return;
        };
        let epoch = link.peer_epoch();
        if epoch != self.peer_epoch {
            self.peer_epoch = epoch;
            self.start_stream();
            let now = Instant::now();
            self.next_heartbeat = now;
            self.next_timesync = now;
        }
    }

    fn disconnect(&mut self) {
        if self.link.take().is_some() {
            *self
                .shared
                .link
                .lock()
                .unwrap_or_else(PoisonError::into_inner) = None;
            self.shared.counters.link_up.store(false, Ordering::Relaxed);
        }
    }

    /// Sends on the current link; a failure marks it broken. Returns whether
    /// the message went out to a peer.
    fn send(&mut self, message: &MavMessage) -> bool {
        let Some((generation, link)) = &self.link else {
            return false;
        };
        match link.send(&self.shared.header, message) {
            Ok(sent) => sent,
            Err(error) => {
                self.shared.mark_broken(*generation, &error);
                false
            }
        }
    }

    /// A new connection: the autopilot behind it may have restarted, so the
    /// TIMESYNC estimate and the pose clock start afresh.
    fn start_stream(&mut self) {
        self.shared
            .timesync
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .reset();
        self.shared
            .clock
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .start_stream(monotonic_now_ns());
        let counters = &self.shared.counters;
        counters.set_offset(None);
        self.shared.send_log.set_offset(None);
        counters.monotonic_clock.store(false, Ordering::Relaxed);
    }

    /// The pose clock's stamp for a sample; keeps the stats in step.
    fn stamp(&mut self, capture_ns: u64) -> Stamp {
        let shared = &self.shared;
        let estimate = shared.estimate();
        let mut clock = shared.clock.lock().unwrap_or_else(PoisonError::into_inner);
        let stamp = clock.stamp(capture_ns, monotonic_now_ns(), estimate);
        let counters = &shared.counters;
        counters.set_offset(clock.applied_offset_ns());
        shared.send_log.set_offset(clock.applied_offset_ns());
        counters
            .monotonic_clock
            .store(clock.clock() == StreamClock::Monotonic, Ordering::Relaxed);
        stamp
    }

    fn send_timesync_request(&mut self) {
        let now_ns = monotonic_now_ns() as i64;
        self.shared
            .timesync
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .request_sent(now_ns);
        if self.send(&messages::timesync(0, now_ns, 0, 0)) {
            bump(&self.shared.counters.timesync_requests_sent);
        }
    }

    fn handle(&mut self, sample: &PoseSample) {
        let shared = self.shared.clone();
        let counters = &shared.counters;
        if !sample.tracking {
            if self.state == LinkState::Active {
                tracing::info!("tracking lost: pose messages paused");
                self.state = LinkState::Lost;
            }
            self.reset.lost();
            bump(&counters.poses_dropped_lost);
            return;
        }
        if self.state != LinkState::Active {
            tracing::info!("tracking: pose messages flowing");
            self.state = LinkState::Active;
        }
        if self.link.is_none() {
            bump(&counters.poses_dropped_link);
            return;
        }
        let age_ns = monotonic_now_ns().saturating_sub(sample.capture_ns);
        if age_ns > self.max_age_ns {
            tracing::debug!(age_ms = age_ns / 1_000_000, "stale pose dropped");
            bump(&counters.poses_dropped_stale);
            return;
        }
        if !self.rate.allows(sample.capture_ns) {
            bump(&counters.poses_dropped_rate);
            return;
        }
        // A pose that changed reset_counter gets one rate interval of wall
        // time to itself. ArduPilot flags only that one sample as a reset;
        // when the next one came right behind it (the tracker catching up
        // after a relocalization), EKF3 dated both to the same fusion time,
        // kept the newer and lost the reset: it then fused a 1.1 m jump as a
        // measurement and overshot by 75 cm (hil_tests/test_sitl_blackout.py).
        if let Some(until) = self.reset_hold_until {
            if Instant::now() < until {
                bump(&counters.poses_dropped_rate);
                return;
            }
            self.reset_hold_until = None;
        }
        let pose = self.converter.ned_pose(&sample.world_from_camera);
        let finite = pose.position_ned_m().iter().all(|v| v.is_finite())
            && [pose.roll_rad, pose.pitch_rad, pose.yaw_rad]
                .iter()
                .all(|v| v.is_finite());
        if !finite {
            tracing::warn!(pose = ?sample.world_from_camera, "non-finite pose not sent");
            bump(&counters.poses_dropped_invalid);
            return;
        }
        let usec = match self.stamp(sample.capture_ns) {
            Stamp::Usec(usec) => usec,
            Stamp::Hold => {
                bump(&counters.poses_dropped_clock);
                return;
            }
            Stamp::Skip => {
                tracing::debug!(
                    capture_ns = sample.capture_ns,
                    "pose skipped: under the autopilot's minimum spacing"
                );
                bump(&counters.poses_dropped_spacing);
                return;
            }
        };
        let twist_covariance = Matrix6::from_fn(|r, c| sample.covariance_6x6[r][c]);
        let mut covariance = self.converter.pose_covariance(&pose, &twist_covariance);
        let config = &shared.config;
        frames::floor_variances(
            &mut covariance,
            config.position_sigma_floor_m,
            config.angle_sigma_floor_deg.to_radians(),
        );
        let reset_counter =
            self.reset
                .next(sample.reset_counter, sample.capture_ns, &pose.ned_from_body);
        let (message, counter) = match shared.config.message {
            PoseMessage::VisionPositionEstimate => (
                messages::vision_position_estimate(usec, &pose, &covariance, reset_counter),
                &counters.vision_position_estimate_sent,
            ),
            PoseMessage::Odometry => (
                messages::odometry(
                    usec,
                    &pose,
                    &covariance,
                    reset_counter,
                    sample.quality_percent,
                ),
                &counters.odometry_sent,
            ),
        };
        if self.send(&message) {
            self.last_pose_sent = Some(Instant::now());
            bump(counter);
            shared.send_log.push(SendRecord {
                capture_ns: sample.capture_ns,
                send_ns: monotonic_now_ns(),
                timesync_offset_ns: shared.send_log.offset_ns(),
            });
            counters
                .reset_counter
                .store(reset_counter, Ordering::Relaxed);
            self.rate.sent(sample.capture_ns);
            if self
                .last_reset_sent
                .is_some_and(|last| last != reset_counter)
            {
                self.reset_hold_until =
                    Some(Instant::now() + Duration::from_nanos(shared.config.min_interval_ns()));
            }
            self.last_reset_sent = Some(reset_counter);
        } else {
            bump(&counters.poses_dropped_link);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Pose;

    fn sample(capture_ns: u64) -> PoseSample {
        PoseSample {
            capture_ns,
            world_from_camera: Pose::identity(),
            covariance_6x6: [[0.0; 6]; 6],
            reset_counter: 0,
            quality_percent: 90,
            tracking: true,
        }
    }

    /// Sends what the cap allows of `stamps_ns`; returns the sent stamps.
    fn run_cap(interval_ns: u64, stamps_ns: impl IntoIterator<Item = u64>) -> Vec<u64> {
        let mut cap = RateCap::new(interval_ns);
        let mut sent = Vec::new();
        for t in stamps_ns {
            if cap.allows(t) {
                cap.sent(t);
                sent.push(t);
            }
        }
        sent
    }

    #[test]
    fn rate_cap_keeps_a_jittered_camera_at_the_cap() {
        // 50 Hz camera, capture times jittered by +-1 ms, 50 Hz cap.
        let stamps = (0..1000u64).map(|k| k * 20_000_000 + (k % 3) * 1_000_000);
        let sent = run_cap(20_000_000, stamps);
        assert_eq!(
            sent.len(),
            1000,
            "no frame of a camera at the cap is dropped"
        );
    }

    #[test]
    fn rate_cap_bounds_the_rate_of_a_faster_camera() {
        // 200 Hz for 10 s into a 50 Hz cap: at most 50 Hz on average, at
        // least half an interval apart, and not starved.
        let sent = run_cap(20_000_000, (0..2000u64).map(|k| k * 5_000_000));
        assert!((499..=502).contains(&sent.len()), "{} sent", sent.len());
        for w in sent.windows(2) {
            assert!(w[1] - w[0] >= 10_000_000, "{w:?}");
        }
        // Any 1 s window holds at most 51 samples.
        for (i, &t) in sent.iter().enumerate() {
            let n = sent[i..]
                .iter()
                .take_while(|&&u| u < t + 1_000_000_000)
                .count();
            assert!(n <= 51, "{n} samples in 1 s from {t}");
        }
    }

    #[test]
    fn rate_cap_does_not_burst_after_a_gap() {
        // After 1 s of silence (lost tracking), a 200 Hz stream gets at
        // most two samples in the first interval, not a catch-up burst.
        let mut stamps: Vec<u64> = (0..10u64).map(|k| k * 20_000_000).collect();
        stamps.extend((0..40u64).map(|k| 1_200_000_000 + k * 5_000_000));
        let sent = run_cap(20_000_000, stamps);
        let after: Vec<u64> = sent.into_iter().filter(|&t| t >= 1_200_000_000).collect();
        let first_interval = after.iter().filter(|&&t| t < 1_220_000_000).count();
        assert!(first_interval <= 2, "{after:?}");
        assert!((10..=11).contains(&after.len()), "{after:?}");
    }

    #[test]
    fn heartbeat_and_timesync_wait_for_the_middle_of_a_gap() {
        let t0 = Instant::now();
        let i = Duration::from_millis(20);
        let ms = Duration::from_millis;
        // No pose yet, or none for two intervals: at once.
        assert_eq!(quiet_at(t0, None, i), t0);
        assert_eq!(quiet_at(t0 + ms(40), Some(t0), i), t0 + ms(40));
        // Right after a pose: half an interval after it.
        assert_eq!(quiet_at(t0 + ms(1), Some(t0), i), t0 + ms(10));
        // In the middle of the gap: at once.
        assert_eq!(quiet_at(t0 + ms(8), Some(t0), i), t0 + ms(8));
        assert_eq!(quiet_at(t0 + ms(15), Some(t0), i), t0 + ms(15));
        // Just before the next pose: not before it (nor past a pause).
        assert_eq!(quiet_at(t0 + ms(18), Some(t0), i), t0 + ms(40));
    }

    #[test]
    fn mailbox_keeps_only_the_newest() {
        let m = Mailbox::new();
        for k in 0..5 {
            m.put(sample(k));
        }
        assert_eq!(m.take(Duration::ZERO).map(|s| s.capture_ns), Some(4));
        assert!(m.take(Duration::from_millis(1)).is_none());
    }

    #[test]
    fn mailbox_wakes_a_waiting_taker() {
        let m = Arc::new(Mailbox::new());
        let m2 = m.clone();
        let t = std::thread::spawn(move || m2.take(Duration::from_secs(10)));
        std::thread::sleep(Duration::from_millis(20));
        m.put(sample(7));
        assert_eq!(t.join().unwrap().map(|s| s.capture_ns), Some(7));
    }
}
