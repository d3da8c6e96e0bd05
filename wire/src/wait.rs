//! How a thread waits for the next message: the daemon's worker for poses, a client for
//! answers. Blocking on an iceoryx2 event costs a wake-up (tens of microseconds, more when the
//! core has gone idle) but no CPU; polling costs a core but answers within microseconds.

use std::time::{Duration, Instant};

use serde::{Deserialize, Serialize};

/// A wait strategy. In a daemon configuration:
/// `wait = { strategy = "event" }` (the default), `{ strategy = "busy-spin", core = 1 }`,
/// `{ strategy = "spin-then-block", spin_us = 50 }`. On command lines: `event`, `busy-spin`,
/// `busy-spin:CORE`, `spin-then-block:SPIN_US`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(tag = "strategy", rename_all = "kebab-case", deny_unknown_fields)]
pub enum WaitStrategy {
    /// Sleep until a notification arrives: no CPU while idle.
    #[default]
    Event,
    /// Poll without sleeping: the lowest latency, one core busy all the time.
    BusySpin {
        /// Pin the waiting thread to this CPU core (0-based), so that nothing else is
        /// scheduled on its cache; `None` leaves placement to the kernel.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        core: Option<usize>,
    },
    /// Poll for `spin_us` microseconds, then sleep until a notification arrives: low latency
    /// for messages that follow each other closely, no CPU through long pauses.
    SpinThenBlock {
        /// How long to poll before sleeping (microseconds, at most 1 000 000).
        spin_us: u64,
    },
}

/// Longest spin budget accepted (microseconds): beyond a second, block instead.
pub const MAX_SPIN_US: u64 = 1_000_000;

/// The shortest time [`WaitStrategy::wait`] blocks for; with less left it only polls. iceoryx2's
/// socket-based listener passes the time as a socket timeout in whole microseconds, and a
/// timeout that rounds to zero means "wait forever": a spin that ends a few hundred nanoseconds
/// before its deadline hung a client for good (found by the daemon tests, 1 run in many).
pub const MIN_BLOCK: Duration = Duration::from_micros(10);

/// A strategy that cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum WaitError {
    /// The text names no strategy.
    #[error("{0:?}: expected event, busy-spin, busy-spin:CORE or spin-then-block:SPIN_US")]
    Unknown(String),
    /// The spin budget is out of range.
    #[error("spin_us = {0}: must be 1 to {MAX_SPIN_US}")]
    SpinBudget(u64),
    /// No thread of this process may run on the core (it does not exist, or a cpuset keeps
    /// this process off it).
    #[error("core {core}: the kernel lets no thread of this process run there (it runs on cores {running_on} now)")]
    CoreNotAllowed {
        /// The core asked for.
        core: usize,
        /// The cores the asking thread runs on, as ranges (`0-3,6`).
        running_on: String,
    },
    /// The kernel refused to pin the thread.
    #[error("pinning the thread to core {core}")]
    Pin {
        /// The core.
        core: usize,
        /// Why.
        #[source]
        source: std::io::Error,
    },
}

impl std::str::FromStr for WaitStrategy {
    type Err = WaitError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let unknown = || WaitError::Unknown(s.to_string());
        let strategy = match s.split_once(':') {
            None if s == "event" => WaitStrategy::Event,
            None if s == "busy-spin" => WaitStrategy::BusySpin { core: None },
            Some(("busy-spin", core)) => WaitStrategy::BusySpin {
                core: Some(core.parse().map_err(|_| unknown())?),
            },
            Some(("spin-then-block", us)) => WaitStrategy::SpinThenBlock {
                spin_us: us.parse().map_err(|_| unknown())?,
            },
            _ => return Err(unknown()),
        };
        strategy.validate()?;
        Ok(strategy)
    }
}

/// Pins the calling thread to `core`.
fn pin_to(core: usize) -> rustix::io::Result<()> {
    if core >= rustix::thread::CpuSet::MAX_CPU {
        return Err(rustix::io::Errno::INVAL);
    }
    let mut set = rustix::thread::CpuSet::new();
    set.set(core);
    rustix::thread::sched_setaffinity(None, &set)
}

/// The cores in `set`, in order.
fn cores_in(set: &rustix::thread::CpuSet) -> impl Iterator<Item = usize> + '_ {
    (0..rustix::thread::CpuSet::MAX_CPU).filter(|&c| set.is_set(c))
}

