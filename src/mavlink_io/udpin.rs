//! The `udpin:` transport: our own UDP socket, locked to one autopilot.
//!
//! Owns the listening socket and the peer lock. rust-mavlink's `udpin`
//! sends to whoever sent the last datagram, so one datagram from anywhere
//! (20 random bytes will do) took the pose stream away from the autopilot
//! (issue 24). Here:
//!
//! - every datagram is parsed on its own (no frame spans two datagrams or
//!   two senders); only CRC-checked MAVLink frames count, garbage is ignored;
//! - the link locks to the first sender of an autopilot HEARTBEAT
//!   (`autopilot` not MAV_AUTOPILOT_INVALID, `type` not MAV_TYPE_GCS) from an
//!   allowed system id ([`PeerPolicy::autopilot_system_ids`]; empty = any);
//! - while locked, frames from any other address are dropped unread (they
//!   cannot feed TIMESYNC either) and counted; another sender takes the link
//!   only once the locked peer has sent no valid frame for
//!   [`PeerPolicy::peer_silence`], and only with such a HEARTBEAT; every
//!   change of peer is logged at warn;
//! - nothing is sent before a peer is locked (`send` returns `Ok(false)`).
//!
//! Takes datagrams from the socket and messages to send; gives out the
//! locked peer's messages, a peer epoch (how many locks so far: the sender
//! starts a new stream on each), and the foreign-datagram count. Sending
//! serializes into a stack buffer: no allocation per message. Receiving
//! parses each datagram with the crate's reader over the datagram's bytes
//! (the reader's one small buffer per datagram is the receive thread's only
//! allocation; the pose path never receives).

use std::collections::VecDeque;
use std::io;
use std::net::{SocketAddr, UdpSocket};
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicU8, Ordering};
use std::sync::{Arc, Mutex, PoisonError};
use std::time::{Duration, Instant};

use mavlink::dialects::common::{MavAutopilot, MavMessage, MavType};
use mavlink::error::MessageReadError;
use mavlink::{MAVLinkMessageRaw, MavHeader, MavlinkReader};

use super::signing::{self, Signing};
use super::stats::{bump, Counters};

/// Largest UDP datagram we read (the UDP maximum payload).
const DATAGRAM_BYTES: usize = 65_536;
/// Messages of one datagram kept for `recv`; a datagram holding more is
/// cut there (an autopilot sends one message per datagram).
const MAX_MESSAGES_PER_DATAGRAM: usize = 32;

/// Who may take the link.
#[derive(Debug, Clone, PartialEq)]
pub struct PeerPolicy {
    /// System ids whose autopilot HEARTBEAT locks the link; empty = any.
    pub autopilot_system_ids: Vec<u8>,
    /// How long the locked peer must be silent (no valid frame) before
    /// another may take the link.
    pub peer_silence: Duration,
    /// Our own system and component id: our echoes never lock the link.
    pub own_ids: (u32, u8),
}

impl Default for PeerPolicy {
    fn default() -> Self {
        Self {
            autopilot_system_ids: Vec::new(),
            peer_silence: Duration::from_secs(5),
            own_ids: (1, super::config::COMPONENT_ID_VISUAL_INERTIAL_ODOMETRY),
        }
    }
}

impl PeerPolicy {
    /// True when `message` from `header` is an autopilot HEARTBEAT that may
    /// lock the link.
    pub fn may_lock(&self, header: &MavHeader, message: &MavMessage) -> bool {
        let MavMessage::HEARTBEAT(hb) = message else {
            return false;
        };
        if (header.system_id, header.component_id) == self.own_ids {
            return false;
        }
        let allowed = self.autopilot_system_ids.is_empty()
            || u8::try_from(header.system_id)
                .is_ok_and(|id| self.autopilot_system_ids.contains(&id));
        allowed
            && hb.autopilot != MavAutopilot::MAV_AUTOPILOT_INVALID
            && hb.mavtype != MavType::MAV_TYPE_GCS
    }
}

/// What to do with one datagram's valid frames.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Verdict {
    /// From the locked peer (or the peer just locked): use the frames.
    Deliver,
    /// From the peer that just took the link; `previous` is the one it
    /// replaced, if any.
    Locked {
        /// The peer before (None at the first lock).
        previous: Option<SocketAddr>,
    },
    /// From anyone else, or garbage: drop it.
    Ignore,
}

/// The peer lock: a pure state machine over (sender, time, frames).
#[derive(Debug, Clone)]
pub struct PeerLock {
    policy: PeerPolicy,
    peer: Option<SocketAddr>,
    last_heard: Option<Instant>,
    epoch: u64,
}

