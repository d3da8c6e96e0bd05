//! The clock every timestamp on the wire uses.

/// `CLOCK_MONOTONIC` now, in nanoseconds: comparable across the processes of one machine.
pub fn monotonic_ns() -> u64 {
    let t = rustix::time::clock_gettime(rustix::time::ClockId::Monotonic);
    t.tv_sec as u64 * 1_000_000_000 + t.tv_nsec as u64
}
