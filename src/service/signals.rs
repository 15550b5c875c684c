//! SIGTERM/SIGINT handling: the first signal sets a shared shutdown flag that
//! every loop polls; a second one exits at once (exit code 128 + signal).
//!
//! Takes nothing; gives out the process-wide `Arc<AtomicBool>` shutdown flag.
//! The handler only does async-signal-safe work: atomic loads and stores,
//! and `_exit` for the second signal.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, OnceLock};

/// The flag the handler sets. Initialized before the handler is installed.
static SHUTDOWN: OnceLock<Arc<AtomicBool>> = OnceLock::new();
/// Whether a signal already arrived (a second one forces the exit).
static SIGNALLED: AtomicBool = AtomicBool::new(false);

/// Installing a signal handler failed.
#[derive(Debug, thiserror::Error)]
#[error("cannot install the handler for signal {signal}: {source}")]
pub struct SignalError {
    /// The signal number.
    pub signal: i32,
    /// The OS error.
    pub source: std::io::Error,
}

extern "C" fn on_signal(signal: libc::c_int) {
    if SIGNALLED.swap(true, Ordering::SeqCst) {
        // SAFETY: _exit is async-signal-safe.
        unsafe { libc::_exit(128 + signal) };
    }
    if let Some(flag) = SHUTDOWN.get() {
        flag.store(true, Ordering::SeqCst);
    }
}

/// Installs the SIGTERM and SIGINT handlers (idempotent) and returns the
/// shutdown flag they set. Pass clones of it to every thread that must stop.
pub fn install_shutdown_handler() -> Result<Arc<AtomicBool>, SignalError> {
    let flag = SHUTDOWN
        .get_or_init(|| Arc::new(AtomicBool::new(false)))
        .clone();
    for signal in [libc::SIGTERM, libc::SIGINT] {
        // SAFETY: a zeroed sigaction is a valid starting value; the handler
        // only touches atomics and calls _exit, which are async-signal-safe.
        unsafe {
            let mut action: libc::sigaction = std::mem::zeroed();
            action.sa_sigaction = on_signal as extern "C" fn(libc::c_int) as libc::sighandler_t;
            action.sa_flags = libc::SA_RESTART;
            libc::sigemptyset(&mut action.sa_mask);
            if libc::sigaction(signal, &action, std::ptr::null_mut()) != 0 {
                return Err(SignalError {
                    signal,
                    source: std::io::Error::last_os_error(),
                });
            }
        }
    }
    Ok(flag)
}
