//! The last poses the link sent, for the flight log (`star track --record`).
//!
//! The `mavlink-tx` thread pushes one [`SendRecord`] per pose message that
//! went out (its capture time, when it went out, the TIMESYNC offset its
//! `usec` carries); the recorder thread looks a frame's capture time up
//! after the link had time to send it. A fixed ring of [`SendLog::CAPACITY`]
//! records behind a mutex that only those two threads take: the tracker
//! thread never touches it, and pushing allocates nothing.

use std::sync::{Mutex, PoisonError};

/// One pose message sent.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SendRecord {
    /// Capture time of the frame the pose came from, CLOCK_MONOTONIC ns.
    pub capture_ns: u64,
    /// When the message went out, CLOCK_MONOTONIC ns.
    pub send_ns: u64,
    /// The offset `usec` carried (`autopilot - monotonic`, ns); `None`
    /// while the stream is in star's own clock (TIMESYNC off or unanswered).
    pub timesync_offset_ns: Option<i64>,
}

#[derive(Debug)]
struct Ring {
    records: [SendRecord; SendLog::CAPACITY],
    /// Where the next record goes.
    next: usize,
    /// Records held (at most the capacity).
    len: usize,
    /// The offset of the last stamp taken, sent or not.
    offset_ns: Option<i64>,
}

/// The ring of recent sends, shared by the link and the recorder.
#[derive(Debug)]
pub struct SendLog {
    ring: Mutex<Ring>,
}

impl Default for SendLog {
    fn default() -> Self {
        Self {
            ring: Mutex::new(Ring {
                records: [SendRecord::default(); Self::CAPACITY],
                next: 0,
                len: 0,
                offset_ns: None,
            }),
        }
    }
}

impl SendLog {
    /// Records kept: about 5 s of poses at 50 Hz, far more than the
    /// recorder's look-up delay.
    pub const CAPACITY: usize = 256;

    /// Adds a record, replacing the oldest when full.
    pub fn push(&self, record: SendRecord) {
        let mut ring = self.ring.lock().unwrap_or_else(PoisonError::into_inner);
        let at = ring.next;
        ring.records[at] = record;
        ring.next = (at + 1) % Self::CAPACITY;
        ring.len = (ring.len + 1).min(Self::CAPACITY);
        ring.offset_ns = record.timesync_offset_ns;
    }

    /// Notes the offset of the stream's clock (also when no pose went out).
    pub fn set_offset(&self, offset_ns: Option<i64>) {
        self.ring
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .offset_ns = offset_ns;
    }

    /// The send of the pose captured at `capture_ns`, if it went out and is
    /// still in the ring.
    pub fn find(&self, capture_ns: u64) -> Option<SendRecord> {
        let ring = self.ring.lock().unwrap_or_else(PoisonError::into_inner);
        (1..=ring.len)
            .map(|back| ring.records[(ring.next + Self::CAPACITY - back) % Self::CAPACITY])
            .find(|r| r.capture_ns == capture_ns)
    }

    /// The offset of the stream's clock at the last stamp.
    pub fn offset_ns(&self) -> Option<i64> {
        self.ring
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .offset_ns
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn record(capture_ns: u64) -> SendRecord {
        SendRecord {
            capture_ns,
            send_ns: capture_ns + 1_000,
            timesync_offset_ns: Some(-5),
        }
    }

    #[test]
    fn finds_recent_sends_and_forgets_the_oldest() {
        let log = SendLog::default();
        assert_eq!(log.find(1), None);
        for t in 1..=(SendLog::CAPACITY as u64 + 10) {
            log.push(record(t));
        }
        assert_eq!(log.find(5), None, "overwritten");
        assert_eq!(log.find(11), Some(record(11)));
        let last = SendLog::CAPACITY as u64 + 10;
        assert_eq!(log.find(last), Some(record(last)));
        assert_eq!(log.offset_ns(), Some(-5));
        log.set_offset(None);
        assert_eq!(log.offset_ns(), None);
    }
}