impl PeerLock {
    /// Unlocked.
    pub fn new(policy: PeerPolicy) -> Self {
        Self {
            policy,
            peer: None,
            last_heard: None,
            epoch: 0,
        }
    }

    /// The locked peer.
    pub fn peer(&self) -> Option<SocketAddr> {
        self.peer
    }

    /// How many times a peer was locked (0 = never).
    pub fn epoch(&self) -> u64 {
        self.epoch
    }

    /// Decides on a datagram from `from` at `now` whose CRC-valid frames
    /// are `frames` (empty for garbage).
    pub fn on_datagram(
        &mut self,
        from: SocketAddr,
        now: Instant,
        frames: &[(MavHeader, MavMessage)],
    ) -> Verdict {
        if frames.is_empty() {
            return Verdict::Ignore;
        }
        if self.peer == Some(from) {
            self.last_heard = Some(now);
            return Verdict::Deliver;
        }
        let free = match (self.peer, self.last_heard) {
            (Some(_), Some(heard)) => {
                now.saturating_duration_since(heard) >= self.policy.peer_silence
            }
            _ => true,
        };
        if free && frames.iter().any(|(h, m)| self.policy.may_lock(h, m)) {
            let previous = self.peer.replace(from);
            self.last_heard = Some(now);
            self.epoch += 1;
            return Verdict::Locked { previous };
        }
        Verdict::Ignore
    }
}

/// State of the receiving side (used by the one `mavlink-rx` thread).
struct Rx {
    datagram: Box<[u8]>,
    pending: VecDeque<(MavHeader, MavMessage)>,
    frames: Vec<(MavHeader, MavMessage)>,
}

/// The `udpin` socket and its peer lock.
pub struct UdpIn {
    socket: UdpSocket,
    lock: Mutex<PeerLock>,
    rx: Mutex<Rx>,
    /// The locked peer, copied out of `lock` for the send path.
    peer: Mutex<Option<SocketAddr>>,
    epoch: AtomicU64,
    sequence: AtomicU8,
    waiting_logged: AtomicBool,
    counters: Arc<Counters>,
    signing: Option<Arc<Signing>>,
}

impl UdpIn {
    /// Binds `address` (`ADDR:PORT`) with `read_timeout` on receives.
    pub(crate) fn bind(
        address: &str,
        policy: PeerPolicy,
        read_timeout: Duration,
        counters: Arc<Counters>,
        signing: Option<Arc<Signing>>,
    ) -> io::Result<Self> {
        let socket = UdpSocket::bind(address)?;
        socket.set_read_timeout(Some(read_timeout))?;
        Ok(Self {
            socket,
            lock: Mutex::new(PeerLock::new(policy)),
            rx: Mutex::new(Rx {
                datagram: vec![0; DATAGRAM_BYTES].into_boxed_slice(),
                pending: VecDeque::with_capacity(MAX_MESSAGES_PER_DATAGRAM),
                frames: Vec::with_capacity(MAX_MESSAGES_PER_DATAGRAM),
            }),
            peer: Mutex::new(None),
            epoch: AtomicU64::new(0),
            sequence: AtomicU8::new(0),
            waiting_logged: AtomicBool::new(false),
            counters,
            signing,
        })
    }

    /// The bound address.
    pub fn local_addr(&self) -> io::Result<SocketAddr> {
        self.socket.local_addr()
    }

    /// How many peers were locked so far (0 = none yet).
    pub fn peer_epoch(&self) -> u64 {
        self.epoch.load(Ordering::Acquire)
    }

    /// Sends `message` to the locked peer; `Ok(false)` while none is.
    pub fn send(&self, header: &MavHeader, message: &MavMessage) -> io::Result<bool> {
        let header = MavHeader {
            sequence: self.sequence.fetch_add(1, Ordering::Relaxed),
            ..*header
        };
        let mut frame = [0u8; mavlink::consts::MAX_FRAME_SIZE];
        let n = mavlink::write_v2_msg(&mut &mut frame[..], header, message)
            .map_err(|e| io::Error::other(e.to_string()))?;
        self.send_frame(frame.get(..n).unwrap_or(&frame))
    }

    /// Sends one serialized frame to the locked peer; `Ok(false)` while
    /// none is.
    pub fn send_frame(&self, bytes: &[u8]) -> io::Result<bool> {
        let Some(peer) = *self.peer.lock().unwrap_or_else(PoisonError::into_inner) else {
            if !self.waiting_logged.swap(true, Ordering::Relaxed) {
                tracing::info!(
                    local = ?self.socket.local_addr().ok(),
                    "udpin: no autopilot locked yet; nothing is sent until one sends a HEARTBEAT"
                );
            }
            return Ok(false);
        };
        self.socket.send_to(bytes, peer)?;
        Ok(true)
    }

