//! `lanealign soak`: many sources at once through one daemon, latency and loss, with and without
//! correction (pass-through measures the iceoryx2 round trip alone), for each wait strategy of
//! the daemon's workers and the clients.

use std::path::Path;
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::Context;
use clap::Args;
use lanealign_cli::daemon_process::DaemonProcess;
use lanealign_cli::replay::{replay, Rate, ReplayError};
use lanealign_cli::synthetic;
use lanealign_cli::{daemon_config, report};
use lanealign_client::Connection;
use lanealign_core::params::{CorrectorConfig, Method, Preset};
use lanealign_core::pose::AxisConvention;
use lanealign_wire::service::Namespace;
use lanealign_wire::wait::WaitStrategy;

use super::percentile_us;

/// The `lanealign soak` arguments.
#[derive(Args)]
pub struct SoakArgs {
    /// Number of sources.
    #[arg(long, default_value_t = 8)]
    sources: usize,
    /// Poses per second per source.
    #[arg(long, default_value_t = 100.0)]
    rate: f64,
    /// Seconds per phase. A phase is one wait strategy with correction or in pass-through, each
    /// with a daemon of its own: the soak takes about 2 x strategies x this.
    #[arg(long, default_value_t = 10.0)]
    duration: f64,
    /// Wait strategies to compare (comma-separated: event, spin-then-block:SPIN_US,
    /// busy-spin[:CORE]), used by the daemon's workers and the clients alike; a core pins the
    /// daemon's worker. A spinning strategy keeps two cores busy per source (worker and client),
    /// so it runs at most one source per two cores of this machine.
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "event,spin-then-block:100,busy-spin"
    )]
    waits: Vec<WaitStrategy>,
    /// Have each phase's daemon ask the kernel to keep every CPU able to run within this many
    /// microseconds (the daemon's `cpu_dma_latency_us`; 0: idle CPUs poll instead of halting).
    /// Needs write access to /dev/cpu_dma_latency.
    #[arg(long)]
    cpu_dma_latency_us: Option<u32>,
}

/// One source's outcome: round trips (ns) of the answered poses, and the poses not answered.
struct SourceResult {
    round_trip_ns: Vec<u64>,
    lost: usize,
}

/// A phase's outcome: per source, and the daemon's resident memory (KiB) after start-up, at each
/// quarter of the phase and at the end.
struct Phase {
    sources: Vec<SourceResult>,
    rss_kib: Vec<u64>,
}

/// Resident memory of process `pid` in KiB (from /proc; 0 where unavailable).
fn rss_kib(pid: u32) -> u64 {
    std::fs::read_to_string(format!("/proc/{pid}/status"))
        .ok()
        .and_then(|s| {
            s.lines()
                .find_map(|l| l.strip_prefix("VmRSS:"))
                .and_then(|v| v.trim().trim_end_matches("kB").trim().parse().ok())
        })
        .unwrap_or(0)
}

/// What one phase runs: how many sources, corrected or passed through, waiting how; `index`
/// tells its sources and files apart from the other phases'.
struct PhaseSpec {
    sources: usize,
    pass_through: bool,
    wait: WaitStrategy,
    index: usize,
}

