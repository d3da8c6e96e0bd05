//! The daemon: loads the tile once, runs a worker per source, cleans up after dead processes,
//! watches for poses sent to unknown sources, and shuts down cleanly on SIGINT/SIGTERM.

use std::collections::BTreeSet;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

use iceoryx2::node::NodeView;
use iceoryx2::prelude::*;
use lanealign_core::tile;

use crate::config::{Config, ResolvedSource};
use crate::worker::{self, WorkerSummary};

/// How often the supervisor looks for dead nodes and unknown sources.
const SUPERVISION_PERIOD: Duration = Duration::from_millis(500);

/// The daemon could not start.
#[derive(Debug, thiserror::Error)]
pub enum DaemonError {
    /// The tile could not be loaded.
    #[error(transparent)]
    Tile(#[from] tile::TileError),
    /// The supervisor's node could not be created.
    #[error("creating the supervisor node failed: {0}")]
    Node(String),
    /// A worker thread could not be started.
    #[error("starting the worker of source {name}: {error}")]
    Spawn {
        /// The source.
        name: String,
        /// The error.
        error: std::io::Error,
    },
}

/// Removes the resources of nodes whose process died; returns how many were cleaned.
pub fn remove_dead_nodes() -> usize {
    let mut removed = 0;
    let listed = Node::<ipc::Service>::list(iceoryx2::config::Config::global_config(), |state| {
        if let NodeState::Dead(view) = state {
            let id = *view.id();
            match view.try_remove_stale_resources() {
                Ok(()) => {
                    removed += 1;
                    tracing::info!(node = ?id, "removed the resources of a dead node");
                }
                Err(e) => {
                    tracing::warn!(node = ?id, error = ?e, "could not remove a dead node's resources")
                }
            }
        }
        CallbackProgression::Continue
    });
    if let Err(e) = listed {
        tracing::warn!(error = ?e, "listing nodes failed");
    }
    removed
}

/// Names of sources that have an odom service but no configured worker.
fn unknown_sources(known: &[String]) -> BTreeSet<String> {
    let mut unknown = BTreeSet::new();
    let _ = ipc::Service::list(iceoryx2::config::Config::global_config(), |details| {
        let name = details.static_details.name().to_string();
        if let Some(source) = name
            .strip_prefix("lanealign/")
            .and_then(|r| r.strip_suffix("/odom"))
        {
            if !known.iter().any(|k| k == source) {
                unknown.insert(source.to_string());
            }
        }
        CallbackProgression::Continue
    });
    unknown
}

/// Runs until SIGINT or SIGTERM: returns each source's summary.
pub fn run(
    config: &Config,
    sources: Vec<ResolvedSource>,
) -> Result<Vec<(String, WorkerSummary)>, DaemonError> {
    let started = std::time::Instant::now();
    let (map, info) = tile::load(&config.tile)?;
    let map = Arc::new(map);
    tracing::info!(
        tile = %config.tile.display(),
        lanes = info.lanes,
        points = info.points,
        load_us = started.elapsed().as_micros() as u64,
        "tile loaded"
    );
    let cleaned = remove_dead_nodes();
    if cleaned > 0 {
        tracing::info!(cleaned, "removed stale resources left by earlier processes");
    }
    let node = NodeBuilder::new()
        .create::<ipc::Service>()
        .map_err(|e| DaemonError::Node(format!("{e:?}")))?;
    let shutdown = Arc::new(AtomicBool::new(false));
    let interval = Duration::from_secs_f64(config.metrics_interval_s);
    let known: Vec<String> = sources.iter().map(|s| s.name.clone()).collect();
    let mut workers = Vec::new();
    for source in sources {
        let (map, shutdown, plane) = (map.clone(), shutdown.clone(), info.plane);
        let name = source.name.clone();
        let handle = std::thread::Builder::new()
            .name(format!("worker-{name}"))
            .spawn(move || worker::run(source, map, plane, interval, shutdown))
            .map_err(|error| DaemonError::Spawn {
                name: name.clone(),
                error,
            })?;
        workers.push((name, handle));
    }
    let mut refused = BTreeSet::new();
    // node.wait returns an error on SIGINT / SIGTERM: that is the shutdown request.
    while node.wait(SUPERVISION_PERIOD).is_ok() {
        remove_dead_nodes();
        for source in unknown_sources(&known) {
            if refused.insert(source.clone()) {
                tracing::warn!(
                    source,
                    refused_sources = refused.len(),
                    "poses sent to a source that is not configured are refused"
                );
            }
        }
        if workers.iter().all(|(_, h)| h.is_finished()) {
            tracing::error!("every worker has stopped");
            break;
        }
    }
    tracing::info!("shutting down");
    shutdown.store(true, Ordering::Relaxed);
    let mut summaries = Vec::new();
    for (name, handle) in workers {
        match handle.join() {
            Ok(Ok(summary)) => summaries.push((name, summary)),
            Ok(Err(e)) => tracing::error!(source = %name, error = %e, "worker failed"),
            Err(_) => tracing::error!(source = %name, "worker panicked"),
        }
    }
    Ok(summaries)
}
