//! The `mavlink-tx` thread and the one-slot mailbox it reads.
//!
//! Takes the newest [`PoseSample`] from the mailbox; owns (re)connecting with
//! exponential backoff, the rate cap, the staleness check, frame conversion,
//! HEARTBEAT at 1 Hz and our TIMESYNC requests; gives out messages on the link.

use std::sync::atomic::Ordering;
use std::sync::{Arc, Condvar, Mutex, PoisonError};
use std::time::{Duration, Instant};

use mavlink::dialects::common::MavMessage;
use nalgebra::Matrix6;

use super::frames::FrameConverter;
use super::link::Link;
use super::messages::{self, LinkState};
use super::reset::ResetCounter;
use super::stats::bump;
use super::timesync::{monotonic_now_ns, to_public_ns};
use super::{PoseMessage, PoseSample, Shared};

/// HEARTBEAT period.
const HEARTBEAT_PERIOD: Duration = Duration::from_secs(1);
/// Period of our TIMESYNC requests.
const TIMESYNC_PERIOD: Duration = Duration::from_millis(500);
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

/// Per-thread state of the sender.
struct Sender {
    shared: Arc<Shared>,
    converter: FrameConverter,
    min_interval_ns: u64,
    max_age_ns: u64,
    reset: ResetCounter,
    last_sent_capture_ns: Option<u64>,
    state: LinkState,
    link: Option<(u64, Arc<Link>)>,
    generation: u64,
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
        min_interval_ns: config.min_interval_ns(),
        max_age_ns: u64::from(config.max_pose_age_ms) * 1_000_000,
        reset: ResetCounter::new(),
        last_sent_capture_ns: None,
        state: LinkState::Standby,
        link: None,
        generation: 0,
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
        let now = Instant::now();
        if self.link.is_some() {
            if now >= self.next_heartbeat {
                self.next_heartbeat = now + HEARTBEAT_PERIOD;
                if self.send(&messages::heartbeat(self.state)) {
                    bump(&self.shared.counters.heartbeat_sent);
                }
            }
            if self.shared.config.timesync && now >= self.next_timesync {
                self.next_timesync = now + TIMESYNC_PERIOD;
                self.send_timesync_request();
            }
        }
        let mut deadline = (now + POLL).min(self.next_heartbeat);
        if self.shared.config.timesync {
            deadline = deadline.min(self.next_timesync);
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
        match Link::open(&self.shared.address) {
            Ok(link) => {
                self.generation += 1;
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
        if let Some(last) = self.last_sent_capture_ns {
            if sample.capture_ns < last.saturating_add(self.min_interval_ns) {
                bump(&counters.poses_dropped_rate);
                return;
            }
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
        let twist_covariance = Matrix6::from_fn(|r, c| sample.covariance_6x6[r][c]);
        let covariance = self.converter.pose_covariance(&pose, &twist_covariance);
        let reset_counter =
            self.reset
                .next(sample.reset_counter, sample.capture_ns, &pose.ned_from_body);
        let offset_ns = shared.offset_ns();
        counters.set_offset(offset_ns);
        let usec = (to_public_ns(sample.capture_ns, offset_ns).max(0) / 1000) as u64;
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
            bump(counter);
            counters
                .reset_counter
                .store(reset_counter, Ordering::Relaxed);
            self.last_sent_capture_ns = Some(sample.capture_ns);
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
