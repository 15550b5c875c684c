//! SIGTERM and SIGINT set the shared shutdown flag instead of killing the
//! process. One test in this binary, because handlers are process-wide.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::sync::atomic::Ordering;

#[test]
fn sigterm_sets_the_shutdown_flag() {
    let flag = star::service::signals::install_shutdown_handler().unwrap();
    assert!(!flag.load(Ordering::SeqCst));
    let again = star::service::signals::install_shutdown_handler().unwrap();
    assert!(
        std::sync::Arc::ptr_eq(&flag, &again),
        "one process-wide flag"
    );
    // SAFETY: raise() sends the signal to this thread; the handler only sets atomics.
    let rc = unsafe { libc::raise(libc::SIGTERM) };
    assert_eq!(rc, 0);
    assert!(
        flag.load(Ordering::SeqCst),
        "SIGTERM sets the flag and the process lives on"
    );
}
