//! The clock published with readings: `CLOCK_BOOTTIME`, in nanoseconds — the clock Android
//! stamps sensor events with (`SensorEvent.timestamp`, `SystemClock.elapsedRealtimeNanos`):
//! monotonic, and still counting while the system is suspended, so a client can compare a
//! reading's time with its own `clock_gettime(CLOCK_BOOTTIME)` to measure latency.

/// Now on `CLOCK_BOOTTIME` (ns).
pub fn boottime_ns() -> u64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    #[allow(unsafe_code)]
    // SAFETY: `ts` is a valid, writable `timespec` for the call's duration; clock_gettime
    // writes only into it.
    let rc = unsafe { libc::clock_gettime(libc::CLOCK_BOOTTIME, &mut ts) };
    // CLOCK_BOOTTIME exists on every Linux since 2.6.39; the call cannot fail with a valid
    // pointer, so a failure is a broken system — stamp 0 ("no time") rather than panic.
    if rc != 0 {
        return 0;
    }
    let secs = u64::try_from(ts.tv_sec).unwrap_or(0);
    let nanos = u64::try_from(ts.tv_nsec).unwrap_or(0);
    secs.saturating_mul(1_000_000_000).saturating_add(nanos)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Against an independent reading of the same clock: `/proc/uptime` (seconds since boot,
    /// suspend included, 10 ms resolution) — and never going backwards.
    #[test]
    fn boottime_is_monotone_and_agrees_with_proc_uptime() {
        let a = boottime_ns();
        let uptime_s: f64 = std::fs::read_to_string("/proc/uptime")
            .expect("/proc/uptime")
            .split_whitespace()
            .next()
            .and_then(|s| s.parse().ok())
            .expect("uptime seconds");
        let b = boottime_ns();
        assert!(b >= a, "{a} then {b}");
        let diff_s = (b as f64 * 1e-9 - uptime_s).abs();
        assert!(
            diff_s < 0.05,
            "CLOCK_BOOTTIME {b} ns vs uptime {uptime_s} s"
        );
    }
}
