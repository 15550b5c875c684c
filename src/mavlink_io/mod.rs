//! The MAVLink link to the autopilot (PX4 or ArduPilot), on the `mavlink`
//! crate with the common dialect, MAVLink 2.
//!
//! Owns the connection (`udpout:`, `udpin:` locked to one autopilot, see
//! `udpin.rs`, `tcpout:`, `serial:`) and two
//! threads: `mavlink-tx` (reconnects, sends poses at a capped rate, HEARTBEAT
//! at 1 Hz, TIMESYNC requests) and `mavlink-rx` (answers TIMESYNC requests,
//! feeds the offset estimator). Takes [`PoseSample`]s from the tracker through
//! a one-slot mailbox ([`MavlinkHandle::publish`] never blocks on the link and
//! never allocates); gives out VISION_POSITION_ESTIMATE or ODOMETRY in local
//! NED / body FRD (ODOMETRY: `frame_id` MAV_FRAME_LOCAL_FRD, which is our
//! NED frame, see `messages.rs`), and [`LinkStats`].
//!
//! Sending rules: nothing is sent while tracking is lost; poses are capped at
//! `rate_hz` on capture time by a token bucket of depth two (a camera at the
//! cap whose capture times jitter keeps every frame; no two poses closer than
//! half an interval); samples
//! older than `max_pose_age_ms` when the link takes them are dropped, so a
//! link that comes back gets the newest pose and never a burst of stale ones.
//!
//! Timestamps (`stamp.rs`): one stream (one link connection), one clock.
//! No pose goes out before the clock is settled: four TIMESYNC answers
//! (asked for every 25 ms, about 100 ms), or at least one by
//! `timesync_wait_ms`; poses meanwhile are dropped and counted
//! (`poses_dropped_clock`). `usec` is then the capture
//! time (CLOCK_MONOTONIC) plus a slew-limited TIMESYNC offset for the whole
//! stream; if the autopilot has not answered within `timesync_wait_ms`, it is
//! the bare capture time from the stream's first pose on, also after answers
//! arrive (logged at warn). Consecutive `usec` values are at least
//! `autopilot_min_interval_ms` apart (EKF3 drops samples under 20 ms apart):
//! a pose that would land closer is stamped at the minimum when that moves
//! it by at most 0.5 ms, skipped (`poses_dropped_spacing`) otherwise; an
//! offset change moves consecutive values apart by at most 1 % of their
//! capture interval, and closer only out of the slack above the minimum.
//!
//! HEARTBEAT and TIMESYNC requests go out between poses, half an interval
//! after the last one: ArduPilot dates a packet by the byte time of what is
//! queued behind it in its UART buffer, so one sent right after a pose
//! back-dated the pose (and its jitter correction then shortened the gap to
//! the pose before, under EKF3's 20 ms), and one sent right before a pose
//! was back-dated itself.
//!
//! ```no_run
//! # use std::sync::{Arc, atomic::AtomicBool};
//! # use star::mavlink_io::{MavlinkConfig, MavlinkLink, PoseSample};
//! let shutdown = Arc::new(AtomicBool::new(false));
//! let link = MavlinkLink::spawn(&MavlinkConfig::default(), shutdown)?;
//! # let sample: PoseSample = todo!();
//! link.publish(sample); // once per tracked (or lost) frame
//! println!("{:?}", link.stats());
//! link.shutdown();
//! # Ok::<(), star::mavlink_io::MavlinkError>(())
//! ```

pub mod config;
pub mod frames;
pub mod link;
pub mod messages;
mod receiver;
pub mod reset;
pub mod send_log;
mod sender;
pub mod signing;
pub mod stamp;
mod stats;
pub mod timesync;
pub mod udpin;

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{mpsc, Arc, Mutex, PoisonError};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use mavlink::MavHeader;

pub use config::{MavlinkConfig, PoseMessage, TransformConfig};
pub use frames::{FrameConverter, NedPose};
pub use link::{LinkAddress, LinkError};
pub use send_log::{SendLog, SendRecord};
pub use stats::LinkStats;

use crate::geometry::Pose;
use sender::Mailbox;
use stamp::PoseClock;
use stats::Counters;
use timesync::{OffsetEstimate, TimesyncEstimator};

/// How long [`MavlinkHandle::shutdown`] waits for the threads.
pub const SHUTDOWN_TIMEOUT: Duration = Duration::from_millis(900);