    /// The next message from the locked peer; `Ok(None)` after a read
    /// timeout or on a datagram that was dropped.
    pub fn recv(&self) -> io::Result<Option<(MavHeader, MavMessage)>> {
        let mut rx = self.rx.lock().unwrap_or_else(PoisonError::into_inner);
        if let Some(m) = rx.pending.pop_front() {
            return Ok(Some(m));
        }
        let Rx {
            datagram,
            pending,
            frames,
        } = &mut *rx;
        let (n, from) = self.socket.recv_from(datagram)?;
        frames.clear();
        let (signing, counters) = (self.signing.as_deref(), &*self.counters);
        parse_datagram(datagram.get(..n).unwrap_or_default(), frames, |raw| {
            signing::admit(signing, counters, raw)
        });
        let verdict = self
            .lock
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .on_datagram(from, Instant::now(), frames);
        match verdict {
            Verdict::Ignore => {
                bump(&self.counters.udpin_foreign_datagrams);
                let count = self
                    .counters
                    .udpin_foreign_datagrams
                    .load(Ordering::Relaxed);
                // 1st, 2nd, 4th, 8th ...: a flood cannot flood the log.
                if count.is_power_of_two() {
                    tracing::warn!(%from, bytes = n, valid_frames = frames.len(), ignored = count,
                        "udpin: datagram from a sender that is not the locked autopilot ignored");
                }
                return Ok(None);
            }
            Verdict::Locked { previous } => {
                *self.peer.lock().unwrap_or_else(PoisonError::into_inner) = Some(from);
                self.epoch.fetch_add(1, Ordering::AcqRel);
                bump(&self.counters.udpin_peer_locks);
                let system_id = frames.first().map(|(h, _)| h.system_id);
                match previous {
                    None => tracing::info!(peer = %from, ?system_id, "udpin: autopilot locked"),
                    Some(previous) => tracing::warn!(
                        %previous, peer = %from, ?system_id,
                        "udpin: autopilot peer changed (the previous one was silent)"
                    ),
                }
            }
            Verdict::Deliver => {}
        }
        pending.extend(frames.drain(..));
        Ok(pending.pop_front())
    }
}

