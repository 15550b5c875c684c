//! Running as a systemd service: readiness, the progress-gated watchdog,
//! status lines, and clean shutdown on SIGTERM/SIGINT/SIGHUP/SIGQUIT/SIGUSR1.
//!
//! Owns the `service` thread, which pings `WATCHDOG=1` every half
//! `WatchdogSec` when (and only when) the tracking loop fed the [`Watchdog`]
//! since the last ping, and sends `STATUS=` once a second from the
//! [`StatusBoard`]. Takes from the tracker: [`Service::ready`] once the map is
//! loaded and the renderer is up, [`Watchdog::feed`] per loop iteration, and
//! [`StatusBoard`] updates. Gives out sd_notify datagrams (nothing when not
//! run by systemd) and the shared shutdown flag
//! ([`signals::install_shutdown_handler`]).
//!
//! ```no_run
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! use star::service::{self, Service, ServiceState};
//! let shutdown = service::signals::install_shutdown_handler()?;
//! let svc = Service::start(shutdown.clone())?;
//! // ... load the map, start the renderer ...
//! svc.ready();
//! let dog = svc.watchdog();
//! while !shutdown.load(std::sync::atomic::Ordering::Relaxed) {
//!     // ... wait for a frame (with a timeout), track it ...
//!     dog.feed();
//!     svc.status().frame_done();
//! }
//! svc.stop();
//! # Ok(()) }
//! ```

pub mod notify;
pub mod signals;
pub mod status;
pub mod watchdog;

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

pub use notify::Notifier;
pub use status::{ServiceState, StatusBoard};
pub use watchdog::{Watchdog, WatchdogGate};

use crate::clock::monotonic_now_ns;

/// How often `STATUS=` is refreshed.
pub const STATUS_PERIOD: Duration = Duration::from_secs(1);
/// Longest sleep of the service thread between flag checks.
const POLL: Duration = Duration::from_millis(50);

/// Errors starting the service thread.
#[derive(Debug, thiserror::Error)]
pub enum ServiceError {
    /// The thread could not be spawned.
    #[error("cannot start the service thread: {0}")]
    Thread(std::io::Error),
    /// A signal handler could not be installed.
    #[error(transparent)]
    Signal(#[from] signals::SignalError),
}

/// The service side of a `star` process.
pub struct Service {
    notifier: Notifier,
    watchdog: Watchdog,
    status: Arc<StatusBoard>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

impl Service {
    /// Starts the service thread. It ends when `shutdown` is set or on
    /// [`Service::stop`].
    pub fn start(shutdown: Arc<AtomicBool>) -> Result<Self, ServiceError> {
        let notifier = Notifier;
        let watchdog = Watchdog::new();
        let status = Arc::new(StatusBoard::new());
        let stop = Arc::new(AtomicBool::new(false));
        let timeout = notifier.watchdog_timeout();
        match timeout {
            Some(t) => tracing::info!(timeout = ?t, "systemd watchdog enabled"),
            None => tracing::debug!("no systemd watchdog"),
        }
        let thread = {
            let (watchdog, status, stop) = (watchdog.clone(), status.clone(), stop.clone());
            std::thread::Builder::new()
                .name("service".into())
                .spawn(move || run(notifier, timeout, &watchdog, &status, &stop, &shutdown))
                .map_err(ServiceError::Thread)?
        };
        Ok(Self {
            notifier,
            watchdog,
            status,
            stop,
            thread: Some(thread),
        })
    }

    /// Tells systemd the service is up (`READY=1`): call once the map is
    /// loaded and the renderer is running.
    pub fn ready(&self) {
        self.status.set_state(ServiceState::Waiting);
        self.notifier
            .ready(&self.status.line(0.0, monotonic_now_ns()));
        tracing::info!("service ready");
    }

    /// The watchdog the tracking loop feeds.
    pub fn watchdog(&self) -> Watchdog {
        self.watchdog.clone()
    }

    /// The status board the tracker updates.
    pub fn status(&self) -> Arc<StatusBoard> {
        self.status.clone()
    }

    /// Sends `STOPPING=1` and ends the service thread.
    pub fn stop(mut self) {
        self.stop_thread();
    }

    fn stop_thread(&mut self) {
        if let Some(thread) = self.thread.take() {
            self.status.set_state(ServiceState::Stopping);
            self.notifier.stopping("stopping");
            self.stop.store(true, Ordering::Relaxed);
            let _ = thread.join();
        }
    }
}

impl Drop for Service {
    fn drop(&mut self) {
        self.stop_thread();
    }
}

fn run(
    notifier: Notifier,
    watchdog_timeout: Option<Duration>,
    watchdog: &Watchdog,
    status: &StatusBoard,
    stop: &AtomicBool,
    shutdown: &AtomicBool,
) {
    let ping_period = watchdog_timeout.map(|t| t / 2);
    let mut gate = WatchdogGate::new();
    let start = Instant::now();
    let mut next_ping = start;
    let mut next_status = start + STATUS_PERIOD;
    let (mut last_frames, mut last_status_at) = (status.frames(), start);
    while !stop.load(Ordering::Relaxed) && !shutdown.load(Ordering::Relaxed) {
        let now = Instant::now();
        if let Some(period) = ping_period {
            if now >= next_ping {
                next_ping = now + period;
                if gate.should_ping(watchdog.progress()) {
                    notifier.watchdog();
                }
            }
        }
        if now >= next_status {
            next_status = now + STATUS_PERIOD;
            let frames = status.frames();
            let elapsed_s = now.duration_since(last_status_at).as_secs_f64();
            let fps = status::fps(last_frames, frames, elapsed_s);
            (last_frames, last_status_at) = (frames, now);
            if status.state() != ServiceState::Starting {
                notifier.status(&status.line(fps, monotonic_now_ns()));
            }
        }
        let mut wake = next_status.min(now + POLL);
        if ping_period.is_some() {
            wake = wake.min(next_ping);
        }
        std::thread::sleep(wake.saturating_duration_since(Instant::now()));
    }
}
