//! Signal handling: SIGTERM, SIGINT, SIGHUP, SIGQUIT and SIGUSR1 all ask for
//! a graceful stop. The first one sets a shared shutdown flag that every loop
//! and every blocking wait polls (at least every 100 ms), so the process ends
//! within a second with its trajectory flushed; a second one exits at once
//! (exit code 128 + signal).
//!
//! SIGHUP, SIGQUIT and SIGUSR1 are treated like SIGTERM on purpose: `star`
//! has no configuration to reload and no state to dump, and a signal that
//! killed the process outright (the default for all three) would lose the
//! last second of the trajectory and skip `STOPPING=1`.
//!
//! Takes nothing; gives out the process-wide `Arc<AtomicBool>` shutdown flag,
//! [`shutdown_requested`] for code that has no handle on it (the replay
//! source), and [`sleep_unless_shutdown`]. The handler only does
//! async-signal-safe work: atomic loads and stores, a call of the handler it
//! replaced (iceoryx2's, which records the signal so `Node::wait` still
//! reports it), and `_exit` for the second signal.

use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, OnceLock};
use std::time::{Duration, Instant};

/// The signals that ask for a graceful stop.
pub const STOP_SIGNALS: [libc::c_int; 5] = [
    libc::SIGTERM,
    libc::SIGINT,
    libc::SIGHUP,
    libc::SIGQUIT,
    libc::SIGUSR1,
];

/// Longest slice of [`sleep_unless_shutdown`] between flag checks.
pub const SLEEP_SLICE: Duration = Duration::from_millis(50);

/// The flag the handler sets. Initialized before the handler is installed.
static SHUTDOWN: OnceLock<Arc<AtomicBool>> = OnceLock::new();
/// Whether a signal already arrived (a second one forces the exit).
static SIGNALLED: AtomicBool = AtomicBool::new(false);
/// The handler each signal had before ours (a plain `fn(c_int)`), or 0.
static PREVIOUS: [AtomicUsize; 32] = [const { AtomicUsize::new(0) }; 32];

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
    let previous = usize::try_from(signal)
        .ok()
        .and_then(|i| PREVIOUS.get(i))
        .map_or(0, |p| p.load(Ordering::SeqCst));
    if previous != 0 {
        // SAFETY: only plain handlers other than SIG_DFL/SIG_IGN are stored
        // (see `install_shutdown_handler`); iceoryx2's records the signal in
        // an atomic, which is async-signal-safe.
        let handler = unsafe {
            std::mem::transmute::<libc::sighandler_t, extern "C" fn(libc::c_int)>(previous)
        };
        handler(signal);
    }
}

/// Whether a stop signal arrived (or someone set the flag of
/// [`install_shutdown_handler`]). False when no handler was installed.
pub fn shutdown_requested() -> bool {
    SHUTDOWN.get().is_some_and(|f| f.load(Ordering::Relaxed))
}

/// Sleeps `total` in slices of at most [`SLEEP_SLICE`]; returns `false` as
/// soon as [`shutdown_requested`] says so, `true` when the whole time passed.
pub fn sleep_unless_shutdown(total: Duration) -> bool {
    let end = Instant::now() + total;
    loop {
        if shutdown_requested() {
            return false;
        }
        let left = end.saturating_duration_since(Instant::now());
        if left.is_zero() {
            return true;
        }
        std::thread::sleep(left.min(SLEEP_SLICE));
    }
}

/// Installs the handlers of [`STOP_SIGNALS`] (idempotent) and returns the
/// shutdown flag they set. Pass clones of it to every thread that must stop.
///
/// iceoryx2 installs its own handlers for SIGINT, SIGTERM, SIGQUIT and
/// SIGUSR1 the first time it needs them (creating shared memory, waiting on
/// a node), which would silently replace ours; so its handler is installed
/// first, here, and ours replaces it and calls it.
pub fn install_shutdown_handler() -> Result<Arc<AtomicBool>, SignalError> {
    let flag = SHUTDOWN
        .get_or_init(|| Arc::new(AtomicBool::new(false)))
        .clone();
    // Forces iceoryx2's one-time handler registration now.
    let _ = iceoryx2_bb_posix::signal::SignalHandler::last_signal();
    let ours = on_signal as extern "C" fn(libc::c_int) as libc::sighandler_t;
    for signal in STOP_SIGNALS {
        // SAFETY: a zeroed sigaction is a valid starting value; the handler
        // only touches atomics, calls the previous plain handler and calls
        // _exit, which are async-signal-safe.
        unsafe {
            let mut action: libc::sigaction = std::mem::zeroed();
            let mut previous: libc::sigaction = std::mem::zeroed();
            action.sa_sigaction = ours;
            action.sa_flags = libc::SA_RESTART;
            libc::sigemptyset(&mut action.sa_mask);
            if libc::sigaction(signal, &action, &mut previous) != 0 {
                return Err(SignalError {
                    signal,
                    source: std::io::Error::last_os_error(),
                });
            }
            let chained = previous.sa_flags & libc::SA_SIGINFO == 0
                && previous.sa_sigaction != libc::SIG_DFL
                && previous.sa_sigaction != libc::SIG_IGN
                && previous.sa_sigaction != ours;
            if chained {
                if let Some(slot) = usize::try_from(signal).ok().and_then(|i| PREVIOUS.get(i)) {
                    slot.store(previous.sa_sigaction, Ordering::SeqCst);
                }
            }
        }
    }
    Ok(flag)
}
