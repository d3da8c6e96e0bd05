//! The clock every timestamp on the wire uses, and the deadlines of waits.

use std::time::{Duration, Instant};

/// `CLOCK_MONOTONIC` now, in nanoseconds: comparable across the processes of one machine.
pub fn monotonic_ns() -> u64 {
    let t = rustix::time::clock_gettime(rustix::time::ClockId::Monotonic);
    t.tv_sec as u64 * 1_000_000_000 + t.tv_nsec as u64
}

/// The instant `timeout` from now; `None` when no instant is that far: a wait of
/// `Duration::MAX` (or of 10^19 s) is a wait without end, where `Instant::now() + timeout`
/// panicked on the overflow.
pub fn deadline_after(timeout: Duration) -> Option<Instant> {
    Instant::now().checked_add(timeout)
}

/// How long is left until `deadline` (zero once it has passed; `Duration::MAX` when there is
/// none, [`deadline_after`]).
pub fn time_left(deadline: Option<Instant>) -> Duration {
    deadline.map_or(Duration::MAX, |d| {
        d.saturating_duration_since(Instant::now())
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_wait_too_long_for_any_instant_has_no_end() {
        assert_eq!(deadline_after(Duration::MAX), None);
        assert_eq!(time_left(deadline_after(Duration::MAX)), Duration::MAX);
        let soon = deadline_after(Duration::from_secs(60));
        assert!(time_left(soon) > Duration::from_secs(59));
        assert!(time_left(soon) <= Duration::from_secs(60));
        assert_eq!(time_left(Some(Instant::now())), Duration::ZERO);
    }
}
