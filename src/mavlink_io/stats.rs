//! Perf counters of the link (PX4 style): written by the link threads with
//! relaxed atomics, read by anyone as a [`LinkStats`] snapshot.

use std::sync::atomic::{AtomicBool, AtomicI64, AtomicU64, AtomicU8, Ordering::Relaxed};

/// A snapshot of the link's counters.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct LinkStats {
    /// Whether the transport is open now.
    pub link_up: bool,
    /// Successful opens of the transport (the first one included).
    pub connects: u64,
    /// Transport failures (open failures, broken links).
    pub link_errors: u64,
    /// VISION_POSITION_ESTIMATE messages sent.
    pub vision_position_estimate_sent: u64,
    /// ODOMETRY messages sent.
    pub odometry_sent: u64,
    /// HEARTBEAT messages sent.
    pub heartbeat_sent: u64,
    /// Our TIMESYNC requests sent.
    pub timesync_requests_sent: u64,
    /// TIMESYNC replies we sent to the autopilot's requests.
    pub timesync_replies_sent: u64,
    /// Replies to our requests that were used for the offset.
    pub timesync_samples: u64,
    /// TIMESYNC replies not used: not ours, too slow, an implausible time,
    /// or outside the plausibility bound of the estimate.
    pub timesync_rejected: u64,
    /// Confirmed jumps of the TIMESYNC estimate (autopilot restarts).
    pub timesync_resyncs: u64,
    /// HEARTBEATs received from an autopilot.
    pub autopilot_heartbeats: u64,
    /// `udpin`: datagrams ignored (garbage, or from a sender other than the
    /// locked autopilot).
    pub udpin_foreign_datagrams: u64,
    /// `udpin`: autopilots locked (the first one included; more means the
    /// peer changed after a silence).
    pub udpin_peer_locks: u64,
    /// Signing required: unsigned (or MAVLink 1) frames dropped.
    pub signing_rejected_unsigned: u64,
    /// Signing on: frames with a bad signature or a replayed timestamp dropped.
    pub signing_rejected_bad: u64,
    /// Samples not sent because tracking was lost.
    pub poses_dropped_lost: u64,
    /// Samples not sent because they were older than `max_pose_age_ms`.
    pub poses_dropped_stale: u64,
    /// Samples not sent because of the rate cap.
    pub poses_dropped_rate: u64,
    /// Samples not sent because the link was down or had no peer yet.
    pub poses_dropped_link: u64,
    /// Samples not sent because the pose was not finite.
    pub poses_dropped_invalid: u64,
    /// Samples not sent because the stream's clock was not settled yet
    /// (waiting for the first TIMESYNC answer, up to `timesync_wait_ms`).
    pub poses_dropped_clock: u64,
    /// Samples not sent because their `usec` would have been closer than
    /// `autopilot_min_interval_ms` to the last one sent (or a downward
    /// offset correction needed the room).
    pub poses_dropped_spacing: u64,
    /// Whether the current stream's `usec` is star's own CLOCK_MONOTONIC
    /// (TIMESYNC off, or no answer within `timesync_wait_ms`).
    pub monotonic_clock: bool,
    /// The reset counter last sent.
    pub reset_counter: u8,
    /// The offset applied to `usec` (`autopilot - monotonic`, ns), while the
    /// stream is in the autopilot's clock.
    pub timesync_offset_ns: Option<i64>,
}

/// The live counters.
#[derive(Debug, Default)]
pub(crate) struct Counters {
    pub link_up: AtomicBool,
    pub connects: AtomicU64,
    pub link_errors: AtomicU64,
    pub vision_position_estimate_sent: AtomicU64,
    pub odometry_sent: AtomicU64,
    pub heartbeat_sent: AtomicU64,
    pub timesync_requests_sent: AtomicU64,
    pub timesync_replies_sent: AtomicU64,
    pub timesync_samples: AtomicU64,
    pub timesync_rejected: AtomicU64,
    pub timesync_resyncs: AtomicU64,
    pub autopilot_heartbeats: AtomicU64,
    pub udpin_foreign_datagrams: AtomicU64,
    pub udpin_peer_locks: AtomicU64,
    pub signing_rejected_unsigned: AtomicU64,
    pub signing_rejected_bad: AtomicU64,
    pub poses_dropped_lost: AtomicU64,
    pub poses_dropped_stale: AtomicU64,
    pub poses_dropped_rate: AtomicU64,
    pub poses_dropped_link: AtomicU64,
    pub poses_dropped_invalid: AtomicU64,
    pub poses_dropped_clock: AtomicU64,
    pub poses_dropped_spacing: AtomicU64,
    pub monotonic_clock: AtomicBool,
    pub reset_counter: AtomicU8,
    pub has_offset: AtomicBool,
    pub offset_ns: AtomicI64,
}

/// Adds one.
pub(crate) fn bump(counter: &AtomicU64) {
    counter.fetch_add(1, Relaxed);
}

impl Counters {
    pub fn set_offset(&self, offset_ns: Option<i64>) {
        if let Some(o) = offset_ns {
            self.offset_ns.store(o, Relaxed);
        }
        self.has_offset.store(offset_ns.is_some(), Relaxed);
    }

    pub fn snapshot(&self) -> LinkStats {
        LinkStats {
            link_up: self.link_up.load(Relaxed),
            connects: self.connects.load(Relaxed),
            link_errors: self.link_errors.load(Relaxed),
            vision_position_estimate_sent: self.vision_position_estimate_sent.load(Relaxed),
            odometry_sent: self.odometry_sent.load(Relaxed),
            heartbeat_sent: self.heartbeat_sent.load(Relaxed),
            timesync_requests_sent: self.timesync_requests_sent.load(Relaxed),
            timesync_replies_sent: self.timesync_replies_sent.load(Relaxed),
            timesync_samples: self.timesync_samples.load(Relaxed),
            timesync_rejected: self.timesync_rejected.load(Relaxed),
            timesync_resyncs: self.timesync_resyncs.load(Relaxed),
            autopilot_heartbeats: self.autopilot_heartbeats.load(Relaxed),
            udpin_foreign_datagrams: self.udpin_foreign_datagrams.load(Relaxed),
            udpin_peer_locks: self.udpin_peer_locks.load(Relaxed),
            signing_rejected_unsigned: self.signing_rejected_unsigned.load(Relaxed),
            signing_rejected_bad: self.signing_rejected_bad.load(Relaxed),
            poses_dropped_lost: self.poses_dropped_lost.load(Relaxed),
            poses_dropped_stale: self.poses_dropped_stale.load(Relaxed),
            poses_dropped_rate: self.poses_dropped_rate.load(Relaxed),
            poses_dropped_link: self.poses_dropped_link.load(Relaxed),
            poses_dropped_invalid: self.poses_dropped_invalid.load(Relaxed),
            poses_dropped_clock: self.poses_dropped_clock.load(Relaxed),
            poses_dropped_spacing: self.poses_dropped_spacing.load(Relaxed),
            monotonic_clock: self.monotonic_clock.load(Relaxed),
            reset_counter: self.reset_counter.load(Relaxed),
            timesync_offset_ns: self
                .has_offset
                .load(Relaxed)
                .then(|| self.offset_ns.load(Relaxed)),
        }
    }
}