fn run_phase(
    dir: &Path,
    tile_path: &Path,
    namespace: &Namespace,
    args: &SoakArgs,
    spec: PhaseSpec,
) -> anyhow::Result<Phase> {
    let PhaseSpec {
        sources,
        pass_through,
        wait,
        index,
    } = spec;
    let (rate, duration) = (args.rate, args.duration);
    let tag = format!("{}{index}", if pass_through { "pass" } else { "corr" });
    let names: Vec<String> = (0..sources)
        .map(|k| format!("soak-{}-{tag}-{k}", std::process::id()))
        .collect();
    let config = dir.join(format!("{tag}.toml"));
    let anchor = synthetic::town_anchor();
    let entries: Vec<daemon_config::Source> = names
        .iter()
        .map(|n| daemon_config::Source {
            name: n.clone(),
            corrector: CorrectorConfig::new(Preset::KissIcp, Method::Robust),
            frame: AxisConvention::Flu,
            anchor,
            pass_through,
            wait,
        })
        .collect();
    let mut daemon_config = daemon_config::config(
        tile_path,
        namespace.as_str(),
        5.0,
        &dir.join("state"),
        &entries,
    );
    daemon_config.cpu_dma_latency_us = args.cpu_dma_latency_us;
    daemon_config::write(&config, &daemon_config)?;
    let daemon = DaemonProcess::start_ready(
        &config,
        &dir.join(format!("{tag}.log")),
        Duration::from_secs(20),
    )?;
    let mut rss = vec![rss_kib(daemon.id())];
    let count = (rate * duration).round() as usize;
    let (_, odometry) = synthetic::drive_at_least(count, 7);
    let odometry = Arc::new(odometry);
    let handles: Vec<_> = names
        .into_iter()
        .map(|name| {
            let odometry = odometry.clone();
            let namespace = namespace.clone();
            std::thread::spawn(move || -> anyhow::Result<SourceResult> {
                let mut conn = Connection::connect_in(
                    &namespace,
                    &name.parse()?,
                    lanealign_client::connection::new_session_id(),
                )?;
                conn.set_wait_strategy(wait);
                let poses = &odometry[..count];
                match replay(
                    &mut conn,
                    &name,
                    poses,
                    &[],
                    Rate::Hz(rate),
                    Duration::from_secs(10),
                    Duration::from_secs(10),
                ) {
                    Ok(r) => Ok(SourceResult {
                        round_trip_ns: r.round_trip_ns,
                        lost: 0,
                    }),
                    Err(ReplayError::Lost {
                        missing, partial, ..
                    }) => Ok(SourceResult {
                        round_trip_ns: partial
                            .answers
                            .iter()
                            .map(|a| a.seq as usize - 1)
                            .map(|i| partial.round_trip_ns[i])
                            .collect(),
                        lost: missing.len(),
                    }),
                    Err(e) => Err(e.into()),
                }
            })
        })
        .collect();
    let started = Instant::now();
    for quarter in 1..4 {
        let at = Duration::from_secs_f64(duration * quarter as f64 / 4.0);
        std::thread::sleep(at.saturating_sub(started.elapsed()));
        rss.push(rss_kib(daemon.id()));
    }
    let mut results = Vec::new();
    for h in handles {
        results.push(
            h.join()
                .map_err(|_| anyhow::anyhow!("a soak thread panicked"))??,
        );
    }
    rss.push(rss_kib(daemon.id()));
    let clean = daemon.stop()?;
    anyhow::ensure!(clean, "the daemon did not exit cleanly");
    Ok(Phase {
        sources: results,
        rss_kib: rss,
    })
}

/// Sources a soak runs at most: as many as a daemon serves (each a worker thread of the daemon
/// and a client thread).
const MAX_SOURCES: usize = lanealign_service::config::MAX_SOURCES;
/// Poses a source sends in a phase at most (rate x duration: about 28 hours at 100 Hz). The
/// drive is made before the phase starts and every round trip is kept, so this bounds memory.
const MAX_POSES_PER_SOURCE: f64 = 1e7;

