//! lanealignd: the drift correction daemon. Odometry processes publish poses over iceoryx2 shared
//! memory; one worker per source corrects each client session against a validated lane tile and
//! answers it on the session's own service; every session is journaled so that a killed daemon
//! continues it exactly. See [`daemon::run`] and `configs/lanealignd.toml`.

pub mod config;
pub mod cpu_latency;
pub mod daemon;
pub mod fail_stop;
pub mod grid_loader;
pub mod journal;
pub mod metrics;
pub mod persistence;
pub mod repeat_log;
pub mod served_map;
pub mod session;
pub mod session_watch;
pub mod tile_watch;
pub mod worker;

use std::collections::hash_map::RandomState;
use std::hash::{BuildHasher, Hasher};

/// A fresh random number (from the standard library's per-process random hasher keys, mixed
/// with the clock): daemon epochs and journal folder names.
pub fn new_nonce() -> u64 {
    let mut h = RandomState::new().build_hasher();
    h.write_u64(lanealign_wire::clock::monotonic_ns());
    h.write_u32(std::process::id());
    h.finish()
}
