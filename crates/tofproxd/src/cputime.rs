//! The loop thread's own CPU time (`CLOCK_THREAD_CPUTIME_ID`): what a reading's processing
//! cost the CPU, for the energy account (issue 34: a cheaper sensor reading bought with more
//! computation shows in the energy per reading).

use std::time::Duration;

/// CPU time the calling thread has used so far (zero where the clock is missing).
pub fn thread_cpu() -> Duration {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    #[allow(unsafe_code)]
    // SAFETY: `ts` is a valid, writable `timespec` for the call's duration; clock_gettime
    // writes only into it.
    let rc = unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) };
    if rc != 0 {
        return Duration::ZERO;
    }
    let secs = u64::try_from(ts.tv_sec).unwrap_or(0);
    let nanos = u32::try_from(ts.tv_nsec).unwrap_or(0);
    Duration::new(secs, nanos)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Work on this thread advances its CPU clock by about the work's wall time; sleeping
    /// does not.
    #[test]
    fn counts_this_threads_work_not_its_sleep() {
        let a = thread_cpu();
        std::thread::sleep(Duration::from_millis(50));
        let b = thread_cpu();
        assert!(b - a < Duration::from_millis(20), "sleep: {:?}", b - a);
        // busy until this thread has run 5 ms (on a shared machine that may take longer on
        // the wall clock, never less)
        let start = std::time::Instant::now();
        let mut x = 0u64;
        while thread_cpu() - b < Duration::from_millis(5)
            && start.elapsed() < Duration::from_secs(5)
        {
            x = std::hint::black_box(x.wrapping_mul(31).wrapping_add(7));
        }
        let (c, wall) = (thread_cpu(), start.elapsed());
        assert!(c - b >= Duration::from_millis(5), "work: {:?} ({x})", c - b);
        assert!(
            c - b <= wall + Duration::from_millis(2),
            "{:?} > {wall:?}",
            c - b
        );
    }
}