/// The cores the calling thread may run on now, as ranges: `0-3,6`.
fn running_on() -> String {
    let Ok(set) = rustix::thread::sched_getaffinity(None) else {
        return "(unknown)".into();
    };
    let mut ranges: Vec<(usize, usize)> = Vec::new();
    for core in cores_in(&set) {
        match ranges.last_mut() {
            Some((_, last)) if *last + 1 == core => *last = core,
            _ => ranges.push((core, core)),
        }
    }
    let text: Vec<String> = ranges
        .iter()
        .map(|&(first, last)| match first == last {
            true => first.to_string(),
            false => format!("{first}-{last}"),
        })
        .collect();
    text.join(",")
}

impl std::fmt::Display for WaitStrategy {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            WaitStrategy::Event => write!(f, "event"),
            WaitStrategy::BusySpin { core: None } => write!(f, "busy-spin"),
            WaitStrategy::BusySpin { core: Some(c) } => write!(f, "busy-spin:{c}"),
            WaitStrategy::SpinThenBlock { spin_us } => write!(f, "spin-then-block:{spin_us}"),
        }
    }
}

impl WaitStrategy {
    /// Checks the spin budget and that a thread can be pinned to the core. The kernel decides,
    /// on a thread made for the try: the cores a process runs on are not the ones it may be
    /// pinned to (`isolcpus` keeps an isolated core out of every process's mask, and that core
    /// is the one to give a spinning worker; `taskset` and `CPUAffinity=` narrow the mask too).
    pub fn validate(&self) -> Result<(), WaitError> {
        match *self {
            WaitStrategy::SpinThenBlock { spin_us } if !(1..=MAX_SPIN_US).contains(&spin_us) => {
                Err(WaitError::SpinBudget(spin_us))
            }
            WaitStrategy::BusySpin { core: Some(core) } => {
                match std::thread::spawn(move || pin_to(core)).join() {
                    Ok(Ok(())) => Ok(()),
                    _ => Err(WaitError::CoreNotAllowed {
                        core,
                        running_on: running_on(),
                    }),
                }
            }
            _ => Ok(()),
        }
    }

    /// Pins the calling thread to the strategy's core, if it names one.
    pub fn pin_current_thread(&self) -> Result<(), WaitError> {
        let WaitStrategy::BusySpin { core: Some(core) } = *self else {
            return Ok(());
        };
        pin_to(core).map_err(|e| WaitError::Pin {
            core,
            source: e.into(),
        })
    }

    /// True when the strategy polls, so the waiter must drain notifications it did not sleep on.
    pub fn spins(&self) -> bool {
        !matches!(self, WaitStrategy::Event)
    }

