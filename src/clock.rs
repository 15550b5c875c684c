//! The one clock: CLOCK_MONOTONIC and CLOCK_REALTIME readings in
//! nanoseconds, and the conversion of driver timestamps to the monotonic
//! clock that capture times, IPC latencies and MAVLink `usec` all use.

fn clock_ns(clock: libc::clockid_t) -> u64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `ts` is a valid, writable timespec; both clocks always exist on Linux.
    let rc = unsafe { libc::clock_gettime(clock, &mut ts) };
    if rc != 0 {
        return 0;
    }
    (ts.tv_sec as u64).saturating_mul(1_000_000_000) + ts.tv_nsec as u64
}

/// Now on CLOCK_MONOTONIC, nanoseconds.
pub fn monotonic_now_ns() -> u64 {
    clock_ns(libc::CLOCK_MONOTONIC)
}

/// Now on CLOCK_REALTIME, nanoseconds since the Unix epoch.
pub fn realtime_now_ns() -> u64 {
    clock_ns(libc::CLOCK_REALTIME)
}

/// Converts a CLOCK_REALTIME stamp to CLOCK_MONOTONIC using the current
/// offset between the two clocks.
pub fn realtime_to_monotonic_ns(realtime_ns: u64) -> u64 {
    let mono = monotonic_now_ns();
    let real = realtime_now_ns();
    let age_ns = real.saturating_sub(realtime_ns);
    mono.saturating_sub(age_ns)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn monotonic_never_goes_back_and_conversion_keeps_age() {
        let a = monotonic_now_ns();
        let b = monotonic_now_ns();
        assert!(b >= a);
        let real = realtime_now_ns();
        let converted = realtime_to_monotonic_ns(real - 5_000_000);
        let now = monotonic_now_ns();
        assert!(
            converted <= now - 5_000_000,
            "a 5 ms old stamp is at least 5 ms old"
        );
    }
}