/// Checks the soak's arguments before anything starts, naming the one out of range (a rate of
/// 1e300 asked for an allocation of 8e17 bytes, and 10^5 sources started a daemon that never got
/// ready).
fn check(args: &SoakArgs) -> anyhow::Result<()> {
    let (sources, rate, duration) = (args.sources, args.rate, args.duration);
    anyhow::ensure!(
        (1..=MAX_SOURCES).contains(&sources),
        "--sources {sources}: must be between 1 and {MAX_SOURCES}"
    );
    // A replay's rates (a slower one, with a duration that still gives a pose, overflowed the
    // times of the phase's quarters).
    anyhow::ensure!(
        (Rate::SLOWEST_HZ..=Rate::FASTEST_HZ).contains(&rate),
        "--rate {rate:?}: must be {} to {} Hz",
        Rate::SLOWEST_HZ,
        Rate::FASTEST_HZ
    );
    anyhow::ensure!(
        duration > 0.0 && duration.is_finite(),
        "--duration {duration:?}: must be a positive number of seconds"
    );
    let poses = (rate * duration).round();
    anyhow::ensure!(
        (1.0..=MAX_POSES_PER_SOURCE).contains(&poses),
        "--rate {rate:?} x --duration {duration:?} makes {poses:?} poses per source: must be \
         between 1 and {MAX_POSES_PER_SOURCE:e}"
    );
    anyhow::ensure!(!args.waits.is_empty(), "--waits: name at least one");
    if let Some(twice) = args
        .waits
        .iter()
        .enumerate()
        .find_map(|(i, wait)| args.waits[..i].contains(wait).then_some(wait))
    {
        anyhow::bail!("--waits: {twice} is named twice");
    }
    Ok(())
}

/// Runs the soak and prints the table.
pub fn run(args: &SoakArgs) -> anyhow::Result<()> {
    check(args)?;
    let (sources, rate, duration) = (args.sources, args.rate, args.duration);
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let dir = tempfile::tempdir().context("creating a temporary folder")?;
    let tile_path = dir.path().join("town.tile");
    synthetic::write_town_tile(&tile_path)?;
    // The soak's own iceoryx2 namespace: one per run, its files removed after each phase.
    let namespace = daemon_config::run_namespace("soak", std::process::id())?;
    let latency = args.cpu_dma_latency_us.map_or(String::new(), |us| {
        format!("; CPU wake-up latency {us} us asked of the kernel by each daemon")
    });
    println!("soak: {rate} Hz x {duration} s per phase, synthetic town, kiss-icp; round trip = client send to client receive; {cores} cores{latency}");
    println!("| mode | wait | sources | poses | lost | p50 (us) | p99 (us) | max (us) | daemon memory at start / 25 / 50 / 75 % / end (KiB) |");
    println!("|---|---|---|---|---|---|---|---|---|");
    let mut phase_index = 0;
    for &wait in &args.waits {
        let sources = if wait.spins() {
            sources.min((cores / 2).max(1))
        } else {
            sources
        };
        for pass_through in [false, true] {
            let mode = if pass_through {
                "pass-through (iceoryx2 only)"
            } else {
                "correct"
            };
            phase_index += 1;
            let spinner = report::spinner(format!(
                "phase {phase_index} of {}: {mode}, {wait}, {sources} sources, {duration} s",
                2 * args.waits.len()
            ));
            let spec = PhaseSpec {
                sources,
                pass_through,
                wait,
                index: phase_index,
            };
            let phase = run_phase(dir.path(), &tile_path, &namespace, args, spec);
            spinner.finish_and_clear();
            // The phase's daemon and clients are gone: its namespace files go too.
            if let Err(e) = namespace.remove_files() {
                eprintln!("warning: removing the soak's namespace files: {e}");
            }
            let phase = phase?;
            let mut all: Vec<u64> = Vec::new();
            let mut lost = 0;
            for (k, r) in phase.sources.iter().enumerate() {
                if r.lost > 0 {
                    eprintln!("{mode}, {wait}: source {k} lost {} poses", r.lost);
                }
                all.extend(&r.round_trip_ns);
                lost += r.lost;
            }
            all.sort_unstable();
            let rss: Vec<String> = phase.rss_kib.iter().map(u64::to_string).collect();
            println!(
                "| {mode} | {wait} | {sources} | {} | {lost} | {:.1} | {:.1} | {:.1} | {} |",
                all.len() + lost,
                percentile_us(&all, 0.5),
                percentile_us(&all, 0.99),
                percentile_us(&all, 1.0),
                rss.join(" / ")
            );
        }
    }
    Ok(())
}