/// One tracker output, as handed to the link.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseSample {
    /// Capture time of the frame, CLOCK_MONOTONIC, ns.
    pub capture_ns: u64,
    /// The tracked camera pose.
    pub world_from_camera: Pose,
    /// Covariance of the twist `[v; w]` (m, rad) that perturbs
    /// `world_from_camera` on the left, in the WORLD frame:
    /// `true = exp(xi) * world_from_camera`; row-major `[row][col]`.
    /// A camera-frame (right) covariance converts with
    /// [`frames::twist_covariance_world_from_camera`]. Non-finite entries send
    /// "unknown" (NaN in the first element).
    pub covariance_6x6: [[f64; 6]; 6],
    /// The tracker's reset counter: change it on relocalization or any jump.
    pub reset_counter: u8,
    /// Tracking quality, percent (ODOMETRY `quality`; 0 = unknown).
    pub quality_percent: u8,
    /// False while lost: the sample is not sent.
    pub tracking: bool,
}

/// Errors starting the link.
#[derive(Debug, thiserror::Error)]
pub enum MavlinkError {
    /// The configured connection string is invalid.
    #[error(transparent)]
    Address(#[from] link::AddressError),
    /// The configuration failed validation.
    #[error("invalid [mavlink] config: {0}")]
    Config(#[source] crate::settings::SettingError),
    /// The signing key file cannot be used.
    #[error("invalid [mavlink] signing_key: {0}")]
    SigningKey(#[from] signing::SigningKeyError),
    /// A thread could not be started.
    #[error("cannot start MAVLink thread {name}: {source}")]
    Thread {
        /// Thread name.
        name: &'static str,
        /// The OS error.
        source: std::io::Error,
    },
}

/// State shared by the handle and the two threads.
pub(crate) struct Shared {
    pub config: MavlinkConfig,
    /// MAVLink 2 signing, when `signing_key` is set (shared by every link
    /// opened: its timestamps must keep increasing across reconnects).
    pub signing: Option<Arc<signing::Signing>>,
    pub address: LinkAddress,
    pub header: MavHeader,
    pub shutdown: Arc<AtomicBool>,
    pub stop: AtomicBool,
    pub mailbox: Mailbox,
    /// The open link and its generation (generations start at 1).
    pub link: Mutex<Option<(u64, Arc<link::Link>)>>,
    /// Generation that a thread found broken (0 = none).
    pub broken_generation: AtomicU64,
    pub timesync: Mutex<TimesyncEstimator>,
    /// The pose clock; never locked while `timesync` is held (nor the
    /// other way round).
    pub clock: Mutex<PoseClock>,
    pub counters: Arc<Counters>,
    /// The poses sent lately, for the flight log.
    pub send_log: Arc<SendLog>,
}

impl Shared {
    pub fn stopping(&self) -> bool {
        self.stop.load(Ordering::Relaxed) || self.shutdown.load(Ordering::Relaxed)
    }

    pub fn current_link(&self) -> Option<(u64, Arc<link::Link>)> {
        self.link
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .clone()
    }

    pub fn mark_broken(&self, generation: u64, error: &LinkError) {
        if self.broken_generation.swap(generation, Ordering::AcqRel) != generation {
            stats::bump(&self.counters.link_errors);
            tracing::warn!(%error, "MAVLink link down");
        }
    }

    /// The TIMESYNC estimate (none while TIMESYNC is off).
    pub fn estimate(&self) -> Option<OffsetEstimate> {
        if !self.config.timesync {
            return None;
        }
        self.timesync
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .estimate()
    }

    /// Our public time for `monotonic_ns`: the clock `usec` is in.
    pub fn public_ns(&self, monotonic_ns: u64) -> i64 {
        let estimate = self.estimate();
        self.clock
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .public_ns(monotonic_ns, estimate)
    }
}

/// The body of a link thread.
type ThreadBody = fn(Arc<Shared>);

/// Starts the link threads.
pub struct MavlinkLink;

impl MavlinkLink {
    /// Validates `config` and starts the threads. The link itself opens in
    /// the background and reopens after failures, so an autopilot that boots
    /// later is fine. The threads stop when `shutdown` becomes true or the
    /// handle is shut down or dropped.
    pub fn spawn(
        config: &MavlinkConfig,
        shutdown: Arc<AtomicBool>,
    ) -> Result<MavlinkHandle, MavlinkError> {
        config
            .validate()
            .map_err(|e| MavlinkError::Config(e.within("mavlink")))?;
        let address = LinkAddress::parse(&config.connection)?;
        let signing = match &config.signing_key {
            Some(path) => {
                let key = signing::load_key(path)?;
                tracing::info!(key = %path.display(), required = config.signing_required, "MAVLink 2 signing on");
                Some(Arc::new(signing::Signing::new(
                    key,
                    0,
                    config.signing_required,
                )))
            }
            None => None,
        };
        let shared = Arc::new(Shared {
            config: config.clone(),
            signing,
            address,
            header: MavHeader {
                system_id: u32::from(config.system_id),
                component_id: config.component_id,
                sequence: 0,
            },
            shutdown,
            stop: AtomicBool::new(false),
            mailbox: Mailbox::new(),
            link: Mutex::new(None),
            broken_generation: AtomicU64::new(0),
            timesync: Mutex::new(TimesyncEstimator::new()),
            clock: Mutex::new(PoseClock::new(
                config.timesync,
                u64::from(config.timesync_wait_ms) * 1_000_000,
                config.min_usec_spacing_ns(),
            )),
            counters: Arc::default(),
            send_log: Arc::default(),
        });
        let (done_tx, done_rx) = mpsc::channel();
        let mut handle = MavlinkHandle {
            shared: shared.clone(),
            threads: Vec::with_capacity(2),
            done_rx: Mutex::new(done_rx),
        };
        let starts: [(&'static str, ThreadBody); 2] =
            [("mavlink-tx", sender::run), ("mavlink-rx", receiver::run)];
        for (name, body) in starts {
            let shared = shared.clone();
            let done = DoneGuard(done_tx.clone());
            let thread = std::thread::Builder::new()
                .name(name.into())
                .spawn(move || {
                    let _done = done;
                    body(shared);
                })
                .map_err(|source| MavlinkError::Thread { name, source })?;
            handle.threads.push(thread);
        }
        tracing::info!(connection = %shared.address, rate_hz = config.rate_hz, message = ?config.message, "MAVLink link started");
        Ok(handle)
    }
}

/// Tells the handle a thread has finished, also when it panicked.
struct DoneGuard(mpsc::Sender<()>);

impl Drop for DoneGuard {
    fn drop(&mut self) {
        let _ = self.0.send(());
    }
}

/// The tracker's side of the link. `Send + Sync`: share it behind an `Arc`
/// if several threads publish or read stats.
pub struct MavlinkHandle {
    shared: Arc<Shared>,
    threads: Vec<JoinHandle<()>>,
    /// In a mutex only to make the handle `Sync`; used with `&mut self`.
    done_rx: Mutex<mpsc::Receiver<()>>,
}

impl MavlinkHandle {
    /// Hands the newest sample to the link, replacing one not yet taken.
    /// Never waits for the link and never allocates.
    pub fn publish(&self, sample: PoseSample) {
        self.shared.mailbox.put(sample);
    }

    /// Counters: messages sent by type, drops by reason, link up or down.
    pub fn stats(&self) -> LinkStats {
        self.shared.counters.snapshot()
    }

    /// The poses sent lately (capture time, send time, TIMESYNC offset),
    /// for the flight log.
    pub fn send_log(&self) -> Arc<SendLog> {
        self.shared.send_log.clone()
    }

    /// Stops the threads and waits up to [`SHUTDOWN_TIMEOUT`] for them.
    /// Returns whether all of them finished in time (a thread stuck in a
    /// device call is left behind and ends with the process).
    pub fn shutdown(mut self) -> bool {
        self.stop_and_join()
    }

    fn stop_and_join(&mut self) -> bool {
        if self.threads.is_empty() {
            return true;
        }
        self.shared.stop.store(true, Ordering::Relaxed);
        self.shared.mailbox.wake();
        let deadline = Instant::now() + SHUTDOWN_TIMEOUT;
        let mut finished = 0;
        while finished < self.threads.len() {
            let left = deadline.saturating_duration_since(Instant::now());
            let done_rx = self
                .done_rx
                .get_mut()
                .unwrap_or_else(PoisonError::into_inner);
            match done_rx.recv_timeout(left) {
                Ok(()) => finished += 1,
                Err(_) => break,
            }
        }
        let all = finished == self.threads.len();
        if all {
            for t in self.threads.drain(..) {
                let _ = t.join();
            }
            tracing::info!("MAVLink link stopped");
        } else {
            tracing::warn!(
                "MAVLink threads did not stop within {SHUTDOWN_TIMEOUT:?}; leaving them"
            );
            self.threads.clear();
        }
        all
    }
}

impl Drop for MavlinkHandle {
    fn drop(&mut self) {
        self.stop_and_join();
    }
}