    /// Waits until `ready()` says a message is there or `timeout` has passed: polls `ready`
    /// for as long as the strategy spins, and otherwise (or after) calls `block` with the time
    /// left, which sleeps until a notification or that time; never with less than
    /// [`MIN_BLOCK`]. Returns `ready()` at the end.
    pub fn wait(
        &self,
        timeout: Duration,
        mut ready: impl FnMut() -> bool,
        block: impl FnOnce(Duration),
    ) -> bool {
        let start = Instant::now();
        let spin = match *self {
            WaitStrategy::Event => Duration::ZERO,
            WaitStrategy::BusySpin { .. } => timeout,
            WaitStrategy::SpinThenBlock { spin_us } => Duration::from_micros(spin_us).min(timeout),
        };
        // Spinning with a budget yields the core between polls: the kernel tends to wake the
        // other side of the exchange on the waker's core, and a spin that kept it would hold
        // that wake-up back for the whole budget (measured: round trips of twice the budget).
        let yields = matches!(self, WaitStrategy::SpinThenBlock { .. });
        if !spin.is_zero() {
            loop {
                if ready() {
                    return true;
                }
                if start.elapsed() >= spin {
                    break;
                }
                if yields {
                    std::thread::yield_now();
                } else {
                    std::hint::spin_loop();
                }
            }
        }
        let left = timeout.saturating_sub(start.elapsed());
        if left >= MIN_BLOCK {
            block(left);
        }
        ready()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A thread that runs on one core (as under `taskset`, `CPUAffinity=` or `isolcpus`) may
    /// still name another core of the machine for a spinning worker, and the message for one it
    /// may not names the cores it runs on. (Counting the cores it runs on refused core 1 from a
    /// thread on core 0 alone: "this machine has cores 0 to 0".)
    #[test]
    fn a_core_outside_the_callers_mask_is_the_kernels_to_refuse() {
        let Ok(mine) = rustix::thread::sched_getaffinity(None) else {
            panic!("sched_getaffinity failed");
        };
        let cores: Vec<usize> = cores_in(&mine).collect();
        if cores.len() < 2 {
            eprintln!(
                "SKIPPED a_core_outside_the_callers_mask_is_the_kernels_to_refuse: needs two cores"
            );
            return;
        }
        let (kept, other) = (cores[0], cores[cores.len() - 1]);
        std::thread::spawn(move || {
            pin_to(kept).unwrap();
            assert_eq!(running_on(), kept.to_string());
            let spin = WaitStrategy::BusySpin { core: Some(other) };
            assert!(
                spin.validate().is_ok(),
                "core {other} from a thread on core {kept}"
            );
            assert_eq!(
                running_on(),
                kept.to_string(),
                "the check pins another thread"
            );
            let far = WaitStrategy::BusySpin { core: Some(4000) };
            let refused = far.validate().unwrap_err().to_string();
            assert!(
                refused.contains(&format!("runs on cores {kept} now")),
                "{refused}"
            );
        })
        .join()
        .unwrap();
    }

    #[test]
    fn parses_prints_and_checks_every_form() {
        for text in ["event", "busy-spin", "busy-spin:0", "spin-then-block:50"] {
            let s: WaitStrategy = text.parse().unwrap();
            assert_eq!(s.to_string(), text);
        }
        assert!(matches!(
            "spin-then-block:0".parse::<WaitStrategy>(),
            Err(WaitError::SpinBudget(0))
        ));
        assert!(matches!(
            "busy-spin:100000".parse::<WaitStrategy>(),
            Err(WaitError::CoreNotAllowed { core: 100000, .. })
        ));
        assert!(matches!(
            "busy-spin:1024".parse::<WaitStrategy>(),
            Err(WaitError::CoreNotAllowed { core: 1024, .. })
        ));
        assert!(matches!(
            "spin".parse::<WaitStrategy>(),
            Err(WaitError::Unknown(_))
        ));
    }

    #[test]
    fn spinning_sees_a_message_without_blocking_and_event_blocks_first() {
        let mut polls = 0;
        let mut blocked = false;
        let busy = WaitStrategy::BusySpin { core: None };
        let got = busy.wait(
            Duration::from_secs(5),
            || {
                polls += 1;
                polls >= 3
            },
            |_| blocked = true,
        );
        assert!(got && !blocked && polls == 3);

        let (mut polls, mut blocked_for) = (0, None);
        // Two seconds: however long the thread is descheduled, some of it is left to block for.
        let got = WaitStrategy::Event.wait(
            Duration::from_secs(2),
            || {
                polls += 1;
                false
            },
            |d| blocked_for = Some(d),
        );
        assert!(!got && polls == 1, "event polls only after blocking");
        assert!(blocked_for.is_some_and(|d| d <= Duration::from_secs(2)));
    }

    /// Bounds that hold however long the thread is descheduled while it spins: the block gets
    /// at most the timeout less the budget, and at least what was left when this test looked
    /// (a window of 40-50 ms failed on a loaded machine).
    #[test]
    fn spin_then_block_blocks_for_what_is_left_after_its_budget() {
        let s = WaitStrategy::SpinThenBlock { spin_us: 200 };
        let timeout = Duration::from_secs(2);
        let mut blocked_for = None;
        let start = Instant::now();
        let got = s.wait(timeout, || false, |d| blocked_for = Some(d));
        let elapsed = start.elapsed();
        assert!(!got);
        assert!(elapsed >= Duration::from_micros(200));
        let left = blocked_for.expect("blocks with most of two seconds left");
        assert!(left <= timeout - Duration::from_micros(200));
        assert!(left + elapsed >= timeout);
    }

    /// A spin that ends just before its deadline leaves less than a socket timeout can say:
    /// it must not block at all (a zero timeout would block forever).
    #[test]
    fn spin_then_block_never_blocks_for_less_than_the_minimum() {
        let s = WaitStrategy::SpinThenBlock { spin_us: 50 };
        let mut blocked_for = None;
        let got = s.wait(
            Duration::from_micros(50) + Duration::from_nanos(500),
            || false,
            |d| blocked_for = Some(d),
        );
        assert!(!got);
        assert_eq!(blocked_for, None);
    }

    #[test]
    fn reads_the_daemon_configuration_form() {
        #[derive(Deserialize)]
        struct Source {
            wait: WaitStrategy,
        }
        let s: Source = toml::from_str("wait = { strategy = \"busy-spin\", core = 1 }").unwrap();
        assert_eq!(s.wait, WaitStrategy::BusySpin { core: Some(1) });
        let s: Source =
            toml::from_str("wait = { strategy = \"spin-then-block\", spin_us = 50 }").unwrap();
        assert_eq!(s.wait, WaitStrategy::SpinThenBlock { spin_us: 50 });
        assert!(toml::from_str::<Source>("wait = { strategy = \"spin\" }").is_err());
    }
}
