//! The daemon: checks the configuration and the tile ([`prepare`], which `lanealignd check`
//! runs too), starts a worker per source and stops if any cannot start, cleans up after dead
//! processes, watches for poses sent to unknown sources, and shuts down cleanly on SIGINT or
//! SIGTERM.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{mpsc, Arc};
use std::time::Duration;

use iceoryx2::node::NodeView;
use iceoryx2::prelude::*;
use lanealign_core::lane_map::LaneMap;
use lanealign_core::tile::{self, TileInfo};
use lanealign_wire::service::{Namespace, NodeCreateError, SourceName};

use crate::config::{Config, ConfigError, ResolvedSource};
use crate::worker::{self, WorkerError, WorkerSummary};

/// How often the supervisor looks for dead nodes and unknown sources.
const SUPERVISION_PERIOD: Duration = Duration::from_millis(500);

/// The daemon could not start.
#[derive(Debug, thiserror::Error)]
pub enum DaemonError {
    /// The configuration is not usable.
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// The tile could not be loaded.
    #[error("{source}{hint}")]
    Tile {
        /// What failed.
        source: tile::TileError,
        /// How to make the tile, when it does not exist.
        hint: String,
    },
    /// The supervisor's node could not be created.
    #[error(transparent)]
    Node(#[from] NodeCreateError),
    /// A worker thread could not be started.
    #[error("starting the worker of source {name}: {error}")]
    Spawn {
        /// The source.
        name: String,
        /// The error.
        error: std::io::Error,
    },
    /// A worker could not set up its ports: the daemon does not run with a source missing.
    #[error(transparent)]
    Worker(#[from] WorkerError),
}

/// A configuration that passed every check, with its tile loaded.
pub struct Prepared {
    /// The configuration.
    pub config: Config,
    /// The configuration file.
    pub path: PathBuf,
    /// The deployment's namespace.
    pub namespace: Namespace,
    /// The sources.
    pub sources: Vec<ResolvedSource>,
    /// The lane map.
    pub map: Arc<LaneMap>,
    /// What the tile says about itself.
    pub tile: TileInfo,
}

/// Reads and checks the configuration, loads and checks the tile against every source: all the
/// rules the daemon applies before it starts. `lanealignd check` is exactly this.
pub fn prepare(path: &Path) -> Result<Prepared, DaemonError> {
    let config = Config::load(path)?;
    let (namespace, sources) = config.resolve(path)?;
    let (map, info) = tile::load(&config.tile).map_err(|source| {
        let hint = match &source {
            tile::TileError::Io { source: io, .. }
                if io.kind() == std::io::ErrorKind::NotFound =>
            {
                format!(
                    "\nmake the tile with `lanealign-map compile INPUT.osm --origin LAT,LON [--projection kitti] -o {}` (README, \"The daemon\")",
                    config.tile.display()
                )
            }
            _ => String::new(),
        };
        DaemonError::Tile { source, hint }
    })?;
    config.check_tile(path, &sources, &info)?;
    Ok(Prepared {
        path: path.to_path_buf(),
        namespace,
        sources,
        map: Arc::new(map),
        tile: info,
        config,
    })
}

/// Removes the resources of nodes in `namespace` whose process died; returns how many.
pub fn remove_dead_nodes(namespace: &Namespace) -> usize {
    let mut removed = 0;
    let listed = Node::<ipc::Service>::list(&namespace.config(), |state| {
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

/// Sources of `namespace` that have a pose service but no configured worker.
fn unknown_sources(namespace: &Namespace, known: &[SourceName]) -> BTreeSet<String> {
    let mut unknown = BTreeSet::new();
    let _ = ipc::Service::list(&namespace.config(), |details| {
        let name = details.static_details.name().to_string();
        if let Some(source) = SourceName::of_odom_service(&name) {
            if !known.contains(&source) {
                unknown.insert(source.to_string());
            }
        }
        CallbackProgression::Continue
    });
    unknown
}

/// Runs until SIGINT or SIGTERM: returns each source's summary. Fails, stopping every worker,
/// if any source's worker cannot start.
pub fn run(prepared: Prepared) -> Result<Vec<(String, WorkerSummary)>, DaemonError> {
    let Prepared {
        config,
        namespace,
        sources,
        map,
        tile: info,
        ..
    } = prepared;
    tracing::info!(
        tile = %config.tile.display(),
        lanes = info.lanes,
        points = info.points,
        namespace = %namespace,
        "tile loaded"
    );
    let cleaned = remove_dead_nodes(&namespace);
    if cleaned > 0 {
        tracing::info!(cleaned, "removed stale resources left by earlier processes");
    }
    let node = namespace.node()?;
    let shutdown = Arc::new(AtomicBool::new(false));
    let interval = Duration::from_secs_f64(config.metrics_interval_s);
    let known: Vec<SourceName> = sources.iter().map(|s| s.name.clone()).collect();
    let (ready_tx, ready_rx) = mpsc::channel();
    let mut workers = Vec::new();
    let mut failure = None;
    for source in sources {
        let (map, shutdown, plane, ns) =
            (map.clone(), shutdown.clone(), info.plane, namespace.clone());
        let name = source.name.to_string();
        let ready = ready_tx.clone();
        match std::thread::Builder::new()
            .name(format!("worker-{name}"))
            .spawn(move || worker::run(source, ns, map, plane, interval, shutdown, ready))
        {
            Ok(handle) => workers.push((name, handle)),
            Err(error) => {
                failure = Some(DaemonError::Spawn { name, error });
                break;
            }
        }
    }
    drop(ready_tx);
    if failure.is_none() {
        for _ in 0..workers.len() {
            match ready_rx.recv() {
                Ok(Ok(())) => {}
                Ok(Err(e)) => {
                    failure = Some(e.into());
                    break;
                }
                Err(_) => break,
            }
        }
    }
    if let Some(e) = failure {
        shutdown.store(true, Ordering::Relaxed);
        for (_, handle) in workers {
            let _ = handle.join();
        }
        return Err(e);
    }
    tracing::info!(sources = workers.len(), "ready");
    let mut refused = BTreeSet::new();
    // node.wait returns an error on SIGINT / SIGTERM: that is the shutdown request.
    while node.wait(SUPERVISION_PERIOD).is_ok() {
        remove_dead_nodes(&namespace);
        for source in unknown_sources(&namespace, &known) {
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
            Ok(summary) => summaries.push((name, summary)),
            Err(_) => tracing::error!(source = %name, "worker panicked"),
        }
    }
    Ok(summaries)
}
