//! sd_notify messages to systemd (`Type=notify` units), on the `sd-notify`
//! crate.
//!
//! Takes state changes (ready, status text, watchdog ping, stopping); gives
//! out datagrams on `$NOTIFY_SOCKET`. Without that variable (not started by
//! systemd) every call does nothing, so the binary runs the same by hand.

use std::time::Duration;

use sd_notify::NotifyState;

/// Sends notifications to the service manager. Cheap to copy.
#[derive(Debug, Clone, Copy, Default)]
pub struct Notifier;

impl Notifier {
    /// Whether a service manager listens (`$NOTIFY_SOCKET` is set).
    pub fn is_enabled(&self) -> bool {
        std::env::var_os("NOTIFY_SOCKET").is_some()
    }

    /// The watchdog timeout systemd expects pings within (`WatchdogSec=`),
    /// if enabled for this process.
    pub fn watchdog_timeout(&self) -> Option<Duration> {
        sd_notify::watchdog_enabled().filter(|d| !d.is_zero())
    }

    /// `READY=1` with a status line.
    pub fn ready(&self, status: &str) {
        self.send(&[NotifyState::Ready, NotifyState::Status(status)]);
    }

    /// `STATUS=...` (shown by `systemctl status`).
    pub fn status(&self, status: &str) {
        self.send(&[NotifyState::Status(status)]);
    }

    /// `WATCHDOG=1`.
    pub fn watchdog(&self) {
        self.send(&[NotifyState::Watchdog]);
    }

    /// `STOPPING=1` with a status line.
    pub fn stopping(&self, status: &str) {
        self.send(&[NotifyState::Stopping, NotifyState::Status(status)]);
    }

    fn send(&self, states: &[NotifyState]) {
        if let Err(error) = sd_notify::notify(states) {
            tracing::warn!(%error, "sd_notify failed");
        }
    }
}