/// The CRC-valid MAVLink 1 or 2 frames of one datagram that `admit` lets
/// through (signing) and that decode, in order, at most
/// [`MAX_MESSAGES_PER_DATAGRAM`].
pub fn parse_datagram(
    bytes: &[u8],
    out: &mut Vec<(MavHeader, MavMessage)>,
    mut admit: impl FnMut(&MAVLinkMessageRaw) -> bool,
) {
    let mut reader = MavlinkReader::with_capacity(bytes.len(), bytes);
    while out.len() < MAX_MESSAGES_PER_DATAGRAM {
        match reader.read_any_raw_message::<MavMessage>() {
            Ok(raw) => {
                if admit(&raw) {
                    // A valid frame of a message we cannot decode is skipped.
                    out.extend(signing::decode(&raw));
                }
            }
            Err(MessageReadError::Parse(_)) => continue,
            // End of the datagram.
            Err(MessageReadError::Io(_)) => break,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use mavlink::dialects::common::{MavModeFlag, MavState, HEARTBEAT_DATA};

    fn heartbeat(autopilot: MavAutopilot, mavtype: MavType) -> MavMessage {
        MavMessage::HEARTBEAT(HEARTBEAT_DATA {
            custom_mode: 0,
            mavtype,
            autopilot,
            base_mode: MavModeFlag::empty(),
            system_status: MavState::MAV_STATE_STANDBY,
            mavlink_version: 3,
        })
    }

    fn header(system_id: u32, component_id: u8) -> MavHeader {
        MavHeader {
            system_id,
            component_id,
            sequence: 0,
        }
    }

    fn ardupilot(system_id: u32) -> Vec<(MavHeader, MavMessage)> {
        vec![(
            header(system_id, 1),
            heartbeat(
                MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA,
                MavType::MAV_TYPE_QUADROTOR,
            ),
        )]
    }

    fn encode(frames: &[(MavHeader, MavMessage)]) -> Vec<u8> {
        let mut bytes = Vec::new();
        for (h, m) in frames {
            mavlink::write_v2_msg(&mut bytes, *h, m).unwrap();
        }
        bytes
    }

    fn addr(port: u16) -> SocketAddr {
        SocketAddr::from(([127, 0, 0, 1], port))
    }

    #[test]
    fn garbage_and_non_autopilots_never_lock() {
        let mut lock = PeerLock::new(PeerPolicy::default());
        let t0 = Instant::now();
        // Garbage parses to no frame.
        let mut frames = Vec::new();
        parse_datagram(
            &[
                0xFD, 9, 0, 0, 7, 1, 1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10,
            ],
            &mut frames,
            |_| true,
        );
        assert!(frames.is_empty());
        assert_eq!(lock.on_datagram(addr(1), t0, &frames), Verdict::Ignore);
        // A GCS, a non-autopilot (our own kind) and our own echo.
        for (h, m) in [
            (
                header(255, 190),
                heartbeat(MavAutopilot::MAV_AUTOPILOT_INVALID, MavType::MAV_TYPE_GCS),
            ),
            (
                header(255, 190),
                heartbeat(MavAutopilot::MAV_AUTOPILOT_GENERIC, MavType::MAV_TYPE_GCS),
            ),
            (
                header(1, 100),
                heartbeat(
                    MavAutopilot::MAV_AUTOPILOT_INVALID,
                    MavType::MAV_TYPE_ONBOARD_CONTROLLER,
                ),
            ),
            (
                header(1, 197),
                heartbeat(MavAutopilot::MAV_AUTOPILOT_PX4, MavType::MAV_TYPE_QUADROTOR),
            ),
        ] {
            assert_eq!(
                lock.on_datagram(addr(1), t0, &[(h, m)]),
                Verdict::Ignore,
                "{h:?}"
            );
        }
        assert_eq!(lock.peer(), None);
        assert_eq!(lock.epoch(), 0);
    }

    #[test]
    fn locks_holds_and_relocks_only_after_silence() {
        let policy = PeerPolicy {
            peer_silence: Duration::from_secs(5),
            ..PeerPolicy::default()
        };
        let mut lock = PeerLock::new(policy);
        let t0 = Instant::now();
        let s = Duration::from_secs;
        let frames = ardupilot(1);
        assert_eq!(
            lock.on_datagram(addr(1), t0, &frames),
            Verdict::Locked { previous: None }
        );
        assert_eq!(
            lock.on_datagram(addr(1), t0 + s(1), &frames),
            Verdict::Deliver
        );
        // Another autopilot while the peer talks: ignored, also at 4.9 s of silence.
        assert_eq!(
            lock.on_datagram(addr(2), t0 + s(2), &ardupilot(2)),
            Verdict::Ignore
        );
        let almost = t0 + s(1) + Duration::from_millis(4_900);
        assert_eq!(
            lock.on_datagram(addr(2), almost, &ardupilot(2)),
            Verdict::Ignore
        );
        // Garbage from the locked peer does not keep it alive.
        assert_eq!(lock.on_datagram(addr(1), t0 + s(3), &[]), Verdict::Ignore);
        // Silent for 5 s: the other takes it.
        assert_eq!(
            lock.on_datagram(addr(2), t0 + s(6), &ardupilot(2)),
            Verdict::Locked {
                previous: Some(addr(1))
            }
        );
        assert_eq!(lock.peer(), Some(addr(2)));
        assert_eq!(lock.epoch(), 2);
        // The old one is now the foreigner.
        assert_eq!(
            lock.on_datagram(addr(1), t0 + s(7), &frames),
            Verdict::Ignore
        );
    }

    #[test]
    fn listed_system_ids_only() {
        let mut lock = PeerLock::new(PeerPolicy {
            autopilot_system_ids: vec![7],
            ..PeerPolicy::default()
        });
        let t0 = Instant::now();
        assert_eq!(
            lock.on_datagram(addr(1), t0, &ardupilot(1)),
            Verdict::Ignore
        );
        assert_eq!(
            lock.on_datagram(addr(1), t0, &ardupilot(300)),
            Verdict::Ignore
        );
        assert_eq!(
            lock.on_datagram(addr(2), t0, &ardupilot(7)),
            Verdict::Locked { previous: None }
        );
    }

    #[test]
    fn parses_every_frame_of_a_datagram_and_skips_bad_crc() {
        let mut bytes = encode(&ardupilot(1));
        let mut bad = encode(&ardupilot(2));
        let last = bad.len() - 1;
        bad[last] ^= 0xFF; // CRC broken
        bytes.extend_from_slice(&bad);
        bytes.extend_from_slice(&[0x13, 0x37]);
        bytes.extend(encode(&ardupilot(3)));
        let mut frames = Vec::new();
        parse_datagram(&bytes, &mut frames, |_| true);
        let ids: Vec<u32> = frames.iter().map(|(h, _)| h.system_id).collect();
        assert_eq!(ids, [1, 3]);
    }
}
