//! `lanealign soak`: many sources at once through one daemon, latency and loss, with and without
//! correction (pass-through measures the iceoryx2 round trip alone).

use std::path::Path;
use std::sync::Arc;
use std::time::Duration;

use anyhow::Context;
use clap::Args;
use lanealign_cli::daemon_config;
use lanealign_cli::daemon_process::DaemonProcess;
use lanealign_cli::replay::{replay, Rate, ReplayError};
use lanealign_cli::synthetic;
use lanealign_client::Connection;
use lanealign_core::params::{CorrectorConfig, Method, Preset};
use lanealign_core::pose::AxisConvention;

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
    /// Seconds per mode.
    #[arg(long, default_value_t = 10.0)]
    duration: f64,
}

/// One source's outcome: round trips (ns) and lost poses.
struct SourceResult {
    round_trip_ns: Vec<u64>,
    lost: usize,
}

fn run_phase(
    dir: &Path,
    tile_path: &Path,
    sources: usize,
    rate: f64,
    duration: f64,
    pass_through: bool,
) -> anyhow::Result<Vec<SourceResult>> {
    let tag = if pass_through { "pass" } else { "corr" };
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
        })
        .collect();
    let namespace = format!("soak-{}", std::process::id());
    daemon_config::write(
        &config,
        &daemon_config::config(tile_path, &namespace, 5.0, &entries),
    )?;
    let daemon = DaemonProcess::start(&config, &dir.join(format!("{tag}.log")))?;
    let (_, odometry) = synthetic::drive(3, 7);
    let odometry = Arc::new(odometry);
    let count = (rate * duration).round() as usize;
    let handles: Vec<_> = names
        .into_iter()
        .map(|name| {
            let odometry = odometry.clone();
            let namespace = namespace.clone();
            std::thread::spawn(move || -> anyhow::Result<SourceResult> {
                let conn = Connection::connect_in(
                    &namespace.parse()?,
                    &name.parse()?,
                    lanealign_client::connection::new_session_id(),
                )?;
                let poses: Vec<_> = (0..count).map(|i| odometry[i % odometry.len()]).collect();
                match replay(
                    &conn,
                    &name,
                    &poses,
                    &[],
                    1,
                    Rate::Hz(rate),
                    Duration::from_secs(10),
                ) {
                    Ok(r) => Ok(SourceResult {
                        round_trip_ns: r.round_trip_ns,
                        lost: 0,
                    }),
                    Err(ReplayError::Lost { missing, .. }) => Ok(SourceResult {
                        round_trip_ns: Vec::new(),
                        lost: missing,
                    }),
                    Err(e) => Err(e.into()),
                }
            })
        })
        .collect();
    let mut results = Vec::new();
    for h in handles {
        results.push(
            h.join()
                .map_err(|_| anyhow::anyhow!("a soak thread panicked"))??,
        );
    }
    let clean = daemon.stop()?;
    anyhow::ensure!(clean, "the daemon did not exit cleanly");
    Ok(results)
}

/// Runs the soak and prints the table.
pub fn run(args: &SoakArgs) -> anyhow::Result<()> {
    let (sources, rate, duration) = (args.sources, args.rate, args.duration);
    anyhow::ensure!(
        sources > 0 && rate > 0.0 && duration > 0.0,
        "sources, rate and duration must be positive"
    );
    let dir = tempfile::tempdir().context("creating a temporary folder")?;
    let tile_path = dir.path().join("town.tile");
    synthetic::write_town_tile(&tile_path)?;
    println!("soak: {sources} sources x {rate} Hz x {duration} s, synthetic town, kiss-icp; round trip = client send to client receive");
    println!("| mode | source | poses | lost | p50 (us) | p99 (us) | max (us) |");
    println!("|---|---|---|---|---|---|---|");
    for pass_through in [false, true] {
        let mode = if pass_through {
            "pass-through (iceoryx2 only)"
        } else {
            "correct"
        };
        let results = run_phase(
            dir.path(),
            &tile_path,
            sources,
            rate,
            duration,
            pass_through,
        )?;
        let mut all: Vec<u64> = Vec::new();
        let mut lost = 0;
        for (k, r) in results.iter().enumerate() {
            let mut v = r.round_trip_ns.clone();
            v.sort_unstable();
            println!(
                "| {mode} | {k} | {} | {} | {:.1} | {:.1} | {:.1} |",
                v.len() + r.lost,
                r.lost,
                percentile_us(&v, 0.5),
                percentile_us(&v, 0.99),
                percentile_us(&v, 1.0)
            );
            all.extend(v);
            lost += r.lost;
        }
        all.sort_unstable();
        println!(
            "| {mode} | **all** | {} | {lost} | {:.1} | {:.1} | {:.1} |",
            all.len() + lost,
            percentile_us(&all, 0.5),
            percentile_us(&all, 0.99),
            percentile_us(&all, 1.0)
        );
    }
    Ok(())
}
